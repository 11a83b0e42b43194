// diffusion.h — the diffusion approximation (DA) that ends deep paths (Meng et al. 2015:
// the diffusion approximation, and the switch from VPT to it).
//
// Contract. A path that scatters at a point x deeper than diffusionDepth() below the
// boundary stops its random walk; what it would gather from there on is estimated by
// diffusion theory in the reduced medium (σ'_s, σ'_t, α'_s of Jensen et al. 2001, as in
// Meng et al. 2015), in importance form (Li et al. 2005's hybrid of Monte Carlo and
// diffusion):
//
// 0. Single scattering at x: next-event estimation at x (vpt.h mediumNee), its flight to
//    the boundary in the reduced medium (σ'_t: light scattered forward on the way is
//    "uncollided" in the reduced picture). A delta sun is reached only this way.
// 1. The beam (Habel et al. 2013, photon beam diffusion). The light leaving x goes in a
//    direction ω drawn from the phase function p(ω_i → ω) of the path's last flight ω_i,
//    and is first scattered in the reduced sense at y = x + tω with density
//    σ'_s e^{−σ'_t t} (the beam's source density; t is sampled ∝ σ̄'_t e^{−σ̄'_t t} with
//    σ̄'_t the channel mean, the ratio is the weight). If the boundary is nearer along ω
//    than t (probability e^{−σ'_t s}), the light leaves uncollided: the path continues
//    from the boundary point along ω (MIS with step 0's NEE). Measured against an exact random walk in a half
//    space (albedo 0.99/0.9/0.5, g 0/0.7, one and two DA depths; bench/
//    diffusion_models.py), the beam is within −2.5…+4.6% except for photons heading
//    straight down in g = 0.7 media (+2…+18%), where a point source at x erred by
//    −57…+450%: the direction of a forward-scattered photon decides how deep it goes.
// 2. Virtual source placement (our choice; Meng et al. 2015 devise their own): the real
//    source sits at the beam's sample y, not one mean free path below an entry point as
//    in the classical dipole, because our paths are already inside. Its images are placed
//    for the slab through y along the normal n of the boundary point closest to y
//    (distance z): the tangent plane there is the near face, the first boundary crossing
//    along −n the far face (thickness d; none: a half space). With L = d + 2z_b the
//    multipole of Donner & Jensen 2005 (their eq. 7) puts real sources at 2iL + z and
//    virtual ones at 2iL − z − 2z_b, i = −n…n, depths measured from the near face.
// 3. Boundary (d'Eon & Irving 2011, their §3): the aggregate's boundary is not an
//    interface — outside and the pores between grains are the same air — so the index
//    ratio is 1, the Fresnel moments give A = (1 + 3C₂)/(1 − 2C₁) = 1, the extrapolation
//    distance is z_b = 2AD, and the exitance is J = C_φ φ + C_E D ∂φ/∂n with C_φ = 1/4,
//    C_E = 1/2. D = 1/(3σ'_t): Grosjean's D = (2σ_a + σ'_s)/(3σ'_t²), which d'Eon &
//    Irving favour for media lit from outside, measured up to 2× further off the exact
//    walk than the classical D for our deep, already-scattered sources, and z_b from
//    the Milne length (0.71/σ'_t) up to 2.5% further off than 2D (diffusion_models.py).
// 4. The exit: a point x_o of the near or far face is sampled with a stated area pdf
//    (diffusionStep), the weight J/pdf is applied, and the path continues from x_o with
//    d'Eon & Irving's P1 lobe of the exiting light as its "BSDF" (MaterialType::
//    DiffusionExit: NEE, then a direction sampled from the lobe). x_o (and the uncollided
//    beam's exit) is where the light is out of the medium: DiffusionBoundary::exitPoint,
//    the boundary itself for an aggregate, beyond the kernel's skin for an instancer.
//
// Finite thickness. The truncated multipole does not conserve energy as σ_a d → 0: each
// image's plane integral grows like 1/σ_tr and cancels only against images ~1/σ_tr away.
// Its relative energy error falls like e^{−2nσ_tr L}; multipoleTerms() takes the
// smallest n with n σ_tr L ≥ kMultipoleReach (error below 0.3%, tests/core/
// test_diffusion.cpp), at most kMaxMultipoleTerms. A fixed n cannot hold as σ_a → 0, so
// the lateral profile is always scaled to the exact laterally integrated exitance of the
// 1-D slab (exact for any σ_a d, including 0); with n chosen as above that factor is
// within 0.3% of 1 and only the capped, nearly non-absorbing thin slabs lean on it.
#pragma once

#include "aggregate_motion.h"
#include "math.h"
#include "medium.h"

