#include "material.h"

#include "microfacet.h"
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

namespace {
bool sampleRoughDielectric(const Vec3& wo, float ior, float alpha, float uLobe, float u1, float u2, BsdfSample& s);
}  // namespace

Material Material::fromDesc(const MaterialDesc& d) {
  Material m;
  m.type = d.type;
  m.albedo = d.albedo;
  m.ior = d.ior;
  m.absorption = d.absorption;
  m.emission = d.emission;
  if (d.type == MaterialType::Dielectric) m.alpha = alphaFromRoughness(d.roughness);
  if (m.alpha > 0 && d.energyCompensation) {
    // P_valid(μ): the fraction of raw samples with a valid direction, by stratified
    // sampling (a 48×48 grid of visible normals, the lobe choice from a golden-ratio
    // sequence; deterministic, about 1e-3).
    std::vector<float> table;
    for (int side = 0; side < 2; ++side)
      for (int i = 0; i < kValidNodes; ++i) {
        const float mu = (i + 0.5f) / kValidNodes;
        const Vec3 wo(std::sqrt(1.0f - mu * mu), 0.0f, side == 0 ? mu : -mu);
        const int n = 48;
        int valid = 0;
        for (int a = 0; a < n; ++a)
          for (int b = 0; b < n; ++b) {
            const float uLobe = float(std::fmod((a * n + b) * 0.6180339887498949, 1.0));
            BsdfSample s;
            valid += sampleRoughDielectric(wo, m.ior, m.alpha, uLobe, (a + 0.5f) / n, (b + 0.5f) / n, s);
          }
        table.push_back(std::max(0.05f, float(valid) / float(n * n)));
      }
    m.validTable = std::move(table);
  }
  return m;
}

float Material::validFraction(const Vec3& wo) const {
  const float* e = validTable.data() + (wo.z < 0 ? kValidNodes : 0);
  const float x = std::clamp(std::fabs(wo.z) * kValidNodes - 0.5f, 0.0f, float(kValidNodes - 1));
  const int i = std::min(int(x), kValidNodes - 2);
  const float t = x - float(i);
  return (1.0f - t) * e[i] + t * e[i + 1];
}

namespace {
// DiffusionExit: f μ = (2μ + 3μ²)/(4π), sampled as an equal mixture of μ/π (cosine) and
// 3μ²/(2π) (μ = u^{1/3}); the mixture's pdf is exactly f μ, so the weight is 1.
float diffusionExitPdf(float mu) { return mu > 0 ? (2.0f * mu + 3.0f * mu * mu) / (4.0f * kPi) : 0.0f; }

// The rough dielectric's f |cos wi| and pdf for a pair of directions, either side.
// Mirrored so that wo.z > 0, eta = n_t / n_i seen from wo. Reflection: h = wo + wi,
// f = F D G2 / (4 |wo.z| |wi.z|) (Walter eq. 20), pdf = F D_wo(h) / (4 wo·h). Refraction:
// h ∝ −(wo + eta wi) (eq. 16), f = (1 − F) D G2 |wo·h| |wi·h| eta² / (|wo.z| |wi.z| (wo·h +
// eta wi·h)²) — eq. 21 without the 1/eta² radiance scale (header) — and pdf = (1 − F)
// D_wo(h) eta² |wi·h| / (wo·h + eta wi·h)² (eq. 17's Jacobian).
void roughDielectric(Vec3 wo, Vec3 wi, float ior, float alpha, float& fcos, float& pdf) {
  fcos = pdf = 0.0f;
  if (wo.z == 0 || wi.z == 0) return;
  float eta = ior;
  if (wo.z < 0) {
    wo = -wo;
    wi = -wi;
    eta = 1.0f / ior;
  }
  const bool reflect = wi.z > 0;
  Vec3 h = reflect ? wo + wi : -(wo + wi * eta);
  if (length2(h) <= 0) return;
  h = normalize(h);
  if (h.z < 0) h = -h;
  const float oh = dot(wo, h), ih = dot(wi, h);
  if (oh <= 0 || (reflect ? ih <= 0 : ih >= 0)) return;  // back-facing microfacet
  const float F = fresnelDielectric(oh, eta);
  const float D = ggxD(h, alpha), G = ggxG2(wo, wi, alpha), Dv = ggxVisiblePdf(wo, h, alpha);
  if (reflect) {
    fcos = F * D * G / (4.0f * wo.z);
    pdf = F * Dv / (4.0f * oh);
  } else {
    const float denom = (oh + eta * ih) * (oh + eta * ih);
    if (!(denom > 0)) return;
    const float jacobian = eta * eta * std::fabs(ih) / denom;
    fcos = (1.0f - F) * D * G * oh * jacobian / wo.z;
    pdf = (1.0f - F) * Dv * jacobian;
  }
}

// One sample of the uncompensated rough dielectric: a visible normal, then F picks
// reflection or refraction on it; false when the direction is invalid (below the macro
// surface on its side: single scattering loses it). Sets wi, transmitted, delta and the
// weight G2 / G1(wo); not the pdf.
bool sampleRoughDielectric(const Vec3& wo, float ior, float alpha, float uLobe, float u1, float u2, BsdfSample& s) {
  const float sign = wo.z < 0 ? -1.0f : 1.0f;
  const Vec3 w = wo * sign;
  const float eta = sign > 0 ? ior : 1.0f / ior;
  const Vec3 h = sampleGgxVisibleNormal(w, alpha, u1, u2);
  const float oh = dot(w, h);
  if (!(oh > 0)) return false;
  const float F = fresnelDielectric(oh, eta);
  Vec3 wi;
  if (uLobe < F) {
    wi = h * (2.0f * oh) - w;
    if (wi.z <= 0) return false;
  } else {
    const float sin2T = (1.0f - oh * oh) / (eta * eta);
    if (sin2T >= 1.0f) return false;
    const float cosT = std::sqrt(1.0f - sin2T);
    wi = normalize(-w / eta + h * (oh / eta - cosT));
    if (wi.z >= 0) return false;
  }
  s.wi = wi * sign;
  s.transmitted = wi.z < 0;
  s.delta = false;
  s.weight = Vec3(ggxG2(w, wi, alpha) / ggxG1(w, alpha));
  return true;
}

}  // namespace

