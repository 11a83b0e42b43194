// heterogeneous_diffusion.cpp — DA's boundary and rule in an instancer's medium (contract
// in the header).
#include "heterogeneous_diffusion.h"

#include <algorithm>
#include <cmath>

#include <openvdb/openvdb.h>
#include <openvdb/tools/FastSweeping.h>
#include <openvdb/tools/Filter.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "vpt.h"

namespace granular {

namespace {

inline int64_t floorDiv(int64_t i, int64_t n) { return i >= 0 ? i / n : -((-i + n - 1) / n); }

// The distance field of the level set f = iso of the filtered density on every voxel of
// the density's leaves. Peak memory: two grids of the leaves.
std::vector<float> levelSetDistances(const openvdb::FloatGrid& filtered, const VoxelLeaves& f, float iso,
                                     float outside) {
  openvdb::FloatGrid::Ptr sdf = openvdb::tools::fogToSdf(filtered, iso);
  std::vector<float> out(f.values.size(), outside);
  if (!sdf) return out;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, f.leafCount(), 64), [&](const tbb::blocked_range<size_t>& r) {
    openvdb::FloatGrid::ConstAccessor read = sdf->getConstAccessor();
    for (size_t l = r.begin(); l != r.end(); ++l) {
      const auto& o = f.origins[l];
      const auto* leaf = read.probeConstLeaf(openvdb::Coord(o[0], o[1], o[2]));
      if (!leaf) continue;
      for (int v = 0; v < VoxelLeaves::kLeafVoxels; ++v) {
        const float d = leaf->getValue(openvdb::Index(v));
        // Voxels no sweep reached (a component without a crossing) keep their side's bound.
        float& to = out[l * VoxelLeaves::kLeafVoxels + size_t(v)];
        to = std::isfinite(d) ? std::clamp(d, -1e30f, outside) : (d < 0 ? -1e30f : outside);
      }
    }
  });
  return out;
}

// f_b, the mean f of the voxels deeper than `depth` (world) inside the level set of the
// filtered density at iso: those whose every voxel centre within that distance has filtered
// f > iso (the inside eroded by a ball; along a line, between voxel centres, the same test
// as a distance field's d <= −depth). fallback without such voxels. Per leaf in parallel,
// then the leaves' sums in order: the same whatever the threads.
float deepMean(const openvdb::FloatGrid& filtered, const VoxelLeaves& f, float iso, float depth, float fallback) {
  const float radius = depth / f.voxelSize;  // voxels
  const int pad = int(std::floor(radius + 1e-4f)), width = 8 + 2 * pad;
  std::vector<int> ball;  // offsets in the padded block within the radius
  for (int a = -pad; a <= pad; ++a)
    for (int b = -pad; b <= pad; ++b)
      for (int c = -pad; c <= pad; ++c)
        if (float(a * a + b * b + c * c) <= radius * radius * (1 + 1e-4f)) ball.push_back((a * width + b) * width + c);
  const int reachLeaves = (pad + 7) / 8;
  std::vector<double> leafSum(f.leafCount()), leafCount(f.leafCount());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, f.leafCount(), 16), [&](const tbb::blocked_range<size_t>& r) {
    openvdb::FloatGrid::ConstAccessor read = filtered.getConstAccessor();
    std::vector<uint8_t> inside(size_t(width) * width * width);
    for (size_t l = r.begin(); l != r.end(); ++l) {
      const auto& o = f.origins[l];
      std::fill(inside.begin(), inside.end(), uint8_t(0));  // no leaf: f = 0, outside
      for (int dx = -reachLeaves; dx <= reachLeaves; ++dx)
        for (int dy = -reachLeaves; dy <= reachLeaves; ++dy)
          for (int dz = -reachLeaves; dz <= reachLeaves; ++dz) {
            const auto* leaf = read.probeConstLeaf(openvdb::Coord(o[0] + 8 * dx, o[1] + 8 * dy, o[2] + 8 * dz));
            if (!leaf) continue;
            for (int i = 0; i < 8; ++i) {
              const int x = 8 * dx + i + pad;
              if (x < 0 || x >= width) continue;
              for (int j = 0; j < 8; ++j) {
                const int y = 8 * dy + j + pad;
                if (y < 0 || y >= width) continue;
                for (int k = 0; k < 8; ++k) {
                  const int z = 8 * dz + k + pad;
                  if (z < 0 || z >= width) continue;
                  inside[size_t((x * width + y) * width + z)] =
                      leaf->getValue(openvdb::Index(VoxelLeaves::offset(i, j, k))) > iso;
                }
              }
            }
          }
      double sum = 0, count = 0;
      for (int i = 0; i < 8; ++i)
        for (int j = 0; j < 8; ++j)
          for (int k = 0; k < 8; ++k) {
            const int at = ((i + pad) * width + j + pad) * width + k + pad;
            if (!std::all_of(ball.begin(), ball.end(), [&](int d) { return inside[size_t(at + d)] != 0; })) continue;
            sum += f.values[l * VoxelLeaves::kLeafVoxels + size_t(VoxelLeaves::offset(i, j, k))];
            count += 1;
          }
      leafSum[l] = sum;
      leafCount[l] = count;
    }
  });
  double sum = 0, count = 0;
  for (size_t l = 0; l < f.leafCount(); ++l) {
    sum += leafSum[l];
    count += leafCount[l];
  }
  return count > 0 ? float(sum / count) : fallback;
}

}  // namespace

