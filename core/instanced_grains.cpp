// instanced_grains.cpp — explicit grains' validation, grid and ray queries
// (instanced_grains.h).
#include "instanced_grains.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <climits>
#include <cmath>
#include <memory>
#include <mutex>

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/concurrent_unordered_set.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include "error.h"
#include "proxy.h"
#include "rng.h"

namespace granular {

namespace {

constexpr uint64_t kEmptyKey = ~uint64_t(0);
constexpr int kBlockCells = 1 << (3 * InstancedGrains::kBlockBits);
// Grid resolution per axis: block coordinates take 21 bits of a key.
constexpr int64_t kMaxCellsPerAxis = (int64_t(1) << (21 + InstancedGrains::kBlockBits)) - 1;


std::string text(const Vec3& v) { return str("(", v.x, ", ", v.y, ", ", v.z, ")"); }

bool isIdentity(const Transform& xf) {
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j)
      if (xf.m[i][j] != (i == j ? 1.0 : 0.0)) return false;
  return true;
}

Mat3 toMat3(const Quat& q) { return quatToMat3(q.w, q.x, q.y, q.z); }

// Arrays validateInstancedGrains found valid: their stamps (shared_array.h: unique, dropped
// by a write) and the prototype count the indices were checked against. The last few kept.
struct Checked {
  std::array<uint64_t, 6> stamps;
  size_t prototypes;
  bool operator==(const Checked& b) const { return stamps == b.stamps && prototypes == b.prototypes; }
};
std::mutex checkedMutex;
std::vector<Checked> checkedArrays;
constexpr size_t kCheckedKept = 32;

bool checkedBefore(const Checked& key) {
  std::lock_guard<std::mutex> lock(checkedMutex);
  return std::find(checkedArrays.begin(), checkedArrays.end(), key) != checkedArrays.end();
}

void rememberChecked(const Checked& key) {
  std::lock_guard<std::mutex> lock(checkedMutex);
  if (std::find(checkedArrays.begin(), checkedArrays.end(), key) != checkedArrays.end()) return;
  if (checkedArrays.size() >= kCheckedKept) checkedArrays.erase(checkedArrays.begin());
  checkedArrays.push_back(key);
}

}  // namespace

void validateInstancedGrains(const InstancedGrainsDesc& desc) {
  const std::string& name = desc.name;
  if (desc.prototypes.empty())
    throw InputError(name, "prototypes", "is empty (at least one grain prototype mesh is needed)");
  for (const GrainPrototypeDesc& p : desc.prototypes)
    if (p.mesh.numTriangles() == 0) throw InputError(p.name, "points", "has no triangles (a grain prototype)");
  const size_t n = desc.protoIndices.size();
  auto sameLength = [&](const char* attr, size_t m, bool optional) {
    if (optional && m == 0) return;
    if (m != n)
      throw InputError(name, attr, str("has ", m, " values but protoIndices has ", n, " (one per instance)"));
  };
  sameLength("positions", desc.positions.size(), false);
  sameLength("orientations", desc.orientations.size(), true);
  sameLength("scales", desc.scales.size(), true);
  sameLength("velocities", desc.velocities.size(), true);
  sameLength("angularVelocities", desc.angularVelocities.size(), true);

  // The per-instance checks once per set of arrays: at 10^8 grains each pass reads 3.4 GB,
  // and the reader, the scene's validation, the grid and the packing-rate grid all ask.
  const Checked key{{desc.positions.stamp(), desc.orientations.stamp(), desc.scales.stamp(), desc.protoIndices.stamp(),
                     desc.velocities.stamp(), desc.angularVelocities.stamp()},
                    desc.prototypes.size()};
  if (n > 0 && checkedBefore(key)) return;
  const int64_t protos = int64_t(desc.prototypes.size());
  int64_t i = firstBadInstance(n, [&](size_t k) { return desc.protoIndices[k] < 0 || desc.protoIndices[k] >= protos; });
  if (i >= 0)
    throw InputError(name, "protoIndices", str("instance ", i, " has ", desc.protoIndices[size_t(i)],
                                               ", not the index of one of its ", protos, " prototypes"));
  if ((i = firstBadInstance(n, [&](size_t k) { return !isFinite(desc.positions[k]); })) >= 0)
    throw InputError(name, "positions", str("instance ", i, " is at ", text(desc.positions[size_t(i)]), " (not finite)"));
  if ((i = firstBadInstance(desc.orientations.size(), [&](size_t k) {
         const Quat& q = desc.orientations[k];
         float n2 = q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z;
         return !(std::fabs(n2 - 1.0f) <= 1e-3f);  // NaN fails too
       })) >= 0) {
    const Quat& q = desc.orientations[size_t(i)];
    throw InputError(name, "orientations",
                     str("instance ", i, " has (", q.w, ", ", q.x, ", ", q.y, ", ", q.z, "), not a unit quaternion"));
  }
  if ((i = firstBadInstance(desc.scales.size(), [&](size_t k) {
         return !(desc.scales[k] > 0 && std::isfinite(desc.scales[k]));
       })) >= 0)
    throw InputError(name, "scales", str("instance ", i, " has scale ", desc.scales[size_t(i)], " (must be > 0 and finite)"));
  const std::pair<const char*, const SharedArray<Vec3>*> motion[] = {{"velocities", &desc.velocities},
                                                                      {"angularVelocities", &desc.angularVelocities}};
  for (const auto& m : motion) {
    const SharedArray<Vec3>& values = *m.second;  // a structured binding cannot be captured before C++20
    if ((i = firstBadInstance(values.size(), [&](size_t k) { return !isFinite(values[k]); })) >= 0)
      throw InputError(name, m.first, str("instance ", i, " has ", text(values[size_t(i)]), " (not finite)"));
  }
  if (n > 0) rememberChecked(key);
}

