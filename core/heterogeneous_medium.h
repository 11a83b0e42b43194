// heterogeneous_medium.h — the medium equivalent to explicit grains whose packing varies
// (a heap's loose top, a slab with a gradient): σ_t follows the grains' local packing rate
// f(x) (grain_density.h), albedo and phase are the homogeneous medium's (vpt.h).
//
// Contract.
//  - σ_t(x) = σ_t,ref · f(x) / f_ref per RGB channel, f the voxel field trilinear between
//    voxel centres; 0 (vacuum) outside every voxel's reach. α_s and the phase function are
//    reference()'s, a HomogeneousMedium of σ_t,ref (MediumParams, medium.h).
//    Why linear: the TT model's extinction is that of grains met along a flight, whose
//    number per length is n π R² = 3 f / (4 R) (Meng et al. 2015's σ_b without Dixmier's
//    1/(1−f) excluded volume): first order in the grains' number density. Its full form,
//    σ_t = 1 / (λ_β + α_s λ_s), λ_b = 4R(1−f)/(3f) (tt.h), departs from it two ways: the
//    1/(1−f) makes σ_t fall faster than f where grains thin out, and the teleport length
//    α_s λ_s, which does not scale with f, makes it fall slower. With bench/README.md's TT
//    statistics and f_ref = 0.6, f / f_ref ∈ [0.5, 1.05] keeps the linear σ_t within 6% of
//    TT's for clear spheres and rocks (it is 9% low for spheres at f/f_ref = 0.1), but
//    for strongly absorbing grains (α_s = 0.26) only f/f_ref ∈ [0.9, 1.05] keeps 7%, and
//    at f/f_ref = 0.5 the linear σ_t is 33% high (bench/heterogeneous_medium.py prints the
//    table). It holds where the packing varies mildly about the bulk; a loose top, an
//    edge, is where it is least right.
//  - Majorants: blocks of 8³ voxels (the density's leaves), block b covering voxel index
//    coordinates [8b, 8b + 8) per axis; its majorant σ̄_b = max_c σ_t,ref,c / f_ref × the
//    largest f among the voxels [8b, 8b + 8]³ (the trilinear stencil of every point in the
//    block), so σ̄_b ≥ σ_t,c(x) for every channel and every x in it. Block arrays are dense
//    over the leaves' bounds plus one block below (8 bytes per block); a range beyond 2^28
//    blocks is refused (InputError on <name>.voxelSize). Rays walk them front to back by a
//    3-D DDA (Amanatides and Woo 1987); a block of σ̄ = 0 costs its step only.
//  - sampleFlight(): spectral tracking (Kutz et al. 2017, §5) with one scalar majorant for
//    RGB. Tentative collisions at rate σ̄_b (restarted at every block boundary: memoryless);
//    at one, with h = pathWeight ⊙ w (w the flight's weight so far, history-aware),
//      P_t = avg(h σ_t) / (avg(h σ_t) + avg(h σ_n)),  σ_n = σ̄ − σ_t,
//    a real collision (probability P_t) ends the flight, a scattering of weight
//    w ⊙ α_s σ_t / (σ̄ P_t); a null one continues with w ← w ⊙ σ_n / (σ̄ (1 − P_t)).
//    E[weight; scatter in dt] = α_s σ_t(t) T(t) dt and E[weight; passing tmax] = T(tmax)
//    per channel, T(t) = exp(−∫_0^t σ_t). avg(w) is kept by every null collision and each
//    w_c stays ≤ 3 avg(w): bounded weights. Grey media: plain delta tracking (Woodcock),
//    weight α_s at a scattering, 1 passing.
//  - transmittance(): ratio tracking (Novák et al. 2014): at tentative collisions of rate
//    σ̄_b, T ← T ⊙ (1 − σ_t/σ̄_b); unbiased for every channel. With roulette, once the
//    largest channel is below 1/8 the walk ends with probability 1/2 at each further
//    collision and doubles T otherwise (unbiased, bounded cost in thick media).
//    transmittanceDelta(): sampleFlight's weight when it passes tmax, 0 when it scatters:
//    delta tracking's estimator, for comparison (bench/heterogeneous_medium.py).
//  - Rays are world space (the density's space), parametrised as given (d need not be
//    unit; t is the ray's parameter, σ per world length). Ray::tmin is honoured; tmax is
//    the argument. Every random number comes from the Rng passed in, in a fixed order:
//    results are deterministic given its state. Thread-safe (const).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "grain_density.h"
#include "math.h"
#include "medium.h"
#include "rng.h"
#include "vpt.h"