Vec3 Material::eval(const Vec3& wo, const Vec3& wi, float* pdfOut) const {
  Vec3 f(0.0f);
  float p = 0.0f;
  if (type == MaterialType::Dielectric) {
    if (alpha > 0) {
      float fcos;
      roughDielectric(wo, wi, ior, alpha, fcos, p);
      if (!validTable.empty()) p /= validFraction(wo);
      f = Vec3(validTable.empty() ? fcos : p);  // compensated: f |cos wi| is the density
    }
  } else if (wo.z > 0 && wi.z > 0) {
    if (type == MaterialType::Lambert) {
      f = albedo * (kInvPi * wi.z);
      p = cosineHemispherePdf(wi.z);
    } else if (type == MaterialType::DiffusionExit) {
      p = diffusionExitPdf(wi.z);
      f = Vec3(p);
    }
  }
  if (pdfOut) *pdfOut = p;
  return f;
}

float Material::pdf(const Vec3& wo, const Vec3& wi) const {
  float p;
  eval(wo, wi, &p);
  return p;
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
  if (alpha > 0) {
    if (validTable.empty()) {
      if (!sampleRoughDielectric(wo, ior, alpha, uLobe, u1, u2, s)) return false;
      float f;
      roughDielectric(wo, s.wi, ior, alpha, f, s.pdf);
      if (!(s.pdf > 0)) return false;
      return true;
    }
    // Compensated: the lobe's valid directions renormalised, drawn by rejection (fresh
    // numbers from additive recurrences per try): pdf = raw pdf / P_valid(wo), weight 1.
    for (int k = 0; k < kCompensationTries; ++k) {
      const float a = float(k);
      const float ul = std::fmod(uLobe + a * 0.6180339887f, 1.0f), v1 = std::fmod(u1 + a * 0.7548776662f, 1.0f),
                  v2 = std::fmod(u2 + a * 0.5698402910f, 1.0f);
      if (!sampleRoughDielectric(wo, ior, alpha, ul, v1, v2, s)) continue;
      float f, p;
      roughDielectric(wo, s.wi, ior, alpha, f, p);
      if (!(p > 0)) continue;
      s.pdf = p / validFraction(wo);
      s.weight = Vec3(1.0f);
      return true;
    }
    return false;
  }
  // Smooth dielectric.
  const SmoothBranches b = smoothBranches(wo);
  return sampleSmooth(b, b.F, uLobe, s);
}

Material::SmoothBranches Material::smoothBranches(const Vec3& wo) const {
  SmoothBranches b;
  b.F = fresnelDielectric(wo.z, ior);
  b.reflected = Vec3(-wo.x, -wo.y, wo.z);
  const bool entering = wo.z > 0;
  const float eta = entering ? ior : 1.0f / ior;  // n_t / n_i
  const float cosA = std::fabs(wo.z);
  const float sin2T = (1.0f - cosA * cosA) / (eta * eta);
  const float cosT = std::sqrt(std::max(0.0f, 1.0f - sin2T));
  // wi = -wo / eta + (cosA / eta - cosT) n, with n on wo's side.
  const Vec3 n(0, 0, entering ? 1.0f : -1.0f);
  b.refracted = normalize(-wo / eta + n * (cosA / eta - cosT));
  return b;
}

bool Material::sampleSmooth(const SmoothBranches& b, float pReflect, float uLobe, BsdfSample& s) {
  s.delta = true;
  s.pdf = 0;
  s.transmitted = !(uLobe < pReflect);
  s.wi = s.transmitted ? b.refracted : b.reflected;
  // 1 where pReflect is F; the refraction's 1/eta^2 radiance scale is left out (see the header).
  s.weight = Vec3(s.transmitted ? (1.0f - b.F) / (1.0f - pReflect) : b.F / pReflect);
  return s.transmitted ? b.F < 1 : b.F > 0;
}

}  // namespace granular
