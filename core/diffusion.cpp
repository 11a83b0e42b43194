#include "diffusion.h"

#include <cmath>

#include "ept.h"
#include "scene.h"

namespace granular {

namespace {

// Laterally integrated exitance through the face z = 0 of the slab [0, d] (d = inf: a
// half space) from a unit source at depth z: the exact solution of the 1-D diffusion
// equation D Φ'' − σ_a Φ = −δ(ζ − z) with Φ = 0 on the extrapolated boundaries −z_b and
// d + z_b, read out as Φ(0)/4 + (D/2) Φ'(0). With κ = σ_tr, a = κ(z + z_b), b = κ(d + z_b − z):
//   Φ(ζ < z) = A sinh(κ(ζ + z_b)),  A = sinh b / (Dκ sinh(a + b)),
// so the total is e^{−a} Â/(Dκ) · (sinh(κz_b)/4 + Dκ cosh(κz_b)/2) with
//   Â = sinh b / sinh(a + b) · e^{a} = (1 − e^{−2b}) / (1 − e^{−2(a+b)})   (1 for d = inf).
// The finite slab's total over the half space's is therefore Â: computed directly, not
// as a quotient of the two totals, which both underflow to 0 for deep sources (a beyond
// ~745: fine grains, large σ_tr) and gave 0/0 = NaN. For κ → 0 the fluence is linear and
// the ratio is the escape probability (d + z_b − z)/(d + 2z_b).
double slabToHalfSpace(double kappa, double zb, double z, double d) {
  if (!std::isfinite(d)) return 1.0;
  if (kappa * (d + 2 * zb) < 1e-4) return (d + zb - z) / (d + 2 * zb);
  double a = kappa * (z + zb), b = kappa * (d + zb - z);
  return -std::expm1(-2 * b) / -std::expm1(-2 * (a + b));
}

}  // namespace

DiffusionProfile::DiffusionProfile(const MediumParams& p) {
  for (int c = 0; c < 3; ++c) {
    float st = std::max(p.sigmaTReduced[c], 1e-30f);
    D[c] = 1.0f / (3.0f * st);
    sigmaTr[c] = p.sigmaTr[c];
    zb[c] = 2.0f * D[c];  // z_b = 2AD, A = 1 for an index-matched boundary
  }
}

Vec3 DiffusionProfile::exitance(float z, float rho, float d, bool farFace) const {
  Vec3 J;
  // The face's own depth of the source.
  const double h = farFace ? double(d) - z : double(z);
  for (int c = 0; c < 3; ++c) {
    const double Dc = D[c], s = sigmaTr[c], b = zb[c];
    // Half-space dipole seen from the face: real source at depth h, image at −(h + 2z_b).
    double phi = 0, dphi = 0;  // fluence and its derivative into the medium, on the face
    auto add = [&](double zs, double sign) {
      double r = std::max(std::sqrt(double(rho) * rho + zs * zs), 1e-12);
      double e = std::exp(-s * r) / (4.0 * kPiD * Dc);
      phi += sign * e / r;
      dphi += sign * zs * (1.0 + s * r) * e / (r * r * r);
    };
    add(h, +1.0);
    add(-(h + 2.0 * b), -1.0);
    // d'Eon & Irving 2011 (η = 1): J = φ/4 + (D/2) ∂φ/∂n (fluence and outward flux).
    double J0 = std::max(0.25 * phi + 0.5 * Dc * dphi, 0.0);  // NaN passes (and is counted), not clamped
    // Finite thickness: keep the dipole's lateral shape, scale its total to the slab's
    // exact 1-D total (a truncated multipole sum does not conserve energy as σ_a d → 0).
    if (std::isfinite(d)) J0 *= slabToHalfSpace(s, b, h, d);
    J[c] = float(J0);
  }
  return J;
}

Vec3 DiffusionProfile::totalExitance(float z, float d, bool farFace) const {
  // ∫ J 2πρ dρ with ρ = h·sinh(u): smooth near ρ = 0 and reaching far tails.
  float h = std::max(farFace ? d - z : z, 1e-6f);
  Vec3 sum;
  const int steps = 4000;
  const double umax = 14.0, du = umax / steps;
  for (int k = 0; k < steps; ++k) {
    double u = (k + 0.5) * du, rho = h * std::sinh(u), drho = h * std::cosh(u) * du;
    sum += exitance(z, float(rho), d, farFace) * float(2.0 * kPiD * rho * drho);
  }
  return sum;
}

namespace {

// Lateral distance ρ on a face at distance h from the source, sampled by one-sample MIS
// of two proposals: p1 = h/(2π r³) (the r⁻³ tail of a non-absorbing dipole; r = h/(1−u))
// and p2 = σ e^{−σ(r−h)}/(2π r) (absorption's exponential fall-off; r = h + Exp(σ)),
// where r = sqrt(ρ² + h²). Returns ρ and the area pdf 0.5 p1 + 0.5 p2.
float sampleRadius(float h, float sigma, float uPick, float u, float& pdfArea) {
  float r;
  if (sigma <= 0 || uPick < 0.5f) r = h / std::max(1.0f - u, 1e-7f);
  else r = h - std::log1p(-u) / sigma;
  double p1 = h / (2.0 * kPiD * double(r) * r * r);
  double p2 = sigma > 0 ? sigma * std::exp(-double(sigma) * (r - h)) / (2.0 * kPiD * r) : 0.0;
  pdfArea = float(sigma > 0 ? 0.5 * (p1 + p2) : p1);
  return std::sqrt(std::max(0.0f, r * r - h * h));
}

}  // namespace

void diffusionStep(const Scene& scene, PathState& path, const Vec3& x) {
  const Aggregate& agg = *scene.aggregates()[path.medium];
  const DiffusionProfile& prof = scene.diffusionProfile(path.medium);
  path.cost[1] += 3;
  // Depth and the locally planar boundary: the nearest boundary point (exact query).
  Vec3 closest;
  float z = agg.closestBoundaryPoint(x, closest);
  if (!(z > 0)) {
    path.alive = false;
    return;
  }
  Vec3 n = (closest - x) / z;  // outward normal of the near face
  // Thickness along −n (the slab of Donner & Jensen); no far face: a half space.
  float tFar, dFar = kInf;
  Vec3 ngFar;
  if (agg.intersectBoundary(x, -n, 0.0f, kInf, tFar, ngFar)) dFar = tFar;
  float d = z + dFar;
  // Face choice: the escape probability of a non-absorbing slab, (d − z + z_b)/(d + 2z_b).
  float zb = average(prof.zb);
  float pNear = std::isfinite(d) ? (dFar + zb) / (d + 2.0f * zb) : 1.0f;
  bool farFace = path.rng.next1D() >= pNear;
  float pFace = farFace ? 1.0f - pNear : pNear;
  float h = farFace ? dFar : z;
  Vec3 faceN = farFace ? -n : n;

  float pdfArea;
  float uPick = path.rng.next1D(), u = path.rng.next1D(), uPhi = path.rng.next1D();
  float rho = sampleRadius(h, average(prof.sigmaTr), uPick, u, pdfArea);
  Frame frame(faceN);
  float phi = 2.0f * kPi * uPhi;
  Vec3 q = x + faceN * h + (frame.s * std::cos(phi) + frame.t * std::sin(phi)) * rho;
  Vec3 J = prof.exitance(z, rho, d, farFace);
  if (!(pdfArea > 0) || isBlack(J)) {
    path.alive = false;
    return;
  }
  // The curved boundary: x_o is where the ray from x towards the planar point leaves.
  Vec3 dir = normalize(q - x);
  float tOut;
  Vec3 ngOut;
  if (!agg.intersectBoundary(x, dir, 0.0f, kInf, tOut, ngOut)) {
    path.alive = false;
    return;
  }
  path.beta *= J / (pdfArea * pFace);
  path.credit = kDa;
  path.medium = -1;
  // At x_o the exit lobe q plays the BSDF: NEE, then a direction sampled from q.
  Hit hit;
  hit.kind = Hit::Surface;
  hit.p = x + dir * tOut;
  hit.ng = dot(ngOut, dir) > 0 ? ngOut : -ngOut;
  hit.t = tOut;
  hit.material = scene.diffusionExitMaterial();
  hit.eps = 1e-5f * std::max(1e-3f, maxComponent(vabs(hit.p)));
  path.ray.o = hit.p;
  path.ray.d = -hit.ng;
  shadeSurface(scene, path, hit, true);
}

}  // namespace granular
