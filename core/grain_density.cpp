// grain_density.cpp — the grains' packing rate on 8³-voxel leaves (contract in the header).
//
// Gather, not scatter: grains are grouped by the leaf holding their centre (their home
// leaf); every leaf a kernel can reach is then filled by one task that sums, in a fixed
// order, the grains of the 27 home leaves around it. No two tasks write the same voxel,
// so the sums do not depend on the threads, and each grain is weighed once per leaf it
// reaches (at most 8 when Δ >= h/2).
// Memory: the grains are ordered by the x of their home leaf (4 bytes a grain), and the
// leaves are filled one slab of leaves (constant x) at a time from the three slabs around
// it, whose grains' centres and volumes (32 bytes a grain) exist only then.
#include "grain_density.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_sort.h>

#include "embree_util.h"
#include "error.h"
#include "grain.h"
#include "instanced_grains.h"

namespace granular {

namespace {

// Cubic B-spline of knot spacing 1, support [−2, 2], ∫ = 1.
inline double bspline3(double x) {
  x = std::fabs(x);
  if (x < 1) return 2.0 / 3.0 - x * x + 0.5 * x * x * x;
  if (x < 2) {
    double t = 2 - x;
    return t * t * t / 6.0;
  }
  return 0;
}

constexpr int64_t kKeyBias = int64_t(1) << 20;  // leaf coordinates in [−2^20, 2^20)

inline int64_t floorDiv8(int64_t i) { return i >= 0 ? i / 8 : -((-i + 7) / 8); }

inline uint64_t leafKey(int64_t lx, int64_t ly, int64_t lz) {
  return (uint64_t(lx + kKeyBias) << 42) | (uint64_t(ly + kKeyBias) << 21) | uint64_t(lz + kKeyBias);
}
inline void keyLeaf(uint64_t key, int64_t l[3]) {
  constexpr uint64_t m = (uint64_t(1) << 21) - 1;
  l[0] = int64_t(key >> 42) - kKeyBias;
  l[1] = int64_t((key >> 21) & m) - kKeyBias;
  l[2] = int64_t(key & m) - kKeyBias;
}

struct Splat {
  double u[3];   // centre in voxel index units (voxel centres at integers)
  float volume;  // world units³
  int32_t proto;
};

}  // namespace

void meshVolumeCentroid(const TriangleMesh& mesh, double& volume, Vec3& centroid) {
  double v = 0, c[3] = {0, 0, 0};
  for (size_t t = 0; t < mesh.numTriangles(); ++t) {
    const Vec3& a = mesh.points[mesh.indices[3 * t]];
    const Vec3& b = mesh.points[mesh.indices[3 * t + 1]];
    const Vec3& d = mesh.points[mesh.indices[3 * t + 2]];
    // The tetrahedron (0, a, b, d): signed volume and centroid (a + b + d) / 4.
    double tv = double(dot(a, cross(b, d))) / 6.0;
    v += tv;
    for (int k = 0; k < 3; ++k) c[k] += tv * (double(a[k]) + b[k] + d[k]) / 4.0;
  }
  volume = v;
  centroid = v != 0 ? Vec3(float(c[0] / v), float(c[1] / v), float(c[2] / v)) : Vec3(0.0f);
}

int64_t VoxelLeaves::findLeaf(int64_t i, int64_t j, int64_t k) const {
  const std::array<int32_t, 3> o = {int32_t(floorDiv8(i) * 8), int32_t(floorDiv8(j) * 8), int32_t(floorDiv8(k) * 8)};
  auto it = std::lower_bound(origins.begin(), origins.end(), o);
  return it != origins.end() && *it == o ? int64_t(it - origins.begin()) : -1;
}

float VoxelLeaves::voxel(int64_t i, int64_t j, int64_t k) const {
  int64_t l = findLeaf(i, j, k);
  return l < 0 ? 0.0f : values[size_t(l) * kLeafVoxels + size_t(offset(int(i & 7), int(j & 7), int(k & 7)))];
}

float VoxelLeaves::sample(const Vec3& world) const {
  if (!(voxelSize > 0) || origins.empty()) return 0;
  const double inv = 1.0 / voxelSize;
  const double u[3] = {world.x * inv, world.y * inv, world.z * inv};
  int64_t i0[3];
  double f[3];
  for (int a = 0; a < 3; ++a) {
    if (!(std::fabs(u[a]) < 1e15)) return 0;
    double fl = std::floor(u[a]);
    i0[a] = int64_t(fl);
    f[a] = u[a] - fl;
  }
  double s = 0;
  for (int c = 0; c < 8; ++c) {
    const int dx = c & 1, dy = (c >> 1) & 1, dz = c >> 2;
    const double w = (dx ? f[0] : 1 - f[0]) * (dy ? f[1] : 1 - f[1]) * (dz ? f[2] : 1 - f[2]);
    if (w > 0) s += w * voxel(i0[0] + dx, i0[1] + dy, i0[2] + dz);
  }
  return float(s);
}

int64_t VoxelLeaves::activeVoxels() const {
  int64_t n = 0;
  for (float v : values) n += v > 0;
  return n;
}

float GrainDensity::numberFraction(int k, const Vec3& world) const {
  const VoxelLeaves& g = packing;
  if (!(g.voxelSize > 0)) return 0;
  const double inv = 1.0 / g.voxelSize;
  const int64_t i = int64_t(std::floor(world.x * inv + 0.5)), j = int64_t(std::floor(world.y * inv + 0.5)),
                l = int64_t(std::floor(world.z * inv + 0.5));
  if (fractions.empty()) return k == 0 && g.voxel(i, j, l) > 0 ? 1.0f : 0.0f;
  if (k < 0 || size_t(k) >= fractions.size()) return 0;
  return fractions[size_t(k)].voxel(i, j, l);
}

GrainDensity buildGrainDensity(const InstancedGrainsDesc& desc, const GrainDensityOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  validateInstancedGrains(desc);
  const std::string& name = desc.name;
  if (!desc.xf.isFinite() || !(std::fabs(desc.xf.determinant3()) > 0))
    throw InputError(name, "transform", "is not invertible");
  const double det = std::fabs(desc.xf.determinant3()), linear = std::cbrt(det);

  // Prototypes: volume, volume centroid and bounding radius (grain.h's fit) at scale 1.
  const size_t P = desc.prototypes.size();
  std::vector<double> protoVolume(P);
  std::vector<Vec3> protoCentroid(P);
  std::vector<float> protoRadius(P);
  {
    const EmbreeDevice device = makeEmbreeDevice();
    for (size_t p = 0; p < P; ++p) {
      const GrainPrototypeDesc& pd = desc.prototypes[p];
      validateClosed(pd.mesh, pd.name);
      meshVolumeCentroid(pd.mesh, protoVolume[p], protoCentroid[p]);
      protoVolume[p] = std::fabs(protoVolume[p]);
      protoRadius[p] = makeGrainPrototype(device, pd).fitRadius;
    }
  }

  const size_t n = desc.size();
  // One pass for both sums, each in index order.
  double radiusSum = 0, volumeSum = 0;
  for (size_t i = 0; i < n; ++i) {
    const size_t p = size_t(desc.protoIndices[i]);
    const float s = desc.scales.empty() ? 1.0f : desc.scales[i];
    radiusSum += double(protoRadius[p]) * double(s);
    volumeSum += float(protoVolume[p] * double(s) * s * s * det);
  }
  GrainDensity out;
  out.stats.grains = int64_t(n);
  out.stats.meanRadius = n ? float(radiusSum / double(n) * linear) : 0.0f;
  for (const GrainPrototypeDesc& p : desc.prototypes) out.prototypeNames.push_back(p.name);

  double h = options.kernelWidth;
  if (!(h > 0)) {
    if (std::isnan(h) || h < 0) throw InputError(name, "kernelWidth", str(h, " must be > 0 (or 0: kernelRadii)"));
    if (!(options.kernelRadii > 0) || !std::isfinite(options.kernelRadii))
      throw InputError(name, "kernelRadii", str(options.kernelRadii, " must be finite and > 0"));
    h = double(options.kernelRadii) * out.stats.meanRadius;
  }
  if (!std::isfinite(h) || !(h > 0)) throw InputError(name, "kernelWidth", str(h, " must be finite and > 0"));
  double delta = options.voxelSize > 0 ? double(options.voxelSize) : 0.5 * h;
  if (std::isnan(options.voxelSize) || !std::isfinite(delta))
    throw InputError(name, "voxelSize", str(options.voxelSize, " must be finite"));
  if (delta < 0.25 * h * (1 - 1e-6) || delta > h * (1 + 1e-6))
    throw InputError(name, "voxelSize", str(delta, " must lie within [h/4, h] of the kernel width h = ", h));
  out.kernelWidth = float(h);
  out.packing.voxelSize = float(delta);
  delta = out.packing.voxelSize;  // the float the grid keeps
  const double reach = 2.0 * h / delta;  // support half-width, voxels (<= 8)

  // A grain's volume centroid in voxel index units, its volume and prototype: computed
  // where needed, never stored for all grains (48 bytes a grain would be 4.5 GiB at 10^8).
  auto splatOf = [&](size_t i) {
    Splat sp;
    const int p = desc.protoIndices[i];
    const float s = desc.scales.empty() ? 1.0f : desc.scales[i];
    const Quat q = desc.orientations.empty() ? Quat() : desc.orientations[i];
    const Vec3d c = desc.xf.pointD(desc.positions[i] + rotate(q, protoCentroid[size_t(p)] * s));
    sp.u[0] = c.x / delta;
    sp.u[1] = c.y / delta;
    sp.u[2] = c.z / delta;
    sp.volume = float(protoVolume[size_t(p)] * double(s) * s * s * det);
    sp.proto = p;
    return sp;
  };
  out.stats.totalVolume = volumeSum;

  // The range check (keys hold leaf coordinates in [−2^20, 2^20)).
  struct Range {
    double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
  };
  const Range range = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, n, 16384), Range(),
      [&](const tbb::blocked_range<size_t>& r, Range m) {
        for (size_t i = r.begin(); i != r.end(); ++i) {
          const Splat sp = splatOf(i);
          for (int a = 0; a < 3; ++a) {
            m.lo[a] = std::min(m.lo[a], sp.u[a]);
            m.hi[a] = std::max(m.hi[a], sp.u[a]);
          }
        }
        return m;
      },
      [](Range a, const Range& b) {
        for (int k = 0; k < 3; ++k) {
          a.lo[k] = std::min(a.lo[k], b.lo[k]);
          a.hi[k] = std::max(a.hi[k], b.hi[k]);
        }
        return a;
      });
  for (int a = 0; a < 3; ++a)
    if (n && (range.hi[a] - range.lo[a] > double(1 << 20) || std::fabs(range.lo[a]) > double(kKeyBias) * 8 - 64 ||
              std::fabs(range.hi[a]) > double(kKeyBias) * 8 - 64))
      throw InputError(name, "voxelSize",
                       str(delta, " is too small for the grains' extent: more than 2^20 voxels along an axis, or "
                                  "grains beyond 2^23 voxels from the origin"));
  auto homeOf = [](const Splat& sp, int64_t l[3]) {
    for (int a = 0; a < 3; ++a) l[a] = floorDiv8(int64_t(std::floor(sp.u[a])));
  };

  // The grains by the x of their home leaf (the leaf holding their centre), each slab of
  // one leaf's width in index order: a counting sort in fixed chunks (deterministic).
  const int64_t x0 = n ? floorDiv8(int64_t(std::floor(range.lo[0]))) : 0;
  const size_t slabs = n ? size_t(floorDiv8(int64_t(std::floor(range.hi[0]))) - x0 + 1) : 0;
  const size_t chunks = std::min<size_t>(256, std::max<size_t>(1, n / 65536));
  auto chunkBegin = [&](size_t c) { return n * c / chunks; };
  std::vector<uint32_t> chunkCount(chunks * slabs, 0);
  std::vector<std::vector<uint64_t>> chunkHomes(chunks);  // each chunk's home leaves, sorted
  tbb::parallel_for(size_t(0), chunks, [&](size_t c) {
    std::vector<uint64_t>& homes = chunkHomes[c];
    uint64_t last = ~uint64_t(0);
    for (size_t i = chunkBegin(c); i < chunkBegin(c + 1); ++i) {
      int64_t l[3];
      homeOf(splatOf(i), l);
      ++chunkCount[c * slabs + size_t(l[0] - x0)];
      const uint64_t key = leafKey(l[0], l[1], l[2]);
      if (key != last) homes.push_back(key);
      last = key;
    }
    std::sort(homes.begin(), homes.end());
    homes.erase(std::unique(homes.begin(), homes.end()), homes.end());
    homes.shrink_to_fit();
  });
  std::vector<size_t> slabStart(slabs + 1, 0);
  {
    size_t at = 0;
    for (size_t x = 0; x < slabs; ++x) {
      slabStart[x] = at;
      for (size_t c = 0; c < chunks; ++c) {
        const uint32_t k = chunkCount[c * slabs + x];
        chunkCount[c * slabs + x] = uint32_t(at - slabStart[x]);  // the chunk's first place in the slab
        at += k;
      }
    }
    slabStart[slabs] = at;
  }
  std::vector<uint32_t> order(n);
  tbb::parallel_for(size_t(0), chunks, [&](size_t c) {
    for (size_t i = chunkBegin(c); i < chunkBegin(c + 1); ++i) {
      int64_t l[3];
      homeOf(splatOf(i), l);
      const size_t x = size_t(l[0] - x0);
      order[slabStart[x] + chunkCount[c * slabs + x]++] = uint32_t(i);
    }
  });
  chunkCount = std::vector<uint32_t>();

  // A slab's grains grouped by home leaf in key order, each leaf's in index order, with the
  // normalisation of their kernel per axis (the same for every leaf a grain reaches); and
  // per home leaf and direction d (target = home − d, dir = 9 (dx + 1) + 3 (dy + 1) + dz + 1)
  // the grains whose support reaches that target, in index order: a target visits only
  // grains that add to it (the others would add nothing), not all 27 leaves' grains.
  struct WindowSplat {
    Splat sp;
    double norm[3];
  };
  struct Slab {
    std::vector<WindowSplat> splats;
    std::vector<uint64_t> homeKeys;
    std::vector<size_t> homeStart;      // one more than homeKeys
    std::vector<uint32_t> reaching;     // places in splats
    std::vector<size_t> reachingStart;  // per home leaf and dir, one more in all
  };
  // Per axis a grain's support s0..s1 may reach the leaf below its home leaf (bit 2a: then
  // directions with d_a = +1 reach the target) and the leaf above (bit 2a + 1: d_a = −1);
  // the voxels s0..s1 against the home leaf's first and last, as the gather clips them.
  auto forDirs = [&](const Splat& sp, const int64_t home[3], auto&& fn) {
    int opts[3][3], count[3];
    for (int a = 0; a < 3; ++a) {
      const int64_t s0 = int64_t(std::ceil(sp.u[a] - reach)), s1 = int64_t(std::floor(sp.u[a] + reach));
      count[a] = 0;
      opts[a][count[a]++] = 0;
      if (s0 <= home[a] * 8 - 1) opts[a][count[a]++] = 1;
      if (s1 >= home[a] * 8 + 8) opts[a][count[a]++] = -1;
    }
    for (int i = 0; i < count[0]; ++i)
      for (int j = 0; j < count[1]; ++j)
        for (int k = 0; k < count[2]; ++k) fn(9 * (opts[0][i] + 1) + 3 * (opts[1][j] + 1) + opts[2][k] + 1);
  };
  std::vector<uint64_t> homeKeys;  // every home leaf, in key order
  for (const auto& hk : chunkHomes) homeKeys.insert(homeKeys.end(), hk.begin(), hk.end());
  chunkHomes = std::vector<std::vector<uint64_t>>();
  tbb::parallel_sort(homeKeys.begin(), homeKeys.end());
  homeKeys.erase(std::unique(homeKeys.begin(), homeKeys.end()), homeKeys.end());
  auto makeSlab = [&](size_t x) {
    Slab slab;
    const size_t m = slabStart[x + 1] - slabStart[x];
    const uint32_t* grains = order.data() + slabStart[x];
    const int64_t lx = x0 + int64_t(x);
    const auto first = std::lower_bound(homeKeys.begin(), homeKeys.end(), leafKey(lx, -kKeyBias, -kKeyBias));
    const auto last = std::lower_bound(first, homeKeys.end(), leafKey(lx + 1, -kKeyBias, -kKeyBias));
    slab.homeKeys.assign(first, last);
    const size_t H = slab.homeKeys.size();
    // A stable counting sort by home leaf, in fixed chunks.
    const size_t parts = std::min<size_t>(16, m / 16384 + 1);
    auto partBegin = [&](size_t c) { return m * c / parts; };
    std::vector<Splat> splats(m);
    std::vector<uint32_t> home(m), count(parts * H, 0);
    tbb::parallel_for(size_t(0), parts, [&](size_t c) {
      for (size_t k = partBegin(c); k < partBegin(c + 1); ++k) {
        splats[k] = splatOf(grains[k]);
        int64_t l[3];
        homeOf(splats[k], l);
        home[k] = uint32_t(std::lower_bound(slab.homeKeys.begin(), slab.homeKeys.end(), leafKey(l[0], l[1], l[2])) -
                           slab.homeKeys.begin());
        ++count[c * H + home[k]];
      }
    });
    slab.homeStart.resize(H + 1);
    size_t at = 0;
    for (size_t hb = 0; hb < H; ++hb) {
      slab.homeStart[hb] = at;
      for (size_t c = 0; c < parts; ++c) {
        const uint32_t k = count[c * H + hb];
        count[c * H + hb] = uint32_t(at);
        at += k;
      }
    }
    slab.homeStart[H] = at;
    slab.splats.resize(m);
    tbb::parallel_for(size_t(0), parts, [&](size_t c) {
      for (size_t k = partBegin(c); k < partBegin(c + 1); ++k) {
        WindowSplat& w = slab.splats[count[c * H + home[k]]++];
        w.sp = splats[k];
        for (int a = 0; a < 3; ++a) {
          // As the gather normalised it: over the whole support.
          const int64_t s0 = int64_t(std::ceil(w.sp.u[a] - reach)), s1 = int64_t(std::floor(w.sp.u[a] + reach));
          double norm = 0;
          for (int64_t j = s0; j <= s1; ++j) norm += bspline3((double(j) - w.sp.u[a]) * delta / h);
          w.norm[a] = norm;
        }
      }
    });
    splats = {};
    home = {};
    count = {};
    slab.reachingStart.assign(H * 27 + 1, 0);
    tbb::parallel_for(size_t(0), H, [&](size_t hb) {
      int64_t l[3];
      keyLeaf(slab.homeKeys[hb], l);
      for (size_t g = slab.homeStart[hb]; g != slab.homeStart[hb + 1]; ++g)
        forDirs(slab.splats[g].sp, l, [&](int dir) { ++slab.reachingStart[hb * 27 + size_t(dir) + 1]; });
    });
    for (size_t k = 1; k < slab.reachingStart.size(); ++k) slab.reachingStart[k] += slab.reachingStart[k - 1];
    slab.reaching.resize(slab.reachingStart.back());
    tbb::parallel_for(size_t(0), H, [&](size_t hb) {
      int64_t l[3];
      keyLeaf(slab.homeKeys[hb], l);
      size_t cursor[27];
      for (int dir = 0; dir < 27; ++dir) cursor[dir] = slab.reachingStart[hb * 27 + size_t(dir)];
      for (size_t g = slab.homeStart[hb]; g != slab.homeStart[hb + 1]; ++g)
        forDirs(slab.splats[g].sp, l, [&](int dir) { slab.reaching[cursor[dir]++] = uint32_t(g); });
    });
    return slab;
  };

  // Target leaves (every leaf a kernel can reach: the home leaves and their 26 neighbours),
  // in key order (= origin order, x-major: slab by slab).
  const size_t homeLeaves = homeKeys.size();
  std::vector<uint64_t> targets;
  targets.reserve(homeLeaves * 27);
  for (uint64_t k : homeKeys) {
    int64_t l[3];
    keyLeaf(k, l);
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) targets.push_back(leafKey(l[0] + dx, l[1] + dy, l[2] + dz));
  }
  tbb::parallel_sort(targets.begin(), targets.end());
  targets.erase(std::unique(targets.begin(), targets.end()), targets.end());
  targets.shrink_to_fit();

  const bool mix = options.fractions && P > 1;
  const size_t T = targets.size();
  // Written in place at each target's index, the leaves no kernel reached squeezed out below.
  out.packing.values.resize(T * VoxelLeaves::kLeafVoxels);
  if (mix) out.fractions.assign(P, VoxelLeaves());
  for (size_t p = 0; mix && p < P; ++p) {
    out.fractions[p].voxelSize = out.packing.voxelSize;
    out.fractions[p].values.resize(T * VoxelLeaves::kLeafVoxels);
  }
  std::vector<uint8_t> touched(T, 0);
  const double invVoxel3 = 1.0 / (delta * delta * delta);
  // The window of slabs x − 1, x, x + 1 around the targets' slab x.
  std::vector<Slab> window(3);
  int64_t windowX = INT64_MIN;  // slab index (x0-relative) of window[1]
  size_t splatPeak = 0;  // bytes of the window at its largest
  for (size_t t0 = 0; t0 < T;) {
    int64_t L0[3];
    keyLeaf(targets[t0], L0);
    size_t t1 = t0;
    while (t1 < T && (targets[t1] >> 42) == (targets[t0] >> 42)) ++t1;
    const int64_t X = L0[0] - x0;  // this run of targets' slab
    auto slabAt = [&](int64_t x) { return x >= 0 && x < int64_t(slabs) ? makeSlab(size_t(x)) : Slab(); };
    if (X == windowX + 1) {
      window[0] = std::move(window[1]);
      window[1] = std::move(window[2]);
      window[2] = slabAt(X + 1);
    } else {
      for (int k = 0; k < 3; ++k) window[size_t(k)] = slabAt(X - 1 + k);
    }
    windowX = X;
    size_t windowBytes = 0;
    for (const Slab& w : window)
      windowBytes += w.splats.size() * sizeof(WindowSplat) + w.reaching.size() * sizeof(uint32_t) +
                     (w.reachingStart.size() + w.homeStart.size() + w.homeKeys.size()) * sizeof(size_t);
    splatPeak = std::max(splatPeak, windowBytes);
    tbb::parallel_for(tbb::blocked_range<size_t>(t0, t1, 4), [&](const tbb::blocked_range<size_t>& r) {
      std::vector<double> acc(VoxelLeaves::kLeafVoxels), num(mix ? P * VoxelLeaves::kLeafVoxels : 0);
      double w[3][VoxelLeaves::kLeafDim];
      for (size_t t = r.begin(); t != r.end(); ++t) {
        int64_t L[3];
        keyLeaf(targets[t], L);
        std::fill(acc.begin(), acc.end(), 0.0);
        std::fill(num.begin(), num.end(), 0.0);
        bool any = false;
        for (int dx = -1; dx <= 1; ++dx) {
          const Slab& slab = window[size_t(dx + 1)];
          for (int dy = -1; dy <= 1; ++dy)
            for (int dz = -1; dz <= 1; ++dz) {
              const uint64_t hk = leafKey(L[0] + dx, L[1] + dy, L[2] + dz);
              auto it = std::lower_bound(slab.homeKeys.begin(), slab.homeKeys.end(), hk);
              if (it == slab.homeKeys.end() || *it != hk) continue;
              const size_t hb = size_t(it - slab.homeKeys.begin());
              const size_t dir = size_t(9 * (dx + 1) + 3 * (dy + 1) + dz + 1);
              for (size_t r = slab.reachingStart[hb * 27 + dir]; r != slab.reachingStart[hb * 27 + dir + 1]; ++r) {
                const WindowSplat& ws = slab.splats[slab.reaching[r]];
                const Splat& sp = ws.sp;
                int64_t a0[3], a1[3];
                bool inside = true;
                for (int a = 0; a < 3 && inside; ++a) {
                  // Voxels within the support, then those of this leaf.
                  const int64_t s0 = int64_t(std::ceil(sp.u[a] - reach)), s1 = int64_t(std::floor(sp.u[a] + reach));
                  a0[a] = std::max(s0, L[a] * 8);
                  a1[a] = std::min(s1, L[a] * 8 + 7);
                  if (a0[a] > a1[a]) { inside = false; break; }
                  // Normalised per axis over the whole support (exactly 1/Δ at Δ = h/2 already).
                  const double norm = ws.norm[a];
                  for (int64_t j = a0[a]; j <= a1[a]; ++j)
                    w[a][j - L[a] * 8] = norm > 0 ? bspline3((double(j) - sp.u[a]) * delta / h) / norm : 0.0;
                }
                if (!inside) continue;
                any = true;
                const double v = double(sp.volume) * invVoxel3;
                for (int64_t i = a0[0]; i <= a1[0]; ++i) {
                  const double wi = w[0][i - L[0] * 8];
                  for (int64_t j = a0[1]; j <= a1[1]; ++j) {
                    const double wij = wi * w[1][j - L[1] * 8];
                    const int base = VoxelLeaves::offset(int(i & 7), int(j & 7), 0);
                    for (int64_t k = a0[2]; k <= a1[2]; ++k) {
                      const double wk = wij * w[2][k - L[2] * 8];
                      acc[size_t(base + int(k & 7))] += v * wk;
                      if (mix) num[size_t(sp.proto) * VoxelLeaves::kLeafVoxels + size_t(base + int(k & 7))] += wk;
                    }
                  }
                }
              }
            }
        }
        if (!any) continue;
        bool nonzero = false;
        float* values = out.packing.values.data() + t * VoxelLeaves::kLeafVoxels;
        for (int o = 0; o < VoxelLeaves::kLeafVoxels; ++o) {
          // Below float's smallest normal a value is 0: a denormal reads as 0 wherever the
          // floating-point mode flushes them (the fractions follow the value kept).
          float f = float(acc[size_t(o)]);
          if (!(f >= std::numeric_limits<float>::min())) f = 0.0f;
          values[o] = f;
          nonzero |= f > 0;
          if (!mix || f == 0.0f) continue;  // the fractions were made 0
          double total = 0;
          for (size_t p = 0; p < P; ++p) total += num[p * VoxelLeaves::kLeafVoxels + size_t(o)];
          for (size_t p = 0; p < P; ++p)
            out.fractions[p].values[t * VoxelLeaves::kLeafVoxels + size_t(o)] =
                total > 0 ? float(num[p * VoxelLeaves::kLeafVoxels + size_t(o)] / total) : 0.0f;
        }
        touched[t] = nonzero;
      }
    });
    t0 = t1;
  }
  window.clear();
  order = std::vector<uint32_t>();
  out.stats.buildBytes = n * sizeof(uint32_t) + splatPeak + homeLeaves * 27 * sizeof(uint64_t);

  // Keep the leaves some kernel reached, in key order (= origin order), moved down in place.
  size_t kept = 0;
  out.packing.origins.reserve(T);
  for (size_t t = 0; t < T; ++t) {
    if (!touched[t]) continue;
    int64_t L[3];
    keyLeaf(targets[t], L);
    const std::array<int32_t, 3> o = {int32_t(L[0] * 8), int32_t(L[1] * 8), int32_t(L[2] * 8)};
    out.packing.origins.push_back(o);
    auto move = [&](std::vector<float>& v) {
      if (kept != t)
        std::copy(v.begin() + ptrdiff_t(t * VoxelLeaves::kLeafVoxels), v.begin() + ptrdiff_t((t + 1) * VoxelLeaves::kLeafVoxels),
                  v.begin() + ptrdiff_t(kept * VoxelLeaves::kLeafVoxels));
    };
    move(out.packing.values);
    for (size_t p = 0; mix && p < P; ++p) {
      move(out.fractions[p].values);
      out.fractions[p].origins.push_back(o);
    }
    ++kept;
  }
  out.packing.values.resize(kept * VoxelLeaves::kLeafVoxels);
  for (size_t p = 0; mix && p < P; ++p) out.fractions[p].values.resize(kept * VoxelLeaves::kLeafVoxels);
  out.stats.leaves = int64_t(kept);
  out.stats.activeVoxels = out.packing.activeVoxels();
  out.stats.bytes = out.packing.bytes();
  for (const VoxelLeaves& f : out.fractions) out.stats.bytes += f.bytes();
  out.stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return out;
}

}  // namespace granular