namespace granular {

struct PathState;
class Scene;
class Aggregate;
class HomogeneousMedium;

constexpr double kMultipoleReach = 4.0;
constexpr int kMaxMultipoleTerms = 32;

// Diffuse exitance per unit source power, per channel, of the slab [0, d] (d = inf: a
// half space) at lateral distance rho from an isotropic point source at depth z:
// on the face z = 0 (near) or z = d (far).
struct DiffusionProfile {
  Vec3 D, sigmaTr, zb;              // per channel
  Vec3 sigmaSReduced, sigmaTReduced;  // the beam's σ'_s, σ'_t
  // Total diffuse reflectance of the half space, R_d(α') (Jensen et al. 2001, Eq. 5, A = 1):
  // the colour the medium has from afar (the albedo AOV of an aggregate: ept.h).
  Vec3 diffuseReflectance;
  DiffusionProfile() = default;
  explicit DiffusionProfile(const MediumParams& p);
  // The profile of the medium whose coefficients (σ_t, σ_s, σ_a) are k times these, with
  // the same albedo and phase: every length divides by k (a heterogeneous medium's local
  // profile, heterogeneous_diffusion.h).
  DiffusionProfile scaled(float k) const;
  // Multipole (half space: the dipole) scaled to the slab's exact 1-D total; see above.
  Vec3 exitance(float z, float rho, float d, bool farFace) const;
  // The exact 1-D slab's laterally integrated exitance (the dipole's for d = inf).
  Vec3 slabTotal(float z, float d, bool farFace) const;
  // The plane integral of the unscaled multipole with n pairs on each side (closed form).
  Vec3 multipoleTotal(float z, float d, bool farFace, int n) const;
  // ∫ exitance dA over the face (numerically, for tests).
  Vec3 totalExitance(float z, float d, bool farFace) const;
};

// Image pairs on each side for a slab of thickness d (inf: 0, the dipole).
int multipoleTerms(double sigmaTr, double zb, double d);

// The boundary DA reads its slab from (step 2) and light leaves through (steps 1 and 4):
// an aggregate's boundary mesh (AggregateBoundary), or the level set that bounds an
// instancer's heterogeneous medium (heterogeneous_diffusion.h). Thread-safe (const).
class DiffusionBoundary {
 public:
  virtual ~DiffusionBoundary() = default;
  // Distance from p to the nearest boundary point, written to closest; not > 0: p is not
  // (measurably) inside.
  virtual float closestPoint(const Vec3& p, Vec3& closest) const = 0;
  // The first boundary crossing along o + t d (d unit) with t in (0, tmax): t and the
  // outward unit normal there.
  virtual bool intersect(const Vec3& o, const Vec3& d, float tmax, float& t, Vec3& ng) const = 0;
  // Where light that crosses the boundary at p (outward normal ng) is out of the medium,
  // σ_t = 0 beyond: p for a sharp boundary (an aggregate's mesh).
  virtual Vec3 exitPoint(const Vec3& p, const Vec3& ng) const { return p; }
};

// An aggregate's boundary mesh, where the aggregate stands at the path's time.
class AggregateBoundary final : public DiffusionBoundary {
 public:
  explicit AggregateBoundary(const PosedAggregate& agg) : agg_(agg) {}
  float closestPoint(const Vec3& p, Vec3& closest) const override;
  bool intersect(const Vec3& o, const Vec3& d, float tmax, float& t, Vec3& ng) const override;

 private:
  PosedAggregate agg_;
};

// A boundary cut by the scene's surfaces (Scene::intersectMedium: meshes, area lights,
// aggregates' boundaries): a crossing is the first of inner's and a surface's, light that
// reaches a surface inside the medium leaving there, just before it, its outward normal
// facing the surface; an exit point stops just before a surface on its way out. For media
// whose boundary does not stop at surfaces: a heap's level set reaches a little below the
// ground it stands on, where VPT's flights end at the ground and DA's exits must too (not
// below it, under the sky's lower half).
class SurfaceCutBoundary final : public DiffusionBoundary {
 public:
  SurfaceCutBoundary(const DiffusionBoundary& inner, const Scene& scene, float time)
      : inner_(inner), scene_(scene), time_(time) {}
  float closestPoint(const Vec3& p, Vec3& closest) const override;
  bool intersect(const Vec3& o, const Vec3& d, float tmax, float& t, Vec3& ng) const override;
  Vec3 exitPoint(const Vec3& p, const Vec3& ng) const override;

  static float margin(const Vec3& p);  // how far before a surface a point stops

 private:
  const DiffusionBoundary& inner_;
  const Scene& scene_;
  float time_;
};

// What a DA step reads of the medium at its switch point: the phase function (of
// `phase`), the local extinction σ_t and the diffusion profile of the local medium, and
// the boundary.
struct DiffusionMedium {
  const HomogeneousMedium& phase;
  Vec3 sigmaT;
  const DiffusionProfile& profile;
  const DiffusionBoundary& boundary;
};

// The curvature guard. The model's slab is planar; on a ball whose radius is a few DA
// depths it is not: DA's own bias (hybrid − EPT+VPT, bench/accuracy_matrix.py) measured
// −1.2% on a ball of 7 DA depths (25 grains in radius), −0.5…−0.7% at 14, nothing
// measurable at 28. DA holds where the local curvature radius is at least
// kCurvatureGuard DA depths. The radius at x (depth z): the closest boundary points of x
// and of x moved by δ = max(delta, z) along ±two tangents; on a sphere of radius R the
// normals turn by an angle a with tan a = δ/(R − z), so R = δ/tan a + z (the least of the
// four; an edge, a corner or an offset point outside: ~0). diffusionHolds() uses δ = z,
// the source's own scale. Larger offsets (B/2) smoothed a faceted cylinder's facets but
// refused DA within B/2 of every edge (the snow field's DA share fell from 17% to 10%).
constexpr float kCurvatureGuard = 20.0f;
float localCurvatureRadius(const Aggregate& agg, const Vec3& x, float delta);
bool diffusionHolds(const Aggregate& agg, const Vec3& x, float daDepth);

// Continues path (scattering at x) by DA in medium; see above. The path leaves the media
// (path.medium −1) where it leaves the boundary.
void diffusionStep(const Scene& scene, PathState& path, const Vec3& x, const DiffusionMedium& medium);
// The same, deep in aggregate path.medium: its medium, profile and boundary.
void diffusionStep(const Scene& scene, PathState& path, const Vec3& x);

}  // namespace granular