InstancedGrain InstancedGrains::grain(int64_t i, float time) const {
  InstancedGrain g;
  const size_t k = size_t(i);
  g.index = i;
  g.prototype = desc_.protoIndices[k];
  if (!desc_.orientations.empty()) g.orientation = desc_.orientations[k];
  if (!desc_.scales.empty()) g.scale = desc_.scales[k];
  const GrainPrototype& p = prototypes_[size_t(g.prototype)];
  Vec3 position = desc_.positions[k];
  if (time != 0 && !desc_.velocities.empty()) position += desc_.velocities[k] * time;
  if (time != 0 && !desc_.angularVelocities.empty()) {
    // USD's order: the orientation, then the spin about the instancer-space axis.
    const Vec3& w = desc_.angularVelocities[k];
    const float speed = length(w);
    if (speed > 0) {
      const float half = 0.5f * speed * time * kPi / 180.0f, s = std::sin(half) / speed;
      const Quat r{std::cos(half), w.x * s, w.y * s, w.z * s};
      const Quat& q = g.orientation;
      g.orientation = Quat{r.w * q.w - r.x * q.x - r.y * q.y - r.z * q.z, r.w * q.x + r.x * q.w + r.y * q.z - r.z * q.y,
                           r.w * q.y - r.x * q.z + r.y * q.w + r.z * q.x, r.w * q.z + r.x * q.y - r.y * q.x + r.z * q.w};
    }
  }
  g.center = position + rotate(g.orientation, p.fitCenter) * g.scale;
  g.radius = p.fitRadius * g.scale;
  return g;
}

inline void InstancedGrains::sphere(size_t i, Vec3& center, float& radius) const {
  const GrainPrototype& p = prototypes_[size_t(desc_.protoIndices[i])];
  const Quat q = desc_.orientations.empty() ? Quat() : desc_.orientations[i];
  const float s = desc_.scales.empty() ? 1.0f : desc_.scales[i];
  center = desc_.positions[i] + rotate(q, p.fitCenter) * s;
  radius = p.fitRadius * s;
}

inline float InstancedGrains::sweep(int64_t i) const {
  if (motionSpan_ <= 0) return 0.0f;
  const size_t k = size_t(i);
  float s = desc_.velocities.empty() ? 0.0f : length(desc_.velocities[k]) * motionSpan_;
  if (!desc_.angularVelocities.empty()) {
    // The bounding centre turns about the instance's position: a chord of at most the angle
    // swept (radians) times its distance, and never more than the diameter.
    const GrainPrototype& p = prototypes_[size_t(desc_.protoIndices[k])];
    const float arm = length(p.fitCenter) * (desc_.scales.empty() ? 1.0f : desc_.scales[k]);
    const float angle = length(desc_.angularVelocities[k]) * motionSpan_ * kPi / 180.0f;
    s += arm * std::min(2.0f, angle);
  }
  return s * (1.0f + 1e-5f);
}

