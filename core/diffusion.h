// diffusion.h — the diffusion approximation (DA) that ends deep paths (seed §1.4, §3).
//
// Contract. A path that scatters at a point x deeper than diffusionDepth() below the
// boundary stops its random walk. The radiance it would gather there, ∫ p L_i dω, is taken
// as φ(x)/4π (diffusion: nearly isotropic radiance), and by reciprocity
//   φ(x)/4π = ∫_boundary J(x → x_o) ∫ q(μ) L_ext(x_o, ω) μ dω dA(x_o),
// with J the diffuse exitance at x_o per unit power of an isotropic point source at x
// (the "virtual source" sits at x itself, at depth z below the locally planar boundary),
// q the angular lobe of the exiting light (∫ q μ dω = 1) and L_ext the radiance arriving
// at x_o from outside. diffusionStep() samples one x_o (on the near face or, for a slab
// of finite thickness, the far face) with a stated area pdf, multiplies the path weight
// by J/pdf and continues the path from x_o with the lobe q as its "BSDF" (NEE there, then
// a direction sampled from q): Li et al. 2005's hybrid, in importance form.
//
// J uses the reduced parameters (Jensen 2001) with D = 1/(3σ'_t), σ_tr = sqrt(3σ_aσ'_t),
// an index-matched boundary (A = 1, extrapolation distance z_b = 2AD), d'Eon & Irving
// 2011's exitance J = φ/4 + (D/2)|∂φ/∂n| (fluence and flux terms; C_φ = 1/4, C_E = 1/2
// at η = 1) and their P1 angular profile of the exiting light (MaterialType::
// DiffusionExit). Finite thickness (Donner & Jensen 2005's concern): the slab through x
// along the boundary normal has thickness d; each face keeps its dipole's lateral shape,
// scaled to the exact laterally integrated exitance of the 1-D slab problem. (The image
// series of the multipole, truncated, loses energy conservation as σ_a d → 0; the 1-D
// solution is exact there.)
#pragma once

#include "math.h"
#include "tt.h"

namespace granular {

struct PathState;
class Scene;

// Diffuse exitance per unit source power, per channel, of the slab [0, d] (d = inf: a
// half space) at lateral distance rho from an isotropic point source at depth z:
// on the face z = 0 (near) or z = d (far).
struct DiffusionProfile {
  Vec3 D, sigmaTr, zb;  // per channel
  DiffusionProfile() = default;
  explicit DiffusionProfile(const MediumParams& p);
  Vec3 exitance(float z, float rho, float d, bool farFace) const;
  // ∫ exitance dA over the face (numerically, for tests and face selection).
  Vec3 totalExitance(float z, float d, bool farFace) const;
};

// Continues path (scattering at x, deep in aggregate path.medium) by DA; see above.
void diffusionStep(const Scene& scene, PathState& path, const Vec3& x);

}  // namespace granular
