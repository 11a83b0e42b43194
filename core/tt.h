// tt.h — teleportation transport (TT): RTE parameters of the homogeneous medium that is
// equivalent to an aggregate of grains (Meng et al. 2015's teleportation transport).
//
// Contract. estimateGrainTransport() characterises one grain prototype, once, by tracing
// random rays that enter its unit bounding sphere (uniform over the sphere's projected
// area, i.e. cosine-weighted entry) and following each through the grain exactly as EPT
// does (same Material::sample, Fresnel, total internal reflection, Beer–Lambert with the
// absorption per unit bounding radius) until it leaves the bounding sphere. All lengths
// are in units of the bounding radius; every estimate carries its Monte Carlo standard
// error. A path still inside after maxBounces counts as absorbed (GrainTransport::
// truncated). Each ray has its own generator seeded by (seed, ray index), so results do
// not depend on threads, and different materials see the same entries (common random
// numbers). The result is a pure function of (mesh, material, options) and is cached on
// disk under a hash of them (cache.h), so a second render reads it back.
//
// deriveMedium() combines per-prototype results by the mixing weights and scales them by
// the aggregate's grain radius R and packing rate f into world-space RTE parameters
// (MediumParams, medium.h):
//   σ_b = 3/(4R) · f/(1−f)                         (Dixmier 1978), λ_b = 1/σ_b
//   λ_β = λ_b + (λ_b + λ_δ)(1−β)/β                 (β: the chance of hitting the grain)
//   λ_t = λ_β + α_s λ_s,  σ_t = 1/λ_t             (Meng et al. 2015)
//   σ'_s = (1−g) α_s σ_t,  σ'_t = σ'_s + (1−α_s) σ_t,  α'_s = σ'_s/σ'_t   (Jensen 2001)
//   σ_tr = sqrt(3 σ_a σ'_t),  σ_a = (1−α_s) σ_t   (Jensen et al. 2001)
// (λ_δ and λ_s, in grain radii, are scaled by R.) Followed explicitly through aggregates
// of clear grains (test_tt.cpp, TTAggregate), EPT's mean λ_β and λ_t agree with these
// within about 1% for spheres, rocks and ellipsoids at f = 0.3–0.64.
// Quantities that depend on absorption (α_s, λ_s, the phase function, g) are per RGB
// channel, so σ_t is per channel too (a chromatic medium).
//
// Degenerate inputs never give NaN or Inf:
//  * no ray hits the grain (β = 0): α_s, λ_s, g = 0 with an isotropic phase table; the
//    medium is empty: σ_t = σ_a = σ'_s = σ'_t = σ_tr = 0, α_s = α'_s = 1 and λ_β, λ_t
//    are FLT_MAX (standing for "never").
//  * black grains (α_s = 0): λ_s = 0, g = 0, isotropic phase; σ_t = 1/λ_β, α'_s = 0.
//  * no absorption (α_s = 1): σ_a = 0, so σ_tr = 0; when also g = 1 (index-matched
//    grains) σ'_t = 0 and α'_s is reported as α_s (1).
//  * f → 0: λ_b grows without bound; every length is clamped to FLT_MAX, σ's to ≥ 0.
//    f near 0.64 needs no guard (1 − f ≥ 0.36); f outside (0, 0.64] is an InputError.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "embree_util.h"
#include "material.h"
#include "math.h"
#include "mesh.h"
#include "rng.h"
#include "scene_desc.h"

namespace granular {

// A phase function tabulated over μ = cos θ = ω_i·ω_o in [-1, 1] with equal-width bins,
// piecewise constant in μ, normalised so that 2π ∫ p dμ = 1 (pdf per steradian).
struct PhaseTable {
  std::vector<float> density;  // p(μ) per bin, per steradian
  std::vector<float> cdf;      // size bins+1, cdf[0] = 0, cdf[bins] = 1
  float g = 0;                 // mean cosine
  // sample()'s guide to the cdf (sampling.h: cdfGuide, bins + 1 entries): the same bin as
  // a binary search, in a step or two. Made by fromHistogram() and the cache's reader
  // (buildGuide()); empty: the binary search.
  std::vector<uint32_t> guide;