void InstancedGrains::build(InstancedGrainsDesc desc, const EmbreeDevice& device, bool checkOverlaps,
                            float motionSpan) {
  validateInstancedGrains(desc);
  if (!(motionSpan >= 0) || !std::isfinite(motionSpan))
    throw InputError(desc.name, "velocities", str("motion span ", motionSpan, " s must be finite and >= 0"));
  device_ = device;
  desc_ = std::move(desc);
  motionSpan_ = desc_.velocities.empty() && desc_.angularVelocities.empty() ? 0.0f : motionSpan;
  stats_ = InstancedGrainsStats();
  identity_ = isIdentity(desc_.xf);
  if (!desc_.xf.isFinite() || !desc_.xf.inverse(inv_) || desc_.xf.determinant3() == 0)
    throw InputError(desc_.name, "transform", "is not invertible");
  prototypes_.clear();
  for (const GrainPrototypeDesc& p : desc_.prototypes) {
    prototypes_.push_back(makeGrainPrototype(device, p));
    const GrainPrototype& g = prototypes_.back();
    stats_.prototypeBytes += g.mesh.points.size() * sizeof(Vec3) + g.mesh.indices.size() * sizeof(uint32_t) +
                             g.normals.size() * sizeof(Vec3) + g.hullFace.size();
  }
  stats_.grains = int64_t(desc_.size());
  stats_.inputBytes = desc_.positions.size() * sizeof(Vec3) + desc_.orientations.size() * sizeof(Quat) +
                      desc_.scales.size() * sizeof(float) + desc_.protoIndices.size() * sizeof(int32_t) +
                      (desc_.velocities.size() + desc_.angularVelocities.size()) * sizeof(Vec3);
  auto t0 = std::chrono::steady_clock::now();
  buildGrid();
  auto t1 = std::chrono::steady_clock::now();
  stats_.buildSeconds = std::chrono::duration<double>(t1 - t0).count();
  if (checkOverlaps) {
    this->checkOverlaps();
    stats_.overlapSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  }
}

// Inline: the grid's build calls these for every grain in each of its passes.
inline void InstancedGrains::cellRange(const Vec3& c, float r, int64_t lo[3], int64_t hi[3]) const {
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::clamp<int64_t>(int64_t(std::floor((c[a] - r - origin_[a]) * invCell_)), 0, n_[a] - 1);
    hi[a] = std::clamp<int64_t>(int64_t(std::floor((c[a] + r - origin_[a]) * invCell_)), 0, n_[a] - 1);
  }
}

inline bool InstancedGrains::sphereTouchesCell(const Vec3& c, float r, int64_t x, int64_t y, int64_t z) const {
  const int64_t cell[3] = {x, y, z};
  float d2 = 0;
  for (int a = 0; a < 3; ++a) {
    float lo = origin_[a] + float(cell[a]) * cell_, hi = lo + cell_;
    float e = c[a] < lo ? lo - c[a] : (c[a] > hi ? c[a] - hi : 0.0f);
    d2 += e * e;
  }
  return d2 <= r * r;
}