FilteredDensity::FilteredDensity(const VoxelLeaves& f) {
  openvdb::initialize();
  auto grid = openvdb::FloatGrid::create(0.0f);
  grid->setTransform(openvdb::math::Transform::createLinearTransform(double(f.voxelSize)));
  // Every voxel of every leaf active with its value: leaves made in parallel, then linked.
  // OpenVDB's leaf layout is VoxelLeaves::offset's: (i << 6) | (j << 3) | k.
  using Leaf = openvdb::FloatGrid::TreeType::LeafNodeType;
  std::vector<Leaf*> leaves(f.leafCount());
  tbb::parallel_for(size_t(0), f.leafCount(), [&](size_t l) {
    const auto& o = f.origins[l];
    auto* leaf = new Leaf(openvdb::Coord(o[0], o[1], o[2]), 0.0f, true);
    for (int v = 0; v < VoxelLeaves::kLeafVoxels; ++v)
      leaf->setValueOnly(openvdb::Index(v), f.values[l * VoxelLeaves::kLeafVoxels + size_t(v)]);
    leaves[l] = leaf;
  });
  for (Leaf* leaf : leaves) grid->tree().addLeaf(leaf);  // the tree owns it
  openvdb::tools::Filter<openvdb::FloatGrid>(*grid).mean(1, 2);  // [1 2 3 2 1]/9 per axis
  grid_ = std::shared_ptr<const void>(grid, grid.get());
}

LevelSetBoundary::LevelSetBoundary(const HeterogeneousMedium& medium, const FilteredDensity& filtered, float iso,
                                   float reach)
    : medium_(&medium), voxelSize_(medium.voxels().voxelSize), reach_(reach) {
  invVoxel_ = 1.0f / voxelSize_;
  // Beyond the leaves f is 0: outside. The value stands in for the distance there (a bound
  // is all sphere tracing from inside needs; it never starts outside).
  outside_ = 2.0f * voxelSize_;
  sdf_ = levelSetDistances(*static_cast<const openvdb::FloatGrid*>(filtered.grid_.get()), medium.voxels(), iso,
                           outside_ + reach);
}

float LevelSetBoundary::distance(const Vec3& p) const {
  return medium_ ? medium_->sampleLeaves(sdf_.data(), p * invVoxel_, outside_) : outside_;
}

