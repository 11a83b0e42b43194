// heterogeneous_medium.cpp — spectral and ratio tracking over majorant blocks (contract in
// the header).
#include "heterogeneous_medium.h"

#include <algorithm>
#include <cmath>

#include "error.h"

namespace granular {

namespace {

inline int64_t floorDiv8(int64_t i) { return i >= 0 ? i / 8 : -((-i + 7) / 8); }

constexpr int64_t kMaxBlocks = int64_t(1) << 28;

}  // namespace

HeterogeneousMedium::HeterogeneousMedium(const GrainDensity& density, const MediumParams& ref, const std::string& name)
    : HeterogeneousMedium(density.packing, ref.packingRate, HomogeneousMedium(ref), name) {}

HeterogeneousMedium::HeterogeneousMedium(VoxelLeaves density, float densityRef, const HomogeneousMedium& reference,
                                         const std::string& name)
    : density_(std::move(density)), reference_(reference) {
  if (!(densityRef > 0) || !std::isfinite(densityRef))
    throw InputError(name, "packingRate", str(densityRef, " (the reference density) must be finite and > 0"));
  if (!(density_.voxelSize > 0) || !std::isfinite(density_.voxelSize))
    throw InputError(name, "voxelSize", str(density_.voxelSize, " must be finite and > 0"));
  if (density_.values.size() != density_.origins.size() * size_t(VoxelLeaves::kLeafVoxels))
    throw InputError(name, "values", "must hold 512 values per leaf");
  for (float v : density_.values)
    if (!(v >= 0) || !std::isfinite(v)) throw InputError(name, "values", str(v, " must be finite and >= 0"));
  const Vec3& sigma = reference_.sigmaT();
  if (!isFinite(sigma) || minComponent(sigma) < 0) throw InputError(name, "sigmaT", "must be finite and >= 0");
  scale_ = sigma / densityRef;
  densityRef_ = densityRef;
  maxScale_ = maxComponent(scale_);
  invVoxel_ = 1.0f / density_.voxelSize;
  if (density_.origins.empty()) return;

  // Blocks: the leaves' range, one more below (its stencil reaches the leaves' first voxels).
  int64_t hi[3];
  for (int a = 0; a < 3; ++a) {
    lo_[a] = INT64_MAX;
    hi[a] = INT64_MIN;
  }
  for (const auto& o : density_.origins)
    for (int a = 0; a < 3; ++a) {
      lo_[a] = std::min(lo_[a], int64_t(o[size_t(a)]) / 8 - 1);
      hi[a] = std::max(hi[a], int64_t(o[size_t(a)]) / 8);
    }
  int64_t count = 1;
  for (int a = 0; a < 3; ++a) {
    dims_[a] = hi[a] - lo_[a] + 1;
    count *= dims_[a];
    if (count > kMaxBlocks)
      throw InputError(name, "voxelSize", str(density_.voxelSize, " makes more than 2^28 majorant blocks of 8^3 voxels "
                                                                  "over the density's bounds"));
  }
  blocks_.assign(size_t(count), Block());
  // Each leaf's maximum goes to its own block; the maxima of its voxels of local index 0
  // along a set S of axes also to the block below along S (whose stencil ends there).
  for (size_t l = 0; l < density_.origins.size(); ++l) {
    const auto& o = density_.origins[l];
    const float* v = density_.values.data() + l * VoxelLeaves::kLeafVoxels;
    float m[8] = {0, 0, 0, 0, 0, 0, 0, 0};  // by S as bits (x 1, y 2, z 4)
    for (int i = 0; i < 8; ++i)
      for (int j = 0; j < 8; ++j)
        for (int k = 0; k < 8; ++k) {
          const float x = v[VoxelLeaves::offset(i, j, k)];
          const int s = (i == 0 ? 1 : 0) | (j == 0 ? 2 : 0) | (k == 0 ? 4 : 0);
          // Every subset of s receives x.
          for (int sub = s;; sub = (sub - 1) & s) {
            m[sub] = std::max(m[sub], x);
            if (sub == 0) break;
          }
        }
    const int64_t b[3] = {int64_t(o[0]) / 8, int64_t(o[1]) / 8, int64_t(o[2]) / 8};
    blocks_[size_t(blockIndex(b[0], b[1], b[2]))].leaf = int32_t(l);
    for (int s = 0; s < 8; ++s) {
      const int64_t at = blockIndex(b[0] - (s & 1), b[1] - ((s >> 1) & 1), b[2] - ((s >> 2) & 1));
      Block& blk = blocks_[size_t(at)];
      // Slightly above the bound: trilinear weights rounded in float never exceed it.
      blk.majorant = std::max(blk.majorant, m[s] * maxScale_ * (1.0f + 1e-5f));
    }
  }
}

int64_t HeterogeneousMedium::blockIndex(int64_t bx, int64_t by, int64_t bz) const {
  bx -= lo_[0];
  by -= lo_[1];
  bz -= lo_[2];
  if (bx < 0 || by < 0 || bz < 0 || bx >= dims_[0] || by >= dims_[1] || bz >= dims_[2]) return -1;
  return (bz * dims_[1] + by) * dims_[0] + bx;
}

int64_t HeterogeneousMedium::leafOf(int64_t i, int64_t j, int64_t k) const {
  const int64_t b = blockIndex(floorDiv8(i), floorDiv8(j), floorDiv8(k));
  return b < 0 ? -1 : blocks_[size_t(b)].leaf;
}

float HeterogeneousMedium::sampleLeaves(const float* values, const Vec3& u, float outside) const {
  if (blocks_.empty() || !isFinite(u) || !(maxComponent(vabs(u)) < 1e9f)) return outside;
  auto voxel = [&](int64_t i, int64_t j, int64_t k) {
    const int64_t l = leafOf(i, j, k);
    if (l < 0) return outside;
    return values[size_t(l) * VoxelLeaves::kLeafVoxels + size_t(VoxelLeaves::offset(int(i & 7), int(j & 7), int(k & 7)))];
  };
  const float fx = std::floor(u.x), fy = std::floor(u.y), fz = std::floor(u.z);
  const int64_t i = int64_t(fx), j = int64_t(fy), k = int64_t(fz);
  const float tx = u.x - fx, ty = u.y - fy, tz = u.z - fz;
  const float c00 = voxel(i, j, k) * (1 - tx) + voxel(i + 1, j, k) * tx;
  const float c10 = voxel(i, j + 1, k) * (1 - tx) + voxel(i + 1, j + 1, k) * tx;
  const float c01 = voxel(i, j, k + 1) * (1 - tx) + voxel(i + 1, j, k + 1) * tx;
  const float c11 = voxel(i, j + 1, k + 1) * (1 - tx) + voxel(i + 1, j + 1, k + 1) * tx;
  return (c00 * (1 - ty) + c10 * ty) * (1 - tz) + (c01 * (1 - ty) + c11 * ty) * tz;
}

Vec3 HeterogeneousMedium::sigmaT(const Vec3& p) const { return scale_ * density(p); }

float HeterogeneousMedium::majorant(const Vec3& p) const {
  const Vec3 u = toIndex(p);
  if (blocks_.empty() || !isFinite(u)) return 0;
  const int64_t b = blockIndex(int64_t(std::floor(u.x / 8)), int64_t(std::floor(u.y / 8)), int64_t(std::floor(u.z / 8)));
  return b < 0 ? 0.0f : blocks_[size_t(b)].majorant;
}

Bounds3 HeterogeneousMedium::bounds() const {
  Bounds3 b;
  if (blocks_.empty()) return b;
  const float e = 8 * density_.voxelSize;
  b.extend(Vec3(float(lo_[0]) * e, float(lo_[1]) * e, float(lo_[2]) * e));
  b.extend(Vec3(float(lo_[0] + dims_[0]) * e, float(lo_[1] + dims_[1]) * e, float(lo_[2] + dims_[2]) * e));
  return b;
}

size_t HeterogeneousMedium::bytes() const { return density_.bytes() + blocks_.size() * sizeof(Block); }

template <typename Seg>
void HeterogeneousMedium::walk(const Ray& ray, float tmax, Seg&& seg) const {
  if (blocks_.empty() || !(tmax > ray.tmin)) return;
  const float len = length(ray.d);
  if (!(len > 0) || !std::isfinite(len)) return;
  // Block space: block b spans [b, b + 1) per axis.
  const float inv = invVoxel_ / 8;
  const Vec3 o = ray.o * inv, d = ray.d * inv;
  Bounds3 box;
  box.lo = Vec3(float(lo_[0]), float(lo_[1]), float(lo_[2]));
  box.hi = Vec3(float(lo_[0] + dims_[0]), float(lo_[1] + dims_[1]), float(lo_[2] + dims_[2]));
  const Vec3 invD(1.0f / d.x, 1.0f / d.y, 1.0f / d.z);
  float t0, t1;
  if (!box.intersect(o, invD, ray.tmin, tmax, t0, t1)) return;
  t1 = std::min(t1, tmax);
  int64_t cell[3], step[3];
  float next[3], delta[3];
  for (int a = 0; a < 3; ++a) {
    const float p = o[a] + d[a] * t0;
    cell[a] = std::clamp(int64_t(std::floor(p)), lo_[a], lo_[a] + dims_[a] - 1);
    if (d[a] > 0) {
      step[a] = 1;
      next[a] = (float(cell[a] + 1) - o[a]) * invD[a];
      delta[a] = invD[a];
    } else if (d[a] < 0) {
      step[a] = -1;
      next[a] = (float(cell[a]) - o[a]) * invD[a];
      delta[a] = -invD[a];
    } else {
      step[a] = 0;
      next[a] = kInf;
      delta[a] = kInf;
    }
  }
  float t = t0;
  while (t < t1) {
    const int a = next[0] < next[1] ? (next[0] < next[2] ? 0 : 2) : (next[1] < next[2] ? 1 : 2);
    const float end = std::min(next[a], t1);
    const int64_t b = blockIndex(cell[0], cell[1], cell[2]);
    if (b < 0) return;
    if (end > t && !seg(t, end, blocks_[size_t(b)].majorant * len)) return;
    t = std::max(t, end);
    cell[a] += step[a];
    next[a] += delta[a];
    if (cell[a] < lo_[a] || cell[a] >= lo_[a] + dims_[a]) return;
  }
}

MediumFlight HeterogeneousMedium::sampleFlight(const Ray& ray, float tmax, Rng& rng, const Vec3& pathWeight) const {
  MediumFlight f;
  f.t = tmax;
  const float len = length(ray.d);
  const Vec3 albedo = reference_.albedo();
  walk(ray, tmax, [&](float a, float b, float m) {
    if (!(m > 0)) return true;
    float t = a;
    for (;;) {
      t -= std::log1p(-rng.next1D()) / m;
      if (!(t < b)) return true;  // memoryless: the next block starts afresh
      const Vec3 sigma = scale_ * sampleDensity(toIndex(ray.o + ray.d * t));
      ++f.lookups;
      const float mw = m / len;  // σ̄ per world length
      const Vec3 null = vmax(Vec3(mw) - sigma, Vec3(0.0f));
      Vec3 h = pathWeight * f.weight;
      if (!(maxComponent(h) > 0)) h = f.weight;
      float pt = average(h * sigma), pn = average(h * null);
      if (!(pt + pn > 0)) {
        pt = average(sigma);
        pn = average(null);
      }
      const float Pt = pt / (pt + pn);
      if (rng.next1D() < Pt) {
        f.t = t;
        f.scattered = true;
        f.weight = f.weight * albedo * sigma / (mw * Pt);
        return false;
      }
      f.weight = f.weight * null / (mw * (1 - Pt));
    }
  });
  return f;
}

Vec3 HeterogeneousMedium::transmittance(const Ray& ray, float tmax, Rng& rng, bool roulette, int64_t* lookups) const {
  Vec3 T(1.0f);
  int64_t n = 0;
  const float len = length(ray.d);
  walk(ray, tmax, [&](float a, float b, float m) {
    if (!(m > 0)) return true;
    float t = a;
    const float mw = m / len;
    for (;;) {
      t -= std::log1p(-rng.next1D()) / m;
      if (!(t < b)) return true;
      ++n;
      const Vec3 sigma = scale_ * sampleDensity(toIndex(ray.o + ray.d * t));
      T = T * vmax(Vec3(1.0f) - sigma / mw, Vec3(0.0f));
      if (roulette && maxComponent(T) < 0.125f) {
        if (rng.next1D() < 0.5f) {
          T = Vec3(0.0f);
          return false;
        }
        T = T * 2.0f;
      }
      if (isBlack(T)) return false;
    }
  });
  if (lookups) *lookups += n;
  return T;
}

Vec3 HeterogeneousMedium::transmittanceDelta(const Ray& ray, float tmax, Rng& rng, int64_t* lookups) const {
  const MediumFlight f = sampleFlight(ray, tmax, rng);
  if (lookups) *lookups += f.lookups;
  return f.scattered ? Vec3(0.0f) : f.weight;
}

}  // namespace granular
