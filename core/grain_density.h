// grain_density.h — the local packing rate f(x) of explicit grains (an InstancedGrainsDesc)
// on a sparse voxel grid: what the heterogeneous medium equivalent to them follows
// (heterogeneous_medium.h) and what `granular export-vdb` writes for an instancer.
//
// Contract.
//  - f(x) = Σ_i V_i W(x − c_i): each grain's volume V_i (its prototype mesh's volume ×
//    scale³ × |det| of the instancer's transform) spread about its volume centroid c_i
//    (world space: the description's xf applied) by the tensor-product cubic B-spline
//    W(x) = Π_a B3(x_a / h) / h, B3 of knot spacing 1 on [−2, 2] (∫W = 1, support ±2h,
//    per-axis standard deviation h/√3). f is the grain-volume fraction (packing rate).
//  - Kernel width h: kernelRadii × R̄ (R̄ the grains' mean bounding radius, the prototype's
//    fitRadius × scale, world units), or kernelWidth when set. Default h = 3 R̄: the
//    support ±6 R̄ is three grain diameters each way.
//    Bias and noise. Inside, the estimate is f smoothed by W: bias (h²/6) ∇²f (zero for
//    a constant or linear f), and an edge (a free surface) rises over ±2h, half way at the
//    surface. Its noise is that of counting grains in the kernel: a relative standard
//    deviation about sqrt(S(0)(1 + CV_V²) / n_eff) with n_eff = f (2.09 h)³ / v̄ grains in
//    the kernel's effective volume 1/∫W² = (2.09 h)³ (v̄ the mean grain volume, CV_V the
//    spread of grain volumes, S(0) the packing's structure factor at 0: 1 for
//    independent grains, ≈ 0.05 for random close packing, ≈ 0 for lattices). Doubling h
//    quarters the bias near curvature and edges, cuts the noise by 2^{3/2}.
//  - Voxel size Δ: h / 2 unless set (then within [h/4, h]). At Δ = h/2 the B-spline's
//    samples at the voxel centres sum to exactly 1/Δ per axis (B-spline partition of
//    unity), so Σ_voxels f Δ³ = Σ_i V_i: no grain volume is lost or made. For other
//    Δ each grain's weights are normalised to sum to 1 per axis, which keeps that. The
//    field between voxel centres is trilinear (sample()), an error (Δ²/8) |∂²f| per axis,
//    below the kernel's own bias at Δ = h/2. Each grain touches (4h/Δ)³ = 512 voxels.
//  - Mixtures: numberFraction(k, ·) is prototype k's share of the kernel-smoothed number
//    density Σ_i W(x − c_i) (what deriveMedium's weights are, tt.h), at every active
//    voxel; the fractions sum to 1 there (to float rounding). One prototype: 1.
//  - Storage: leaves of 8³ voxels (OpenVDB's leaf: voxel (i, j, k) of a leaf at offset
//    ((i&7) << 6) | ((j&7) << 3) | (k&7)), voxel centres at world index × Δ, sorted by
//    origin; a voxel is active where some grain's kernel is > 0 there. Memory: 2 KiB per
//    leaf for f plus 2 KiB per leaf per prototype when there are several (stats.bytes);
//    while it runs, the build needs 4 bytes per grain (the grains ordered by the x of
//    their leaf), for one slab of leaves (constant x) at a time 40 bytes per grain in it
//    (centre, volume, place), and per thread a block of (8 + 2⌈2h/Δ⌉)³ doubles (per
//    prototype too with fractions): stats.buildBytes. In a
//    bulk of packing rate f, Δ = 1.5 R̄ holds about (4/3)π R̄³ φ / (f Δ³) ≈ 2 voxels per grain (φ the grains'
//    fill of their bounding spheres): ≈ 8 bytes per grain per grid, plus the surface leaves.
//  - Build: linear in the grains (counting sorts by slab and by leaf), in parallel (TBB)
//    over leaves, each grain weighed once, each voxel summing its grains in one fixed
//    order: the result does not depend on the thread count. Validates the description (validateInstancedGrains) and
//    throws InputError on <name>.kernelWidth, .voxelSize or .transform; a grid wider than
//    2^20 voxels along an axis is refused (InputError on voxelSize).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "math.h"
#include "scene_desc.h"