Vec3 LevelSetBoundary::normal(const Vec3& p) const {
  const float h = 0.5f * voxelSize_;
  const Vec3 g(distance(p + Vec3(h, 0, 0)) - distance(p - Vec3(h, 0, 0)),
               distance(p + Vec3(0, h, 0)) - distance(p - Vec3(0, h, 0)),
               distance(p + Vec3(0, 0, h)) - distance(p - Vec3(0, 0, h)));
  const float len = length(g);
  return len > 0 && std::isfinite(len) ? g / len : Vec3(0.0f);
}

float LevelSetBoundary::closestPoint(const Vec3& p, Vec3& closest) const {
  const float d = distance(p);
  if (!(d < 0)) return 0.0f;
  closest = p;
  for (int step = 0; step < 3; ++step) {
    const float dc = step == 0 ? d : distance(closest);
    const Vec3 n = normal(closest);
    if (isBlack(n)) return 0.0f;
    closest = closest - n * dc;
  }
  return length(closest - p);
}

bool LevelSetBoundary::intersect(const Vec3& o, const Vec3& d, float tmax, float& t, Vec3& ng) const {
  float s = distance(o);
  float t0 = 0, t1 = 0;
  if (s < 0) {
    const float minStep = voxelSize_ / 16;
    bool crossed = false;
    for (int iter = 0; iter < 1024 && !crossed; ++iter) {
      t0 = t1;
      t1 = t0 + std::max(-0.9f * s, minStep);
      if (!(t1 < tmax)) {
        // The last stretch up to tmax: a crossing there or none.
        t1 = tmax;
        if (!std::isfinite(t1) || !(distance(o + d * t1) >= 0)) return false;
      }
      s = distance(o + d * t1);
      crossed = s >= 0;
    }
    if (!crossed) return false;
    // Bisection between the last inside and the first outside parameter.
    for (int iter = 0; iter < 40 && t1 - t0 > voxelSize_ / 4096; ++iter) {
      const float tm = 0.5f * (t0 + t1);
      (distance(o + d * tm) < 0 ? t0 : t1) = tm;
    }
  }
  t = t1;
  ng = normal(o + d * t);
  if (isBlack(ng)) ng = d;
  return true;
}

float LevelSetBoundary::curvatureRadius(const Vec3& x, float delta) const {
  const float z = -distance(x);
  const Vec3 n = normal(x);
  if (!(z > 0) || isBlack(n)) return 0.0f;
  const Frame frame(n);
  float radius = kInf;
  for (const Vec3& tangent : {frame.s, frame.t}) {
    const float za = -distance(x + tangent * delta), zb = -distance(x - tangent * delta);
    if (!(za > 0) || !(zb > 0)) return 0.0f;  // the boundary within δ aside: an edge
    // Depth at the offsets on a sphere of radius R (convex; concave: a cavity), from
    // (R − z')² = (R − z)² + δ²: R = |z² − z'² + δ²| / (2 |z − z'|), z' their mean.
    const float z2 = 0.5f * (za + zb), drop = std::fabs(z - z2);
    if (drop > 0) radius = std::min(radius, std::fabs(z * z - z2 * z2 + delta * delta) / (2.0f * drop));
  }
  return radius;
}

Vec3 LevelSetBoundary::exitPoint(const Vec3& p, const Vec3& ng) const {
  const float step = 0.5f * voxelSize_;
  float t = 0;
  while (t < reach_ && medium_->density(p + ng * t) > 0) t = std::min(t + step, reach_);
  return p + ng * t;
}

const HeterogeneousDiffusion::Cell* HeterogeneousDiffusion::Level::at(int64_t x, int64_t y, int64_t z) const {
  x -= lo[0];
  y -= lo[1];
  z -= lo[2];
  if (x < 0 || y < 0 || z < 0 || x >= dims[0] || y >= dims[1] || z >= dims[2]) return nullptr;
  return &cells[size_t((z * dims[1] + y) * dims[0] + x)];
}

