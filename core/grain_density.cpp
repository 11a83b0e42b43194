// grain_density.cpp — the grains' packing rate on 8³-voxel leaves (contract in the header).
//
// Gather, not scatter: grains are sorted by the leaf holding their centre (their home
// leaf); every leaf a kernel can reach is then filled by one task that sums, in a fixed
// order, the grains of the 27 home leaves around it. No two tasks write the same voxel,
// so the sums do not depend on the threads, and each grain is weighed once per leaf it
// reaches (at most 8 when Δ >= h/2).
#include "grain_density.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include <tbb/parallel_for.h>
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
  double radiusSum = 0;
  for (size_t i = 0; i < n; ++i)
    radiusSum += double(protoRadius[size_t(desc.protoIndices[i])]) * (desc.scales.empty() ? 1.0 : desc.scales[i]);
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

  // Each grain's volume centroid in voxel index units and its volume.
  std::vector<Splat> splats(n);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i != r.end(); ++i) {
      const int p = desc.protoIndices[i];
      const float s = desc.scales.empty() ? 1.0f : desc.scales[i];
      const Quat q = desc.orientations.empty() ? Quat() : desc.orientations[i];
      const Vec3d c = desc.xf.pointD(desc.positions[i] + rotate(q, protoCentroid[size_t(p)] * s));
      splats[i].u[0] = c.x / delta;
      splats[i].u[1] = c.y / delta;
      splats[i].u[2] = c.z / delta;
      splats[i].volume = float(protoVolume[size_t(p)] * double(s) * s * s * det);
      splats[i].proto = p;
    }
  });
  double volumeSum = 0;
  for (size_t i = 0; i < n; ++i) volumeSum += splats[i].volume;
  out.stats.totalVolume = volumeSum;

  // Home leaves, and the range check (keys hold leaf coordinates in [−2^20, 2^20)).
  std::vector<std::pair<uint64_t, uint32_t>> keys(n);
  double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
  for (size_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], splats[i].u[a]);
      hi[a] = std::max(hi[a], splats[i].u[a]);
    }
  for (int a = 0; a < 3; ++a)
    if (n && (hi[a] - lo[a] > double(1 << 20) || std::fabs(lo[a]) > double(kKeyBias) * 8 - 64 ||
              std::fabs(hi[a]) > double(kKeyBias) * 8 - 64))
      throw InputError(name, "voxelSize",
                       str(delta, " is too small for the grains' extent: more than 2^20 voxels along an axis, or "
                                  "grains beyond 2^23 voxels from the origin"));
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i != r.end(); ++i) {
      const double* u = splats[i].u;
      keys[i] = {leafKey(floorDiv8(int64_t(std::floor(u[0]))), floorDiv8(int64_t(std::floor(u[1]))),
                         floorDiv8(int64_t(std::floor(u[2])))),
                 uint32_t(i)};
    }
  });
  tbb::parallel_sort(keys.begin(), keys.end());
  out.stats.buildBytes = n * (sizeof(Splat) + sizeof(keys[0]));

  std::vector<uint64_t> homeKeys;
  std::vector<size_t> homeStart;
  for (size_t i = 0; i < n; ++i)
    if (i == 0 || keys[i].first != keys[i - 1].first) {
      homeKeys.push_back(keys[i].first);
      homeStart.push_back(i);
    }
  homeStart.push_back(n);
  std::vector<uint64_t> targets;
  targets.reserve(homeKeys.size() * 8);
  for (uint64_t k : homeKeys) {
    int64_t l[3];
    keyLeaf(k, l);
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) targets.push_back(leafKey(l[0] + dx, l[1] + dy, l[2] + dz));
  }
  tbb::parallel_sort(targets.begin(), targets.end());
  targets.erase(std::unique(targets.begin(), targets.end()), targets.end());

  const bool mix = options.fractions && P > 1;
  const size_t T = targets.size();
  std::vector<float> values(T * VoxelLeaves::kLeafVoxels);
  std::vector<float> fractions(mix ? P * T * VoxelLeaves::kLeafVoxels : 0);
  std::vector<uint8_t> touched(T, 0);
  const double invVoxel3 = 1.0 / (delta * delta * delta);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, T, 4), [&](const tbb::blocked_range<size_t>& r) {
    std::vector<double> acc(VoxelLeaves::kLeafVoxels), num(mix ? P * VoxelLeaves::kLeafVoxels : 0);
    double w[3][VoxelLeaves::kLeafDim];
    for (size_t t = r.begin(); t != r.end(); ++t) {
      int64_t L[3];
      keyLeaf(targets[t], L);
      std::fill(acc.begin(), acc.end(), 0.0);
      std::fill(num.begin(), num.end(), 0.0);
      bool any = false;
      for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dz = -1; dz <= 1; ++dz) {
            const uint64_t hk = leafKey(L[0] + dx, L[1] + dy, L[2] + dz);
            auto it = std::lower_bound(homeKeys.begin(), homeKeys.end(), hk);
            if (it == homeKeys.end() || *it != hk) continue;
            const size_t hb = size_t(it - homeKeys.begin());
            for (size_t g = homeStart[hb]; g != homeStart[hb + 1]; ++g) {
              const Splat& sp = splats[keys[g].second];
              int64_t a0[3], a1[3];
              bool inside = true;
              for (int a = 0; a < 3 && inside; ++a) {
                // Voxels within the support, then those of this leaf.
                const int64_t s0 = int64_t(std::ceil(sp.u[a] - reach)), s1 = int64_t(std::floor(sp.u[a] + reach));
                a0[a] = std::max(s0, L[a] * 8);
                a1[a] = std::min(s1, L[a] * 8 + 7);
                if (a0[a] > a1[a]) { inside = false; break; }
                // Normalised per axis over the whole support (exactly 1/Δ at Δ = h/2 already).
                double norm = 0;
                for (int64_t j = s0; j <= s1; ++j) norm += bspline3((double(j) - sp.u[a]) * delta / h);
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
      if (!any) continue;
      bool nonzero = false;
      for (int o = 0; o < VoxelLeaves::kLeafVoxels; ++o) {
        // Below float's smallest normal a value is 0: a denormal reads as 0 wherever the
        // floating-point mode flushes them (the fractions follow the value kept).
        float f = float(acc[size_t(o)]);
        if (!(f >= std::numeric_limits<float>::min())) f = 0.0f;
        values[t * VoxelLeaves::kLeafVoxels + size_t(o)] = f;
        nonzero |= f > 0;
        if (!mix || f == 0.0f) continue;
        double total = 0;
        for (size_t p = 0; p < P; ++p) total += num[p * VoxelLeaves::kLeafVoxels + size_t(o)];
        for (size_t p = 0; p < P; ++p)
          fractions[(p * T + t) * VoxelLeaves::kLeafVoxels + size_t(o)] =
              total > 0 ? float(num[p * VoxelLeaves::kLeafVoxels + size_t(o)] / total) : 0.0f;
      }
      touched[t] = nonzero;
    }
  });

  // Keep the leaves some kernel reached, in key order (= origin order).
  size_t kept = 0;
  for (size_t t = 0; t < T; ++t) kept += touched[t];
  out.packing.origins.reserve(kept);
  out.packing.values.reserve(kept * VoxelLeaves::kLeafVoxels);
  if (mix) out.fractions.assign(P, VoxelLeaves());
  for (size_t p = 0; mix && p < P; ++p) {
    out.fractions[p].voxelSize = out.packing.voxelSize;
    out.fractions[p].values.reserve(kept * VoxelLeaves::kLeafVoxels);
  }
  for (size_t t = 0; t < T; ++t) {
    if (!touched[t]) continue;
    int64_t L[3];
    keyLeaf(targets[t], L);
    const std::array<int32_t, 3> o = {int32_t(L[0] * 8), int32_t(L[1] * 8), int32_t(L[2] * 8)};
    out.packing.origins.push_back(o);
    auto first = values.begin() + ptrdiff_t(t * VoxelLeaves::kLeafVoxels);
    out.packing.values.insert(out.packing.values.end(), first, first + VoxelLeaves::kLeafVoxels);
    for (size_t p = 0; mix && p < P; ++p) {
      out.fractions[p].origins.push_back(o);
      auto f = fractions.begin() + ptrdiff_t((p * T + t) * VoxelLeaves::kLeafVoxels);
      out.fractions[p].values.insert(out.fractions[p].values.end(), f, f + VoxelLeaves::kLeafVoxels);
    }
  }
  out.stats.leaves = int64_t(kept);
  out.stats.activeVoxels = out.packing.activeVoxels();
  out.stats.bytes = out.packing.bytes();
  for (const VoxelLeaves& f : out.fractions) out.stats.bytes += f.bytes();
  out.stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return out;
}

}  // namespace granular
