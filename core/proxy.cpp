// proxy.cpp — tabulated grain scattering for proxies (Müller et al. 2016, §4). See proxy.h.
#include "proxy.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "cache.h"
#include "embree_util.h"
#include "error.h"
#include "grain.h"
#include "rng.h"
#include "sampling.h"
#include "tt.h"

namespace granular {

namespace {

constexpr int64_t kChunk = 16384;  // rays per chunk: fixed, so results ignore the thread count

// The frame in which an exit offset is stored: perpendicular to the (folded) exit
// direction w, e1 along the part of the entry frame's x perpendicular to w.
void exitFrame(const Vec3& w, Vec3& e1, Vec3& e2) {
  // |x − w (w·x)|² = 1 − w.x² for a unit w: one root, no normalize.
  const float a2 = 1.0f - w.x * w.x;
  if (a2 < 1e-10f) {  // w along ±x
    e1 = normalize(Vec3(0.0f, 1.0f, 0.0f) - w * w.y);
  } else {
    e1 = (Vec3(1.0f, 0.0f, 0.0f) - w * w.x) * (1.0f / std::sqrt(a2));
  }
  e2 = cross(w, e1);
}

// Where a line of direction w (unit) at offset e (perpendicular to w, |e| ≤ 1) leaves the
// unit sphere.
Vec3 sphereExitPoint(const Vec3& e, const Vec3& w) {
  return e + w * std::sqrt(std::max(0.0f, 1.0f - length2(e)));
}

struct Record {
  uint32_t bin;  // (b, direction) bin
  float c1, c2;
};

struct ChunkSums {
  std::vector<int64_t> entered, hits;  // per b bin
  std::vector<double> energy;          // per (b, direction) bin and channel
  std::vector<double> pass;            // per b bin and channel: straight on
  std::vector<Record> records;         // in ray order
};

// Cache record (cache.h: RecordWriter) of a table.
constexpr RecordMagic kMagic = {'G', 'R', 'P', 'X', '\0', '\0', '\0', '\0'};
constexpr uint32_t kFormatVersion = 3;  // 2: bins equal in θ; 3: the straight lobe
static_assert(sizeof(Vec3) == 3 * sizeof(float), "a Vec3 is stored as three floats");

uint64_t cacheKey(const TriangleMesh& mesh, const Material& m, const ProxyOptions& o) {
  uint64_t h = hashGrainInputs(hashInts(0x47525058 /* "GRPX" */, kFormatVersion), mesh, m);
  for (int64_t v : {o.rays, int64_t(o.bBins), int64_t(o.muBins), int64_t(o.phiBins), int64_t(o.offsetsPerBin),
                    int64_t(o.maxBounces)})
    h = hashValue(h, v);
  return hashValue(h, o.seed);
}

void validate(const TriangleMesh& mesh, const ProxyOptions& o) {
  const char* obj = "proxy table";
  if (o.rays < 1) throw InputError(obj, "rays", str(o.rays, " is < 1"));
  for (auto [name, v] : {std::pair<const char*, int>{"bBins", o.bBins}, {"muBins", o.muBins}, {"phiBins", o.phiBins}})
    if (v < 1 || v > 1024) throw InputError(obj, name, str(v, " is outside [1, 1024]"));
  if (int64_t(o.bBins) * o.muBins * o.phiBins > (1 << 20))
    throw InputError(obj, "bins", "more than 2^20 bins in all");
  if (o.offsetsPerBin < 1 || o.offsetsPerBin > 4096)
    throw InputError(obj, "offsetsPerBin", str(o.offsetsPerBin, " is outside [1, 4096]"));
  if (o.maxBounces < 1) throw InputError(obj, "maxBounces", str(o.maxBounces, " is < 1"));
  if (mesh.numTriangles() == 0) throw InputError(obj, "mesh", "has no triangles");
}

}  // namespace

float ProxyTable::binSolidAngle(int mu) const {
  return 2.0f * (muEdge_[size_t(mu) + 1] - muEdge_[size_t(mu)]) * (kPi / float(nphi_));
}

int ProxyTable::directionBin(const Vec3& w) const {
  const int cell = std::clamp(int((w.z + 1.0f) * 0.5f * float(kMuCells)), 0, kMuCells - 1);
  int mu = int(muCell_[size_t(cell)]);
  while (mu + 1 < nmu_ && w.z >= muEdge_[size_t(mu) + 1]) ++mu;
  while (mu > 0 && w.z < muEdge_[size_t(mu)]) --mu;  // a cell index rounded up past an edge
  const float phi = std::atan2(std::max(w.y, 0.0f), w.x);  // in [0, π]
  const int ph = std::clamp(int(phi / kPi * float(nphi_)), 0, nphi_ - 1);
  return mu * nphi_ + ph;
}

bool ProxyTable::sample(int b, float uBin, float u1, float u2, float uSide, ProxyDirection& out) const {
  const int nd = nmu_ * nphi_;
  const float* cdf = &cdf_[size_t(b) * size_t(nd + 1)];
  const Vec3& pass = pass_[size_t(b)];
  const float passMass = pass.x + pass.y + pass.z;
  if (!(cdf[nd] + passMass > 0)) return false;
  float u = uBin * (cdf[nd] + passMass);
  if (u < passMass || !(cdf[nd] > 0)) {  // the straight lobe (proxy.h)
    const Vec3& a = albedo_[size_t(b)];
    out.w = Vec3(0.0f, 0.0f, 1.0f);
    out.f = pass;
    out.pdf = passMass / std::max(a.x + a.y + a.z, passMass);
    out.bin = -1;
    out.mirrored = uSide < 0.5f;
    out.straight = true;
    return out.pdf > 0;
  }
  out.straight = false;
  // u's direction bin, from the guide of u's share of the total forward.
  u = std::min(u - passMass, cdf[nd]);
  const int i = guidedBin(cdf, nd, &guide_[size_t(b) * size_t(kGuides + 1)], kGuides, u);
  const int mu = i / nphi_, ph = i % nphi_;
  const float z0 = muEdge_[size_t(mu)], z1 = muEdge_[size_t(mu) + 1];
  const float z = z0 + (z1 - z0) * std::clamp(u1, 1e-4f, 1.0f - 1e-4f);
  const float s = std::sqrt(std::max(0.0f, 1.0f - z * z));
  const float du = std::clamp(u2, 1e-4f, 1.0f - 1e-4f);
  float cosPhi, sinPhi;
  if (!phiStart_.empty()) {
    // φ = φ_bin + δ, δ ≤ π/16 ≤ 0.2: the angle sum with series of δ good to float (error
    // below δ⁷/5040 < 3e-9) instead of a sine and cosine.
    const float dl = kPi / float(nphi_) * du, d2 = dl * dl;
    const float sd = dl * (1.0f - d2 * (1.0f / 6.0f) * (1.0f - d2 * (1.0f / 20.0f)));
    const float cd = 1.0f - d2 * 0.5f * (1.0f - d2 * (1.0f / 12.0f) * (1.0f - d2 * (1.0f / 30.0f)));
    const float c0 = phiStart_[size_t(2 * ph)], s0 = phiStart_[size_t(2 * ph + 1)];
    cosPhi = c0 * cd - s0 * sd;
    sinPhi = s0 * cd + c0 * sd;
  } else {
    const float phi = kPi * (float(ph) + du) / float(nphi_);
    cosPhi = std::cos(phi);
    sinPhi = std::sin(phi);
  }
  out.w = Vec3(s * cosPhi, s * sinPhi, z);
  out.mirrored = uSide < 0.5f;
  if (out.mirrored) out.w.y = -out.w.y;
  out.bin = i;
  setValue(b, out);
  return out.pdf > 0;
}

void ProxyTable::buildMuBins() {
  muEdge_.resize(size_t(nmu_) + 1);
  for (int k = 0; k <= nmu_; ++k) muEdge_[size_t(k)] = float(-std::cos(kPiD * double(k) / double(nmu_)));
  muEdge_.front() = -1.0f;
  muEdge_.back() = 1.0f;
  muCell_.resize(kMuCells);
  for (int c = 0, mu = 0; c < kMuCells; ++c) {
    const float start = -1.0f + 2.0f * float(c) / float(kMuCells);
    while (mu + 1 < nmu_ && muEdge_[size_t(mu) + 1] <= start) ++mu;
    muCell_[size_t(c)] = uint16_t(mu);
  }
}

void ProxyTable::buildSamplingTables() {
  const int nd = nmu_ * nphi_;
  phiStart_.clear();
  if (kPi / float(nphi_) <= 0.2f)
    for (int ph = 0; ph < nphi_; ++ph) {
      const double phi = double(kPi) * double(ph) / double(nphi_);
      phiStart_.push_back(float(std::cos(phi)));
      phiStart_.push_back(float(std::sin(phi)));
    }
  guide_.assign(size_t(nb_) * size_t(kGuides + 1), 0);
  for (int b = 0; b < nb_; ++b)
    cdfGuide(&cdf_[size_t(b) * size_t(nd + 1)], nd, kGuides, &guide_[size_t(b) * size_t(kGuides + 1)]);
}

void ProxyTable::setValue(int b, ProxyDirection& d) const {
  // pdf = Σ_c f_c / Σ_c albedo_c (proxy.h); 0 where nothing leaves a grain met at b.
  d.f = f_[size_t(b) * size_t(nmu_ * nphi_) + size_t(d.bin)];
  const Vec3& a = albedo_[size_t(b)];
  const float total = a.x + a.y + a.z;
  d.pdf = total > 0 ? (d.f.x + d.f.y + d.f.z) / total : 0.0f;
}

ProxyDirection ProxyTable::eval(int b, const Vec3& wLocal) const {
  ProxyDirection out;
  out.w = wLocal;
  out.mirrored = wLocal.y < 0;
  Vec3 folded = wLocal;
  folded.y = std::fabs(folded.y);
  out.bin = directionBin(folded);
  setValue(b, out);
  return out;
}

Vec3 ProxyTable::exitPoint(int b, const ProxyDirection& d, float u) const {
  Vec3 w = d.straight ? Vec3(0.0f, 0.0f, 1.0f) : d.w;  // the straight lobe: on along the entry's z
  w.y = std::fabs(w.y);
  const size_t cell = offsetCell(b, d);
  const uint32_t first = offsetStart_[cell], count = offsetStart_[cell + 1] - first;
  Vec3 p = w;  // no offset recorded: leave through the point straight ahead
  if (count > 0) {
    const uint32_t k = first + std::min(count - 1, uint32_t(u * float(count)));
    Vec3 e1, e2;
    exitFrame(w, e1, e2);
    p = sphereExitPoint(e1 * offsets_[2 * k] + e2 * offsets_[2 * k + 1], w);
  }
  if (d.mirrored) p.y = -p.y;
  return p;
}

void ProxyTables::add(int prototype, float size, ProxyTable table) {
  if (int(tables_.size()) <= prototype) {
    tables_.resize(size_t(prototype) + 1);
    sizes_.resize(size_t(prototype) + 1);
  }
  tables_[size_t(prototype)].push_back(std::move(table));
  sizes_[size_t(prototype)].push_back(size);
}

const ProxyTable& ProxyTables::at(int prototype, float size) const {
  const std::vector<float>& s = sizes_[size_t(prototype)];
  size_t best = 0;
  for (size_t i = 1; i < s.size(); ++i)
    if (std::fabs(s[i] - size) < std::fabs(s[best] - size)) best = i;
  return tables_[size_t(prototype)][best];
}

uint64_t ProxyTables::key() const {
  uint64_t h = hashInts(0x50544253 /* "PTBS" */, uint64_t(tables_.size()));
  for (size_t p = 0; p < tables_.size(); ++p)
    for (size_t i = 0; i < tables_[p].size(); ++i) h = hashInts(hashValue(h, sizes_[p][i]), tables_[p][i].key());
  return h;
}

Vec3 ProxyTable::meanAlbedo() const {
  // b bins hold equal shares of the entering rays: weigh each by its hits.
  Vec3 s(0.0f);
  float h = 0;
  for (int b = 0; b < nb_; ++b) {
    s += albedo_[size_t(b)] * hit_[size_t(b)];
    h += hit_[size_t(b)];
  }
  return h > 0 ? s / h : Vec3(0.0f);
}

float ProxyTable::meanHitProbability() const {
  float h = 0;
  for (float v : hit_) h += v;
  return nb_ > 0 ? h / float(nb_) : 0.0f;
}

std::vector<char> serialiseProxyTable(const ProxyTable& t, uint64_t key) {
  RecordWriter w(kMagic);
  w.putHeader(kFormatVersion, key);
  for (int v : {t.nb_, t.nmu_, t.nphi_}) w.putI32(int32_t(v));
  w.putI64(t.rays_);
  w.putU64(uint64_t(t.offsets_.size()));
  w.putArray(t.hit_);
  w.putArray(t.albedo_);
  w.putArray(t.pass_);
  w.putArray(t.f_);
  w.putArray(t.cdf_);
  w.putArray(t.offsets_);
  w.putArray(t.offsetStart_);
  return w.finish();
}

bool deserialiseProxyTable(const std::vector<char>& in, uint64_t key, ProxyTable& t) {
  RecordReader r(in, kMagic);
  uint64_t offsets = 0;
  int32_t nb = 0, nmu = 0, nphi = 0;
  if (!r.getHeader(kFormatVersion, key)) return false;
  if (!r.getI32(nb) || !r.getI32(nmu) || !r.getI32(nphi) || !r.getI64(t.rays_) || !r.getU64(offsets)) return false;
  const size_t nd = size_t(nmu) * size_t(nphi), cells = size_t(nb) * nd;
  const size_t offsetCells = cells + size_t(nb);  // and the straight lobes'
  // The lengths the counts imply, checked before anything is allocated for them.
  if (nb < 1 || nmu < 1 || nphi < 1 || offsets % 2 != 0 ||
      r.remaining() != size_t(nb) * 4 + size_t(nb) * 24 + cells * 12 + size_t(nb) * (nd + 1) * 4 + offsets * 4 +
                           (offsetCells + 1) * 4)
    return false;
  t.nb_ = nb; t.nmu_ = nmu; t.nphi_ = nphi;
  t.hit_.resize(size_t(nb)); t.albedo_.resize(size_t(nb)); t.pass_.resize(size_t(nb)); t.f_.resize(cells);
  t.cdf_.resize(size_t(nb) * (nd + 1)); t.offsets_.resize(offsets); t.offsetStart_.resize(offsetCells + 1);
  if (!r.getArray(t.hit_) || !r.getArray(t.albedo_) || !r.getArray(t.pass_) || !r.getArray(t.f_) ||
      !r.getArray(t.cdf_) || !r.getArray(t.offsets_) || !r.getArray(t.offsetStart_) || !r.finish())
    return false;
  for (const std::vector<Vec3>* a : {&t.f_, &t.pass_})
    for (const Vec3& v : *a)
      if (!isFinite(v) || minComponent(v) < 0) return false;
  if (t.offsetStart_.back() * 2 != offsets) return false;
  for (size_t i = 0; i + 1 < t.offsetStart_.size(); ++i)
    if (t.offsetStart_[i] > t.offsetStart_[i + 1]) return false;
  for (int b = 0; b < nb; ++b)  // a CDF: finite, from 0, never falling
    for (size_t i = 0; i <= nd; ++i) {
      const float c = t.cdf_[size_t(b) * (nd + 1) + i];
      if (!std::isfinite(c) || (i == 0 ? c != 0.0f : c < t.cdf_[size_t(b) * (nd + 1) + i - 1])) return false;
    }
  t.buildMuBins();
  t.buildSamplingTables();
  t.key_ = key;
  return true;
}

ProxyTable estimateProxyTable(const TriangleMesh& mesh, const Material& material, const ProxyOptions& opt) {
  validate(mesh, opt);
  const uint64_t key = cacheKey(mesh, material, opt);
  const std::string name = str("proxy-", std::hex, key, ".bin");
  if (opt.useCache) {
    std::vector<char> bytes;
    ProxyTable cached;
    if (readCacheFile(name, bytes) && deserialiseProxyTable(bytes, key, cached)) {
      cached.fromCache_ = true;
      return cached;
    }
  }
  const int nb = opt.bBins, nd = opt.muBins * opt.phiBins;
  ProxyTable t;
  t.nb_ = nb;
  t.nmu_ = opt.muBins;
  t.nphi_ = opt.phiBins;
  t.rays_ = opt.rays;
  t.key_ = key;
  t.buildMuBins();

  EmbreeDevice device = makeEmbreeDevice();
  EmbreeScene bvh = buildTriangleScene(device, mesh);
  const float cosStraight = float(std::cos(kStraightOnDegrees * kPiD / 180.0));
  const int64_t chunks = (opt.rays + kChunk - 1) / kChunk;
  std::vector<ChunkSums> parts{size_t(chunks)};
  tbb::parallel_for(tbb::blocked_range<int64_t>(0, chunks, 1), [&](const tbb::blocked_range<int64_t>& r) {
    for (int64_t c = r.begin(); c < r.end(); ++c) {
      ChunkSums& s = parts[size_t(c)];
      s.entered.assign(size_t(nb), 0);
      s.hits.assign(size_t(nb), 0);
      s.energy.assign(size_t(nb) * size_t(nd) * 3, 0.0);
      s.pass.assign(size_t(nb) * 3, 0.0);
      const int64_t first = c * kChunk, count = std::min(kChunk, opt.rays - first);
      for (int64_t k = 0; k < count; ++k) {
        Rng rng(hashInts(opt.seed, 0x5058 /* "PX" */, uint64_t(first + k)));
        Vec3 xi, wi;
        sampleSphereEntry(rng, xi, wi);
        const ProxyFrame frame(wi, xi);
        const int b = t.bBin(frame.b);
        ++s.entered[size_t(b)];
        const GrainPassage g = traceGrainPassage(bvh.get(), mesh, material, opt.maxBounces, xi, wi, rng);
        if (!g.hit) continue;
        ++s.hits[size_t(b)];
        if (isBlack(g.weight)) continue;
        Vec3 w = normalize(frame.toLocal(g.d));
        const Vec3 oc = frame.toLocal(g.o);
        Vec3 e = oc - w * dot(oc, w);  // the exit line's offset from the centre
        if (w.y < 0) {  // fold onto y >= 0: the mirror image of the whole exit
          w.y = -w.y;
          e.y = -e.y;
        }
        if (w.z > cosStraight) {  // the straight lobe: its energy and its line's offset
          for (int ch = 0; ch < 3; ++ch) s.pass[size_t(b) * 3 + size_t(ch)] += double(g.weight[ch]);
          // Its offset in exitFrame of (0, 0, 1): the entry frame's x and y.
          s.records.push_back({uint32_t(size_t(nb) * size_t(nd) + size_t(b)), e.x, e.y});
          continue;
        }
        const int i = t.directionBin(w);
        const size_t cell = size_t(b) * size_t(nd) + size_t(i);
        for (int ch = 0; ch < 3; ++ch) s.energy[cell * 3 + size_t(ch)] += double(g.weight[ch]);
        Vec3 e1, e2;
        exitFrame(w, e1, e2);
        s.records.push_back({uint32_t(cell), dot(e, e1), dot(e, e2)});
      }
    }
  });

  std::vector<int64_t> entered(size_t(nb), 0), hits(size_t(nb), 0);
  std::vector<double> energy(size_t(nb) * size_t(nd) * 3, 0.0), pass(size_t(nb) * 3, 0.0);
  std::vector<std::vector<float>> kept(size_t(nb) * size_t(nd) + size_t(nb));  // and the straight lobes'
  for (const ChunkSums& s : parts) {  // in chunk order: reproducible sums and samples
    for (int b = 0; b < nb; ++b) {
      entered[size_t(b)] += s.entered[size_t(b)];
      hits[size_t(b)] += s.hits[size_t(b)];
    }
    for (size_t i = 0; i < energy.size(); ++i) energy[i] += s.energy[i];
    for (size_t i = 0; i < pass.size(); ++i) pass[i] += s.pass[i];
    for (const Record& r : s.records) {
      auto& k = kept[r.bin];
      if (int(k.size()) < 2 * opt.offsetsPerBin) {
        k.push_back(r.c1);
        k.push_back(r.c2);
      }
    }
  }
  t.hit_.resize(size_t(nb));
  t.albedo_.resize(size_t(nb));
  t.pass_.resize(size_t(nb));
  t.f_.assign(size_t(nb) * size_t(nd), Vec3(0.0f));
  t.cdf_.assign(size_t(nb) * size_t(nd + 1), 0.0f);
  for (int b = 0; b < nb; ++b) {
    t.hit_[size_t(b)] = entered[size_t(b)] > 0 ? float(double(hits[size_t(b)]) / double(entered[size_t(b)])) : 0.0f;
    const double h = double(std::max<int64_t>(1, hits[size_t(b)]));
    double a[3], mass = 0;
    for (int ch = 0; ch < 3; ++ch) {
      a[ch] = pass[size_t(b) * 3 + size_t(ch)] / h;
      t.pass_[size_t(b)][ch] = float(a[ch]);
    }
    float* cdf = &t.cdf_[size_t(b) * size_t(nd + 1)];
    for (int i = 0; i < nd; ++i) {
      const size_t cell = size_t(b) * size_t(nd) + size_t(i);
      Vec3 f;
      for (int ch = 0; ch < 3; ++ch) {
        a[ch] += energy[cell * 3 + size_t(ch)] / h;
        f[ch] = float(energy[cell * 3 + size_t(ch)] / (h * double(t.binSolidAngle(i / t.nphi_))));
      }
      t.f_[cell] = f;
      mass += (energy[cell * 3] + energy[cell * 3 + 1] + energy[cell * 3 + 2]) / h;
      cdf[i + 1] = float(mass);
    }
    t.albedo_[size_t(b)] = Vec3(float(a[0]), float(a[1]), float(a[2]));
  }
  t.offsetStart_.assign(1, 0);
  for (const auto& k : kept) {
    t.offsets_.insert(t.offsets_.end(), k.begin(), k.end());
    t.offsetStart_.push_back(uint32_t(t.offsets_.size() / 2));
  }
  t.buildSamplingTables();
  if (opt.useCache) writeCacheFile(name, serialiseProxyTable(t, key));
  return t;
}

}  // namespace granular