  int bins() const { return int(density.size()); }
  // p(ω_i·ω_o), per steradian.
  float eval(float mu) const;
  // Samples ω_o around ω_i (unit): μ by inverting the cdf, azimuth uniform.
  // Returns ω_o; pdf (per steradian) = eval(dot(wi, ωo)), also written to *pdf. μ is
  // kept 1e-4 of a bin away from the bin's edges so that rounding of dot(wi, ωo) never
  // moves it into a neighbouring (possibly empty) bin.
  Vec3 sample(const Vec3& wi, float u1, float u2, float* pdf = nullptr) const;
  // Probability mass of μ in [a, b] (exact for the piecewise-constant table).
  double mass(double a, double b) const;
  // Isotropic table (every bin 1/(4π)).
  static PhaseTable isotropic(int bins = 1);
  // From unnormalised per-bin weights (energy exiting into each μ bin); g is the table's
  // own mean cosine (bin centres), i.e. what sampling it reproduces. Negative or
  // non-finite weights count as 0; all-zero weights give the isotropic table.
  static PhaseTable fromHistogram(const std::vector<double>& weights);
  // Makes guide from cdf.
  void buildGuide();
};

// Where a grain lets light out, by the angle it turns it: the moves the equivalent medium's
// exits model (vpt.h, MediumModel::Exits) applies at a scattering. Per bin of μ = ω_i·ω_o
// (kBins equal bins over [−1, 1]) up to kPerBin moves, drawn in proportion to the energy
// that exits in that bin (one channel's), each from where the ray entered the bounding
// sphere to where its exit line leaves it, in units of the radius and in the frame
// (ω_i, u, ω_i × u), u the unit part of ω_o across ω_i. Light a grain sends back leaves
// near where it came in; light it sends on, about a diameter further (bench/README.md,
// "Where a grain lets light out"): TT's single λ_s cannot tell them apart.
struct ExitMoves {
  static constexpr int kBins = 16, kPerBin = 256;
  std::array<std::vector<Vec3>, kBins> moves;
  static int bin(float mu) { return std::min(kBins - 1, std::max(0, int((mu + 1.0f) * 0.5f * kBins))); }
  bool empty() const;
  // A move for the turn ω_i → ω_o (unit vectors), in world directions, of unit radius: the
  // sample u ∈ [0, 1) picks of μ's bin; zero where the bin holds none.
  Vec3 sample(const Vec3& wi, const Vec3& wo, float u) const;
};

// One prototype's intra-grain statistics, in units of the bounding radius.
struct GrainTransport {
  double beta = 1, betaSE = 0;                // P(ray entering the bounding sphere hits the grain)
  double lambdaDelta = 0, lambdaDeltaSE = 0;  // mean chord in the sphere of rays that miss
  std::array<double, 3> lambdaS{}, lambdaSSE{};  // mean |x_o − x_i| of hits that exit, energy-weighted
  std::array<double, 3> albedo{}, albedoSE{};    // α_s: exiting fraction of the energy of a hit
  std::array<PhaseTable, 3> phase;               // exit distribution over cos θ, per channel
  std::array<double, 3> g{}, gSE{};              // mean cosine of the exits (exact μ, not bin centres)
  std::array<ExitMoves, 3> exits;                // where the exits leave, per channel
  // Energy-weighted means over the exits of the move Δ (ExitMoves): Δ·ω_i, Δ·ω_o and |Δ|²,
  // per channel; what the exits model's diffusion needs (exitsDiffusionMedium).
  std::array<double, 3> moveIn{}, moveOut{}, moveSquared{};
  int64_t rays = 0;                              // rays traced
  int64_t truncated = 0;   // hits still inside after maxBounces (their energy counts as absorbed)
  bool fromCache = false;  // read back from the disk cache rather than traced
};

struct TTOptions {
  int64_t rays = 1 << 18;   // rays entering the bounding sphere
  int phaseBins = 64;
  int maxBounces = 4096;    // inside one grain, as EPT's default maxDepth: faceted spheres trap
                            // TIR paths for 1000+ bounces before they escape
  uint64_t seed = 1;
  bool useCache = true;
};

// prototypeMesh must already be normalised into the unit bounding sphere (GrainPrototype).
// Rays are traced in fixed chunks of 4096 with per-chunk seeds and reduced in order, so
// the result does not depend on the number of threads. Throws InputError for options
// out of range (rays < 1, phaseBins outside [1, 65536], maxBounces < 1) or an empty mesh.
GrainTransport estimateGrainTransport(const TriangleMesh& prototypeMesh, const Material& material,
                                      const TTOptions& options = TTOptions());

// The entry of a ray into a unit bounding sphere as TT traces it: uniform over the
// sphere's projected area (a uniform point xi on the sphere, an inward cosine-weighted
// direction wi); by the grains' random rotations, also any ray that meets a sphere.
void sampleSphereEntry(Rng& rng, Vec3& xi, Vec3& wi);

// One ray through a grain in its unit bounding sphere, scattered exactly as EPT scatters
// it (Material::sample at each interface, Beer–Lambert inside with absorption per bounding
// radius), until it leaves the grain for good. weight: the energy left per channel (0
// when absorbed, or truncated after maxBounces). o, d: the last ray, leaving the grain
// (or the entry ray when it missed).
struct GrainPassage {
  bool hit = false, truncated = false;
  Vec3 weight{1.0f};
  Vec3 o, d;
};
GrainPassage traceGrainPassage(RTCScene bvh, const TriangleMesh& mesh, const Material& m, int maxBounces,
                               const Vec3& xi, const Vec3& wi, Rng& rng);

// A cache key's part that names the grain: its mesh and what its material does to light.
uint64_t hashGrainInputs(uint64_t h, const TriangleMesh& mesh, const Material& m);

// File name (inside cacheDirectory()) of the cache entry of these inputs.
std::string grainTransportCacheName(const TriangleMesh& prototypeMesh, const Material& material,
                                    const TTOptions& options);

// What deriveMedium() and aggregateMedium() return: the aggregate's medium (medium.h).
struct MediumParams;

// Mixture: a sphere's grain is prototype i with probability w_i (normalised weights), so
//   β = Σ w_i β_i;  λ_δ averages over misses (weights w_i(1−β_i));
//   α_s = Σ w_i β_i α_i / β;  λ_s, phase and g average over exiting energy (w_i β_i α_i).
// Phase tables with different bin counts are rebinned exactly (by mass) onto the finest;
// an empty table counts as isotropic. Standard errors combine in quadrature, treating
// the weights as exact. Throws InputError for mismatched or negative weights, grain
// radius ≤ 0 or packing rate outside (0, 0.64].
MediumParams deriveMedium(const std::vector<GrainTransport>& prototypes, const std::vector<float>& weights,
                          float grainRadius, float packingRate);

// Grains of many sizes (polydisperse; Müller et al. 2016 render such mixtures): kind i has
// number fraction n_i (weights, normalised) and bounding radius s_i R (sizes); its
// transport is traced in its unit bounding sphere with its absorption scaled by s_i
// (absorption is per R). A flight between spheres ends in a sphere of kind i with
// probability proportional to its cross-section, so the mixture above runs over
//   w_i = n_i s_i² / Σ_j n_j s_j²,
// and the lengths measured in unit spheres scale by s_i: λ_δ = Σ w_i (1−β_i) s_i λ_δ,i /
// Σ w_i (1−β_i), λ_s likewise over exiting energy. The flights themselves follow the
// spheres' surface area per volume S_v (stereology: the mean chord of the space between
// them is 4(1−f)/S_v), S_v = 3f / (R s_32) with the Sauter mean size s_32 = Σ n s³ / Σ n s²:
//   σ_b = 3/(4 R s_32) · f/(1−f)
// (all s_i = 1: Dixmier's formula and the equal-size mixture above). sauterSize > 0 gives
// s_32 directly (the tile's own spheres); 0 takes it from the kinds. Traced through
// polydisperse aggregates (test_tt.cpp, TTAggregate), λ_β and λ_t agree with explicit
// walks within 2%.
MediumParams deriveMedium(const std::vector<GrainTransport>& kinds, const std::vector<float>& weights,
                          const std::vector<float>& sizes, float grainRadius, float packingRate,
                          double sauterSize = 0);

// The exits model's flights between grains, in λ_β (vpt.h). A flight between grains in a
// dense packing has λ_β's mean but is more spread than an exponential one, and a walk's
// spread goes with the flights' mean square (exitsDiffusionMedium: 2 L²): the exponential
// flight of explicit grains' mean square is 1.026 λ_β for rocks of IOR 1.55 and 1.032 for
// IOR 2.4 (bench/README.md, "The exits model"), and 1.03 makes the walk's transport over
// distance explicit grains'.
constexpr float kExitFlight = 1.03f;

// The standard medium (TT's phase functions and α_s) whose walk spreads as far per
// scattering as the exits model's (vpt.h), for DA after it: per channel, a scattering's
// step s = Δ + ℓ ω_o (the grain's move, then a flight ℓ of mean L = kExitFlight λ_β) has
// E|s|² = E|Δ|² + 2 L E[Δ·ω_o] + 2 L², and along the walk E[s_k | ω_k] = (E[Δ·ω_i] + L g) ω_k
// with E[ω_k | ω_1] = g^(k−1) ω_1, so the mean square distance grows per scattering by
//   M = E|s|² + 2 (E[Δ·ω_i] + L g)(E[Δ·ω_o] + L) / (1 − g);
// a standard medium's grows by 2 / (σ_t² (1 − g)), whence σ_t = sqrt(2 / (M (1 − g))), and
// σ'_s, σ'_t, σ_a, σ_tr from it as deriveMedium does (both walks lose 1 − α_s per
// scattering). Without moves (a medium given directly), or where g ≥ 1 (index-matched
// grains: nothing to diffuse), p's own.
MediumParams exitsDiffusionMedium(const MediumParams& p);

// An aggregate's medium (what Scene::build derives): its prototypes (meshes normalised into
// their unit bounding spheres, and materials) as grain kinds — each prototype at its size,
// or with a size spread at the three Gauss–Legendre nodes of the uniform spread, which
// weigh s² and s³ exactly — traced by estimateGrainTransport (cached) and mixed by
// deriveMedium with the tile's Sauter mean size.
MediumParams aggregateMedium(const std::vector<const TriangleMesh*>& prototypeMeshes,
                             const std::vector<Material>& materials, const AggregateDesc& desc, double sauterSize,
                             const TTOptions& options = TTOptions());

}  // namespace granular
