// grain_density.cpp — the grains' packing rate on 8³-voxel leaves (contract in the header).
//
// A scatter in a fixed order: grains are grouped by the leaf holding their centre (their
// home leaf); each home leaf sums its grains' kernels, each grain read and weighed once,
// into a block of voxels covering the leaf and the reach of its kernels, then adds the
// block into the (up to 27) leaves it covers. Home leaves whose blocks could share a leaf
// are never summed at once, and every voxel receives its home leaves in one order, so the
// sums do not depend on the threads.
// Memory: the grains are ordered by the x of their home leaf (4 bytes a grain), and the
// home leaves are summed one slab of leaves (constant x) at a time, whose grains' centres
// and volumes (36 bytes a grain) exist only then.
#include "grain_density.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
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

  // Target leaves (every leaf a kernel can reach: the home leaves and their 26 neighbours),
  // in key order (= origin order, x-major: slab by slab).
  std::vector<uint64_t> homeKeys;  // every home leaf, in key order
  for (const auto& hk : chunkHomes) homeKeys.insert(homeKeys.end(), hk.begin(), hk.end());
  chunkHomes = std::vector<std::vector<uint64_t>>();
  tbb::parallel_sort(homeKeys.begin(), homeKeys.end());
  homeKeys.erase(std::unique(homeKeys.begin(), homeKeys.end()), homeKeys.end());
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
  auto targetOf = [&](int64_t lx, int64_t ly, int64_t lz) {
    return size_t(std::lower_bound(targets.begin(), targets.end(), leafKey(lx, ly, lz)) - targets.begin());
  };

  const bool mix = options.fractions && P > 1;
  const size_t T = targets.size();
  // Written in place at each target's index, the leaves no kernel reached squeezed out below.
  // With several prototypes the fractions' arrays first sum each prototype's weights.
  out.packing.values.assign(T * VoxelLeaves::kLeafVoxels, 0.0f);
  if (mix) out.fractions.assign(P, VoxelLeaves());
  for (size_t p = 0; mix && p < P; ++p) {
    out.fractions[p].voxelSize = out.packing.voxelSize;
    out.fractions[p].values.assign(T * VoxelLeaves::kLeafVoxels, 0.0f);
  }
  std::vector<uint8_t> touched(T, 0);
  const double invVoxel3 = 1.0 / (delta * delta * delta);

  // A home leaf's grains reach the voxels [8 l − R, 8 l + 7 + R] per axis, R = ⌈2h/Δ⌉ (at
  // most 8: no further than the next leaf): a block of B³ voxels summed in double, then
  // added into the (up to 27) targets it covers.
  const int R = std::min(8, int(std::ceil(reach))), B = 8 + 2 * R;
  const size_t blockVoxels = size_t(B) * B * B;
  struct Block {
    std::vector<double> f, num;  // B³; P × B³ with several prototypes
  };
  tbb::enumerable_thread_specific<Block> blocks([&] {
    Block b;
    b.f.resize(blockVoxels);
    b.num.resize(mix ? P * blockVoxels : 0);
    return b;
  });
  auto scatterHome = [&](const Splat* sp, size_t count, const int64_t l[3]) {
    Block& b = blocks.local();
    std::fill(b.f.begin(), b.f.end(), 0.0);
    std::fill(b.num.begin(), b.num.end(), 0.0);
    for (size_t g = 0; g < count; ++g) {
      const Splat& s = sp[g];
      // Per axis the weights over the support, normalised to sum to 1 (exactly 1/Δ · Δ
      // at Δ = h/2 already), and where they start in the block.
      double w[3][17];
      int first[3], len[3];
      for (int a = 0; a < 3; ++a) {
        const int64_t s0 = int64_t(std::ceil(s.u[a] - reach)), s1 = int64_t(std::floor(s.u[a] + reach));
        double norm = 0;
        for (int64_t j = s0; j <= s1; ++j) norm += w[a][j - s0] = bspline3((double(j) - s.u[a]) * delta / h);
        const double inv = norm > 0 ? 1.0 / norm : 0.0;
        for (int64_t j = s0; j <= s1; ++j) w[a][j - s0] *= inv;
        first[a] = int(s0 - (l[a] * 8 - R));
        len[a] = int(s1 - s0 + 1);
        // s0 ≥ 8 l − ⌊reach⌋ ≥ 8 l − R always; s1 ≤ 8 l + 7 + R but where Δ rounds just
        // below h/4 (R capped at 8), whose weight there, at ±2h, is about 0.
        len[a] = std::min(len[a], B - first[a]);
      }
      const double v = double(s.volume) * invVoxel3;
      double* num = mix ? b.num.data() + size_t(s.proto) * blockVoxels : nullptr;
      for (int i = 0; i < len[0]; ++i) {
        const double wi = w[0][i];
        for (int j = 0; j < len[1]; ++j) {
          const double wij = wi * w[1][j];
          const size_t row = (size_t(first[0] + i) * size_t(B) + size_t(first[1] + j)) * size_t(B) + size_t(first[2]);
          double* f = b.f.data() + row;
          for (int k = 0; k < len[2]; ++k) f[k] += v * (wij * w[2][k]);
          if (num)
            for (int k = 0; k < len[2]; ++k) num[row + size_t(k)] += wij * w[2][k];
        }
      }
    }
    // Into the targets: per axis the block's voxels [0, R) lie in the leaf below, [R, R + 8)
    // in the home leaf, [R + 8, B) in the leaf above.
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          const int d[3] = {dx, dy, dz};
          int lo[3], hi[3];
          for (int a = 0; a < 3; ++a) {
            lo[a] = d[a] < 0 ? 0 : d[a] == 0 ? R : R + 8;
            hi[a] = d[a] < 0 ? R : d[a] == 0 ? R + 8 : B;
          }
          if (lo[0] == hi[0] || lo[1] == hi[1] || lo[2] == hi[2]) continue;
          const size_t t = targetOf(l[0] + dx, l[1] + dy, l[2] + dz);
          touched[t] = 1;
          float* dst = out.packing.values.data() + t * VoxelLeaves::kLeafVoxels;
          for (int i = lo[0]; i < hi[0]; ++i)
            for (int j = lo[1]; j < hi[1]; ++j)
              for (int k = lo[2]; k < hi[2]; ++k) {
                // Block voxel b lies at 8 l − R + b, in the target at (8 l − R + b) & 7.
                const int o = VoxelLeaves::offset(i - R, j - R, k - R);
                const size_t src = (size_t(i) * size_t(B) + size_t(j)) * size_t(B) + size_t(k);
                dst[o] = float(double(dst[o]) + b.f[src]);
                for (size_t p = 0; mix && p < P; ++p) {
                  float* nd = out.fractions[p].values.data() + t * VoxelLeaves::kLeafVoxels;
                  nd[o] = float(double(nd[o]) + b.num[p * blockVoxels + src]);
                }
              }
        }
  };

  // Slab by slab (constant x of the home leaf): its grains grouped by home leaf in key
  // order, each leaf's in index order (a stable counting sort in fixed chunks), then its
  // home leaves scattered in nine passes by (y mod 3, z mod 3) of the leaf: home leaves of
  // one pass are 3 leaves apart or more, so their blocks (±1 leaf) never share a target,
  // and every target voxel sums its home leaves in a fixed order (slab, pass, grain)
  // whatever the threads.
  size_t slabPeak = 0;  // bytes of a slab's working arrays at their largest
  for (size_t x = 0; x < slabs; ++x) {
    const size_t m = slabStart[x + 1] - slabStart[x];
    if (m == 0) continue;
    const uint32_t* grains = order.data() + slabStart[x];
    const int64_t lx = x0 + int64_t(x);
    const auto firstHome = std::lower_bound(homeKeys.begin(), homeKeys.end(), leafKey(lx, -kKeyBias, -kKeyBias));
    const auto lastHome = std::lower_bound(firstHome, homeKeys.end(), leafKey(lx + 1, -kKeyBias, -kKeyBias));
    const std::vector<uint64_t> slabHomes(firstHome, lastHome);
    const size_t H = slabHomes.size();
    const size_t parts = std::min<size_t>(16, m / 16384 + 1);
    auto partBegin = [&](size_t c) { return m * c / parts; };
    // Each home leaf's place in the slab: through a table over the slab's (y, z) box of
    // leaves where that box is not much larger than the leaves it holds, else searched.
    int64_t ylo = INT64_MAX, yhi = INT64_MIN, zlo = INT64_MAX, zhi = INT64_MIN;
    for (uint64_t k : slabHomes) {
      int64_t l[3];
      keyLeaf(k, l);
      ylo = std::min(ylo, l[1]), yhi = std::max(yhi, l[1]), zlo = std::min(zlo, l[2]), zhi = std::max(zhi, l[2]);
    }
    const size_t ny = size_t(yhi - ylo + 1), nz = size_t(zhi - zlo + 1);
    std::vector<uint32_t> table;
    if (double(ny) * double(nz) <= 16.0 * double(H) + 4096) {
      table.resize(ny * nz);
      for (size_t hb = 0; hb < H; ++hb) {
        int64_t l[3];
        keyLeaf(slabHomes[hb], l);
        table[size_t(l[1] - ylo) * nz + size_t(l[2] - zlo)] = uint32_t(hb);
      }
    }
    auto placeOf = [&](const int64_t l[3]) {
      return table.empty() ? uint32_t(std::lower_bound(slabHomes.begin(), slabHomes.end(), leafKey(l[0], l[1], l[2])) -
                                      slabHomes.begin())
                           : table[size_t(l[1] - ylo) * nz + size_t(l[2] - zlo)];
    };
    std::vector<Splat> unsorted(m);
    std::vector<uint32_t> home(m), count(parts * H, 0);
    tbb::parallel_for(size_t(0), parts, [&](size_t c) {
      for (size_t k = partBegin(c); k < partBegin(c + 1); ++k) {
        int64_t l[3];
        unsorted[k] = splatOf(grains[k]);
        homeOf(unsorted[k], l);
        home[k] = placeOf(l);
        ++count[c * H + home[k]];
      }
    });
    std::vector<size_t> homeStart(H + 1);
    size_t at = 0;
    for (size_t hb = 0; hb < H; ++hb) {
      homeStart[hb] = at;
      for (size_t c = 0; c < parts; ++c) {
        const uint32_t k = count[c * H + hb];
        count[c * H + hb] = uint32_t(at);
        at += k;
      }
    }
    homeStart[H] = at;
    std::vector<Splat> splats(m);
    tbb::parallel_for(size_t(0), parts, [&](size_t c) {
      for (size_t k = partBegin(c); k < partBegin(c + 1); ++k) splats[count[c * H + home[k]]++] = unsorted[k];
    });
    slabPeak = std::max(slabPeak, m * (2 * sizeof(Splat) + sizeof(uint32_t)) + (parts * H + table.size()) * sizeof(uint32_t) +
                                      H * (sizeof(uint64_t) + sizeof(size_t)));
    unsorted = {};
    home = {};
    count = {};
    for (int pass = 0; pass < 9; ++pass) {
      std::vector<size_t> these;
      for (size_t hb = 0; hb < H; ++hb) {
        int64_t l[3];
        keyLeaf(slabHomes[hb], l);
        if (int(((l[1] % 3) + 3) % 3) * 3 + int(((l[2] % 3) + 3) % 3) == pass) these.push_back(hb);
      }
      tbb::parallel_for(size_t(0), these.size(), [&](size_t e) {
        const size_t hb = these[e];
        int64_t l[3];
        keyLeaf(slabHomes[hb], l);
        scatterHome(splats.data() + homeStart[hb], homeStart[hb + 1] - homeStart[hb], l);
      });
    }
  }
  order = std::vector<uint32_t>();
  size_t blockBytes = 0;
  for (const Block& b : blocks) blockBytes += (b.f.size() + b.num.size()) * sizeof(double);
  out.stats.buildBytes = n * sizeof(uint32_t) + slabPeak + T * sizeof(uint64_t) + blockBytes;

  // Below float's smallest normal a value is 0: a denormal reads as 0 wherever the
  // floating-point mode flushes them; the fractions divide the prototypes' weights by
  // their sum where a value is kept, else are 0.
  tbb::parallel_for(size_t(0), T, [&](size_t t) {
    if (!touched[t]) return;
    bool nonzero = false;
    float* values = out.packing.values.data() + t * VoxelLeaves::kLeafVoxels;
    for (int o = 0; o < VoxelLeaves::kLeafVoxels; ++o) {
      float& f = values[o];
      if (!(f >= std::numeric_limits<float>::min())) f = 0.0f;
      nonzero |= f > 0;
      if (!mix) continue;
      const size_t at = t * VoxelLeaves::kLeafVoxels + size_t(o);
      double total = 0;
      for (size_t p = 0; p < P; ++p) total += out.fractions[p].values[at];
      for (size_t p = 0; p < P; ++p) {
        float& q = out.fractions[p].values[at];
        q = f > 0 && total > 0 ? float(double(q) / total) : 0.0f;
      }
    }
    touched[t] = nonzero;
  });

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