namespace granular {

struct MediumFlight {
  float t = kInf;          // the scattering's parameter, or tmax when the flight passed
  bool scattered = false;
  Vec3 weight{1.0f};       // see the contract: includes α_s at a scattering
  int64_t lookups = 0;     // σ_t evaluations (tentative collisions)
};

class HeterogeneousMedium {
 public:
  HeterogeneousMedium() = default;
  // density: f on voxels; σ_t(x) = reference.sigmaT() · f(x) / densityRef. name: for messages.
  HeterogeneousMedium(VoxelLeaves density, float densityRef, const HomogeneousMedium& reference,
                      const std::string& name = "medium");
  // The grains' packing rate, with the TT medium of the bulk (ref.packingRate is f_ref).
  HeterogeneousMedium(const GrainDensity& density, const MediumParams& ref, const std::string& name = "medium");

  Vec3 sigmaT(const Vec3& p) const;
  float density(const Vec3& p) const { return sampleDensity(toIndex(p)); }
  float densityRef() const { return densityRef_; }  // f_ref: σ_t(x) = reference().sigmaT() f(x) / f_ref
  const VoxelLeaves& voxels() const { return density_; }
  // The index in voxels().origins of the leaf holding voxel (i, j, k), or -1 (no leaf): O(1).
  int64_t leafOf(int64_t i, int64_t j, int64_t k) const;
  // A field on the density's voxels (values: 512 per leaf of voxels(), in its order) at u
  // in voxel index coordinates: trilinear between voxel centres, `outside` for a voxel of
  // no leaf, and everywhere when u is not finite or beyond 1e9 voxels.
  float sampleLeaves(const float* values, const Vec3& u, float outside) const;
  float majorant(const Vec3& p) const;  // σ̄ of the block holding p (per world length), 0 outside
  const HomogeneousMedium& reference() const { return reference_; }
  const Vec3& albedo() const { return reference_.albedo(); }
  Bounds3 bounds() const;               // world bounds of the blocks (σ_t = 0 beyond)
  bool empty() const { return blocks_.empty(); }
  size_t bytes() const;                 // voxels and block arrays

  MediumFlight sampleFlight(const Ray& ray, float tmax, Rng& rng, const Vec3& pathWeight = Vec3(1.0f)) const;
  Vec3 transmittance(const Ray& ray, float tmax, Rng& rng, bool roulette = true, int64_t* lookups = nullptr) const;
  Vec3 transmittanceDelta(const Ray& ray, float tmax, Rng& rng, int64_t* lookups = nullptr) const;

 private:
  struct Block {
    int32_t leaf = -1;   // index into density_'s leaves
    float majorant = 0;  // scalar σ̄, per world length
  };
  Vec3 toIndex(const Vec3& p) const { return p * invVoxel_; }
  // f at continuous index coordinates.
  float sampleDensity(const Vec3& u) const { return sampleLeaves(density_.values.data(), u, 0.0f); }
  int64_t blockIndex(int64_t bx, int64_t by, int64_t bz) const;
  // Calls seg(t0, t1, σ̄ per unit t) for each block the ray crosses in [tmin, tmax], front
  // to back, until it returns false.
  template <typename Seg>
  void walk(const Ray& ray, float tmax, Seg&& seg) const;

  VoxelLeaves density_;
  Vec3 scale_;           // σ_t,ref / f_ref
  float densityRef_ = 0;
  float maxScale_ = 0;   // its largest channel
  float invVoxel_ = 0;
  HomogeneousMedium reference_;
  int64_t lo_[3] = {0, 0, 0}, dims_[3] = {0, 0, 0};  // block range
  std::vector<Block> blocks_;
};

}  // namespace granular
