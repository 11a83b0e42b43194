// light.h — the UsdLux lights: distant (with angular size), sphere, rect, disk, cylinder
// and dome, the area lights shaped by UsdLuxShapingAPI (LightShaping, scene_desc.h: its
// cone, focus and IES profile, ies.h).
//
// Contract: sampleLi() picks a direction from a shading point towards the light and
// returns its radiance and pdf in solid angle (delta lights: pdf 0, radiance is the
// irradiance). areaLe()/escapedLe() and pdfLi() evaluate the same quantities for a
// direction found by BSDF sampling, so that the integrator can weight both strategies by
// MIS. Area lights are emitters hit by intersect(): a sphere outward, a rect and a disk on
// their −Z side, a cylinder outward from its side (not its caps), a mesh on its front faces
// (both sides when LightDesc::doubleSided); a light's back side and
// inside neither emit nor block. Distant and dome lights are seen by rays that escape the
// scene (escapedLe()). Sampling draws points uniformly over the emitting area (the sphere:
// directions uniformly in the cone it subtends), so pdf = d² / (cos θ_light · area); a
// cylinder's over the half of its side that faces the point (every point it sees lies
// there; those facing away are rejected: sampleLi false), area / 2; a shaping's cone is
// not sampled (its zero radiance is). A constant dome is sampled uniformly over the
// sphere, pdf 1/(4π), or, given `above` (a unit normal: a surface that only reflects, whose
// BSDF is zero below it), cosine-weighted over that hemisphere, pdf cos θ / π: the
// directions below would count nothing, and cos θ is the factor every reflection has.
// A mesh light's triangles are picked in proportion to their area and sampled uniformly
// within, so pdf = d² / (|cos θ_light| · total area) as for a rect; a point on a face that
// turns its back (a one-sided mesh) is rejected (sampleLi false). It is hit by its own BVH.
#pragma once

#include <memory>
#include <vector>

#include "ies.h"
#include "math.h"
#include "sampling.h"
#include "scene_desc.h"

namespace granular {

struct MeshEmitter;  // a mesh light's triangles, their areas and BVH (light.cpp)

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
// The IES profile a light names (LightShaping::iesFile), or null: InputError(object,
// "shaping_ies_file", ...) when it cannot be read (readIesFile).
std::shared_ptr<const IesProfile> lightIesProfile(const LightDesc& d, const std::string& object);

class Light {
 public:
  static Light fromDesc(const LightDesc& d);

  LightType type() const { return type_; }
  bool isInfinite() const { return type_ == LightType::Distant || type_ == LightType::Dome; }
  // above: see the contract (zero vector: the whole sphere; only a constant dome uses it).
  bool sampleLi(const Vec3& p, float u1, float u2, LightSample& s, const Vec3& above = Vec3(0.0f)) const;
  // For infinite lights: radiance and solid-angle pdf for an escaping direction.
  Vec3 escapedLe(const Vec3& dir) const;
  // A sun narrower than the cone of half-angle halfAngle (radians, > 0) seen as that cone,
  // of uniform radiance and the same irradiance (RenderSettings::sunRegularization), by the
  // paths that see it so (ept.cpp, ppt.cpp): its radiance toward an escaping dir (and, given
  // pdf, the solid-angle pdf sampleLiSeen has for dir, for MIS), and a direction sampled
  // uniformly in the cone with its pdf. Other lights, delta suns, wider suns and
  // halfAngle ≤ 0: escapedLe() (and pdfLi()), sampleLi(). `above` as for sampleLi().
  Vec3 escapedLeSeen(const Vec3& dir, float halfAngle, float* pdf = nullptr, const Vec3& above = Vec3(0.0f)) const;
  bool sampleLiSeen(const Vec3& p, float u1, float u2, float halfAngle, LightSample& s,
                    const Vec3& above = Vec3(0.0f)) const;
  float pdfLi(const Vec3& p, const Vec3& wi, float dist, const Vec3& above = Vec3(0.0f)) const;
  // For area lights: nearest hit of the emitting shape in (tmin, tmax).
  bool intersect(const Ray& r, float& t) const;
  // For area lights: a box holding the emitting shape (Scene's BVH over many lights).
  Bounds3 bounds() const;
  // For area lights: whether this light blocks the shadow ray r, over (r.tmin, r.tmax). A
  // ray of finite r.tmax is aimed at a light's surface point there, and intersect() may meet
  // that light a little short of it, since the ray leaves from an origin offset off its
  // surface (bench/README.md, "Area lights"): so a convex light the ray ends on (within
  // 10⁻³ of its length) does not block it, being sampled only where it faces the ray; a
  // mesh, which may shadow itself, blocks by the faces met short of that tolerance.
  bool blocksShadowRay(Ray r) const;
  // Radiance leaving the area light at its point q towards -dir (q: intersect()'s hit).
  Vec3 areaLe(const Vec3& q, const Vec3& dir) const;
  // This light's weight in light sampling (Scene::lightPick): the irradiance E it gives a
  // point at `ref` facing it, times √(4π/Ω), Ω the solid angle its light arrives from there
  // (a textured dome's effective one, (∫L dω)² / ∫L² dω; a delta sun's, that of the widest
  // sun that is still one). E alone would be right were light sampling the only strategy:
  // a light spread over many directions is found as well by BSDF and phase sampling under
  // MIS, a small one by light sampling alone. 0 for a black light. An IES profile scales E
  // by its candela toward ref, or by their mean where that is more.
  double pickWeight(const Vec3& ref) const;
  // The IES profile that shapes this light (null: none), for the logs.
  const IesProfile* iesProfile() const { return ies_.get(); }

