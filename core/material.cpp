#include "material.h"

#include "sampling.h"

namespace granular {

float fresnelDielectric(float cosI, float eta) {
  // eta = n_inside / n_outside; flip when arriving from inside.
  if (cosI < 0) { eta = 1.0f / eta; cosI = -cosI; }
  float sin2T = (1.0f - cosI * cosI) / (eta * eta);
  if (sin2T >= 1.0f) return 1.0f;  // total internal reflection
  float cosT = std::sqrt(std::max(0.0f, 1.0f - sin2T));
  float rs = (cosI - eta * cosT) / (cosI + eta * cosT);
  float rp = (eta * cosI - cosT) / (eta * cosI + cosT);
  return 0.5f * (rs * rs + rp * rp);
}

Material Material::fromDesc(const MaterialDesc& d) {
  Material m;
  m.type = d.type;
  m.albedo = d.albedo;
  m.ior = d.ior;
  m.absorption = d.absorption;
  m.emission = d.emission;
  return m;
}

namespace {
// DiffusionExit: f μ = (2μ + 3μ²)/(4π), sampled as an equal mixture of μ/π (cosine) and
// 3μ²/(2π) (μ = u^{1/3}); the mixture's pdf is exactly f μ, so the weight is 1.
float diffusionExitPdf(float mu) { return mu > 0 ? (2.0f * mu + 3.0f * mu * mu) / (4.0f * kPi) : 0.0f; }
}  // namespace

Vec3 Material::eval(const Vec3& wo, const Vec3& wi) const {
  if (wo.z <= 0 || wi.z <= 0) return Vec3(0.0f);
  if (type == MaterialType::Lambert) return albedo * (kInvPi * wi.z);
  if (type == MaterialType::DiffusionExit) return Vec3(diffusionExitPdf(wi.z));
  return Vec3(0.0f);
}

float Material::pdf(const Vec3& wo, const Vec3& wi) const {
  if (wo.z <= 0) return 0.0f;
  if (type == MaterialType::Lambert) return cosineHemispherePdf(wi.z);
  if (type == MaterialType::DiffusionExit) return diffusionExitPdf(wi.z);
  return 0.0f;
}

bool Material::sample(const Vec3& wo, float uLobe, float u1, float u2, BsdfSample& s) const {
  if (type == MaterialType::DiffusionExit) {
    if (wo.z <= 0) return false;
    if (uLobe < 0.5f) {
      s.wi = sampleCosineHemisphere(u1, u2);
    } else {
      float mu = std::cbrt(u1), r = std::sqrt(std::max(0.0f, 1.0f - mu * mu)), phi = 2.0f * kPi * u2;
      s.wi = Vec3(r * std::cos(phi), r * std::sin(phi), mu);
    }
    s.pdf = diffusionExitPdf(s.wi.z);
    if (s.pdf <= 0) return false;
    s.weight = Vec3(1.0f);
    s.delta = false;
    s.transmitted = false;
    return true;
  }
  if (type == MaterialType::Lambert) {
    if (wo.z <= 0) return false;  // seen from behind: opaque and black
    s.wi = sampleCosineHemisphere(u1, u2);
    s.pdf = cosineHemispherePdf(s.wi.z);
    if (s.pdf <= 0) return false;
    s.weight = albedo;  // (albedo/pi) cos / (cos/pi)
    s.delta = false;
    s.transmitted = false;
    return true;
  }
  // Smooth dielectric.
  float cosO = wo.z;
  float F = fresnelDielectric(cosO, ior);
  s.delta = true;
  s.pdf = 0;
  if (uLobe < F) {
    s.wi = Vec3(-wo.x, -wo.y, wo.z);
    s.weight = Vec3(1.0f);
    s.transmitted = false;
    return true;
  }
  bool entering = cosO > 0;
  float eta = entering ? ior : 1.0f / ior;  // n_t / n_i
  float cosA = std::fabs(cosO);
  float sin2T = (1.0f - cosA * cosA) / (eta * eta);
  float cosT = std::sqrt(std::max(0.0f, 1.0f - sin2T));
  // wi = -wo / eta + (cosA / eta - cosT) n, with n on wo's side.
  Vec3 n(0, 0, entering ? 1.0f : -1.0f);
  s.wi = normalize(-wo / eta + n * (cosA / eta - cosT));
  s.weight = Vec3(1.0f);  // see the header: the 1/eta^2 radiance scale cancels on exit
  s.transmitted = true;
  return true;
}

}  // namespace granular
