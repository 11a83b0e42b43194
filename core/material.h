// material.h — surface scattering of meshes and grains.
//
// Contract: directions are in the local shading frame (+Z = outward geometric
// normal), wo points back along the incoming ray. sample() returns the sampled
// direction, its pdf (solid angle; 0 marks a delta lobe) and weight = f cos / pdf,
// already multiplied by the choice probability of a lobe. Lambert: f = albedo / pi.
// Dielectric: smooth interface with exact Fresnel reflectance, reflection chosen with
// probability F and refraction with 1 - F, so the weight is 1 (sampleSmooth: another
// choice, weighted). The radiance scale
// 1/eta^2 of refraction (Veach 1997 §5.2) is left out on purpose: cameras and lights
// sit outside every grain, so each entry is undone by an exit, and leaving it out keeps
// throughput at 1 inside clear grains (no Russian-roulette noise there). A rough
// dielectric (alpha > 0) is Walter et al. 2007's microfacet BSDF with GGX normals
// (microfacet.h), sampled by visible normals, F choosing reflection or refraction per
// microfacet, so the weight is G2 / G1(wo); its transmission term leaves out 1/eta^2 as the
// smooth one does (eq. 21 times eta_t²/eta_i²). It works from either side (wo.z < 0 is
// inside the grain) and is not delta: lights connect to it. Single-scattering
// microfacets lose the light that would scatter again among the microfacets — 37% of a
// white furnace of grains of roughness 0.5 — so by default (MaterialDesc::
// energyCompensation) the BSDF is its own sampling density renormalised: f |cos wi| =
// pdf(wi) / P_valid(wo), where P_valid is the probability that visible-normal sampling
// gives a valid direction (tabulated per side and |cos|). Every wo keeps all its energy,
// sampled weights are exactly 1 (no variance grows along paths through many grains), and
// the lobes keep their shape up to the masking of wi that G2 / G1(wo) applied.
// Absorption is
// applied by the integrator along the path inside (Beer–Lambert). DiffusionExit is the
// angular distribution of light leaving a diffusing half space through an index-matched
// boundary, in the P1 approximation: L(μ) ∝ φ + 3Eμ with φ = 2E at the boundary
// (d'Eon & Irving 2011, η = 1), i.e. f = (2 + 3μ_i)/(4π), normalised so ∫ f μ dω = 1.
#pragma once

#include <vector>

#include "math.h"
#include "scene_desc.h"

namespace granular {

struct BsdfSample {
  Vec3 wi;
  Vec3 weight;
  float pdf = 0;      // 0 for delta lobes
  bool delta = false;
  bool transmitted = false;
};

// Unpolarised Fresnel reflectance of a smooth dielectric; cosI may be negative (inside).
float fresnelDielectric(float cosI, float eta);

struct Material {
  MaterialType type = MaterialType::Lambert;
  Vec3 albedo{0.5f};
  float ior = 1.5f;
  Vec3 absorption{0.0f};   // per unit length of the object's own space
  Vec3 emission{0.0f};
  float alpha = 0.0f;      // Dielectric: GGX width (alphaFromRoughness); 0: smooth
  // Energy compensation: P_valid(μ), the fraction of the single-scattering lobe's samples
  // from cosine μ that leave in a valid direction, at μ_i = (i + ½) / n, outside side
  // first, then inside; empty: no compensation.
  std::vector<float> validTable;
  static constexpr int kValidNodes = 64;
  static constexpr int kCompensationTries = 16;
  float validFraction(const Vec3& wo) const;  // interpolated; needs the table

  static Material fromDesc(const MaterialDesc& d);
  bool isDelta() const { return type == MaterialType::Dielectric && alpha == 0; }
  // Directions wo with wo.z < 0 (seen from behind) can scatter: rough dielectrics.
  bool twoSided() const { return type == MaterialType::Dielectric; }
  // Angular width (radians) a non-delta bounce gives a ray cone: a GGX lobe's is about
  // 2α; diffuse lobes are wide (the caller caps it).
  float lobeSpread() const { return type == MaterialType::Dielectric ? 2.0f * alpha : kInf; }
  // f * |cos wi| (zero for delta lobes); with pdfOut also pdf(wo, wi), computed once.
  Vec3 eval(const Vec3& wo, const Vec3& wi, float* pdfOut = nullptr) const;
  float pdf(const Vec3& wo, const Vec3& wi) const;
  bool sample(const Vec3& wo, float uLobe, float u1, float u2, BsdfSample& s) const;
  // A smooth dielectric (isDelta) seen from wo: its Fresnel reflectance F, the mirror
  // direction and the refracted one (meaningless under total internal reflection, F = 1).
  struct SmoothBranches {
    float F;
    Vec3 reflected, refracted;
  };
  SmoothBranches smoothBranches(const Vec3& wo) const;
  // Its delta sample with reflection chosen with probability pReflect (F: sample()'s
  // choice; else in (0, 1) where 0 < F < 1): weight F / pReflect, or (1 − F) / (1 − pReflect)
  // for the refraction — the same expectation, any choice of pReflect.
  static bool sampleSmooth(const SmoothBranches& b, float pReflect, float uLobe, BsdfSample& s);
};

}  // namespace granular