HeterogeneousDiffusion::HeterogeneousDiffusion(const HeterogeneousMedium& medium, const MediumParams& reference,
                                               float kernelWidth)
    : reference_(reference), profile_(reference) {
  densityRef_ = medium.densityRef();
  voxelSize_ = medium.voxels().voxelSize;
  skin_ = 2.0f * kernelWidth;
  const VoxelLeaves& f = medium.voxels();
  if (f.origins.empty()) return;
  // The bulk's packing: f_ref (Σf²/Σf) counts the skin too, so it is low by the skin's
  // share; the voxels deeper than the skin below the level set at f_ref / 2 give it, and
  // the boundary is the level set at half of it.
  const float reach = skin_ + 2.0f * voxelSize_;
  const FilteredDensity filtered(f);
  bulk_ = deepMean(*static_cast<const openvdb::FloatGrid*>(filtered.grid_.get()), f, 0.5f * densityRef_, skin_,
                   densityRef_);
  const bool atRef = !(std::fabs(bulk_ - densityRef_) > 1e-3f * densityRef_);
  boundary_ = LevelSetBoundary(medium, filtered, 0.5f * (atRef ? densityRef_ : bulk_), reach);
  // Calls fn(origin, i, j, k, f) for each voxel of leaf l deeper than the skin below
  // boundary_: the leaf's origin, the voxel's index in it and its f.
  auto forDeepVoxels = [&](size_t l, auto&& fn) {
    const auto& o = f.origins[l];
    for (int i = 0; i < 8; ++i)
      for (int j = 0; j < 8; ++j)
        for (int k = 0; k < 8; ++k) {
          const size_t v = l * VoxelLeaves::kLeafVoxels + size_t(VoxelLeaves::offset(i, j, k));
          if (!(boundary_.voxelDistance(v) <= -skin_)) continue;
          fn(o, i, j, k, f.values[v]);
        }
  };

  // Level 0: cells of 4³ voxels, over the leaves' bounds (a leaf is 2³ cells).
  Level base;
  int64_t hi[3];
  for (int a = 0; a < 3; ++a) {
    base.lo[a] = INT64_MAX;
    hi[a] = INT64_MIN;
  }
  for (const auto& o : f.origins)
    for (int a = 0; a < 3; ++a) {
      base.lo[a] = std::min(base.lo[a], floorDiv(o[size_t(a)], kCellVoxels));
      hi[a] = std::max(hi[a], floorDiv(o[size_t(a)], kCellVoxels) + 1);
    }
  for (int a = 0; a < 3; ++a) base.dims[a] = hi[a] - base.lo[a] + 1;
  base.cells.assign(size_t(base.dims[0] * base.dims[1] * base.dims[2]), Cell());
  // A cell of 4³ voxels lies in one leaf of 8³: leaves in parallel write disjoint cells.
  tbb::parallel_for(size_t(0), f.leafCount(), [&](size_t l) {
    forDeepVoxels(l, [&](const auto& o, int i, int j, int k, float value) {
      Cell& c = base.cells[size_t(((floorDiv(o[2] + k, kCellVoxels) - base.lo[2]) * base.dims[1] +
                                   (floorDiv(o[1] + j, kCellVoxels) - base.lo[1])) *
                                      base.dims[0] +
                                  (floorDiv(o[0] + i, kCellVoxels) - base.lo[0]))];
      c.sum += value;
      c.count += 1;
    });
  });
  levels_.push_back(std::move(base));
  // Coarser levels until at most 2 cells per axis cover everything (cells split at index 0
  // at every level: a range about it never shrinks to one).
  while (levels_.back().dims[0] > 2 || levels_.back().dims[1] > 2 || levels_.back().dims[2] > 2) {
    const Level& fine = levels_.back();
    Level coarse;
    for (int a = 0; a < 3; ++a) {
      coarse.lo[a] = floorDiv(fine.lo[a], 2);
      coarse.dims[a] = floorDiv(fine.lo[a] + fine.dims[a] - 1, 2) - coarse.lo[a] + 1;
    }
    coarse.cells.assign(size_t(coarse.dims[0] * coarse.dims[1] * coarse.dims[2]), Cell());
    for (int64_t z = 0; z < fine.dims[2]; ++z)
      for (int64_t y = 0; y < fine.dims[1]; ++y)
        for (int64_t x = 0; x < fine.dims[0]; ++x) {
          const Cell& c = fine.cells[size_t((z * fine.dims[1] + y) * fine.dims[0] + x)];
          const int64_t cx = floorDiv(fine.lo[0] + x, 2) - coarse.lo[0], cy = floorDiv(fine.lo[1] + y, 2) - coarse.lo[1],
                        cz = floorDiv(fine.lo[2] + z, 2) - coarse.lo[2];
          Cell& to = coarse.cells[size_t((cz * coarse.dims[1] + cy) * coarse.dims[0] + cx)];
          to.sum += c.sum;
          to.count += c.count;
        }
    levels_.push_back(std::move(coarse));
  }
}