void InstancedGrains::buildGrid() {
  const size_t n = desc_.size();
  hashKeys_.clear();
  hashBlock_.clear();
  starts_.clear();
  list_.clear();
  bounds_ = Bounds3();
  n_[0] = n_[1] = n_[2] = 0;
  if (n == 0) return;

  struct Extent {
    Bounds3 box;
    float rmax = 0;
  };
  Extent ext = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, n, 8192), Extent(),
      [&](const tbb::blocked_range<size_t>& r, Extent e) {
        for (size_t i = r.begin(); i < r.end(); ++i) {
          Vec3 c;
          float radius;
          sphere(i, c, radius);
          const float r = radius + sweep(int64_t(i));  // moving grains: the sphere of their sweep
          e.box.extend(c - Vec3(r));
          e.box.extend(c + Vec3(r));
          e.rmax = std::max(e.rmax, r);
        }
        return e;
      },
      [](Extent a, const Extent& b) {
        a.box.extend(b.box);
        a.rmax = std::max(a.rmax, b.rmax);
        return a;
      });
  bounds_ = ext.box;
  // Rounding: a hit on a cell face must find its grain listed on both sides.
  cell_ = kCellRadii * ext.rmax;
  const Vec3 size = bounds_.extent();
  while (maxComponent(size) / cell_ >= float(kMaxCellsPerAxis)) cell_ *= 2;
  invCell_ = 1.0f / cell_;
  origin_ = bounds_.lo;
  for (int a = 0; a < 3; ++a) n_[a] = std::max<int64_t>(1, int64_t(std::ceil(size[a] * invCell_)));
  const float pad = 1e-4f * cell_;

  // Occupied blocks: their keys, sorted (deterministic order), hashed. Where the grid's box
  // holds few blocks for its grains (a heap, a slab: not far-flung grains), marked on a bit
  // per block of the box and numbered through a dense table while building, which is
  // faster than the hash; else gathered in a concurrent set.
  const int64_t nb[3] = {((n_[0] - 1) >> kBlockBits) + 1, ((n_[1] - 1) >> kBlockBits) + 1,
                         ((n_[2] - 1) >> kBlockBits) + 1};
  const double boxBlocks = double(nb[0]) * double(nb[1]) * double(nb[2]);
  const bool compact = boxBlocks <= std::max(double(1 << 22), 0.25 * double(n));
  auto linearBlock = [&](int64_t x, int64_t y, int64_t z) {  // cell coordinates; key order
    return size_t(((z >> kBlockBits) * nb[1] + (y >> kBlockBits)) * nb[0] + (x >> kBlockBits));
  };
  auto forBlocks = [&](size_t i, auto&& fn) {
    Vec3 c;
    float radius;
    sphere(i, c, radius);
    int64_t lo[3], hi[3];
    cellRange(c, radius + sweep(int64_t(i)) + pad, lo, hi);
    for (int64_t z = lo[2] >> kBlockBits; z <= hi[2] >> kBlockBits; ++z)
      for (int64_t y = lo[1] >> kBlockBits; y <= hi[1] >> kBlockBits; ++y)
        for (int64_t x = lo[0] >> kBlockBits; x <= hi[0] >> kBlockBits; ++x)
          fn(x << kBlockBits, y << kBlockBits, z << kBlockBits);
  };
  std::vector<uint64_t> sorted;
  std::vector<uint32_t> dense;  // compact: each box block's index, or UINT32_MAX
  if (compact) {
    const size_t words = (size_t(boxBlocks) + 63) / 64;
    std::unique_ptr<std::atomic<uint64_t>[]> bits(new std::atomic<uint64_t>[words]);
    tbb::parallel_for(size_t(0), words, [&](size_t w) { bits[w].store(0, std::memory_order_relaxed); });
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& r) {
      for (size_t i = r.begin(); i < r.end(); ++i)
        forBlocks(i, [&](int64_t x, int64_t y, int64_t z) {
          const size_t b = linearBlock(x, y, z);
          const uint64_t bit = uint64_t(1) << (b & 63);
          if (!(bits[b >> 6].load(std::memory_order_relaxed) & bit)) bits[b >> 6].fetch_or(bit, std::memory_order_relaxed);
        });
    });
    dense.assign(size_t(boxBlocks), UINT32_MAX);
    for (size_t w = 0; w < words; ++w)
      for (uint64_t m = bits[w].load(std::memory_order_relaxed); m; m &= m - 1) {
        const size_t b = w * 64 + size_t(__builtin_ctzll(m));
        const int64_t x = int64_t(b % size_t(nb[0])), y = int64_t(b / size_t(nb[0]) % size_t(nb[1])),
                      z = int64_t(b / size_t(nb[0]) / size_t(nb[1]));
        dense[b] = uint32_t(sorted.size());
        sorted.push_back(blockKey(x << kBlockBits, y << kBlockBits, z << kBlockBits));
      }
  } else {
    // Mixed: std::hash of an integer is the identity, and a key's low bits are x alone.
    struct Mix {
      size_t operator()(uint64_t k) const { return size_t(mix64(k)); }
    };
    tbb::concurrent_unordered_set<uint64_t, Mix> keys;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& r) {
      uint64_t last = kEmptyKey;
      for (size_t i = r.begin(); i < r.end(); ++i)
        forBlocks(i, [&](int64_t x, int64_t y, int64_t z) {
          const uint64_t key = blockKey(x, y, z);
          if (key != last) keys.insert(key);
          last = key;
        });
    });
    sorted.assign(keys.begin(), keys.end());
    keys.clear();
    std::sort(sorted.begin(), sorted.end());
  }
  const size_t blocks = sorted.size();
  size_t cap = 16;
  while (cap < 2 * blocks) cap *= 2;
  hashKeys_.assign(cap, kEmptyKey);
  hashBlock_.assign(cap, 0);
  hashMask_ = cap - 1;
  for (size_t b = 0; b < blocks; ++b) {
    uint64_t s = mix64(sorted[b]) & hashMask_;
    while (hashKeys_[s] != kEmptyKey) s = (s + 1) & hashMask_;
    hashKeys_[s] = sorted[b];
    hashBlock_[s] = uint32_t(b);
  }
  sorted = std::vector<uint64_t>();
  auto blockOf = [&](int64_t x, int64_t y, int64_t z) {
    return compact ? size_t(dense[linearBlock(x, y, z)]) : size_t(findBlock(blockKey(x, y, z)));
  };

  // Count, place and order each cell's entries.
  const size_t cells = blocks * kBlockCells;
  std::unique_ptr<std::atomic<uint32_t>[]> count(new std::atomic<uint32_t>[cells]);
  tbb::parallel_for(size_t(0), cells, [&](size_t c) { count[c].store(0, std::memory_order_relaxed); });
  auto forCells = [&](size_t i, auto&& fn) {
    Vec3 c;
    float radius;
    sphere(i, c, radius);
    const float r = radius + sweep(int64_t(i)) + pad;
    int64_t lo[3], hi[3];
    cellRange(c, r, lo, hi);
    for (int64_t z = lo[2]; z <= hi[2]; ++z)
      for (int64_t y = lo[1]; y <= hi[1]; ++y)
        for (int64_t x = lo[0]; x <= hi[0]; ++x)
          if (sphereTouchesCell(c, r, x, y, z)) fn(blockOf(x, y, z) * kBlockCells + size_t(localCell(x, y, z)));
  };
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i < r.end(); ++i)
      forCells(i, [&](size_t c) { count[c].fetch_add(1, std::memory_order_relaxed); });
  });
  starts_.resize(cells + 1);
  uint64_t total = 0;
  for (size_t c = 0; c < cells; ++c) {
    starts_[c] = uint32_t(total);
    total += count[c].load(std::memory_order_relaxed);
    if (total > UINT32_MAX)
      throw InputError(desc_.name, "positions", str("has too many grains for one grid (", n, ")"));
    count[c].store(starts_[c], std::memory_order_relaxed);
  }
  starts_[cells] = uint32_t(total);
  list_.resize(size_t(total));
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i < r.end(); ++i)
      forCells(i, [&](size_t c) { list_[count[c].fetch_add(1, std::memory_order_relaxed)] = uint32_t(i); });
  });
  count.reset();
  tbb::parallel_for(tbb::blocked_range<size_t>(0, cells, 1024), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t c = r.begin(); c < r.end(); ++c) std::sort(list_.begin() + starts_[c], list_.begin() + starts_[c + 1]);
  });

  stats_.cells[0] = n_[0];
  stats_.cells[1] = n_[1];
  stats_.cells[2] = n_[2];
  stats_.occupiedBlocks = int64_t(blocks);
  stats_.entries = int64_t(total);
  stats_.cellSize = cell_;
  stats_.gridBytes = list_.size() * sizeof(uint32_t) + starts_.size() * sizeof(uint32_t) +
                     hashKeys_.size() * sizeof(uint64_t) + hashBlock_.size() * sizeof(uint32_t);
}