namespace granular {

// A sparse float field on 8³-voxel leaves (the layout above), trilinear between voxel
// centres, 0 where no leaf is. Thread-safe to read.
struct VoxelLeaves {
  static constexpr int kLeafDim = 8, kLeafVoxels = 512;
  float voxelSize = 0;                           // world units
  std::vector<std::array<int32_t, 3>> origins;   // index of each leaf's first voxel (multiples of 8), sorted
  std::vector<float> values;                     // kLeafVoxels per leaf

  static int offset(int i, int j, int k) { return ((i & 7) << 6) | ((j & 7) << 3) | (k & 7); }
  size_t leafCount() const { return origins.size(); }
  // The leaf holding voxel (i, j, k), or -1.
  int64_t findLeaf(int64_t i, int64_t j, int64_t k) const;
  float voxel(int64_t i, int64_t j, int64_t k) const;
  float sample(const Vec3& world) const;  // trilinear; 0 outside every leaf's reach
  int64_t activeVoxels() const;           // voxels holding a value > 0
  size_t bytes() const { return values.size() * sizeof(float) + origins.size() * sizeof(origins[0]); }
  // A field from values at voxels: fn(i, j, k) for every voxel of the leaves that cover
  // the index box [lo, hi] (inclusive): for tests and hand-made media.
  template <typename Fn>
  static VoxelLeaves fromFunction(float voxelSize, const std::array<int64_t, 3>& lo, const std::array<int64_t, 3>& hi, Fn fn);
};

struct GrainDensityOptions {
  float kernelRadii = 3.0f;  // h in mean bounding radii
  float kernelWidth = 0;     // h in world units; > 0 overrides kernelRadii
  float voxelSize = 0;       // world units; <= 0: h / 2
  bool fractions = true;     // per-prototype number fractions (with several prototypes)
};

struct GrainDensityStats {
  int64_t grains = 0;
  int64_t leaves = 0, activeVoxels = 0;
  double totalVolume = 0;    // Σ V_i, world units³
  float meanRadius = 0;      // R̄, world
  size_t bytes = 0;          // the grids kept (VoxelLeaves::bytes, fractions included)
  size_t buildBytes = 0;     // per-grain working arrays during the build
  double seconds = 0;
};

struct GrainDensity {
  float kernelWidth = 0;     // h, world
  VoxelLeaves packing;       // f
  // One per prototype (same leaves as packing) when there are several; else empty.
  std::vector<VoxelLeaves> fractions;
  std::vector<std::string> prototypeNames;
  GrainDensityStats stats;

  float packingRate(const Vec3& world) const { return packing.sample(world); }
  // Prototype k's number fraction at the nearest voxel (trilinear would mix in the
  // empty voxels' 0 at the edge); 0 outside the active voxels.
  float numberFraction(int k, const Vec3& world) const;
};

GrainDensity buildGrainDensity(const InstancedGrainsDesc& desc, const GrainDensityOptions& options = GrainDensityOptions());

// One prototype mesh's volume and volume centroid (divergence theorem; closed, outward).
void meshVolumeCentroid(const TriangleMesh& mesh, double& volume, Vec3& centroid);

template <typename Fn>
VoxelLeaves VoxelLeaves::fromFunction(float voxelSize, const std::array<int64_t, 3>& lo, const std::array<int64_t, 3>& hi,
                                      Fn fn) {
  VoxelLeaves v;
  v.voxelSize = voxelSize;
  auto leafLo = [](int64_t i) { return i >= 0 ? i / 8 * 8 : -((-i + 7) / 8) * 8; };
  for (int64_t x = leafLo(lo[0]); x <= hi[0]; x += 8)
    for (int64_t y = leafLo(lo[1]); y <= hi[1]; y += 8)
      for (int64_t z = leafLo(lo[2]); z <= hi[2]; z += 8) {
        v.origins.push_back({int32_t(x), int32_t(y), int32_t(z)});
        for (int i = 0; i < 8; ++i)
          for (int j = 0; j < 8; ++j)
            for (int k = 0; k < 8; ++k) v.values.push_back(float(fn(x + i, y + j, z + k)));
      }
  return v;
}

}  // namespace granular