 private:
  LightType type_ = LightType::Distant;
  Vec3 radiance_;
  // distant
  Vec3 dir_;            // towards the light
  float cosMax_ = 1;
  double sunSin2_ = 0;  // sin² of a distant light's half-angle (its cone's pdf)
  // sphere, disk, cylinder
  Vec3 center_;
  float radius_ = 0;  // sphere, cylinder (world)
  // rect: corner and edges; disk: centre and semi-axes (local X and Y, scaled)
  Vec3 corner_, edgeU_, edgeV_, normal_;  // emits along normal_
  float area_ = 0;
  // cylinder: its axis (unit, local X), half its length, and two unit vectors across it
  Vec3 axis_, across1_, across2_;
  float halfLength_ = 0;
  // shaping (LightShaping): the light's axis (local −Z), the cone's angles in radians
  bool shaped_ = false;
  Vec3 shapeAxis_, focusTint_;
  float coneAngle_ = 0, coneSmooth_ = 0, focus_ = 0;
  // an IES profile (ies.h): read in the light's frame (toLocal_), its candela times iesScale_
  std::shared_ptr<const IesProfile> ies_;
  float iesAngleScale_ = 0, iesScale_ = 1;
  float iesFactor(const Vec3& w) const;  // toward w (unit), angleScale applied
  Vec3 centre() const;                   // of a rect (its corners' mean), a disk, sphere or cylinder; a mesh's bounds
  Vec3 surfaceNormal(const Vec3& q) const;
  bool endsOn(const Vec3& e, float tol) const;  // e on the emitting surface, within tol (convex lights)
  // A cylinder's side sampled for p: the half centred on p's side of the axis (the angle
  // about the axis from across1_ toward across2_), uniform in area, pdf 2 / area there.
  float facingHalf(const Vec3& p) const;
  // radiance_ leaving point q of the light in direction w (unit), shaped.
  Vec3 emitted(const Vec3& q, const Vec3& w) const;
  // mesh (LightType::Mesh)
  std::shared_ptr<const MeshEmitter> emitter_;
  // dome (and an IES profile's frame: toLocal_)
  Transform toLocal_, toWorld_;
  std::shared_ptr<const std::vector<float>> texels_;  // RGB
  int texW_ = 0, texH_ = 0;
  std::shared_ptr<const Distribution2D> dist_;
  double domeRms_ = 0;  // a textured dome's root mean square radiance over the sphere (channel mean)
  Vec3 domeLookup(const Vec3& localDir) const;
};

}  // namespace granular
