// vpt.h — volumetric path tracing (VPT) of the homogeneous medium equivalent to an
// aggregate (Meng et al. 2015), bounded by the aggregate's boundary mesh, which acts as an
// index-matched interface (no refraction, no reflection).
//
// Contract: a HomogeneousMedium holds world-space σ_t and α_s per RGB channel and a
// phase function per channel (tt.h's PhaseTable). Free flights in a chromatic medium are
// sampled by one-sample MIS over the channels (a channel chosen uniformly, then an
// exponential flight in it), so the pdf of a flight t is
//   p(t) = (1/3) Σ_c σ_c exp(−σ_c t)        and   P(flight ≥ s) = (1/3) Σ_c exp(−σ_c s),
// and the path weight of a scattering at t is α σ_t exp(−σ_t t) / p(t) (per channel), of
// passing the boundary at s it is exp(−σ_t s) / P(flight ≥ s). Phase directions are drawn
// likewise from one channel's table, with pdf the mean of the three tables' pdfs.
//
// The exits model (MediumModel::Exits): flights of kExitFlight λ_β (tt.h), to the next
// grain met rather than TT's λ_t, and each scattering's light moved by a sample of the grain's move for
// the angle it turned (tt.h, ExitMoves), before its next flight and before a next-event
// estimate's shadow ray (the move's law depends on ω_o only through μ, so both strategies
// see it alike and MIS keeps its weights). The same α_s and phase functions as TT's; DA
// after it diffuses as its walk does (tt.h, exitsDiffusionMedium). It takes a path over at
// a grain, its first flight the packing's (enterMedia, below).
#pragma once

#include <array>
#include <memory>

#include "math.h"
#include "medium.h"

namespace granular {

// RTE parameters given directly (σ_t, α_s, phase), with the reduced and diffusion
// parameters derived as deriveMedium() does (tt.h): for closed-form
// tests and validation against other renderers.
MediumParams mediumFromRte(const Vec3& sigmaT, const Vec3& albedo, const PhaseTable& phase);

class HomogeneousMedium {
 public:
  HomogeneousMedium() = default;
  // model Exits with p's exits' moves (p.combined.exits): the exits model above; else TT.
  explicit HomogeneousMedium(const MediumParams& p, MediumModel model = MediumModel::Tt);
  // For tests and hand-made media: σ_t, α_s and one phase table for all channels.
  HomogeneousMedium(const Vec3& sigmaT, const Vec3& albedo, const PhaseTable& phase);

  const Vec3& sigmaT() const { return sigmaT_; }
  const Vec3& albedo() const { return albedo_; }
  bool empty() const { return maxComponent(sigmaT_) <= 0; }

  Vec3 transmittance(float t) const { return vexp(sigmaT_ * -t); }

  // Samples a flight distance (may be +inf for a channel with σ = 0); pdf as above.
  float sampleDistance(float uChannel, float u) const;
  float distancePdf(float t) const;
  float survivalProbability(float s) const;

  // Phase function value per channel for ω_i (direction of travel in) → ω_o (out).
  Vec3 phase(const Vec3& wi, const Vec3& wo) const;
  float phasePdf(const Vec3& wi, const Vec3& wo) const;
  // Returns ω_o; pdf = phasePdf(wi, ω_o); weight = phase / pdf per channel.
  Vec3 samplePhase(const Vec3& wi, float uChannel, float u1, float u2, Vec3& weight, float& pdf) const;

  // Whether scatterings move light (the exits model).
  bool movesLight() const { return exits_ != nullptr; }
  float moveRadius() const { return moveRadius_; }  // the grain radius the moves scale by
  // The move of a scattering's light that turns ω_i → ω_o, a world vector of length at most
  // the grain's diameter: a channel's moves by uChannel (uniform; the channels' moves differ
  // only by what absorption inside the grain keeps), one of them by u; zero without moves.
  Vec3 exitMove(const Vec3& wi, const Vec3& wo, float uChannel, float u) const;

