// tt.cpp — teleportation-transport parameters of a grain prototype and of an aggregate
// (Meng et al. 2015's teleportation transport). See tt.h for the contract.
#include "tt.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cfloat>
#include <cmath>

#include "cache.h"
#include "embree_util.h"
#include "error.h"
#include "grain.h"
#include "medium.h"
#include "rng.h"
#include "sampling.h"

namespace granular {

namespace {

constexpr double kFourPi = 4.0 * kPiD;
constexpr double kTwoPi = 2.0 * kPiD;
constexpr int64_t kChunk = 4096;  // rays per chunk: fixed, so results ignore the thread count
constexpr int kMaxBins = 1 << 16;

// ExitMoves' frame: the unit part of ω_o across ω_i (any side where ω_o is along ±ω_i).
// Where the trace writes a move and where the medium reads it back: the same frame.
Vec3 acrossOf(const Vec3& wi, const Vec3& wo) {
  const Vec3 across = wo - wi * dot(wi, wo);
  return length2(across) > 1e-12f ? normalize(across) : Frame(wi).s;
}

int binOf(double mu, int bins) {
  if (!(mu > -1.0)) return 0;  // also NaN
  int b = int((mu + 1.0) * 0.5 * bins);
  return std::min(std::max(b, 0), bins - 1);
}

// Far root of |o + t d| = 1 (d unit), clamped to ≥ 0: where a ray leaves the bounding sphere.
double sphereExit(const Vec3& o, const Vec3& d) {
  double b = double(o.x) * d.x + double(o.y) * d.y + double(o.z) * d.z;
  double c = double(o.x) * o.x + double(o.y) * o.y + double(o.z) * o.z - 1.0;
  double disc = std::max(0.0, b * b - c);
  return std::max(0.0, -b + std::sqrt(disc));
}

// Running sums of one chunk; reduced in chunk order so the totals are reproducible.
struct Sums {
  int64_t rays = 0, hits = 0, truncated = 0;
  double missChord = 0, missChord2 = 0;
  // Per channel, over hits: w (exit energy), w², w d, (w d)², w² d, and the same for μ.
  double w[3] = {}, w2[3] = {}, wd[3] = {}, wd2[3] = {}, w2d[3] = {}, wm[3] = {}, wm2[3] = {}, w2m[3] = {};
  std::vector<double> hist[3];
  std::array<ExitMoves, 3> exits;  // the first kPerBin drawn per bin (tt.h)
  double wIn[3] = {}, wOut[3] = {}, wSq[3] = {};  // w Δ·ω_i, w Δ·ω_o, w |Δ|²