int64_t InstancedGrains::findBlock(uint64_t key) const {
  if (hashKeys_.empty()) return -1;
  uint64_t s = mix64(key) & hashMask_;
  for (;;) {
    const uint64_t k = hashKeys_[s];
    if (k == key) return int64_t(hashBlock_[s]);
    if (k == kEmptyKey) return -1;
    s = (s + 1) & hashMask_;
  }
}

void InstancedGrains::checkOverlaps() {
  // Every pair listed together in a cell, each pair judged once: in the cell that holds the
  // middle of the lens where the two spheres overlap (inside both by half the depth, so both
  // are listed there whatever the rounding). Each grain's sphere is placed once per cell.
  // The first offending pair (i, j), smallest i then j.
  struct Pair {
    int64_t i = -1, j = -1;
  };
  auto better = [](const Pair& a, const Pair& b) {
    if (a.i < 0) return b;
    if (b.i < 0) return a;
    return (b.i < a.i || (b.i == a.i && b.j < a.j)) ? b : a;
  };
  std::vector<uint64_t> keyOf(hashKeys_.empty() ? 0 : starts_.size() / kBlockCells);
  for (size_t s = 0; s < hashKeys_.size(); ++s)
    if (hashKeys_[s] != kEmptyKey) keyOf[hashBlock_[s]] = hashKeys_[s];
  Pair first = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, keyOf.size(), 64), Pair(),
      [&](const tbb::blocked_range<size_t>& r, Pair found) {
        struct Placed {
          int64_t index;
          Vec3 center;
          float radius;
        };
        std::vector<Placed> here;
        for (size_t b = r.begin(); b < r.end(); ++b) {
          const uint64_t key = keyOf[b];
          const int64_t base[3] = {int64_t(key & 0x1fffff) << kBlockBits, int64_t((key >> 21) & 0x1fffff) << kBlockBits,
                                   int64_t((key >> 42) & 0x1fffff) << kBlockBits};
          for (int local = 0; local < kBlockCells; ++local) {
            const size_t c = b * kBlockCells + size_t(local);
            if (starts_[c + 1] - starts_[c] < 2) continue;
            const int64_t cell[3] = {base[0] + (local & ((1 << kBlockBits) - 1)),
                                     base[1] + ((local >> kBlockBits) & ((1 << kBlockBits) - 1)),
                                     base[2] + (local >> (2 * kBlockBits))};
            here.clear();
            for (uint32_t k = starts_[c]; k < starts_[c + 1]; ++k) {
              Placed p;
              p.index = int64_t(list_[k]);
              sphere(list_[k], p.center, p.radius);
              here.push_back(p);
            }
            for (size_t a = 0; a < here.size(); ++a)
              for (size_t e = a + 1; e < here.size(); ++e) {
                const Placed &g = here[a], &h = here[e];  // g.index < h.index: lists are sorted
                const Vec3 d = h.center - g.center;
                // Apart (no overlap at all) for certain, in double with a margin far above
                // float rounding: most pairs; the others are judged exactly as below.
                const double d2 = double(d.x) * d.x + double(d.y) * d.y + double(d.z) * d.z,
                             reach = double(g.radius) + double(h.radius);
                if (d2 > reach * reach * (1.0 + 1e-4)) continue;
                const float dist = length(d);
                const float depth = g.radius + h.radius - dist;
                if (!(depth > kOverlapTolerance * std::min(g.radius, h.radius))) continue;
                const Vec3 mid = dist > 0 ? g.center + d * ((g.radius - 0.5f * depth) / dist) : g.center;
                int64_t lo[3], hi[3];
                cellRange(mid, 0.0f, lo, hi);
                if (lo[0] == cell[0] && lo[1] == cell[1] && lo[2] == cell[2])
                  found = better(found, Pair{g.index, h.index});
              }
          }
        }
        return found;
      },
      better);
  if (first.i < 0) return;
  InstancedGrain a = grain(first.i), b = grain(first.j);
  const float depth = a.radius + b.radius - length(a.center - b.center);
  throw InputError(desc_.name, "positions",
                   str("instances ", first.i, " and ", first.j, " overlap: their bounding spheres (radii ", a.radius,
                       " and ", b.radius, ") interpenetrate by ", 100.0f * depth / std::min(a.radius, b.radius),
                       "% of the smaller radius (at most ", 100.0f * kOverlapTolerance, "% is allowed)"));
}