 private:
  Vec3 sigmaT_, albedo_;
  std::array<PhaseTable, 3> phase_;
  bool samePhase_ = true;  // one table serves all channels (cheaper evaluation)
  std::shared_ptr<const std::array<ExitMoves, 3>> exits_;  // the exits model's, in grain radii
  float moveRadius_ = 0;                                  // the grain radius they scale by
};

struct PathState;
class Scene;
struct ShadowCasters;
class DiffusionBoundary;

// A path leaves the discrete levels (explicit grains, proxies) for the media: the hybrid's
// switch (hybrid.h), the level-of-detail shortcut (ept.h, ppt.h); the medium it stands in
// takes it. In the exits model it takes it over at a grain, not in the gap it stands in:
// where the path leaves a grain of that aggregate (Scene::takesOverAtGrains), its first
// flight is the packing's (Aggregate::flightToGrain: the proxy spheres at their true
// positions, each grain met with its table's chance), past the boundary too (a grain of
// the surface layer may stand out of it); the grain it meets scatters as the medium does,
// its weight α_s alone (the flight's chance is the packing's own). Why: the line the path
// came in by runs through the packing's gaps, and light a grain sends back along it leaves
// through the gap it came in by; a memoryless first flight closes that gap, and the medium
// right after a grain was too dark by what it kept (bench/README.md, "The exits model
// takes over at a grain"). TT's medium keeps its own first flight: its excess deep inside
// made up for that deficit, and its bias at the first grain would turn positive.
void enterMedia(const Scene& scene, PathState& path);

// One event of a path in the media (VPT): flights through boundaries (null crossings),
// then a scattering in a medium (next-event estimation with transmittance, phase
// sampling, MIS), a surface bounce, an emitter or an escape. Sets alive = false when
// the path ends. With technique Hybrid, a scattering deeper than diffusionDepth() below
// the boundary, of a path that has scattered RenderSettings::daMinOrder times, hands the
// path to diffusion.h; in an instancer's medium, where heterogeneous_diffusion.h's rule
// holds (RenderSettings::daInstanced).
void vptStep(const Scene& scene, PathState& path);

// Next-event estimation at a scattering at p in med for a path arriving along path.ray.d:
// one light (Scene::pickLight), its transmittance through the media, the phase function,
// MIS against phase sampling (power heuristic; delta lights unweighted). Adds to
// path.L[path.credit]. Deep in the path's aggregate, where the distance field bounds the
// transmittance below 1/2 (vpt.cpp: kShadowRouletteBelow), the shadow ray is traced by
// Russian roulette with a chance in proportion to that bound (unbiased).
// boundary: the flight up to its first crossing of it is in a medium of extinction
// reducedBy less than the media's (DA's reduced medium, σ_t − σ'_t given back: diffusion.h).
void mediumNee(const Scene& scene, PathState& path, const HomogeneousMedium& med, const Vec3& p,
               const DiffusionBoundary* boundary = nullptr, const Vec3& reducedBy = Vec3(0.0f));

// The shadow ray of a scattering at p in the media toward who.light, over dist along wi:
// its transmittance (Scene::transmittance) from `from` (p, or where the exits model lets
// the light out), times, with a boundary, e^{reducedBy s} for its flight s to that boundary
// (as mediumNee). Next-event estimation and shadow linking's sampled directions
// (ept.h: addDirectPastNonCasters) share it.
Vec3 mediumShadow(const Scene& scene, PathState& path, const Vec3& p, const Vec3& from, const Vec3& wi, float dist,
                  ShadowCasters who, const DiffusionBoundary* boundary = nullptr,
                  const Vec3& reducedBy = Vec3(0.0f));

// Depth below the boundary beyond which DA replaces VPT: factor × Meng et al. 2015's
// min(1/σ'_t, 0.5/σ_tr), taken for the channel with the longest such depth (DA must be
// valid in every channel). The factor is RenderSettings::daDepthFactor.
float diffusionDepth(const MediumParams& p, float factor);

}  // namespace granular
