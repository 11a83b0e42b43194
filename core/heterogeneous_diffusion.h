// heterogeneous_diffusion.h — the diffusion approximation (DA, diffusion.h) in the
// heterogeneous medium of an instancer's grains (heterogeneous_medium.h): the boundary it
// reads its slab from, and the rule for where it holds (Meng et al. 2015 hand the high
// orders to DA; a simulated heap has no boundary mesh and no uniform density).
//
// Contract.
//  - The boundary (LevelSetBoundary): the level set f = f_b / 2 of the packing-rate field
//    f (grain_density.h), f_b the bulk's packing: the mean f of the voxels deeper than the
//    skin (below) under a first level set at half the medium's f_ref (Σf²/Σf over all
//    voxels, HeterogeneousMedium::densityRef, which the skin lowers: the block of the
//    tests, f_ref 0.30 for a bulk of 0.33, put that first level set half a grain radius
//    out). Deeper than the skin there: every voxel centre within the skin has filtered f
//    above f_ref / 2 (the inside eroded by a ball of the skin's radius; along a line, with
//    the crossing between voxel centres, the test d <= −skin of that level set's distance
//    field, so that no distance field is made for it). A signed distance field on the density's own voxels: OpenVDB's fast sweeping
//    (tools::fogToSdf) of f filtered by OpenVDB's mean filter of 3 voxels, twice
//    ([1 2 3 2 1]/9 along each axis), negative inside, world units, trilinear between
//    voxel centres. The filter (symmetric: a planar surface's half level stays put) takes
//    out the kernel's counting noise, whose bumps of the level set tilted its normals by
//    3–15° and read as curvature.
//    Why half: f is the grains' packing smoothed by the kernel W (width h), so at a free
//    surface it ramps from 0 to f_b over ±2h. W is symmetric, so across a planar surface
//    the ramp's optical depth missing inside the half level equals the optical depth it
//    has outside it: a sharp surface at the half level with f_b within keeps the optical
//    depth of every line through the skin, and in optical depth the planar diffusion
//    equation does not see how σ_t is spread along the normal. DA's slab has that sharp
//    surface.
//    closestPoint(): p moved by −d ∇d/|∇d| and two more such steps onto the level set
//    (d the field; its distance from p); intersect(): sphere tracing (steps of 0.9 |d|,
//    at least Δ/16, Δ the voxel) from an inside point, the crossing bisected to Δ/4096,
//    the normal the field's normalised gradient (central differences over one voxel).
//    exitPoint(): light crossing the half level has the ramp's outer half still to cross,
//    whose optical depth the sharp surface already counted inside; it is out of the
//    medium where f = 0, at most 2h + 2Δ further out along the normal (the kernel's
//    reach and the trilinear stencil), found in steps of Δ/2 (diffusion.cpp stops it just
//    short of a surface in the way: the ground a heap stands on).
//  - The rule (decide()), at a scattering point x of a path that may switch (technique
//    Hybrid, RenderSettings::daMinOrder, vpt.h):
//    1. Depth. z, x's depth below the level set, is at least the skin 2h (within the
//       kernel's reach of the surface f is the kernel's ramp, not the grains' packing) and
//       at least the local medium's DA depth, diffusionDepth(reference, factor) f_ref / f̄.
//    2. Homogeneity. The region: the cube of half-width 3z about x, which holds the column
//       up to the near face and the part of that face within 3z of it, where 68% of a
//       non-absorbing half space's dipole exitance leaves (1 − 1/√10; more with
//       absorption), rounded out to whole cells of the pyramid's level that spans it in at
//       most 4 cells per axis (below). Its deep voxels (deeper than the skin) give f̄, their
//       mean. Each of its cells with at least a quarter of its voxels deep, or 64, has a
//       mean (a thin part's coarse cells are mostly skin and outside, yet hold many); DA
//       holds where the largest and the smallest of those lie within ±ε of their middle:
//       max ≤ (1 + ε)/(1 − ε) · min, ε = 0.1. Cells grow with the region: the variation
//       tested is at the region's scale (a quarter of it), where the diffusion sees it; the
//       kernel's counting noise (a few percent a voxel, grain_density.h) averages out in
//       them. Extremes over the finest cells did not: on the generated heap (a uniform
//       jittered lattice) cells of 4³ voxels spread ±12% over a region of 1000 of them.
//       Why 0.1: a source at depth z escapes as e^{−σ_tr z}, so an error δ in the mean σ_t
//       along its column errs its light by about δ σ_tr z, σ_tr z ≈ 1–1.5 for the light
//       that escapes from beyond the DA depth. Within the tolerance a trend over the
//       region's 6z moves the column's mean (over z) from f̄ by at most ε/3: a few percent
//       of DA's light at worst; noise averages out along the column. Measured with the
//       homogeneity test off (the slabs of tests/core/test_diffusion_heterogeneous.cpp,
//       packing falling by half across the slab, sideways or with depth; bench/README.md):
//       DA − VPT +0.2 ± 0.3% and −0.05 ± 0.2% of the image with DA carrying 12% and 8% of
//       its light, next to DA's own 1–2% on homogeneous media (bench/README.md,
//       "Diffusion"). So ε = 0.1 is conservative: DA only where the medium is close to
//       homogeneous, as the rule promises; beyond it VPT goes on.
//    3. Curvature: diffusion.h's guard, a curvature radius of at least kCurvatureGuard
//       DA depths, measured from depths instead of normals (curvatureRadius()): the depths
//       z± at x ± δ t along two tangents t (δ = z), a sphere of radius R giving
//       (R − z')² = (R − z)² + δ² for their mean z'; the smaller R of the two tangents, 0
//       where the boundary lies within δ aside (an edge). The level set is rough at the
//       grains' scale even filtered: diffusion.h's angles between closest-point normals
//       read its bumps as radii of a few DA depths on a flat slab (DA took 6% of a test
//       slab's paths, 16% with depths, which average the bumps out); a ball of grains
//       reads its radius within 30%.
//    DA then runs on the local homogeneous medium: σ_t = σ_t,ref f̄ / f_ref per channel,
//    the reference's α_s and phase (diffusion.h: diffusionStep with a DiffusionMedium).
//  - Pyramid: level 0 holds per cell of 4³ voxels its deep voxels' sum and count; level
//    L + 1 combines 2³ cells of level L. A region reads one level, the finest at which it
//    spans at most 4 cells per axis: at most 64 reads. Dense over the leaves' bounds:
//    8 bytes a cell, 1/8 byte a voxel. The distance field: 4 bytes a voxel on the
//    density's leaves.
//  - Build: the density's leaves as an OpenVDB grid, every voxel active (leaves filled in
//    parallel), filtered in place (FilteredDensity), f_b from it (the erosion above, in
//    parallel over leaves, their sums added in leaf order), then one distance grid
//    (OpenVDB's sweeps, TBB inside): two grids of the leaves at the peak (4 bytes a voxel
//    each, with OpenVDB's masks). The distances read back and the pyramid's finest level
//    in parallel over leaves (a level-0 cell lies in one leaf: its sum in the same order).
//    Made only where the settings ask for DA (Scene::instancedDiffusion). Thread-safe to
//    query.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "diffusion.h"
#include "heterogeneous_medium.h"
#include "math.h"
#include "medium.h"

