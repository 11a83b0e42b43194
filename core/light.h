// light.h — the UsdLux lights: distant (with angular size), sphere, rect and dome.
//
// Contract: sampleLi() picks a direction from a shading point towards the light and
// returns its radiance and pdf in solid angle (delta lights: pdf 0, radiance is the
// irradiance). Le()/pdfLi() evaluate the same quantities for a direction found by BSDF
// sampling, so that the integrator can weight both strategies by MIS. Area lights
// (sphere, rect) are one-sided emitters hit by intersectLight(); distant and dome lights
// are seen by rays that escape the scene (escapedLe()).
#pragma once

#include <memory>
#include <vector>

#include "math.h"
#include "sampling.h"
#include "scene_desc.h"

namespace granular {

struct LightSample {
  Vec3 wi;          // towards the light
  float dist = kInf;
  Vec3 Li;          // radiance arriving along -wi
  float pdf = 0;    // solid angle; 0 for delta lights
  bool delta = false;
};

// A distant light so small that it is a delta light (angle below ~0.05°).
bool isDeltaSun(const LightDesc& d);
// What a light's radiance (color × intensity × 2^exposure) is divided by when it is
// normalised: its area (sphere, rect) or π sin² of a sun's half-angle; 1 when it is not
// normalised, for a point-like sun and for a dome. In double: a tiny light's area
// underflows a float (0 / 0 made the radiance NaN: the USD fuzzer's finding).
double normalizationArea(const LightDesc& d);

class Light {
 public:
  static Light fromDesc(const LightDesc& d);

  LightType type() const { return type_; }
  bool isInfinite() const { return type_ == LightType::Distant || type_ == LightType::Dome; }
  bool sampleLi(const Vec3& p, float u1, float u2, LightSample& s) const;
  // For infinite lights: radiance and solid-angle pdf for an escaping direction.
  Vec3 escapedLe(const Vec3& dir) const;
  // A sun narrower than the cone of half-angle halfAngle (radians, > 0) seen as that cone,
  // of uniform radiance and the same irradiance (RenderSettings::sunRegularization), by the
  // paths that see it so (ept.cpp, ppt.cpp): its radiance toward an escaping dir (and, given
  // pdf, the solid-angle pdf sampleLiSeen has for dir, for MIS), and a direction sampled
  // uniformly in the cone with its pdf. Other lights, delta suns, wider suns and
  // halfAngle ≤ 0: escapedLe() (and pdfLi()), sampleLi().
  Vec3 escapedLeSeen(const Vec3& dir, float halfAngle, float* pdf = nullptr) const;
  bool sampleLiSeen(const Vec3& p, float u1, float u2, float halfAngle, LightSample& s) const;
  float pdfLi(const Vec3& p, const Vec3& wi, float dist) const;
  // For area lights: nearest hit of the emitting shape in (tmin, tmax).
  bool intersect(const Ray& r, float& t) const;
  // Radiance leaving the area light at a hit point towards -dir.
  Vec3 areaLe(const Vec3& dir) const;
  // This light's weight in light sampling (Scene::lightPick): the irradiance E it gives a
  // point at `ref` facing it, times √(4π/Ω), Ω the solid angle its light arrives from there
  // (a textured dome's effective one, (∫L dω)² / ∫L² dω; a delta sun's, that of the widest
  // sun that is still one). E alone would be right were light sampling the only strategy:
  // a light spread over many directions is found as well by BSDF and phase sampling under
  // MIS, a small one by light sampling alone. 0 for a black light.
  double pickWeight(const Vec3& ref) const;

 private:
  LightType type_ = LightType::Distant;
  Vec3 radiance_;
  // distant
  Vec3 dir_;            // towards the light
  float cosMax_ = 1;
  double sunSin2_ = 0;  // sin² of a distant light's half-angle (its cone's pdf)
  // sphere
  Vec3 center_;
  float radius_ = 0;
  // rect
  Vec3 corner_, edgeU_, edgeV_, normal_;  // emits along normal_
  float area_ = 0;
  // dome
  Transform toLocal_, toWorld_;
  std::shared_ptr<const std::vector<float>> texels_;  // RGB
  int texW_ = 0, texH_ = 0;
  std::shared_ptr<const Distribution2D> dist_;
  double domeRms_ = 0;  // a textured dome's root mean square radiance over the sphere (channel mean)
  Vec3 domeLookup(const Vec3& localDir) const;
};

}  // namespace granular