  void add(const Sums& o) {
    rays += o.rays; hits += o.hits; truncated += o.truncated;
    missChord += o.missChord; missChord2 += o.missChord2;
    for (int c = 0; c < 3; ++c) {
      w[c] += o.w[c]; w2[c] += o.w2[c]; wd[c] += o.wd[c]; wd2[c] += o.wd2[c]; w2d[c] += o.w2d[c];
      wm[c] += o.wm[c]; wm2[c] += o.wm2[c]; w2m[c] += o.w2m[c];
      wIn[c] += o.wIn[c]; wOut[c] += o.wOut[c]; wSq[c] += o.wSq[c];
      for (size_t i = 0; i < hist[c].size(); ++i) hist[c][i] += o.hist[c][i];
      for (int b = 0; b < ExitMoves::kBins; ++b) {
        std::vector<Vec3>& m = exits[size_t(c)].moves[size_t(b)];
        const std::vector<Vec3>& om = o.exits[size_t(c)].moves[size_t(b)];
        for (size_t i = 0; i < om.size() && m.size() < size_t(ExitMoves::kPerBin); ++i) m.push_back(om[i]);
      }
    }
  }
};

// Standard error of a plain mean from n samples with sums s, s2.
double meanSE(double s, double s2, int64_t n) {
  if (n < 2) return n == 1 ? std::fabs(s) : 0.0;  // one sample: its own size as the uncertainty
  double m = s / double(n);
  double var = std::max(0.0, (s2 - double(n) * m * m) / double(n - 1));
  return std::sqrt(var / double(n));
}

// Standard error of the ratio estimator r = Σ w x / Σ w (delta method): the sample variance
// of w x − r w, over n hits, divided by n and by the mean weight squared.
double ratioSE(double sw, double sw2, double swx, double swx2, double sw2x, int64_t n) {
  if (n < 2 || !(sw > 0)) return 0.0;
  double r = swx / sw;
  double var = std::max(0.0, (swx2 - 2.0 * r * sw2x + r * r * sw2) / double(n - 1));
  double wbar = sw / double(n);
  return std::sqrt(var / double(n)) / wbar;
}

void traceChunk(RTCScene bvh, const TriangleMesh& mesh, const Material& m, const TTOptions& opt, int64_t chunk,
                Sums& s) {
  int64_t first = chunk * kChunk, count = std::min(kChunk, opt.rays - first);
  for (int64_t k = 0; k < count; ++k) {
    // One generator per ray: ray k enters at the same place for every material (common
    // random numbers), however many numbers the rays before it used.
    Rng rng(hashInts(opt.seed, 0x5454 /* "TT" */, uint64_t(first + k)));
    Vec3 xi, wi;
    sampleSphereEntry(rng, xi, wi);
    const GrainPassage g = traceGrainPassage(bvh, mesh, m, opt.maxBounces, xi, wi, rng);
    const Vec3 &o = g.o, &d = g.d, &w = g.weight;
    const bool hit = g.hit, truncated = g.truncated;
    ++s.rays;
    double tOut = sphereExit(o, d);
    if (!hit) {
      s.missChord += tOut;
      s.missChord2 += tOut * tOut;
      continue;
    }
    ++s.hits;
    if (truncated) ++s.truncated;
    if (isBlack(w)) continue;
    Vec3 xo = o + d * float(tOut);
    double dist = length(xo - xi);
    double mu = std::min(1.0, std::max(-1.0, double(dot(wi, d))));
    int bin = binOf(mu, opt.phaseBins);
    for (int c = 0; c < 3; ++c) {
      double wc = w[c];
      s.w[c] += wc; s.w2[c] += wc * wc;
      s.wd[c] += wc * dist; s.wd2[c] += wc * dist * wc * dist; s.w2d[c] += wc * wc * dist;
      s.wm[c] += wc * mu; s.wm2[c] += wc * mu * wc * mu; s.w2m[c] += wc * wc * mu;
      s.hist[c][bin] += wc;
    }
    // The exit's move (tt.h, ExitMoves), kept per channel with its energy as the chance, by a
    // generator of its own so that the statistics above draw the same numbers as ever.
    const Vec3 dx = xo - xi;
    const Vec3 across = acrossOf(wi, d);
    const Vec3 move(dot(dx, wi), dot(dx, across), dot(dx, cross(wi, across)));
    const int eb = ExitMoves::bin(float(mu));
    Rng pick(hashInts(opt.seed, 0x4558 /* "EX" */, uint64_t(first + k)));
    const double in = dot(dx, wi), out = dot(dx, d), sq = length2(dx);
    for (int c = 0; c < 3; ++c) {
      s.wIn[c] += w[c] * in;
      s.wOut[c] += w[c] * out;
      s.wSq[c] += w[c] * sq;
      std::vector<Vec3>& m = s.exits[size_t(c)].moves[size_t(eb)];
      if (pick.next1D() < w[c] && m.size() < size_t(ExitMoves::kPerBin)) m.push_back(move);
    }
  }
}

// --- cache -------------------------------------------------------------------------------
constexpr RecordMagic kMagic = {'G', 'R', 'T', 'T', '\0', '\0', '\0', '\0'};
constexpr uint32_t kTTFormatVersion = 3;  // 2: one generator per ray; 3: the exits' moves

uint64_t cacheKey(const TriangleMesh& mesh, const Material& m, const TTOptions& o) {
  uint64_t h = hashGrainInputs(hashInts(0x47525454 /* "GRTT" */, kTTFormatVersion), mesh, m);
  h = hashValue(h, o.rays);
  h = hashValue(h, int32_t(o.phaseBins));
  h = hashValue(h, int32_t(o.maxBounces));
  return hashValue(h, o.seed);
}

std::vector<char> serialise(const GrainTransport& g, uint64_t key) {
  RecordWriter w(kMagic);
  w.putHeader(kTTFormatVersion, key);
  for (double v : {g.beta, g.betaSE, g.lambdaDelta, g.lambdaDeltaSE}) w.putF64(v);
  for (const auto* a : {&g.lambdaS, &g.lambdaSSE, &g.albedo, &g.albedoSE, &g.g, &g.gSE, &g.moveIn, &g.moveOut,
                        &g.moveSquared})
    w.putArray(*a);
  w.putI64(g.rays);
  w.putI64(g.truncated);
  w.putI32(int32_t(g.phase[0].bins()));
  for (const PhaseTable& p : g.phase) {
    w.putArray(p.density);
    w.putArray(p.cdf);
    w.putF32(p.g);
  }
  for (const ExitMoves& e : g.exits)
    for (const std::vector<Vec3>& m : e.moves) {
      w.putI32(int32_t(m.size()));
      w.putArray(m);
    }
  return w.finish();
}

bool deserialise(const std::vector<char>& in, uint64_t key, const TTOptions& opt, GrainTransport& g) {
  const int bins = opt.phaseBins;
  RecordReader r(in, kMagic);
  int32_t storedBins = 0;
  if (!r.getHeader(kTTFormatVersion, key)) return false;
  for (double* v : {&g.beta, &g.betaSE, &g.lambdaDelta, &g.lambdaDeltaSE})
    if (!r.getF64(*v)) return false;
  for (auto* a : {&g.lambdaS, &g.lambdaSSE, &g.albedo, &g.albedoSE, &g.g, &g.gSE, &g.moveIn, &g.moveOut,
                  &g.moveSquared})
    if (!r.getArray(*a)) return false;
  if (!r.getI64(g.rays) || !r.getI64(g.truncated) || !r.getI32(storedBins)) return false;
  if (storedBins != bins || g.rays != opt.rays) return false;
  for (PhaseTable& p : g.phase) {
    p.density.resize(bins);
    p.cdf.resize(bins + 1);
    if (!r.getArray(p.density) || !r.getArray(p.cdf) || !r.getF32(p.g)) return false;
    for (float v : p.density)
      if (!std::isfinite(v) || v < 0) return false;
    if (p.cdf.front() != 0.0f || p.cdf.back() != 1.0f || !std::isfinite(p.g)) return false;
    p.buildGuide();
  }
  for (ExitMoves& e : g.exits)
    for (std::vector<Vec3>& m : e.moves) {
      int32_t count = 0;
      if (!r.getI32(count) || count < 0 || count > ExitMoves::kPerBin) return false;
      m.resize(size_t(count));
      if (!r.getArray(m)) return false;
      for (const Vec3& v : m)
        if (!isFinite(v) || length2(v) > 16.0f) return false;  // a move stays within the sphere's diameter
    }
  for (double v : {g.beta, g.betaSE, g.lambdaDelta, g.lambdaDeltaSE})
    if (!std::isfinite(v)) return false;
  for (const auto* a : {&g.lambdaS, &g.lambdaSSE, &g.albedo, &g.albedoSE, &g.g, &g.gSE, &g.moveIn, &g.moveOut,
                        &g.moveSquared})
    for (double v : *a)
      if (!std::isfinite(v)) return false;
  return r.finish();
}

void validateOptions(const TriangleMesh& mesh, const TTOptions& o) {
  if (o.rays < 1) throw InputError("grain transport", "rays", str(o.rays, " is < 1"));
  if (o.phaseBins < 1 || o.phaseBins > kMaxBins)
    throw InputError("grain transport", "phaseBins", str(o.phaseBins, " is outside [1, ", kMaxBins, "]"));
  if (o.maxBounces < 1) throw InputError("grain transport", "maxBounces", str(o.maxBounces, " is < 1"));
  if (mesh.numTriangles() == 0) throw InputError("grain transport", "mesh", "has no triangles");
}

GrainTransport trace(const TriangleMesh& mesh, const Material& m, const TTOptions& opt) {
  EmbreeDevice device = makeEmbreeDevice();
  EmbreeScene bvh = buildTriangleScene(device, mesh);
  const int64_t chunks = (opt.rays + kChunk - 1) / kChunk;
  std::vector<Sums> parts{size_t(chunks)};
  tbb::parallel_for(tbb::blocked_range<int64_t>(0, chunks, 1), [&](const tbb::blocked_range<int64_t>& r) {
    for (int64_t c = r.begin(); c < r.end(); ++c) {
      Sums& s = parts[size_t(c)];
      for (auto& h : s.hist) h.assign(size_t(opt.phaseBins), 0.0);
      traceChunk(bvh.get(), mesh, m, opt, c, s);
    }
  });
  Sums t;
  for (auto& h : t.hist) h.assign(size_t(opt.phaseBins), 0.0);
  for (const Sums& s : parts) t.add(s);

  GrainTransport g;
  g.rays = t.rays;
  g.truncated = t.truncated;
  const int64_t n = t.rays, hits = t.hits, misses = t.rays - t.hits;
  g.beta = double(hits) / double(n);
  g.betaSE = std::sqrt(g.beta * (1.0 - g.beta) / double(n));
  g.lambdaDelta = misses > 0 ? t.missChord / double(misses) : 0.0;
  g.lambdaDeltaSE = meanSE(t.missChord, t.missChord2, misses);
  for (int c = 0; c < 3; ++c) {
    g.albedo[c] = hits > 0 ? t.w[c] / double(hits) : 0.0;
    g.albedoSE[c] = meanSE(t.w[c], t.w2[c], hits);
    if (t.w[c] > 0) {
      g.lambdaS[c] = t.wd[c] / t.w[c];
      g.lambdaSSE[c] = ratioSE(t.w[c], t.w2[c], t.wd[c], t.wd2[c], t.w2d[c], hits);
      g.g[c] = std::min(1.0, std::max(-1.0, t.wm[c] / t.w[c]));
      g.moveIn[c] = t.wIn[c] / t.w[c];
      g.moveOut[c] = t.wOut[c] / t.w[c];
      g.moveSquared[c] = t.wSq[c] / t.w[c];
      g.gSE[c] = ratioSE(t.w[c], t.w2[c], t.wm[c], t.wm2[c], t.w2m[c], hits);
    }  // else no energy exits: λ_s = g = 0 and the table is isotropic (tt.h)
    g.phase[c] = PhaseTable::fromHistogram(t.hist[c]);
  }
  g.exits = std::move(t.exits);
  return g;
}

// The mixture's moves (tt.h, ExitMoves), in the mixture's unit radius: per bin, kPerBin
// of them taken from the kinds in proportion to the energy each sends into the bin (the
// largest remainders get the counts' rest), each kind's scaled by its size.
ExitMoves mixExits(const std::vector<GrainTransport>& kinds, const std::vector<double>& exitWeights,
                   const std::vector<double>& sizes, int c) {
  ExitMoves mix;
  const int K = ExitMoves::kPerBin;
  for (int b = 0; b < ExitMoves::kBins; ++b) {
    const double lo = -1.0 + 2.0 * b / ExitMoves::kBins, hi = -1.0 + 2.0 * (b + 1) / ExitMoves::kBins;
    std::vector<double> share(kinds.size(), 0.0);
    double total = 0;
    for (size_t i = 0; i < kinds.size(); ++i) {
      if (kinds[i].exits[size_t(c)].moves[size_t(b)].empty() || !(exitWeights[i] > 0)) continue;
      share[i] = exitWeights[i] * kinds[i].phase[size_t(c)].mass(lo, hi);
      total += share[i];
    }
    if (!(total > 0)) continue;
    std::vector<int> count(kinds.size(), 0);
    std::vector<std::pair<double, size_t>> rest;
    int given = 0;
    for (size_t i = 0; i < kinds.size(); ++i) {
      const double exact = K * share[i] / total;
      count[i] = int(exact);
      given += count[i];
      rest.push_back({exact - count[i], i});
    }
    std::stable_sort(rest.begin(), rest.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
    for (size_t k = 0; given < K && k < rest.size(); ++k, ++given) ++count[rest[k].second];
    std::vector<Vec3>& out = mix.moves[size_t(b)];
    for (size_t i = 0; i < kinds.size(); ++i) {
      const std::vector<Vec3>& m = kinds[i].exits[size_t(c)].moves[size_t(b)];
      for (int k = 0; k < count[i]; ++k) out.push_back(m[size_t(k) % m.size()] * float(sizes[i]));
    }
  }
  return mix;
}

float clampToFloat(double v) { return float(std::min(std::max(v, 0.0), double(FLT_MAX))); }

}  // namespace

uint64_t hashGrainInputs(uint64_t h, const TriangleMesh& mesh, const Material& m) {
  h = hashBytes(h, mesh.points.data(), mesh.points.size() * sizeof(Vec3));
  h = hashBytes(h, mesh.indices.data(), mesh.indices.size() * sizeof(uint32_t));
  h = hashValue(h, int32_t(m.type));
  h = hashValue(h, m.albedo);
  h = hashValue(h, m.ior);
  h = hashValue(h, m.absorption);
  if (m.alpha > 0) {  // smooth grains keep their cached entries
    h = hashValue(h, m.alpha);
    h = hashBytes(h, m.validTable.data(), m.validTable.size() * sizeof(float));
  }
  return h;
}

void sampleSphereEntry(Rng& rng, Vec3& xi, Vec3& wi) {
  // Uniform over the projected area: a uniform point on the sphere, entering along an
  // inward cosine-weighted direction.
  xi = sampleUniformSphere(rng.next1D(), rng.next1D());
  float u1 = rng.next1D(), u2 = rng.next1D();
  wi = Frame(-xi).toWorld(sampleCosineHemisphere(u1, u2));
}

GrainPassage traceGrainPassage(RTCScene bvh, const TriangleMesh& mesh, const Material& m, int maxBounces,
                               const Vec3& xi, const Vec3& wi, Rng& rng) {
  const bool absorbs = m.type == MaterialType::Dielectric && !isBlack(m.absorption);
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  GrainPassage g;
  Vec3 o = xi, d = wi, w(1.0f);
  int bounces = 0;
  for (;;) {
    RTCRayHit rh = makeRayHit(o, d, 0.0f, kInf);
    rtcIntersect1(bvh, &ctx, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) break;
    g.hit = true;
    if (++bounces > maxBounces) { g.truncated = true; w = Vec3(0.0f); break; }
    float t = rh.ray.tfar;
    Vec3 p = o + d * t;
    Vec3 ng = triangleNormal(mesh, rh.hit.primID);
    // Beer–Lambert over the segment just travelled inside (absorption per grain radius).
    if (absorbs && dot(d, ng) > 0) w *= vexp(m.absorption * -t);
    Frame frame(ng);
    BsdfSample bs;
    float uLobe = rng.next1D(), v1 = rng.next1D(), v2 = rng.next1D();
    if (!m.sample(frame.toLocal(-d), uLobe, v1, v2, bs)) { w = Vec3(0.0f); break; }
    w *= bs.weight;
    d = normalize(frame.toWorld(bs.wi));
    o = offsetRayOrigin(p, ng, d, kGrainEps);
    if (isBlack(w)) break;  // all energy absorbed: where it would leave no longer matters
  }
  g.o = o;
  g.d = d;
  g.weight = w;
  return g;
}

// --- PhaseTable -------------------------------------------------------------------------

float PhaseTable::eval(float mu) const {
  if (density.empty()) return float(1.0 / kFourPi);
  return density[size_t(binOf(mu, bins()))];
}

double PhaseTable::mass(double a, double b) const {
  if (density.empty()) return std::max(0.0, std::min(b, 1.0) - std::max(a, -1.0)) * 0.5;
  // The cdf is piecewise linear in μ: interpolate it at both ends.
  auto cdfAt = [&](double mu) {
    double x = (std::min(std::max(mu, -1.0), 1.0) + 1.0) * 0.5 * bins();
    int i = std::min(int(x), bins() - 1);
    return double(cdf[i]) + (x - i) * (double(cdf[i + 1]) - double(cdf[i]));
  };
  return b > a ? cdfAt(b) - cdfAt(a) : 0.0;
}

Vec3 PhaseTable::sample(const Vec3& wi, float u1, float u2, float* pdf) const {
  float mu;
  if (density.empty()) {
    mu = 1.0f - 2.0f * u1;
    if (pdf) *pdf = float(1.0 / kFourPi);
  } else {
    // Largest i with cdf[i] <= u1: a bin of non-zero mass (u1 < 1 = cdf[bins]).
    int lo = 0;
    if (!guide.empty()) {
      lo = guidedBin(cdf.data(), bins(), guide.data(), bins(), u1);
    } else {
      int hi = bins() - 1;
      while (lo < hi) {
        int mid = (lo + hi + 1) / 2;
        if (cdf[mid] <= u1) lo = mid; else hi = mid - 1;
      }
    }
    float width = cdf[lo + 1] - cdf[lo];
    float du = width > 0 ? (u1 - cdf[lo]) / width : 0.5f;
    du = std::min(std::max(du, 1e-4f), 1.0f - 1e-4f);
    mu = -1.0f + 2.0f * (float(lo) + du) / float(bins());
    if (pdf) *pdf = density[lo];
  }
  float sinT = std::sqrt(std::max(0.0f, 1.0f - mu * mu)), phi = 2.0f * kPi * u2;
  return normalize(Frame(wi).toWorld(Vec3(sinT * std::cos(phi), sinT * std::sin(phi), mu)));
}

PhaseTable PhaseTable::isotropic(int bins) {
  return fromHistogram(std::vector<double>(size_t(std::max(bins, 1)), 1.0));
}

PhaseTable PhaseTable::fromHistogram(const std::vector<double>& weights) {
  const int n = std::max(int(weights.size()), 1);
  std::vector<double> w(size_t(n), 0.0);
  double total = 0;
  for (size_t i = 0; i < weights.size(); ++i) {
    w[i] = std::isfinite(weights[i]) && weights[i] > 0 ? weights[i] : 0.0;
    total += w[i];
  }
  if (!(total > 0)) {
    std::fill(w.begin(), w.end(), 1.0);
    total = n;
  }
  PhaseTable p;
  p.density.resize(size_t(n));
  p.cdf.resize(size_t(n) + 1);
  const double dmu = 2.0 / n;
  double acc = 0, g = 0;
  p.cdf[0] = 0;
  for (int i = 0; i < n; ++i) {
    double pi = w[size_t(i)] / total;
    p.density[size_t(i)] = float(pi / (kTwoPi * dmu));  // 2π ∫ p dμ = 1
    acc += pi;
    p.cdf[size_t(i) + 1] = float(std::min(acc, 1.0));
    g += pi * (-1.0 + (i + 0.5) * dmu);
  }
  p.cdf[size_t(n)] = 1.0f;
  p.g = float(std::min(1.0, std::max(-1.0, g)));
  p.buildGuide();
  return p;
}

void PhaseTable::buildGuide() {
  guide.assign(size_t(bins()) + 1, 0);
  cdfGuide(cdf.data(), bins(), bins(), guide.data());
}

// --- estimation -------------------------------------------------------------------------

bool ExitMoves::empty() const {
  for (const std::vector<Vec3>& m : moves)
    if (!m.empty()) return false;
  return true;
}

Vec3 ExitMoves::sample(const Vec3& wi, const Vec3& wo, float u) const {
  const std::vector<Vec3>& m = moves[size_t(bin(dot(wi, wo)))];
  if (m.empty()) return Vec3(0.0f);
  const Vec3 across = acrossOf(wi, wo);
  const Vec3& x = m[std::min(m.size() - 1, size_t(u * float(m.size())))];
  return wi * x.x + across * x.y + cross(wi, across) * x.z;
}

std::string grainTransportCacheName(const TriangleMesh& mesh, const Material& material, const TTOptions& options) {
  return str("tt-v", kTTFormatVersion, "-", std::hex, cacheKey(mesh, material, options), ".bin");
}

GrainTransport estimateGrainTransport(const TriangleMesh& mesh, const Material& material, const TTOptions& options) {
  validateOptions(mesh, options);
  if (!options.useCache) return trace(mesh, material, options);
  const uint64_t key = cacheKey(mesh, material, options);
  const std::string name = grainTransportCacheName(mesh, material, options);
  std::vector<char> bytes;
  GrainTransport g;
  if (readCacheFile(name, bytes) && deserialise(bytes, key, options, g)) {
    g.fromCache = true;
    return g;
  }
  g = trace(mesh, material, options);  // absent or corrupt: recompute and rewrite
  writeCacheFile(name, serialise(g, key));
  return g;
}

// --- medium -----------------------------------------------------------------------------

MediumParams deriveMedium(const std::vector<GrainTransport>& prototypes, const std::vector<float>& weights,
                          float grainRadius, float packingRate) {
  return deriveMedium(prototypes, weights, std::vector<float>(prototypes.size(), 1.0f), grainRadius, packingRate);
}

MediumParams deriveMedium(const std::vector<GrainTransport>& prototypes, const std::vector<float>& weights,
                          const std::vector<float>& sizes, float grainRadius, float packingRate, double sauterSize) {
  const char* obj = "medium";
  if (prototypes.empty()) throw InputError(obj, "prototypes", "no grain prototypes");
  if (weights.size() != prototypes.size())
    throw InputError(obj, "weights", str(weights.size(), " weights for ", prototypes.size(), " prototypes"));
  double wsum = 0;
  for (float w : weights) {
    if (!(std::isfinite(w) && w >= 0)) throw InputError(obj, "weights", str(w, " is not a finite weight >= 0"));
    wsum += w;
  }
  if (!(wsum > 0)) throw InputError(obj, "weights", "all weights are zero");
  if (sizes.size() != prototypes.size())
    throw InputError(obj, "sizes", str(sizes.size(), " sizes for ", prototypes.size(), " prototypes"));
  for (float x : sizes)
    if (!(std::isfinite(x) && x > 0)) throw InputError(obj, "sizes", str(x, " is not a finite size > 0"));
  if (!(std::isfinite(grainRadius) && grainRadius > 0))
    throw InputError(obj, "grainRadius", str(grainRadius, " is not > 0"));
  if (!(packingRate > 0 && packingRate <= 0.64f))
    throw InputError(obj, "packingRate", str(packingRate, " is outside (0, 0.64]"));

  // Mixture rules of tt.h: a sphere holds prototype i with probability n_i (by number); a
  // flight meets it with probability w_i = n_i s_i² / Σ n s² (its cross-section), and its
  // lengths scale with s_i.
  const size_t np = prototypes.size();
  std::vector<double> w(np), sz(np);
  double area = 0, volume = 0;
  for (size_t i = 0; i < np; ++i) {
    sz[i] = sizes[i];
    area += weights[i] / wsum * sz[i] * sz[i];
    volume += weights[i] / wsum * sz[i] * sz[i] * sz[i];
  }
  for (size_t i = 0; i < np; ++i) w[i] = weights[i] / wsum * sz[i] * sz[i] / area;
  GrainTransport mix;
  double missW = 0, betaVar = 0, deltaVar = 0;
  mix.beta = 0;
  for (size_t i = 0; i < np; ++i) {
    const GrainTransport& p = prototypes[i];
    double b = std::min(1.0, std::max(0.0, p.beta));
    mix.beta += w[i] * b;
    betaVar += std::pow(w[i] * p.betaSE, 2);
    missW += w[i] * (1.0 - b);
    mix.lambdaDelta += w[i] * (1.0 - b) * p.lambdaDelta * sz[i];
    deltaVar += std::pow(w[i] * (1.0 - b) * p.lambdaDeltaSE * sz[i], 2);
    mix.rays += p.rays;
    mix.truncated += p.truncated;
  }
  mix.betaSE = std::sqrt(betaVar);
  if (missW > 0) {
    mix.lambdaDelta /= missW;
    mix.lambdaDeltaSE = std::sqrt(deltaVar) / missW;
  } else {
    mix.lambdaDelta = 0;  // every ray hits: no misses to average
  }
  int bins = 1;
  for (const GrainTransport& p : prototypes)
    for (const PhaseTable& t : p.phase) bins = std::max(bins, t.bins());
  for (int c = 0; c < 3; ++c) {
    double hitW = 0, exitW = 0, aVar = 0, sVar = 0, gVar = 0;
    double a = 0, ls = 0, g = 0;
    std::vector<double> hist(size_t(bins), 0.0);
    for (size_t i = 0; i < np; ++i) {
      const GrainTransport& p = prototypes[i];
      double b = std::min(1.0, std::max(0.0, p.beta));
      double alpha = std::min(1.0, std::max(0.0, p.albedo[c]));
      double hw = w[i] * b, ew = hw * alpha;
      hitW += hw;
      a += hw * alpha;
      aVar += std::pow(hw * p.albedoSE[c], 2);
      exitW += ew;
      ls += ew * p.lambdaS[c] * sz[i];
      sVar += std::pow(ew * p.lambdaSSE[c] * sz[i], 2);
      g += ew * p.g[c];
      gVar += std::pow(ew * p.gSE[c], 2);
      mix.moveIn[c] += ew * p.moveIn[c] * sz[i];
      mix.moveOut[c] += ew * p.moveOut[c] * sz[i];
      mix.moveSquared[c] += ew * p.moveSquared[c] * sz[i] * sz[i];
      if (ew > 0)
        for (int j = 0; j < bins; ++j)
          hist[size_t(j)] += ew * p.phase[c].mass(-1.0 + 2.0 * j / bins, -1.0 + 2.0 * (j + 1) / bins);
    }
    if (hitW > 0) {
      mix.albedo[c] = a / hitW;
      mix.albedoSE[c] = std::sqrt(aVar) / hitW;
    }
    if (exitW > 0) {
      mix.lambdaS[c] = ls / exitW;
      mix.lambdaSSE[c] = std::sqrt(sVar) / exitW;
      mix.g[c] = std::min(1.0, std::max(-1.0, g / exitW));
      mix.gSE[c] = std::sqrt(gVar) / exitW;
      mix.moveIn[c] /= exitW;
      mix.moveOut[c] /= exitW;
      mix.moveSquared[c] /= exitW;
    }
    mix.phase[c] = PhaseTable::fromHistogram(hist);  // all zero → isotropic
    std::vector<double> exitWeights(np);
    for (size_t i = 0; i < np; ++i)
      exitWeights[i] = w[i] * std::min(1.0, std::max(0.0, prototypes[i].beta)) *
                       std::min(1.0, std::max(0.0, prototypes[i].albedo[c]));
    mix.exits[size_t(c)] = mixExits(prototypes, exitWeights, sz, c);
  }

  MediumParams mp;
  mp.grainRadius = grainRadius;
  mp.packingRate = packingRate;
  const double R = grainRadius, f = packingRate;
  // Dixmier 1978: σ_b = S_v / (4(1−f)), S_v the spheres' area per
  // volume, 3f/R for equal spheres; of mixed sizes 3f/(R s_32), s_32 = Σ n s³ / Σ n s² the
  // Sauter mean size (the stereological mean chord 4 V/S of the space between spheres).
  const double s32 = sauterSize > 0 ? sauterSize : volume / area;
  const double sigmaB = 3.0 / (4.0 * R * s32) * f / (1.0 - f);
  const double lambdaB = 1.0 / sigmaB;
  mp.sigmaB = float(sigmaB);
  // λ_β = λ_b + (λ_b + λ_δ)(1−β)/β ; "never" (FLT_MAX) when no ray hits.
  const double lambdaBeta = mix.beta > 0 ? lambdaB + (lambdaB + R * mix.lambdaDelta) * (1.0 - mix.beta) / mix.beta
                                         : double(FLT_MAX);
  const bool empty = !(mix.beta > 0);  // f → 0 needs no branch: the lengths clamp to FLT_MAX
  for (int c = 0; c < 3; ++c) {
    double alpha = mix.albedo[c], g = mix.g[c];
    if (empty) {
      mp.lambdaBeta[c] = mp.lambdaT[c] = FLT_MAX;
      mp.sigmaT[c] = mp.sigmaA[c] = mp.sigmaSReduced[c] = mp.sigmaTReduced[c] = mp.sigmaTr[c] = 0;
      mp.albedo[c] = mp.albedoReduced[c] = 1;
      mp.g[c] = float(g);
      continue;
    }
    double lambdaT = lambdaBeta + alpha * R * mix.lambdaS[c];  // λ_t = λ_β + α_s λ_s (Meng et al. 2015)
    double sigmaT = 1.0 / lambdaT;
    double sigmaSr = (1.0 - g) * alpha * sigmaT;               // Jensen et al. 2001
    double sigmaA = (1.0 - alpha) * sigmaT;
    double sigmaTr = sigmaSr + sigmaA;
    mp.lambdaBeta[c] = clampToFloat(lambdaBeta);
    mp.lambdaT[c] = clampToFloat(lambdaT);
    mp.sigmaT[c] = clampToFloat(sigmaT);
    mp.albedo[c] = float(alpha);
    mp.g[c] = float(g);
    mp.sigmaSReduced[c] = clampToFloat(sigmaSr);
    mp.sigmaTReduced[c] = clampToFloat(sigmaTr);
    mp.albedoReduced[c] = sigmaTr > 0 ? float(sigmaSr / sigmaTr) : float(alpha);  // tt.h: σ'_t = 0 → α_s
    mp.sigmaA[c] = clampToFloat(sigmaA);
    mp.sigmaTr[c] = clampToFloat(std::sqrt(3.0 * sigmaA * sigmaTr));  // Jensen et al. 2001
  }
  mp.phase = mix.phase;
  mp.combined = mix;
  return mp;
}

MediumParams exitsDiffusionMedium(const MediumParams& p) {
  MediumParams d = p;
  const double R = p.grainRadius;
  for (int c = 0; c < 3; ++c) {
    const double g = p.phase[size_t(c)].g, alpha = p.albedo[c];  // the table's g: what the walk samples
    if (p.combined.exits[size_t(c)].empty() || !(p.lambdaBeta[c] < FLT_MAX) || !(g < 1.0 - 1e-6) || !(R > 0))
      continue;
    const double L = double(kExitFlight) * p.lambdaBeta[c];
    const double in = R * p.combined.moveIn[c], out = R * p.combined.moveOut[c];
    const double step2 = R * R * p.combined.moveSquared[c] + 2.0 * L * out + 2.0 * L * L;
    const double M = step2 + 2.0 * (in + L * g) * (out + L) / (1.0 - g);
    if (!(M > 0)) continue;
    const double sigmaT = std::sqrt(2.0 / (M * (1.0 - g)));
    const double sigmaSr = (1.0 - g) * alpha * sigmaT, sigmaA = (1.0 - alpha) * sigmaT, sigmaTr = sigmaSr + sigmaA;
    d.sigmaT[c] = clampToFloat(sigmaT);
    d.lambdaT[c] = clampToFloat(1.0 / sigmaT);
    d.sigmaSReduced[c] = clampToFloat(sigmaSr);
    d.sigmaTReduced[c] = clampToFloat(sigmaTr);
    d.albedoReduced[c] = sigmaTr > 0 ? float(sigmaSr / sigmaTr) : float(alpha);
    d.sigmaA[c] = clampToFloat(sigmaA);
    d.sigmaTr[c] = clampToFloat(std::sqrt(3.0 * sigmaA * sigmaTr));
  }
  return d;
}

MediumParams aggregateMedium(const std::vector<const TriangleMesh*>& prototypeMeshes,
                             const std::vector<Material>& materials, const AggregateDesc& desc, double sauterSize,
                             const TTOptions& options) {
  static const double kNodes[3] = {-0.7745966692414834, 0.0, 0.7745966692414834};
  static const double kNodeWeights[3] = {5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0};
  const bool spread = desc.sizeSpread > 0;
  std::vector<GrainTransport> kinds;
  std::vector<float> weights, sizes;
  for (size_t i = 0; i < prototypeMeshes.size(); ++i)
    for (int q = spread ? 0 : 1; q < (spread ? 3 : 2); ++q) {
      const double size = (desc.sizes.empty() ? 1.0 : desc.sizes[i]) * (1.0 + desc.sizeSpread * kNodes[q]);
      Material m = materials[i];
      m.absorption = m.absorption * float(size);  // absorption is per R: a larger grain absorbs more across
      kinds.push_back(estimateGrainTransport(*prototypeMeshes[i], m, options));
      weights.push_back(float(desc.weights[i] * (spread ? kNodeWeights[q] : 1.0)));
      sizes.push_back(float(size));
    }
  return deriveMedium(kinds, weights, sizes, desc.grainRadius, desc.packingRate, sauterSize);
}

}  // namespace granular