bool InstancedGrains::traceGrain(int64_t i, const Vec3& o, const Vec3& d, float tmin, float tmax, float time,
                                 InstancedGrainHit& hit) const {
  const InstancedGrain g = grain(i, motionSpan_ > 0 ? time : 0.0f);
  // Bounding sphere first (slightly grown: the BVH, not rounding, decides a grazing ray).
  const Vec3 oc = o - g.center;
  const float r = g.radius * (1.0f + 1e-5f);
  const float a = dot(d, d), b = dot(oc, d), c = dot(oc, oc) - r * r;
  const float disc = b * b - a * c;
  if (!(disc >= 0)) return false;
  const float sq = std::sqrt(disc);
  if ((-b + sq) / a < tmin || (-b - sq) / a > tmax) return false;
  if (!traceable(oc, d, tmin, tmax)) return false;
  float t;
  unsigned prim;
  Vec3 ng;
  if (!tracePrototype(prototypes_[size_t(g.prototype)], toMat3(g.orientation), g.radius, oc, d, tmin, tmax, t, prim,
                      ng))
    return false;
  hit.t = t;
  hit.grain = i;
  hit.prototype = g.prototype;
  hit.prim = prim;
  hit.ng = ng;
  hit.radius = g.radius;
  return true;
}

template <class Visit>
void InstancedGrains::forCellsAlong(const Vec3& o, const Vec3& d, float tmin, float tmax, Visit&& visit) const {
  if (list_.empty() || !(tmin <= tmax)) return;
  Bounds3 grid;
  grid.lo = origin_;
  grid.hi = origin_ + Vec3(float(n_[0]), float(n_[1]), float(n_[2])) * cell_;
  const Vec3 invD(1.0f / d.x, 1.0f / d.y, 1.0f / d.z);
  float t0, t1;
  if (!grid.intersect(o, invD, tmin, tmax, t0, t1)) return;
  const Vec3 p = o + d * t0;
  int64_t c[3], step[3];
  float tNext[3], tDelta[3];
  for (int a = 0; a < 3; ++a) {
    c[a] = std::clamp<int64_t>(int64_t(std::floor((p[a] - origin_[a]) * invCell_)), 0, n_[a] - 1);
    if (d[a] > 0) {
      step[a] = 1;
      tNext[a] = (origin_[a] + float(c[a] + 1) * cell_ - o[a]) * invD[a];
      tDelta[a] = cell_ * invD[a];
    } else if (d[a] < 0) {
      step[a] = -1;
      tNext[a] = (origin_[a] + float(c[a]) * cell_ - o[a]) * invD[a];
      tDelta[a] = -cell_ * invD[a];
    } else {
      step[a] = 0;
      tNext[a] = kInf;
      tDelta[a] = kInf;
    }
  }
  uint64_t lastKey = kEmptyKey;
  int64_t block = -1;
  float tEnter = -kInf;  // the first cell holds whatever lies before the grid's entry
  for (;;) {
    const float tExit = std::min(tNext[0], std::min(tNext[1], tNext[2]));
    const bool last = tExit >= t1;
    const uint64_t key = blockKey(c[0], c[1], c[2]);
    if (key != lastKey) {
      block = findBlock(key);
      lastKey = key;
    }
    if (block >= 0) {
      const size_t cell = size_t(block) * kBlockCells + size_t(localCell(c[0], c[1], c[2]));
      if (!visit(starts_[cell], starts_[cell + 1], tEnter, last ? kInf : tExit)) return;
    } else if (!visit(0u, 0u, tEnter, last ? kInf : tExit)) {
      return;
    }
    if (last) return;
    const int a = tNext[0] < tNext[1] ? (tNext[0] < tNext[2] ? 0 : 2) : (tNext[1] < tNext[2] ? 1 : 2);
    c[a] += step[a];
    if (c[a] < 0 || c[a] >= n_[a]) return;
    tEnter = tExit;
    tNext[a] += tDelta[a];
  }
}