namespace granular {

// The packing rate filtered as the boundary reads it (the contract's mean filter), as an
// OpenVDB grid (opaque here): made once, in parallel, for every level set of one density.
class FilteredDensity {
 public:
  explicit FilteredDensity(const VoxelLeaves& f);

 private:
  friend class LevelSetBoundary;
  friend class HeterogeneousDiffusion;
  std::shared_ptr<const void> grid_;  // openvdb::FloatGrid
};

class LevelSetBoundary final : public DiffusionBoundary {
 public:
  LevelSetBoundary() = default;
  // The level set f = iso of medium's density (filtered: medium.voxels() filtered); reach:
  // how far beyond it f is > 0 at most. The medium must outlive this.
  LevelSetBoundary(const HeterogeneousMedium& medium, const FilteredDensity& filtered, float iso, float reach);

  float distance(const Vec3& p) const;  // signed, negative inside (f > iso); trilinear
  // The distance at a voxel centre: index l * 512 + v into the density's leaves (l the
  // leaf, v VoxelLeaves::offset).
  float voxelDistance(size_t index) const { return sdf_[index]; }
  Vec3 normal(const Vec3& p) const;     // the field's normalised gradient (outward)
  float closestPoint(const Vec3& p, Vec3& closest) const override;
  bool intersect(const Vec3& o, const Vec3& d, float tmax, float& t, Vec3& ng) const override;
  Vec3 exitPoint(const Vec3& p, const Vec3& ng) const override;
  // The boundary's radius of curvature seen from x at lateral offsets ±δ (rule 3).
  float curvatureRadius(const Vec3& x, float delta) const;