HeterogeneousDiffusion::Region HeterogeneousDiffusion::region(const Vec3& x, float r) const {
  Region out;
  if (levels_.empty() || !isFinite(x) || !(r >= 0) || !std::isfinite(r)) return out;
  const float inv = 1.0f / voxelSize_;
  // Voxel centres within the cube: indices [lo, hi] per axis.
  int64_t lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = int64_t(std::ceil(double(x[a] - r) * inv));
    hi[a] = int64_t(std::floor(double(x[a] + r) * inv));
  }
  // The finest level whose cells the cube spans at most 4 of per axis.
  size_t L = 0;
  for (;; ++L) {
    const int64_t edge = int64_t(kCellVoxels) << L;
    bool fits = true;
    for (int a = 0; a < 3; ++a) fits = fits && floorDiv(hi[a], edge) - floorDiv(lo[a], edge) < 4;
    if (fits || L + 1 == levels_.size()) break;
  }
  const Level& level = levels_[L];
  const int64_t edge = int64_t(kCellVoxels) << L;
  // A cell's mean counts where enough of its voxels are deep: a quarter, at most 64 (a
  // level-0 cell's worth; coarse cells in a thin part are mostly skin or outside).
  const float enough = float(std::min(kMinDeepFraction * double(edge * edge * edge), double(kMinDeepCount)));
  double sum = 0;
  for (int64_t z = floorDiv(lo[2], edge); z <= floorDiv(hi[2], edge); ++z)
    for (int64_t y = floorDiv(lo[1], edge); y <= floorDiv(hi[1], edge); ++y)
      for (int64_t xx = floorDiv(lo[0], edge); xx <= floorDiv(hi[0], edge); ++xx) {
        const Cell* c = level.at(xx, y, z);
        if (!c) continue;
        sum += c->sum;
        out.count += c->count;
        if (c->count >= enough) {
          const float mean = c->sum / c->count;
          out.min = std::min(out.min, mean);
          out.max = std::max(out.max, mean);
        }
      }
  out.mean = out.count > 0 ? float(sum / out.count) : 0.0f;
  return out;
}

HeterogeneousDecision HeterogeneousDiffusion::decide(const Vec3& x, float daDepthFactor) const {
  HeterogeneousDecision d;
  d.depth = -boundary_.distance(x);
  if (!(d.depth >= skin_)) return d;
  const Region r = region(x, kRegionDepths * d.depth);
  if (!(r.count > 0) || !(r.mean > 0)) return d;
  d.packing = r.mean;
  const float daDepth = diffusionDepth(reference_, daDepthFactor) * (densityRef_ / r.mean);
  if (!(d.depth >= daDepth)) return d;
  // No cell with a mean (every one mostly skin): nothing says the region is homogeneous.
  d.spread = r.max >= r.min ? r.max / r.min : kInf;
  if (!(d.spread <= (1.0f + kTolerance) / (1.0f - kTolerance))) {
    d.outcome = DiffusionOutcome::Varies;
    return d;
  }
  const float radius = boundary_.curvatureRadius(x, d.depth);
  d.outcome = radius >= kCurvatureGuard * daDepth ? DiffusionOutcome::Takes : DiffusionOutcome::Curved;
  return d;
}

}  // namespace granular