bool InstancedGrains::walk(const Vec3& o, const Vec3& d, float tmin, float tmax, float time, bool anyHit,
                           InstancedGrainHit& hit) const {
  float best = tmax;
  bool found = false;
  // Grains already traced on this ray (a grain is listed by every cell it overlaps; best
  // only shrinks, so a second trace cannot find anything new).
  uint32_t recent[8];
  int nRecent = 0, cursor = 0;
  forCellsAlong(o, d, tmin, tmax, [&](uint32_t k0, uint32_t k1, float, float tExit) {
    for (uint32_t k = k0; k < k1; ++k) {
      const uint32_t g = list_[k];
      if (std::find(recent, recent + nRecent, g) != recent + nRecent) continue;
      recent[cursor] = g;
      cursor = (cursor + 1) & 7;
      nRecent = std::min(nRecent + 1, 8);
      if (traceGrain(g, o, d, tmin, best, time, hit)) {
        best = hit.t;
        found = true;
        if (anyHit) return false;
      }
    }
    return !(found && best <= tExit);
  });
  return found;
}

namespace {

// Where an object-space ray enters grain g's bounding sphere: its t (tmin when it starts
// inside), or false when it misses the sphere or leaves it before tmin; b2: the squared
// impact parameter over the squared radius.
bool enterSphere(const InstancedGrain& g, const Vec3& o, const Vec3& d, float a, float tmin, float& t, float& b2) {
  const Vec3 oc = o - g.center;
  const float b = dot(oc, d), c = dot(oc, oc) - g.radius * g.radius;
  const float w2 = std::max(0.0f, dot(oc, oc) - b * b / a);  // squared distance of the line from the centre
  const float disc = b * b - a * c;
  if (!(disc >= 0)) return false;
  const float sq = std::sqrt(disc);
  if ((-b + sq) / a <= tmin) return false;
  t = std::max((-b - sq) / a, tmin);
  b2 = std::min(1.0f, w2 / (g.radius * g.radius));
  return true;
}

}  // namespace

bool InstancedGrains::intersectProxy(const Vec3& o, const Vec3& d, float tmin, float tmax, int64_t skip,
                                     InstancedGrain& grain, float& t, float time) const {
  if (!traceable(o, d, tmin, tmax)) return false;
  const Vec3 ol = identity_ ? o : inv_.point(o), dl = identity_ ? d : inv_.vector(d);
  const float a = dot(dl, dl);
  const float when = motionSpan_ > 0 ? time : 0.0f;
  float best = tmax;
  bool found = false;
  forCellsAlong(ol, dl, tmin, tmax, [&](uint32_t k0, uint32_t k1, float, float tExit) {
    for (uint32_t k = k0; k < k1; ++k) {
      if (int64_t(list_[k]) == skip) continue;
      const InstancedGrain g = this->grain(list_[k], when);
      float te, b2;
      if (enterSphere(g, ol, dl, a, tmin, te, b2) && te < best) {
        best = te;
        grain = g;
        found = true;
      }
    }
    return !(found && best <= tExit);
  });
  if (found) t = best;
  return found;
}

ProxyShadow InstancedGrains::proxyTransmittance(const Vec3& o, const Vec3& d, float tmin, float tmax, int64_t skip,
                                                const std::function<ProxyShadow(const InstancedGrain&, float)>& shadow,
                                                uint64_t seed, float time) const {
  if (!traceable(o, d, tmin, tmax)) return ProxyShadow();
  const Vec3 ol = identity_ ? o : inv_.point(o), dl = identity_ ? d : inv_.vector(d);
  const float a = dot(dl, dl);
  const float when = motionSpan_ > 0 ? time : 0.0f;
  ProxyShadow tr;
  uint64_t draws = 0;
  // Each sphere counts once: in the cell where the ray enters it (every cell a sphere
  // touches lists it; the cells' ranges of t do not overlap).
  forCellsAlong(ol, dl, tmin, tmax, [&](uint32_t k0, uint32_t k1, float tEnter, float tExit) {
    for (uint32_t k = k0; k < k1; ++k) {
      if (int64_t(list_[k]) == skip) continue;
      const InstancedGrain g = this->grain(list_[k], when);
      float te, b2;
      if (!enterSphere(g, ol, dl, a, tmin, te, b2) || te >= tmax || te < tEnter || te >= tExit) continue;
      tr *= shadow(g, std::sqrt(b2));
      if (!proxyRoulette(tr, seed, draws)) return false;
    }
    return true;
  });
  return tr;
}

