// switching.cpp — the medium's bias after k proxy visits, measured (see switching.h).
#include "switching.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>

#include <tbb/parallel_for.h>

#include "cache.h"
#include "error.h"
#include "rng.h"
#include "sampling.h"

namespace granular {

namespace {

constexpr int kMaxWalkEvents = 1 << 14;  // a walk longer than this ends (roulette ends them far sooner)
constexpr int kRouletteAfter = 3;        // grain visits or medium scatterings before roulette
constexpr int kPathsPerBlock = 64;
// Paths between two looks at the decision: kFirstBatch, kFirstBatch, 2 kFirstBatch, then
// kBatch. The first looks come early so that a measurement that cannot settle within its
// budget (long walks in nearly clear grains) learns it after a few hundred paths.
constexpr int64_t kFirstBatch = 1 << 9, kBatch = 1 << 11;
int64_t batchAfter(int64_t done) { return done < kBatch ? std::max(kFirstBatch, done) : kBatch; }
// A candidate beyond the tolerance by this many standard errors stops forking (switching.h):
// a true bias within the tolerance shows beyond it by 3 s.e. in a channel with a chance of
// 0.13%.
constexpr double kDecided = 3.0;
// A candidate whose standard error, scaled to the most paths left, still exceeds the
// precision asked by this factor is out of reach (switching.h); the margin covers the
// noise of a standard error estimated from a few thousand paths.
constexpr double kOutOfReach = 1.25;

// Per-channel sums in double (millions of samples).
struct D3 {
  double v[3] = {0, 0, 0};
  D3() = default;
  explicit D3(const Vec3& x) : v{x.x, x.y, x.z} {}
  D3& operator+=(const D3& o) {
    for (int c = 0; c < 3; ++c) v[c] += o.v[c];
    return *this;
  }
  D3 squared() const {
    D3 s;
    for (int c = 0; c < 3; ++c) s.v[c] = v[c] * v[c];
    return s;
  }
};

struct Sums {
  D3 a, a2;  // A∞ samples
  D3 d[kSwitchCandidates], d2[kSwitchCandidates];
  D3 ea[kSwitchExitBins];  // S_K per exit bin
  D3 ed[kSwitchCandidates][kSwitchExitBins], ed2[kSwitchCandidates][kSwitchExitBins];
  int64_t events = 0;  // walk steps taken (the measurement's cost)
  int64_t forkEvents[kSwitchCandidates] = {};  // those of each candidate's forks
  void add(const Sums& o) {
    events += o.events;
    for (int c = 0; c < kSwitchCandidates; ++c) forkEvents[c] += o.forkEvents[c];
    a += o.a;
    a2 += o.a2;
    for (int j = 0; j < kSwitchExitBins; ++j) ea[j] += o.ea[j];
    for (int c = 0; c < kSwitchCandidates; ++c) {
      d[c] += o.d[c];
      d2[c] += o.d2[c];
      for (int j = 0; j < kSwitchExitBins; ++j) {
        ed[c][j] += o.ed[c][j];
        ed2[c][j] += o.ed2[c][j];
      }
    }
  }
};

// Russian roulette on a walk's weight: false ends it; else the weight is divided by the
// survival chance (unbiased).
bool survive(Vec3& w, Rng& rng) {
  const float q = std::min(1.0f, maxComponent(w));
  if (q >= 1.0f) return true;
  if (!(q > 0) || rng.next1D() >= q) return false;
  w /= q;
  return true;
}

// The exit bins (switching.h) of a path that entered at a point of outward normal n along
// d: the exit direction's cosine from n against kSwitchExitCos, and its side — back toward
// where the path came in from (the entry direction reversed, in the tangent plane) or not.
struct ExitBins {
  Vec3 n, back;
  ExitBins(const Vec3& normal, const Vec3& d) : n(normal) {
    back = -d - n * dot(-d, n);
    back = length2(back) > 1e-12f ? normalize(back) : Frame(n).s;  // entered along the normal: any side
  }
  int bin(const Vec3& w) const { return switchExitBin(dot(w, n), dot(w, back) >= 0); }
};

// The flight's weight at a scattering at t (vpt.h: α σ_t T(t) / p(t)); the point moves there.
void flyTo(const HomogeneousMedium& med, float t, Vec3& o, const Vec3& d, Vec3& w) {
  w *= med.transmittance(t) * med.sigmaT() * med.albedo() / med.distancePdf(t);
  o = o + d * t;
}

// The next direction, by the phase function.
bool scatter(const HomogeneousMedium& med, Vec3& d, Vec3& w, Rng& rng) {
  Vec3 weight;
  float pdf;
  const float uc = rng.next1D(), u1 = rng.next1D(), u2 = rng.next1D();
  d = normalize(med.samplePhase(d, uc, u1, u2, weight, pdf));
  w *= weight;
  return isFinite(w);
}

// Light as the dome measurement sees it: a uniform white dome, scored where paths leave.
struct WhiteDome {
  Vec3 escaped(const Vec3&) const { return Vec3(1.0f); }
  Vec3 atProxy(const GrainHit&, const ProxyTable&, const ProxyFrame&, int, Rng&, Vec3&) const { return Vec3(0.0f); }
  Vec3 atScatter(const Vec3&, const Vec3&, Rng&) const { return Vec3(0.0f); }
};

// The energy (or, with a lighting policy of lights, the radiance) a walk in the equivalent
// medium carries out of the boundary, from o along d (vpt.h's flight and phase sampling;
// the boundary index-matched, so a ray that leaves may enter again where the boundary is
// concave); exitBin gets the bin it leaves in. In the exits model it takes over from the
// grain `from` as the renderer's medium does (vpt.h: enterMedia): its first flight is the
// packing's, to the next grain met.
template <typename Lighting>
Vec3 mediumEscape(const Aggregate& agg, const ProxyTables& tables, const HomogeneousMedium& med,
                  const Lighting& light, const ExitBins& bins, const GrainHit& from, Vec3 o, Vec3 d, int& exitBin,
                  Rng& rng, int64_t& events) {
  const float eps = 1e-4f * agg.grainRadius();
  bool inside = agg.insideBoundary(o);
  // The packing's flight (vpt.h: enterMedia): the grain it meets at grainT, past the
  // boundary too (a grain of the surface layer standing out of it); none: kInf.
  bool atGrain = med.movesLight() && inside;
  float grainT = kInf;
  if (atGrain) {
    const GrainFlight f = agg.flightToGrain(o, d, tables, &from, rng);
    grainT = f.t;
    events += f.steps;
  }
  Vec3 w(1.0f), gathered(0.0f);
  for (int event = 0; event < kMaxWalkEvents; ++event) {
    ++events;
    float tb;
    Vec3 ng;
    if (!inside) {
      const bool enters = agg.intersectBoundary(o, d, eps, kInf, tb, ng);
      if (!atGrain || (enters && tb < grainT) || !std::isfinite(grainT)) {
        atGrain = false;
        if (!enters) {  // out, for good
          exitBin = bins.bin(d);
          return gathered + w * light.escaped(d);
        }
        o = o + d * tb;
        inside = true;
        continue;
      }
    }
    // Deep inside, a flight shorter than half the distance field's depth cannot reach
    // the boundary: no ray query (most events of a long walk in nearly clear grains).
    const float t = atGrain ? grainT : med.sampleDistance(rng.next1D(), rng.next1D());
    if (inside && !(t < -0.5f * agg.boundaryDistance(o))) {
      if (!agg.intersectBoundary(o, d, eps, kInf, tb, ng)) return gathered;  // a leak: the renderer ends it
      if (t >= tb) {
        if (atGrain)
          grainT -= tb;  // the packing's flight holds on past the boundary
        else
          w *= med.transmittance(tb) / med.survivalProbability(tb);
        o = o + d * tb;
        inside = false;
        continue;
      }
    }
    if (atGrain) {  // a grain met: its albedo (the flight is the packing's own chance)
      w *= med.albedo();
      o = o + d * t;
      atGrain = false;
    } else {
      flyTo(med, t, o, d, w);
    }
    gathered += w * light.atScatter(o, d, rng);
    const Vec3 wi = d;
    if (!scatter(med, d, w, rng)) return gathered;
    if (med.movesLight()) {  // the exits model (vpt.h): on from where the grain lets the light out
      o = o + med.exitMove(wi, d, rng.next1D(), rng.next1D());
      inside = agg.insideBoundaryFast(o);
    }
    if (event >= kRouletteAfter && !survive(w, rng)) return gathered;
  }
  return gathered;
}

// Boundary triangles by area (Distribution1D): a point uniform on the boundary and its
// outward normal.
struct BoundarySampler {
  const TriangleMesh& mesh;
  Distribution1D byArea;
  static std::vector<float> areas(const TriangleMesh& m) {
    std::vector<float> a(m.numTriangles());
    for (size_t i = 0; i < a.size(); ++i)
      a[i] = 0.5f * length(cross(m.points[m.indices[3 * i + 1]] - m.points[m.indices[3 * i]],
                                 m.points[m.indices[3 * i + 2]] - m.points[m.indices[3 * i]]));
    return a;
  }
  explicit BoundarySampler(const TriangleMesh& m) : mesh(m), byArea(areas(m)) {}
  void sample(float u, float u1, float u2, Vec3& p, Vec3& n) const {
    const size_t i = size_t(byArea.sampleDiscrete(u));
    const Vec3 &a = mesh.points[mesh.indices[3 * i]], &b = mesh.points[mesh.indices[3 * i + 1]],
               &c = mesh.points[mesh.indices[3 * i + 2]];
    const float s = std::sqrt(u1);  // uniform in the triangle
    p = a * (1.0f - s) + b * (s * (1.0f - u2)) + c * (s * u2);
    n = normalize(cross(b - a, c - a));  // outward: build() orients the boundary so
  }
};

// The dome measurement's entries: a point uniform on the boundary, a direction
// cosine-distributed about the inward normal.
struct DomeEntries {
  const BoundarySampler& boundary;
  WhiteDome operator()(Rng& rng, Vec3& p, Vec3& n, Vec3& d) const {
    const float u = rng.next1D(), u1 = rng.next1D(), u2 = rng.next1D();
    boundary.sample(u, u1, u2, p, n);
    d = normalize(Frame(-n).toWorld(sampleCosineHemisphere(rng.next1D(), rng.next1D())));
    return WhiteDome();
  }
};

// One path: A∞'s sample and each candidate's D_k (switching.h), in all and per exit bin.
// Candidates not in `forking` (a bit per candidate) are decided: no fork, nothing summed.
// start(rng, p, n, d) picks the entry point, its outward normal and the direction in, and
// returns the lighting the path gathers (escaped(), atProxy(), atScatter()).
template <typename Start>
void tracePath(const Aggregate& agg, const ProxyTables& tables, const HomogeneousMedium& med, const Start& start,
               uint64_t seed, int64_t index, uint32_t forking, Sums& sums) {
  Rng rng(hashInts(seed, uint64_t(index), 0x5717c4ULL), 0);
  Vec3 p, n, d;
  const auto light = start(rng, p, n, d);
  const float R = agg.grainRadius();
  Vec3 o = p + n * (1e-3f * R);
  const ExitBins bins(n, d);
  // Per candidate: the fork's escape and the bin it left in; what left before it, in all
  // and per bin.
  Vec3 w(1.0f), escaped(0.0f), escapedIn[kSwitchExitBins];
  Vec3 fork[kSwitchCandidates], escapedAtFork[kSwitchCandidates], escapedInAtFork[kSwitchCandidates][kSwitchExitBins];
  int forkBin[kSwitchCandidates] = {};
  int forks = 0, visits = 0;
  GrainHit from;
  bool started = false;
  for (int event = 0; event < kMaxWalkEvents;) {
    // To the next grain met, the spheres whose grains are missed crossed (the packing's flight).
    const GrainFlight flight = agg.flightToGrain(o, d, tables, started ? &from : nullptr, rng);
    sums.events += flight.steps;
    event += flight.steps;
    if (!flight.met()) {
      const Vec3 out = w * light.escaped(d);  // no grain ahead: the light leaves the aggregate
      escaped += out;
      escapedIn[bins.bin(d)] += out;
      break;
    }
    const GrainHit& h = flight.grain;
    const ProxyTable& table = tables.at(h.prototype, h.radius / R);
    const ProxyFrame frame(d, (flight.entry - h.center) / h.radius);
    const int b = table.bBin(frame.b);
    from = h;
    started = true;
    Vec3 straight;
    escaped += w * light.atProxy(h, table, frame, b, rng, straight);
    straight *= w;
    ProxyDirection s;
    const float ub = rng.next1D(), v1 = rng.next1D(), v2 = rng.next1D(), us = rng.next1D(), ue = rng.next1D();
    if (!table.sample(b, ub, v1, v2, us, s)) break;  // nothing leaves this grain
    w *= s.f / s.pdf;
    o = h.center + frame.toWorld(table.exitPoint(b, s, ue)) * h.radius;
    if (s.straight) continue;  // on along the same line, as ppt.h: not a visit
    d = normalize(frame.toWorld(s.w));
    ++visits;
    // The first visit stands for the renderer's explicit first grain: candidate k forks
    // after visit k + 1. The fork's random numbers are its own stream (the path's go on).
    while (forks < kSwitchCandidates && kSwitchVisits[forks] + 1 == visits) {
      if (forking & (1u << forks)) {
        Rng forkRng(hashInts(seed, uint64_t(index), uint64_t(forks), 0xf02cULL), 1);
        const int64_t before = sums.events;
        fork[forks] = w * mediumEscape(agg, tables, med, light, bins, h, o, d, forkBin[forks], forkRng, sums.events);
        sums.forkEvents[forks] += sums.events - before;
      }
      escapedAtFork[forks] = escaped - straight;  // the medium counts those grains as scatterings
      for (int j = 0; j < kSwitchExitBins; ++j) escapedInAtFork[forks][j] = escapedIn[j];
      ++forks;
    }
    if (forks == kSwitchCandidates) break;  // the last fork holds the rest of the path
    if (visits >= kRouletteAfter && !survive(w, rng)) break;
  }
  // S_k, the estimate of switching after k visits: what left before fork k and the fork's
  // escape (a path that ended before fork k: what left in all). The reference is S_last.
  auto estimate = [&](int c) { return c < forks ? escapedAtFork[c] + fork[c] : escaped; };
  auto inBin = [&](int c, int j) {
    if (c >= forks) return escapedIn[j];
    return forkBin[c] == j ? escapedInAtFork[c][j] + fork[c] : escapedInAtFork[c][j];
  };
  const Vec3 last = estimate(kSwitchCandidates - 1);
  const D3 a(last);
  sums.a += a;
  sums.a2 += a.squared();
  for (int j = 0; j < kSwitchExitBins; ++j) sums.ea[j] += D3(inBin(kSwitchCandidates - 1, j));
  for (int c = 0; c < forks; ++c) {  // paths that ended before fork c add 0
    if (!(forking & (1u << c))) continue;
    const D3 dc(estimate(c) - last);
    sums.d[c] += dc;
    sums.d2[c] += dc.squared();
    for (int j = 0; j < kSwitchExitBins; ++j) {
      const D3 dj(inBin(c, j) - inBin(kSwitchCandidates - 1, j));
      sums.ed[c][j] += dj;
      sums.ed2[c][j] += dj.squared();
    }
  }
}

// The means and standard errors of the sums (switching.h: bias_k against S_last): S_last's
// over all m.paths, each D_k's over the m.candidatePaths[k] paths that forked it.
void summarise(const Sums& s, SwitchMeasure& m) {
  auto stdError = [](const D3& sum, const D3& sum2, int ch, double n) {
    const double mean = sum.v[ch] / n;
    return std::sqrt(std::max(0.0, sum2.v[ch] / n - mean * mean) / (n - 1));
  };
  const double n = double(m.paths);
  // A difference's mean and standard error over nc paths, relative to the mean of the
  // reference's sum over all the paths.
  auto relative = [&](const D3& d, const D3& d2, double nc, const D3& reference, Vec3& bias, Vec3& se) {
    for (int ch = 0; ch < 3; ++ch) {
      const double a = std::max(reference.v[ch] / n, 1e-12);
      bias[ch] = float(d.v[ch] / nc / a);
      se[ch] = float(stdError(d, d2, ch, nc) / a);
    }
  };
  for (int ch = 0; ch < 3; ++ch) {
    m.albedo[ch] = float(s.a.v[ch] / n);
    m.albedoSE[ch] = float(stdError(s.a, s.a2, ch, n));
  }
  m.exitReference.assign(kSwitchExitBins, Vec3(0.0f));
  for (int j = 0; j < kSwitchExitBins; ++j)
    for (int ch = 0; ch < 3; ++ch) m.exitReference[size_t(j)][ch] = float(s.ea[j].v[ch] / n);
  m.bias.assign(kSwitchCandidates, Vec3(0.0f));
  m.biasSE.assign(kSwitchCandidates, Vec3(0.0f));
  m.exitBias.assign(size_t(kSwitchCandidates * kSwitchExitBins), Vec3(0.0f));
  m.exitBiasSE.assign(m.exitBias.size(), Vec3(0.0f));
  for (int c = 0; c < kSwitchCandidates; ++c) {
    if (!m.measured(c)) continue;  // SwitchOptions::firstCandidate: 0
    const double nc = double(m.candidatePaths[size_t(c)]);
    relative(s.d[c], s.d2[c], nc, s.a, m.bias[size_t(c)], m.biasSE[size_t(c)]);
    for (int j = 0; j < kSwitchExitBins; ++j) {
      const size_t i = size_t(c * kSwitchExitBins + j);
      relative(s.ed[c][j], s.ed2[c][j], nc, s.ea[j], m.exitBias[i], m.exitBiasSE[i]);
    }
  }
}

// Candidate c's estimate is beyond the tolerance by more than `errors` standard errors in
// some channel.
bool beyond(const SwitchMeasure& m, int c, const SwitchOptions& o, double errors) {
  if (!m.measured(c)) return false;  // nothing shown
  for (int ch = 0; ch < 3; ++ch)
    if (std::fabs(m.bias[size_t(c)][ch]) - errors * m.biasSE[size_t(c)][ch] > o.tolerance) return true;
  return false;
}

// Candidate c cannot be measured to the precision asked in `more` paths (its standard
// error falls as 1/√n).
bool outOfReach(const SwitchMeasure& m, int c, const SwitchOptions& o, int64_t more) {
  const double n = double(m.candidatePaths[size_t(c)]), scale = std::sqrt(n / (n + double(more)));
  for (int ch = 0; ch < 3; ++ch) {
    const double se = m.biasSE[size_t(c)][ch], reach = se * scale;
    if (reach > kOutOfReach * o.precision * o.tolerance) return true;
    // With a margin: its estimate, kDecided standard errors nearer 0, would still fail with
    // that standard error (nearer by fewer, a noisy estimate would pass over candidates).
    if (o.margin > 0 && std::fabs(m.bias[size_t(c)][ch]) - kDecided * se + o.margin * reach > o.tolerance)
      return true;
  }
  return false;
}

// More paths would not lower the choice: every earlier candidate's estimate is beyond the
// tolerance by more than its standard error in some channel (by kDecided of them before
// kBatch paths: a look after a few hundred paths would often see one standard error by
// chance), or out of reach in the `more` paths the measurement may still trace (the chosen
// one passes, or is the last).
bool settled(const SwitchMeasure& m, const SwitchOptions& o, int64_t more) {
  const double errors = m.paths < kBatch ? kDecided : 1.0;
  for (int j = 0; kSwitchVisits[j] < m.visits; ++j)
    if (m.measured(j) && !beyond(m, j, o, errors) && !outOfReach(m, j, o, more)) return false;
  return true;
}

// Cache record (cache.h: RecordWriter) of a measurement.
constexpr RecordMagic kMagic = {'G', 'R', 'S', 'W', '\0', '\0', '\0', '\0'};
constexpr uint32_t kFormatVersion = 8;  // 7: the exit bins; 8: distance fields of a quarter cell

uint64_t recordKey(uint64_t key, const SwitchOptions& o) {
  key = hashInts(key, uint64_t(kFormatVersion), uint64_t(o.paths), o.seed, uint64_t(kSwitchCandidates),
                 uint64_t(o.eventBudget), uint64_t(o.stopEarly));
  // These move where a measurement stops.
  if (o.minPaths > 0) key = hashInts(key, uint64_t(o.minPaths));
  if (o.firstCandidate > 0) key = hashInts(key, uint64_t(o.firstCandidate), 0xf1c4ULL);
  return o.margin > 0 ? hashBytes(key, &o.margin, sizeof o.margin) : key;
}

std::vector<char> serialise(const SwitchMeasure& m, uint64_t key) {
  RecordWriter w(kMagic);
  w.putHeader(kFormatVersion, key);
  w.putArray(std::array<Vec3, 2>{m.albedo, m.albedoSE});
  w.putArray(m.bias);
  w.putArray(m.biasSE);
  w.putArray(m.exitBias);
  w.putArray(m.exitBiasSE);
  w.putArray(m.exitReference);
  w.putI64(m.paths);
  w.putArray(m.candidatePaths);
  w.putI64(m.events);
  w.putF64(m.seconds);
  return w.finish();
}

bool deserialise(const std::vector<char>& in, uint64_t key, SwitchMeasure& m) {
  RecordReader r(in, kMagic);
  if (!r.getHeader(kFormatVersion, key)) return false;
  std::array<Vec3, 2> a;
  m.bias.resize(kSwitchCandidates);
  m.biasSE.resize(kSwitchCandidates);
  m.candidatePaths.resize(kSwitchCandidates);
  m.exitBias.resize(size_t(kSwitchCandidates * kSwitchExitBins));
  m.exitBiasSE.resize(m.exitBias.size());
  m.exitReference.resize(kSwitchExitBins);
  if (!r.getArray(a) || !r.getArray(m.bias) || !r.getArray(m.biasSE) || !r.getArray(m.exitBias) ||
      !r.getArray(m.exitBiasSE) || !r.getArray(m.exitReference) || !r.getI64(m.paths) ||
      !r.getArray(m.candidatePaths) || !r.getI64(m.events) || !r.getF64(m.seconds) || !r.finish())
    return false;
  for (int64_t n : m.candidatePaths)
    if ((n != 0 && n < 2) || n > m.paths) return false;  // 0: not measured
  if (m.candidatePaths.back() != m.paths) return false;  // the reference forks in every path
  m.albedo = a[0];
  m.albedoSE = a[1];
  for (size_t c = 0; c < m.bias.size(); ++c)
    if (!isFinite(m.bias[c]) || !isFinite(m.biasSE[c]) || minComponent(m.biasSE[c]) < 0) return false;
  for (size_t i = 0; i < m.exitBias.size(); ++i)
    if (!isFinite(m.exitBias[i]) || !isFinite(m.exitBiasSE[i]) || minComponent(m.exitBiasSE[i]) < 0) return false;
  for (const Vec3& e : m.exitReference)
    if (!isFinite(e)) return false;
  return isFinite(m.albedo);
}

}  // namespace

namespace {

// Candidate c's estimate is within the tolerance and measured to the precision asked.
bool passes(const SwitchMeasure& m, int c, const SwitchOptions& o) {
  if (!m.measured(c)) return false;
  for (int ch = 0; ch < 3; ++ch)
    if (!(std::fabs(m.bias[size_t(c)][ch]) + o.margin * m.biasSE[size_t(c)][ch] <= o.tolerance &&
          m.biasSE[size_t(c)][ch] <= o.precision * o.tolerance))
      return false;
  return true;
}

// A measurement's record key: the caller's key, its tables' and the options'.
uint64_t measurementKey(uint64_t cacheKey, const ProxyTables& tables, const SwitchOptions& options) {
  return recordKey(hashInts(cacheKey, tables.key()), options);
}

std::string recordName(uint64_t key) { return str("switch-", std::hex, key, ".bin"); }

}  // namespace

std::string switchCacheName(uint64_t cacheKey, const ProxyTables& tables, const SwitchOptions& options) {
  return recordName(measurementKey(cacheKey, tables, options));
}

int chooseSwitchVisits(const SwitchMeasure& m, const SwitchOptions& o) {
  for (int c = 0; c < int(m.bias.size()); ++c)
    if (passes(m, c, o)) return kSwitchVisits[c];
  return kSwitchVisits[kSwitchCandidates - 1];  // a measurement made by hand, whose K does not pass
}

int switchVisitsShownNeeded(const SwitchMeasure& m, const SwitchOptions& o) {
  // Beyond by kDecided standard errors, not by the margin: every candidate's channels are
  // looked at, and at one standard error a few of them would show a bias within the
  // tolerance by chance (each with a chance of up to 16%), where at three all of them
  // together do with a chance of at most 18 × 0.13% ≈ 2.4%.
  // The bias falls with visits: a candidate shown biased shows the earlier ones so too,
  // however noisy their own estimates. So the one after the last shown.
  int c = int(m.bias.size());
  while (c > 0 && !beyond(m, c - 1, o, kDecided)) --c;
  return kSwitchVisits[std::min(c, kSwitchCandidates - 1)];
}

namespace {

// The batches, decisions and summaries of a measurement (switching.h) whose paths start as
// start() says (tracePath).
template <typename Start>
SwitchMeasure measure(const Aggregate& agg, const ProxyTables& tables, const HomogeneousMedium& medium,
                      const Start& start, const SwitchOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  agg.prepareProxies();
  SwitchMeasure m;
  m.candidatePaths.assign(kSwitchCandidates, 0);
  Sums s;
  uint32_t forking = ((1u << kSwitchCandidates) - 1) & ~((1u << options.firstCandidate) - 1);
  while (m.paths < options.paths) {
    // A batch of paths, in blocks summed in order: the same sums whatever the threads.
    const int64_t done = m.paths, end = std::min(options.paths, done + batchAfter(done));
    const Sums before = s;
    const int64_t blocks = (end - done + kPathsPerBlock - 1) / kPathsPerBlock;
    std::vector<Sums> partial(static_cast<size_t>(blocks));
    tbb::parallel_for(int64_t(0), blocks, [&](int64_t k) {
      for (int64_t i = done + k * kPathsPerBlock; i < std::min(end, done + (k + 1) * kPathsPerBlock); ++i)
        tracePath(agg, tables, medium, start, options.seed, i, forking, partial[size_t(k)]);
    });
    for (const Sums& p : partial) s.add(p);
    m.paths = end;
    for (int c = 0; c < kSwitchCandidates; ++c)
      if (forking & (1u << c)) m.candidatePaths[size_t(c)] += end - done;
    summarise(s, m);
    m.visits = chooseSwitchVisits(m, options);
    if (!options.stopEarly) continue;
    if (s.events >= options.eventBudget) break;
    // Neither decisions nor a stop before minPaths: a decided candidate keeps the estimate
    // it had.
    if (m.paths < options.minPaths) continue;
    for (int c = 0; c + 1 < kSwitchCandidates; ++c)  // the last one is the reference
      if (beyond(m, c, options, kDecided)) forking &= ~(1u << c);
    // The most paths still to come: batches start until the budget is spent (at this
    // batch's steps per path, less those of the forks just stopped; the last batch may
    // overrun it) or options.paths are traced.
    int64_t steps = s.events - before.events;
    for (int c = 0; c < kSwitchCandidates; ++c)
      if (!(forking & (1u << c))) steps -= s.forkEvents[c] - before.forkEvents[c];
    const double perPath = std::max(1.0, double(steps)) / double(end - done);
    const int64_t more = int64_t(std::ceil(double(options.eventBudget - s.events) / perPath)) + kBatch;
    if (settled(m, options, std::min(options.paths - m.paths, more))) break;
  }
  m.events = s.events;
  m.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return m;
}

// The measurement under key from the disk cache, its choice made anew (the tolerance is
// not in the key); else measured by compute() and cached (key 0: neither).
template <typename Compute>
SwitchMeasure cachedOrMeasured(uint64_t key, const SwitchOptions& options, const Compute& compute) {
  const std::string name = recordName(key);
  std::vector<char> bytes;
  SwitchMeasure m;
  if (key && readCacheFile(name, bytes) && deserialise(bytes, key, m)) {
    m.fromCache = true;
    m.visits = chooseSwitchVisits(m, options);
    return m;
  }
  m = compute();
  if (key) writeCacheFile(name, serialise(m, key));
  return m;
}

void checkOptions(const SwitchOptions& options) {
  if (options.paths < 2) throw InputError("switching", "paths", str(options.paths, " is < 2"));
  if (!(options.tolerance > 0)) throw InputError("switching", "tolerance", str(options.tolerance, " is not > 0"));
  if (!(options.precision > 0)) throw InputError("switching", "precision", str(options.precision, " is not > 0"));
  if (!(options.margin >= 0)) throw InputError("switching", "margin", str(options.margin, " is not >= 0"));
  if (options.minPaths < 0) throw InputError("switching", "minPaths", str(options.minPaths, " is < 0"));
  if (options.firstCandidate < 0 || options.firstCandidate >= kSwitchCandidates)
    throw InputError("switching", "firstCandidate",
                     str(options.firstCandidate, " is outside [0, ", kSwitchCandidates - 1, "]"));
}

}  // namespace

SwitchMeasure measureSwitch(const Aggregate& agg, const ProxyTables& tables, const HomogeneousMedium& medium,
                            const SwitchOptions& options, uint64_t cacheKey) {
  checkOptions(options);
  const uint64_t key = cacheKey ? measurementKey(cacheKey, tables, options) : 0;
  return cachedOrMeasured(key, options, [&] {
    const BoundarySampler boundary(agg.boundary());
    return measure(agg, tables, medium, DomeEntries{boundary}, options);
  });
}

namespace {

// Light as the view measurement gathers it (switching.h): next-event estimation toward the
// distant lights that reach the entry point, and the domes where paths leave.
struct ViewLighting {
  const Aggregate& agg;
  const ProxyTables& tables;
  const HomogeneousMedium& med;
  const SwitchView& view;
  uint32_t lit;  // bit i: view.lights[i] reaches the entry point
  Vec3 escaped(const Vec3& d) const {
    Vec3 L(0.0f);
    for (const Light& light : *view.lights)
      if (light.type() == LightType::Dome) L += light.escapedLe(d);
    return L;
  }
  // At a grain met among proxies: the table toward the light, from one of its exit points,
  // and the chance that the other proxies' grains let it through; `straight` gets the part
  // that came through their straight lobes (ProxyShadow, proxy.h), which a fork into the
  // medium here leaves to the medium.
  Vec3 atProxy(const GrainHit& h, const ProxyTable& table, const ProxyFrame& frame, int b, Rng& rng,
               Vec3& straight) const {
    Vec3 L(0.0f);
    straight = Vec3(0.0f);
    for (size_t i = 0; i < view.lights->size(); ++i) {
      if (!(lit & (1u << i))) continue;
      LightSample ls;
      const float u1 = rng.next1D(), u2 = rng.next1D(), ue = rng.next1D();
      const uint32_t roulette = rng.nextU32();
      if (!(*view.lights)[i].sampleLi(h.center, u1, u2, ls) || isBlack(ls.Li)) continue;
      const ProxyDirection pd = table.eval(b, frame.toLocal(ls.wi));
      if (!(pd.pdf > 0)) continue;
      const Vec3 x = h.center + frame.toWorld(table.exitPoint(b, pd, ue)) * h.radius;
      const ProxyShadow tr = agg.proxyTransmittance(x, ls.wi, 0.0f, kInf, tables, &h, roulette);
      const Vec3 c = pd.f * ls.Li / (ls.delta ? 1.0f : ls.pdf);
      L += c * tr.crossing;
      straight += c * (tr.crossing - Vec3(tr.unscattered));
    }
    return L;
  }
  // At a scattering in the medium: the phase function toward the light and exp(−σ_t ℓ) to
  // the boundary (none deeper than where that is below e^−9 in every channel).
  Vec3 atScatter(const Vec3& o, const Vec3& d, Rng& rng) const {
    Vec3 L(0.0f);
    if (-agg.boundaryDistance(o) * minComponent(med.sigmaT()) > 9.0f) return L;
    const float eps = 1e-4f * agg.grainRadius();
    for (size_t i = 0; i < view.lights->size(); ++i) {
      if (!(lit & (1u << i))) continue;
      LightSample ls;
      const float u1 = rng.next1D(), u2 = rng.next1D();
      if (!(*view.lights)[i].sampleLi(o, u1, u2, ls) || isBlack(ls.Li)) continue;
      float tb = 0;
      Vec3 ng;
      Vec3 from = o;
      bool out = false;  // moved out of the boundary: nothing of the medium left to cross
      if (med.movesLight()) {  // the exits model (vpt.h): from where the grain lets the light out
        from = o + med.exitMove(d, ls.wi, rng.next1D(), rng.next1D());
        out = !agg.insideBoundaryFast(from);
      }
      if (!out && !agg.intersectBoundary(from, ls.wi, eps, kInf, tb, ng)) continue;
      L += med.phase(d, ls.wi) * med.transmittance(tb) * ls.Li / (ls.delta ? 1.0f : ls.pdf);
    }
    return L;
  }
};

// The view measurement's entries: one of the camera's, uniformly (each stands for the
// same share of the image).
struct ViewEntries {
  const Aggregate& agg;
  const ProxyTables& tables;
  const HomogeneousMedium& med;
  const SwitchView& view;
  ViewLighting operator()(Rng& rng, Vec3& p, Vec3& n, Vec3& d) const {
    const size_t count = view.entries.size();
    const SwitchView::Entry& e = view.entries[std::min(count - 1, size_t(rng.next1D() * float(count)))];
    p = e.p;
    n = e.n;
    d = e.d;
    return ViewLighting{agg, tables, med, view, e.lit};
  }
};

}  // namespace

SwitchOptions viewSwitchOptions() {
  SwitchOptions o;
  o.paths = int64_t(1) << 17;
  o.eventBudget = int64_t(1) << 24;
  o.margin = 1.0f;
  return o;
}

SwitchOptions sunSwitchOptions() {
  SwitchOptions o = viewSwitchOptions();
  o.minPaths = int64_t(1) << 14;
  o.eventBudget = int64_t(1) << 26;
  return o;
}

SwitchMeasure measureViewSwitch(const Aggregate& agg, const ProxyTables& tables, const HomogeneousMedium& medium,
                                const SwitchView& view, const SwitchOptions& options, uint64_t cacheKey) {
  checkOptions(options);
  if (view.entries.empty() || !view.lights) throw InputError("switching", "view", "no entry seen by the camera");
  if (view.lights->size() > 32) throw InputError("switching", "view", "more than 32 lights");
  uint64_t key = 0;
  if (cacheKey) {
    key = hashInts(cacheKey, 0x56494557 /* "VIEW" */);
    for (const SwitchView::Entry& e : view.entries) {
      for (const Vec3* v : {&e.p, &e.n, &e.d}) key = hashBytes(key, v, sizeof(Vec3));
      key = hashInts(key, e.lit);
    }
    // The lights by what they send: a sample toward the origin and the light escaping
    // along the six axes.
    for (const Light& light : *view.lights) {
      LightSample ls;
      const bool sampled = light.sampleLi(Vec3(0.0f), 0.5f, 0.5f, ls);
      key = hashInts(key, uint64_t(light.type()), uint64_t(sampled));
      for (const Vec3* v : {&ls.wi, &ls.Li}) key = hashBytes(key, v, sizeof(Vec3));
      key = hashBytes(key, &ls.pdf, sizeof ls.pdf);
      for (int axis = 0; axis < 6; ++axis) {
        Vec3 dir(0.0f);
        dir[axis / 2] = axis % 2 ? -1.0f : 1.0f;
        const Vec3 le = light.isInfinite() ? light.escapedLe(dir) : Vec3(0.0f);
        key = hashBytes(key, &le, sizeof le);
      }
    }
    key = measurementKey(key, tables, options);
  }
  return cachedOrMeasured(key, options,
                          [&] { return measure(agg, tables, medium, ViewEntries{agg, tables, medium, view}, options); });
}

}  // namespace granular
