#include "diffusion.h"

#include <algorithm>
#include <cmath>

#include "ept.h"
#include "scene.h"
#include "vpt.h"

namespace granular {

namespace {

// Laterally integrated exitance through the face z = 0 of the slab [0, d] (d = inf: a
// half space) from a unit source at depth z: the exact solution of the 1-D diffusion
// equation D Φ'' − σ_a Φ = −δ(ζ − z) with Φ = 0 on the extrapolated boundaries −z_b and
// d + z_b, read out as Φ(0)/4 + (D/2) Φ'(0). With κ = σ_tr, a = κ(z + z_b), b = κ(d + z_b − z):
//   Φ(ζ < z) = A sinh(κ(ζ + z_b)),  A = sinh b / (Dκ sinh(a + b)),
// and the total over the half space's (b → ∞) is
//   Â = sinh b / sinh(a + b) · e^{a} = (1 − e^{−2b}) / (1 − e^{−2(a+b)})   (1 for d = inf),
// computed directly: both totals underflow to 0 for deep sources (a beyond ~745). For
// κ → 0 the fluence is linear and the ratio is the escape probability (d + z_b − z)/(d + 2z_b).
double slabToHalfSpace(double kappa, double zb, double z, double d) {
  if (!std::isfinite(d)) return 1.0;
  if (kappa * (d + 2 * zb) < 1e-4) return (d + zb - z) / (d + 2 * zb);
  double a = kappa * (z + zb), b = kappa * (d + zb - z);
  return -std::expm1(-2 * b) / -std::expm1(-2 * (a + b));
}

// Plane integral over the face ζ = 0 of the exitance of a +1 source at signed depth a and a
// −1 source at b: each source gives e^{−σ|ζ|} (1/(8Dσ) + sign(ζ)/4), from
// ∫ e^{−σr}/(4πDr) dA = e^{−σ|ζ|}/(2Dσ) and its derivative across the face. The 1/σ parts
// cancel to first order within the pair: (e^{−σ|a|} − e^{−σ|b|})/σ = −e^{−σ|a|}
// expm1(−σ(|b| − |a|))/σ, whose σ → 0 limit |b| − |a| makes σ_a = 0 exact.
double pairTotal(double D, double s, double a, double b) {
  const double ea = std::exp(-s * std::fabs(a)), eb = std::exp(-s * std::fabs(b));
  const double gap = std::fabs(b) - std::fabs(a);
  const double diff = std::fabs(s * gap) > 1e-12 ? -ea * std::expm1(-s * gap) / s : ea * gap;  // (ea − eb)/σ
  const double sa = a > 0 ? 1.0 : (a < 0 ? -1.0 : 0.0), sb = b > 0 ? 1.0 : (b < 0 ? -1.0 : 0.0);
  return diff / (8.0 * D) + 0.25 * (sa * ea - sb * eb);
}

// The exact 1-D slab's laterally integrated exitance through a face at distance h from
// the source (the half space's dipole, exact in 1-D, times the slab's factor).
double slabTotalAt(double D, double s, double zb, double h, double d) {
  return std::max(pairTotal(D, s, h, -(h + 2.0 * zb)), 0.0) * slabToHalfSpace(s, zb, h, d);
}

// The plane total of the multipole with n image pairs on each side (Donner & Jensen's
// sources at 2iL + h and 2iL − h − 2z_b, L = d + 2z_b).
double multipoleTotalAt(double D, double s, double zb, double h, double d, int n) {
  const double L = std::isfinite(d) ? d + 2.0 * zb : 0.0;
  double t = 0;
  for (int i = -n; i <= n; ++i) t += pairTotal(D, s, 2 * i * L + h, 2 * i * L - h - 2.0 * zb);
  return t;
}

}  // namespace

int multipoleTerms(double sigmaTr, double zb, double d) {
  if (!std::isfinite(d)) return 0;
  const double reach = sigmaTr * (d + 2.0 * zb);
  if (!(reach > 0)) return kMaxMultipoleTerms;
  return int(std::clamp(std::ceil(kMultipoleReach / reach), 1.0, double(kMaxMultipoleTerms)));
}

DiffusionProfile::DiffusionProfile(const MediumParams& p) {
  for (int c = 0; c < 3; ++c) {
    float st = std::max(p.sigmaTReduced[c], 1e-30f);
    D[c] = 1.0f / (3.0f * st);
    sigmaTr[c] = p.sigmaTr[c];
    zb[c] = 2.0f * D[c];  // z_b = 2AD, A = 1 (index ratio 1, diffusion.h)
  }
  sigmaSReduced = p.sigmaSReduced;
  sigmaTReduced = p.sigmaTReduced;
  for (int c = 0; c < 3; ++c) {
    const float a = p.albedoReduced[c], s = std::sqrt(3.0f * std::max(0.0f, 1.0f - a));
    diffuseReflectance[c] = 0.5f * a * (1.0f + std::exp(-4.0f / 3.0f * s)) * std::exp(-s);
  }
}

DiffusionProfile DiffusionProfile::scaled(float k) const {
  DiffusionProfile p = *this;
  p.D = D / k;
  p.zb = zb / k;
  p.sigmaTr = sigmaTr * k;
  p.sigmaSReduced = sigmaSReduced * k;
  p.sigmaTReduced = sigmaTReduced * k;
  return p;
}

Vec3 DiffusionProfile::slabTotal(float z, float d, bool farFace) const {
  Vec3 T;
  const double h = farFace ? double(d) - z : double(z);
  for (int c = 0; c < 3; ++c) T[c] = float(slabTotalAt(D[c], sigmaTr[c], zb[c], h, d));
  return T;
}

Vec3 DiffusionProfile::multipoleTotal(float z, float d, bool farFace, int n) const {
  Vec3 T;
  const double h = farFace ? double(d) - z : double(z);
  for (int c = 0; c < 3; ++c) T[c] = float(multipoleTotalAt(D[c], sigmaTr[c], zb[c], h, d, n));
  return T;
}

Vec3 DiffusionProfile::exitance(float z, float rho, float d, bool farFace) const {
  Vec3 J;
  // The face's own depth of the source (the multipole is symmetric under swapping faces).
  const double h = farFace ? double(d) - z : double(z);
  for (int c = 0; c < 3; ++c) {
    const double Dc = D[c], s = sigmaTr[c], b = zb[c];
    const int n = multipoleTerms(s, b, d);
    const double L = n > 0 ? double(d) + 2.0 * b : 0.0;
    double phi = 0, dphi = 0;  // fluence and its derivative into the medium, on the face
    auto add = [&](double zs, double sign) {
      double r = std::max(std::sqrt(double(rho) * rho + zs * zs), 1e-12);
      double e = std::exp(-s * r) / (4.0 * kPiD * Dc);
      phi += sign * e / r;
      dphi += sign * zs * (1.0 + s * r) * e / (r * r * r);
    };
    for (int i = -n; i <= n; ++i) {
      add(2 * i * L + h, +1.0);
      add(2 * i * L - h - 2.0 * b, -1.0);
    }
    // d'Eon & Irving 2011 at index ratio 1: J = φ/4 + (D/2) ∂φ/∂n.
    double J0 = std::max(0.25 * phi + 0.5 * Dc * dphi, 0.0);  // NaN passes (and is counted), not clamped
    // Scaled to the exact 1-D total (diffusion.h); a multipole whose total underflowed is 0.
    if (n > 0) {
      const double planeTotal = multipoleTotalAt(Dc, s, b, h, d, n);
      J0 = planeTotal > 0 ? J0 * (slabTotalAt(Dc, s, b, h, d) / planeTotal) : 0.0;
    }
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

// Is the boundary at p (outward normal ng) covered by a surface just outside it (an
// aggregate's bottom face on a ground card)? Then light leaving there enters that surface:
// the exit is moved inside by the SurfaceCutBoundary margin (1e-4 of the coordinates), the
// path stays in its medium and meets the surface first (Scene::intersectMedium's tie rule).
// Offset outwards past the coplanar surface, it would go on under it (to the sky's lower
// half), and its NEE would see that half too.
bool coveredExit(const Scene& scene, const Vec3& p, const Vec3& ng, float time, Vec3& inside) {
  const float margin = SurfaceCutBoundary::margin(p);
  Ray ray;
  ray.o = p - ng * margin;
  ray.d = ng;
  ray.tmin = 0;
  ray.tmax = 2.0f * margin;
  ray.time = time;
  Hit hit;
  if (!scene.intersectMedium(ray, hit) || hit.kind != Hit::Surface) return false;
  inside = ray.o;
  return true;
}

// The path leaves the aggregate at boundary point p (normal ng) along dir, out of the media
// (or, where a surface covers the boundary, into that surface from inside: coveredExit).
void leaveAt(const Scene& scene, PathState& path, const Vec3& p, const Vec3& ng, const Vec3& dir) {
  Vec3 inside;
  if (path.medium >= 0 && coveredExit(scene, p, ng, path.ray.time, inside)) {
    path.ray.o = inside;
    path.ray.d = dir;
    path.ray.tmin = 0;
    path.ray.tmax = kInf;
    return;
  }
  float eps = 1e-5f * std::max(1e-3f, maxComponent(vabs(p)));
  path.ray.o = offsetRayOrigin(p, ng, dir, eps);
  path.ray.d = dir;
  path.ray.tmin = 0;
  path.ray.tmax = kInf;
  path.medium = -1;
}

}  // namespace

float AggregateBoundary::closestPoint(const Vec3& p, Vec3& closest) const {
  return agg_.closestBoundaryPoint(p, closest);
}

bool AggregateBoundary::intersect(const Vec3& o, const Vec3& d, float tmax, float& t, Vec3& ng) const {
  return agg_.intersectBoundary(o, d, 0.0f, tmax, t, ng);
}

float SurfaceCutBoundary::closestPoint(const Vec3& p, Vec3& closest) const { return inner_.closestPoint(p, closest); }

float SurfaceCutBoundary::margin(const Vec3& p) {
  return 1e-4f * std::max(1e-3f, maxComponent(vabs(p)));
}

bool SurfaceCutBoundary::intersect(const Vec3& o, const Vec3& d, float tmax, float& t, Vec3& ng) const {
  if (!inner_.intersect(o, d, tmax, t, ng)) t = tmax;
  Ray ray;
  ray.o = o;
  ray.d = d;
  ray.tmax = std::isfinite(t) ? t : kInf;
  ray.time = time_;
  Hit hit;
  if (scene_.intersectMedium(ray, hit) && hit.t < ray.tmax) {
    // A surface first: the light leaves there, just before it, towards it.
    t = std::max(0.0f, hit.t - margin(hit.p));
    ng = dot(hit.ng, d) > 0 ? hit.ng : -hit.ng;
    return true;
  }
  return std::isfinite(t) && t < tmax;
}

Vec3 SurfaceCutBoundary::exitPoint(const Vec3& p, const Vec3& ng) const {
  const Vec3 e = inner_.exitPoint(p, ng);
  const float len = length(e - p);
  if (!(len > 0)) return p;
  Ray ray;
  ray.o = p;
  ray.d = (e - p) / len;
  ray.tmax = len;
  ray.time = time_;
  Hit hit;
  if (!scene_.intersectMedium(ray, hit) || !(hit.t < len)) return e;
  return p + ray.d * std::max(0.0f, hit.t - margin(hit.p));
}

float localCurvatureRadius(const Aggregate& agg, const Vec3& x, float delta) {
  Vec3 c;
  const float z = agg.closestBoundaryPoint(x, c);
  if (!(z > 0)) return 0.0f;
  delta = std::max(delta, z);
  const Vec3 n = (c - x) / z;
  const Frame frame(n);
  float radius = kInf;
  for (const Vec3& tangent : {frame.s, -frame.s, frame.t, -frame.t}) {
    const Vec3 x2 = x + tangent * delta;
    Vec3 c2;
    const float z2 = agg.closestBoundaryPoint(x2, c2);
    if (!(z2 > 0)) return 0.0f;
    // Outside (the boundary bends within δ), the normal points back: a ≥ 90°, radius 0.
    const float cosA = std::clamp(dot(n, (c2 - x2) / z2), -1.0f, 1.0f);
    const float a = std::acos(cosA);
    if (a >= 0.5f * kPi) return 0.0f;
    if (a > 1e-6f) radius = std::min(radius, delta / std::tan(a) + z);
  }
  return radius;
}

bool diffusionHolds(const Aggregate& agg, const Vec3& x, float daDepth) {
  return localCurvatureRadius(agg, x, 0.0f) >= kCurvatureGuard * daDepth;
}

void diffusionStep(const Scene& scene, PathState& path, const Vec3& x) {
  const AggregateBoundary boundary(scene.aggregateAt(path.medium, path.ray.time));
  const HomogeneousMedium& med = scene.medium(path.medium);
  diffusionStep(scene, path, x, DiffusionMedium{med, med.sigmaT(), scene.diffusionProfile(path.medium), boundary});
}

void diffusionStep(const Scene& scene, PathState& path, const Vec3& x, const DiffusionMedium& m) {
  const DiffusionBoundary& boundary = m.boundary;
  const DiffusionProfile& prof = m.profile;
  const HomogeneousMedium& med = m.phase;
  path.cost[1] += 5;
  // Light reaching x straight from the lights (single scattering, exact; the diffusion
  // below carries the rest): a delta sun can only be reached this way. Its flight to the
  // boundary is in the reduced medium: σ_t − σ'_t of it given back.
  path.credit = kDa;
  const Vec3 reducedBy = m.sigmaT - prof.sigmaTReduced;
  mediumNee(scene, path, med, x, &boundary, reducedBy);

  // 1. The beam: ω from the phase function, the first reduced scattering at t along it.
  Vec3 phaseWeight;
  float phasePdf;
  float uc = path.rng.next1D(), u1 = path.rng.next1D(), u2 = path.rng.next1D();
  const Vec3 w = med.samplePhase(path.ray.d, uc, u1, u2, phaseWeight, phasePdf);
  float s;
  Vec3 ngS;
  if (!(phasePdf > 0) || !boundary.intersect(x, w, kInf, s, ngS)) {
    path.alive = false;  // no boundary along ω: a leak (open by rounding)
    path.lost = true;
    return;
  }
  // MIS with the NEE at x (its weights were computed against this phase pdf), for the
  // uncollided beam below and for shadow linking: the direct light ω brings past objects
  // that cast no shadow, by the single scattering's shadow ray.
  path.scattered(false, phasePdf, x, 1.0f, 0.0f);
  const Vec3 along = path.beta * phaseWeight;
  addDirectPastNonCasters(scene, path, along, x, w, [&](const Vec3& c, float dist, ShadowCasters who) {
    path.L[path.credit] += c * mediumShadow(scene, path, x, x, w, dist, who, &boundary, reducedBy);
  });
  const float sigmaBar = average(prof.sigmaTReduced);
  const float t = -std::log1p(-std::min(path.rng.next1D(), 1.0f - 1e-7f)) / sigmaBar;
  if (t >= s) {
    // Uncollided: probability e^{−σ'_t s} per channel, sampled as e^{−σ̄ s}.
    path.beta *= phaseWeight * vexp((prof.sigmaTReduced - Vec3(sigmaBar)) * -s);
    leaveAt(scene, path, boundary.exitPoint(x + w * s, ngS), ngS, w);
    ++path.depth;
    if (!isFinite(path.beta) || isBlack(path.beta)) path.alive = false;
    return;
  }
  // Source density σ'_s e^{−σ'_t t} per channel over the sampling pdf σ̄ e^{−σ̄ t}.
  path.beta *= phaseWeight * prof.sigmaSReduced * vexp((prof.sigmaTReduced - Vec3(sigmaBar)) * -t) / sigmaBar;
  const Vec3 y = x + w * t;

  // 2. The slab through y: near face at the closest boundary point, far face along −n.
  Vec3 closest;
  float z = boundary.closestPoint(y, closest);
  if (!(z > 0)) {  // y on or outside the boundary: lost to rounding
    path.alive = false;
    path.lost = true;
    return;
  }
  Vec3 n = (closest - y) / z;  // outward normal of the near face
  float tFar, dFar = kInf;
  Vec3 ngFar;
  if (boundary.intersect(y, -n, kInf, tFar, ngFar)) dFar = tFar;
  float d = z + dFar;
  // Face choice: the escape probability of a non-absorbing slab, (d − z + z_b)/(d + 2z_b).
  float zb = average(prof.zb);
  float pNear = std::isfinite(d) ? (dFar + zb) / (d + 2.0f * zb) : 1.0f;
  bool farFace = path.rng.next1D() >= pNear;
  float pFace = farFace ? 1.0f - pNear : pNear;
  float h = farFace ? dFar : z;
  Vec3 faceN = farFace ? -n : n;

  // 3. A point of that face, J/pdf.
  float pdfArea;
  float uPick = path.rng.next1D(), u = path.rng.next1D(), uPhi = path.rng.next1D();
  float rho = sampleRadius(h, average(prof.sigmaTr), uPick, u, pdfArea);
  Frame frame(faceN);
  float phi = 2.0f * kPi * uPhi;
  Vec3 q = y + faceN * h + (frame.s * std::cos(phi) + frame.t * std::sin(phi)) * rho;
  Vec3 J = prof.exitance(z, rho, d, farFace);
  if (!(pdfArea > 0) || isBlack(J)) {
    path.alive = false;
    return;
  }
  // The curved boundary: x_o is where the ray from y towards the planar point leaves.
  Vec3 dir = normalize(q - y);
  float tOut;
  Vec3 ngOut;
  if (!boundary.intersect(y, dir, kInf, tOut, ngOut)) {  // a leak
    path.alive = false;
    path.lost = true;
    return;
  }
  path.beta *= J / (pdfArea * pFace);
  // 4. At x_o the exit lobe plays the BSDF: NEE, then a direction sampled from it.
  Hit hit;
  hit.kind = Hit::Surface;
  hit.ng = dot(ngOut, dir) > 0 ? ngOut : -ngOut;
  hit.p = boundary.exitPoint(y + dir * tOut, hit.ng);
  // A face covered by a surface (the far face on a ground card): out into that surface
  // from just inside, still in the medium (coveredExit); else out of the media.
  Vec3 inside;
  if (path.medium >= 0 && coveredExit(scene, hit.p, hit.ng, path.ray.time, inside)) hit.p = inside;
  else path.medium = -1;
  hit.t = tOut;
  hit.material = scene.diffusionExitMaterial();
  hit.eps = 1e-5f * std::max(1e-3f, maxComponent(vabs(hit.p)));
  path.ray.o = hit.p;
  path.ray.d = -hit.ng;
  shadeSurface(scene, path, hit, true);
}

}  // namespace granular