bool InstancedGrains::intersect(const Vec3& o, const Vec3& d, float tmin, float tmax, InstancedGrainHit& hit,
                                float time) const {
  if (!traceable(o, d, tmin, tmax)) return false;
  const Vec3 ol = identity_ ? o : inv_.point(o), dl = identity_ ? d : inv_.vector(d);
  InstancedGrainHit h;
  if (!walk(ol, dl, tmin, tmax, time, false, h)) return false;
  if (!identity_) h.ng = Transform::normal(inv_, h.ng);
  h.ng = normalize(h.ng);
  hit = h;
  return true;
}

bool InstancedGrains::occluded(const Vec3& o, const Vec3& d, float tmin, float tmax, float time) const {
  if (!traceable(o, d, tmin, tmax)) return false;
  InstancedGrainHit h;
  return walk(identity_ ? o : inv_.point(o), identity_ ? d : inv_.vector(d), tmin, tmax, time, true, h);
}

bool InstancedGrains::intersectAll(const Vec3& o, const Vec3& d, float tmin, float tmax, InstancedGrainHit& hit,
                                   float time) const {
  if (!traceable(o, d, tmin, tmax)) return false;
  const Vec3 ol = identity_ ? o : inv_.point(o), dl = identity_ ? d : inv_.vector(d);
  InstancedGrainHit h;
  float best = tmax;
  bool found = false;
  for (size_t i = 0; i < desc_.size(); ++i)
    if (traceGrain(int64_t(i), ol, dl, tmin, best, time, h)) {
      best = h.t;
      found = true;
    }
  if (!found) return false;
  if (!identity_) h.ng = Transform::normal(inv_, h.ng);
  h.ng = normalize(h.ng);
  hit = h;
  return true;
}

void InstancedGrains::forEachGrain(const Bounds3& box, const std::function<void(const InstancedGrain&)>& fn) const {
  if (list_.empty() || box.empty()) return;
  Bounds3 b = box;
  if (!identity_) {
    b = Bounds3();
    for (int k = 0; k < 8; ++k)
      b.extend(inv_.point(Vec3(k & 1 ? box.hi.x : box.lo.x, k & 2 ? box.hi.y : box.lo.y, k & 4 ? box.hi.z : box.lo.z)));
  }
  const Vec3 mid = b.center(), half = b.extent() * 0.5f;
  int64_t lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    if (b.hi[a] < origin_[a] || b.lo[a] > origin_[a] + float(n_[a]) * cell_) return;
  }
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::clamp<int64_t>(int64_t(std::floor((b.lo[a] - origin_[a]) * invCell_)), 0, n_[a] - 1);
    hi[a] = std::clamp<int64_t>(int64_t(std::floor((b.hi[a] - origin_[a]) * invCell_)), 0, n_[a] - 1);
  }
  std::vector<uint32_t> found;
  auto visitCell = [&](size_t cell) {
    for (uint32_t k = starts_[cell]; k < starts_[cell + 1]; ++k) {
      const InstancedGrain g = grain(list_[k]);
      const Vec3 e = vmax(vabs(g.center - mid) - half, Vec3(0.0f));
      if (dot(e, e) <= g.radius * g.radius) found.push_back(list_[k]);
    }
  };
  const double rangeCells = double(hi[0] - lo[0] + 1) * double(hi[1] - lo[1] + 1) * double(hi[2] - lo[2] + 1);
  if (rangeCells <= double(hashKeys_.size())) {
    for (int64_t z = lo[2]; z <= hi[2]; ++z)
      for (int64_t y = lo[1]; y <= hi[1]; ++y)
        for (int64_t x = lo[0]; x <= hi[0]; ++x) {
          const int64_t blk = findBlock(blockKey(x, y, z));
          if (blk >= 0) visitCell(size_t(blk) * kBlockCells + size_t(localCell(x, y, z)));
        }
  } else {  // a box larger than the occupied space: every occupied block's cells in range
    constexpr int64_t m = (1 << kBlockBits) - 1;
    for (size_t s = 0; s < hashKeys_.size(); ++s) {
      const uint64_t key = hashKeys_[s];
      if (key == kEmptyKey) continue;
      const int64_t base[3] = {int64_t(key & 0x1fffff) << kBlockBits, int64_t((key >> 21) & 0x1fffff) << kBlockBits,
                               int64_t((key >> 42) & 0x1fffff) << kBlockBits};
      for (int64_t z = base[2]; z <= base[2] + m; ++z)
        for (int64_t y = base[1]; y <= base[1] + m; ++y)
          for (int64_t x = base[0]; x <= base[0] + m; ++x)
            if (x >= lo[0] && x <= hi[0] && y >= lo[1] && y <= hi[1] && z >= lo[2] && z <= hi[2])
              visitCell(size_t(hashBlock_[s]) * kBlockCells + size_t(localCell(x, y, z)));
    }
  }
  std::sort(found.begin(), found.end());
  found.erase(std::unique(found.begin(), found.end()), found.end());
  for (uint32_t i : found) fn(grain(i));
}

}  // namespace granular