 private:
  const HeterogeneousMedium* medium_ = nullptr;
  std::vector<float> sdf_;  // 512 per leaf of medium_->voxels(), in its order
  float voxelSize_ = 0, invVoxel_ = 0, reach_ = 0, outside_ = 0;
};

// Why DA is or is not taken at a point (decide()).
enum class DiffusionOutcome { Shallow, Varies, Curved, Takes };

struct HeterogeneousDecision {
  DiffusionOutcome outcome = DiffusionOutcome::Shallow;
  float depth = 0;     // z below the level set (world)
  float packing = 0;   // f̄ over the region (0: not read)
  float spread = 0;    // max / min of the region's cell means (0: not read)
};

class HeterogeneousDiffusion {
 public:
  static constexpr float kTolerance = 0.1f;   // ε above
  static constexpr int kCellVoxels = 4;       // a level-0 cell's edge, in voxels
  static constexpr double kMinDeepFraction = 0.25;  // of a cell's voxels deep, for its mean to count,
  static constexpr int kMinDeepCount = 64;           // or this many
  static constexpr float kRegionDepths = 3.0f;  // the region's half-width, in depths z

  // medium: the instancer's (its reference is f_ref's TT medium, reference: its parameters
  // with packingRate f_ref); kernelWidth: h of its density. The medium must outlive this.
  HeterogeneousDiffusion(const HeterogeneousMedium& medium, const MediumParams& reference, float kernelWidth);

  HeterogeneousDecision decide(const Vec3& x, float daDepthFactor) const;
  // The local medium of a decision that took DA, for diffusionStep (boundary: this one's).
  const LevelSetBoundary& boundary() const { return boundary_; }
  const DiffusionProfile& referenceProfile() const { return profile_; }
  float densityRef() const { return densityRef_; }
  float bulk() const { return bulk_; }  // f_b: the mean f deeper than the skin
  float skin() const { return skin_; }
  // The region's f̄, least and largest cell mean over the cube of half-width r about x
  // (rounded out to the pyramid's cells, at the level read); count: its deep voxels.
  struct Region {
    float mean = 0, min = kInf, max = 0;
    double count = 0;
  };
  Region region(const Vec3& x, float r) const;

 private:
  struct Cell {
    float sum = 0, count = 0;  // of the deep voxels' f
  };
  struct Level {
    int64_t lo[3] = {0, 0, 0}, dims[3] = {0, 0, 0};
    std::vector<Cell> cells;
    const Cell* at(int64_t x, int64_t y, int64_t z) const;
  };
  LevelSetBoundary boundary_;
  MediumParams reference_;
  DiffusionProfile profile_;
  float densityRef_ = 0, bulk_ = 0, skin_ = 0, voxelSize_ = 0;
  std::vector<Level> levels_;
};

}  // namespace granular
