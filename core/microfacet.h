// microfacet.h — the GGX (Trowbridge–Reitz) microfacet distribution of rough grains.
//
// Contract: isotropic GGX of width α in the local shading frame (+Z = macro normal);
// directions on the +Z side unless said. D is the normal distribution (Walter et al.
// 2007, eq. 33), Λ and G1 Smith's masking for it (eq. 34 in Heitz 2014's form), G2 the
// height-correlated masking-shadowing G2 = 1 / (1 + Λ(wo) + Λ(wi)) (Heitz 2014, eq. 99).
// sampleVisibleNormal draws m with the density of the normals visible from wo,
//   D_wo(m) = G1(wo) max(0, wo·m) D(m) / wo.z     (Heitz 2018, eq. 1)
// which makes the sampling weight of a microfacet BSDF G2 / G1(wo).
#pragma once

#include <cmath>

#include "math.h"

namespace granular {

// Roughness (the schema's [0, 1]) to GGX α: α = roughness² (Burley 2012, as UsdPreviewSurface
// and most renderers read it). Below kMinAlpha the lobe is narrower than the grains'
// facets resolve and the smooth (delta) interface is used: 0 means smooth.
constexpr float kMinAlpha = 1e-3f;
inline float alphaFromRoughness(float roughness) {
  const float a = roughness * roughness;
  return a < kMinAlpha ? 0.0f : a;
}

inline float ggxD(const Vec3& m, float alpha) {
  if (m.z <= 0) return 0.0f;
  const float a2 = alpha * alpha, c2 = m.z * m.z;
  const float d = c2 * (a2 - 1.0f) + 1.0f;
  return a2 / (kPi * d * d);
}

// Λ(w) = (−1 + sqrt(1 + α² tan²θ)) / 2, for either side (|cos θ|).
inline float ggxLambda(const Vec3& w, float alpha) {
  const float c2 = w.z * w.z;
  if (c2 <= 0) return kInf;
  const float tan2 = std::max(0.0f, 1.0f - c2) / c2;
  return 0.5f * (std::sqrt(1.0f + alpha * alpha * tan2) - 1.0f);
}
inline float ggxG1(const Vec3& w, float alpha) { return 1.0f / (1.0f + ggxLambda(w, alpha)); }
inline float ggxG2(const Vec3& wo, const Vec3& wi, float alpha) {
  return 1.0f / (1.0f + ggxLambda(wo, alpha) + ggxLambda(wi, alpha));
}

// D_wo(m) above; wo.z > 0.
inline float ggxVisiblePdf(const Vec3& wo, const Vec3& m, float alpha) {
  const float c = dot(wo, m);
  if (c <= 0 || wo.z <= 0) return 0.0f;
  return ggxG1(wo, alpha) * c * ggxD(m, alpha) / wo.z;
}

// A normal m with density D_wo(m) (Heitz 2018: stretch wo to the unit-roughness
// configuration, sample the projected hemisphere there, unstretch); wo.z > 0.
inline Vec3 sampleGgxVisibleNormal(const Vec3& wo, float alpha, float u1, float u2) {
  const Vec3 v = normalize(Vec3(alpha * wo.x, alpha * wo.y, wo.z));
  const float len2 = v.x * v.x + v.y * v.y;
  const Vec3 t1 = len2 > 0 ? Vec3(-v.y, v.x, 0.0f) / std::sqrt(len2) : Vec3(1, 0, 0);
  const Vec3 t2 = cross(v, t1);
  const float r = std::sqrt(u1), phi = 2.0f * kPi * u2;
  const float p1 = r * std::cos(phi);
  const float s = 0.5f * (1.0f + v.z);
  const float p2 = (1.0f - s) * std::sqrt(std::max(0.0f, 1.0f - p1 * p1)) + s * r * std::sin(phi);
  const Vec3 n = t1 * p1 + t2 * p2 + v * std::sqrt(std::max(0.0f, 1.0f - p1 * p1 - p2 * p2));
  return normalize(Vec3(alpha * n.x, alpha * n.y, std::max(1e-7f, n.z)));
}

}  // namespace granular
