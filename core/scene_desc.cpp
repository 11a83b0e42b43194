// scene_desc.cpp — validateSceneDesc: every user-settable value checked once, here,
// so that each front end reports bad input the same way and the renderer can trust
// what it is given. Attribute names follow the USD schema (camelCase).
#include "scene_desc.h"

#include <cstring>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <type_traits>
#include <utility>

#include "error.h"
#include "instanced_grains.h"
#include "light.h"

namespace granular {

namespace {

std::string fmt(const Vec3& v) { return str("(", v.x, ", ", v.y, ", ", v.z, ")"); }

std::string label(const std::string& name, const char* list, size_t i) {
  return name.empty() ? str(list, "[", i, "]") : name;
}

void checkInt(long long v, long long lo, long long hi, const std::string& obj, const char* attr) {
  if (v < lo || v > hi) throw InputError(obj, attr, str(v, " is outside [", lo, ", ", hi, "]"));
}

void checkPositive(float v, const std::string& obj, const char* attr) {
  if (!std::isfinite(v) || !(v > 0)) throw InputError(obj, attr, str(v, " must be finite and > 0"));
}

void checkFinite(float v, const std::string& obj, const char* attr) {
  if (!std::isfinite(v)) throw InputError(obj, attr, str(v, " is not finite"));
}

void checkNonNegative(const Vec3& v, const std::string& obj, const char* attr) {
  if (!isFinite(v)) throw InputError(obj, attr, str(fmt(v), " is not finite"));
  if (minComponent(v) < 0) throw InputError(obj, attr, str(fmt(v), " has a negative component"));
}

void checkTransform(const Transform& xf, const std::string& obj, const char* attr) {
  if (!xf.isFinite()) throw InputError(obj, attr, "is not finite");
  // Everything downstream applies transforms as affine maps (Transform::point ignores the
  // bottom row); a projective matrix (a USD matrix whose last column is not (0, 0, 0, 1))
  // would be silently misread. Rounding (an inverted view matrix has 1e-17s there) is no error.
  const double tol = 1e-9;
  if (std::fabs(xf.m[3][0]) > tol || std::fabs(xf.m[3][1]) > tol || std::fabs(xf.m[3][2]) > tol ||
      std::fabs(xf.m[3][3] - 1) > tol)
    throw InputError(obj, attr,
                     str("is not affine: its row-vector (USD) form has last column (", xf.m[3][0], ", ", xf.m[3][1],
                         ", ", xf.m[3][2], ", ", xf.m[3][3], "), not (0, 0, 0, 1)"));
  Transform inv;
  if (xf.determinant3() == 0 || !xf.inverse(inv)) throw InputError(obj, attr, "is singular (not invertible)");
}

// Scene coordinates are floats, and squared distances must not overflow: every world
// position (mesh and boundary points, the camera, lights) and size stays within ±1e15
// units. (A transform scaling a boundary by 1e38 passed every other check and made the
// aggregate's grid NaN: found by the USD fuzzer.)
constexpr double kMaxCoordinate = 1e15;

void checkWorldPoints(const TriangleMesh& m, const Transform& xf, const std::string& obj) {
  for (size_t i = 0; i < m.points.size(); ++i) {
    const Vec3& p = m.points[i];
    for (int r = 0; r < 3; ++r) {
      double w = xf.m[r][0] * p.x + xf.m[r][1] * p.y + xf.m[r][2] * p.z + xf.m[r][3];
      if (!(std::fabs(w) <= kMaxCoordinate))
        throw InputError(obj, "transform",
                         str("places point ", i, " ", fmt(p), " at world coordinate ", w, ", beyond +-",
                             kMaxCoordinate));
    }
  }
}

void checkWorldPosition(const Transform& xf, const std::string& obj) {
  for (int r = 0; r < 3; ++r)
    if (!(std::fabs(xf.m[r][3]) <= kMaxCoordinate))
      throw InputError(obj, "transform", str("translation ", xf.m[r][3], " is beyond +-", kMaxCoordinate));
}

void checkSize(float v, const std::string& obj, const char* attr) {
  checkPositive(v, obj, attr);
  if (v > kMaxCoordinate) throw InputError(obj, attr, str(v, " is beyond ", kMaxCoordinate));
}

void checkMaterialIndex(int m, size_t count, const std::string& obj) {
  if (m < -1 || m >= int(count))
    throw InputError(obj, "material", str("index ", m, " is out of range [-1, ", count, ")"));
}

}  // namespace

PixelWindow renderWindow(const RenderSettings& s) {
  if (s.cropX0 == 0 && s.cropX1 == 0 && s.cropY0 == 0 && s.cropY1 == 0) return {0, s.width, 0, s.height};
  return {s.cropX0, s.cropX1, s.cropY0, s.cropY1};
}

PixelWindow pixelWindowFromNdc(double xmin, double ymin, double xmax, double ymax, int width, int height) {
  if (!(std::isfinite(xmin) && std::isfinite(ymin) && std::isfinite(xmax) && std::isfinite(ymax))) return PixelWindow{};
  constexpr double eps = 1e-4;
  auto pixel = [](double v, int size) { return int(std::clamp(v, 0.0, double(size))); };
  PixelWindow w;
  w.x0 = pixel(std::floor(xmin * width + eps), width);
  w.x1 = pixel(std::ceil(xmax * width - eps), width);
  w.y0 = pixel(std::floor((1.0 - ymax) * height + eps), height);
  w.y1 = pixel(std::ceil((1.0 - ymin) * height - eps), height);
  return w.x0 < w.x1 && w.y0 < w.y1 ? w : PixelWindow{};
}

void validateCameraDesc(const CameraDesc& c, const std::string& obj) {
  checkTransform(c.cameraToWorld, obj, "transform");
  checkWorldPosition(c.cameraToWorld, obj);
  checkPositive(c.focalLength, obj, "focalLength");
  checkPositive(c.horizontalAperture, obj, "horizontalAperture");
  checkPositive(c.verticalAperture, obj, "verticalAperture");
  checkFinite(c.horizontalApertureOffset, obj, "horizontalApertureOffset");
  checkFinite(c.verticalApertureOffset, obj, "verticalApertureOffset");
  if (!std::isfinite(c.lensRadius) || c.lensRadius < 0)
    throw InputError(obj, "lensRadius", str(c.lensRadius, " must be finite and >= 0 (0: a pinhole)"));
  if (c.lensRadius > lensRadiusFromFStop(c.focalLength, kFastestFStop) * (1 + 1e-6f))
    throw InputError(obj, "lensRadius",
                     str(c.lensRadius, " is wider than an f/", kFastestFStop, " lens of focal length ", c.focalLength,
                         " (", lensRadiusFromFStop(c.focalLength, kFastestFStop), "), the fastest a lens in air can be"));
  if (c.lensRadius > 0 && !(std::isfinite(c.focusDistance) && c.focusDistance > 0))
    throw InputError(obj, "focusDistance", str(c.focusDistance, " must be finite and > 0 with a lens"));
  if (!std::isfinite(c.clipNear) || !(c.clipNear > 0))
    throw InputError(obj, "clippingRange", str("near ", c.clipNear, " must be finite and > 0"));
  if (std::isnan(c.clipFar) || !(c.clipFar > c.clipNear))
    throw InputError(obj, "clippingRange", str("far ", c.clipFar, " must exceed near ", c.clipNear));
  // An hour each way is far beyond any shutter; it keeps τ·velocity finite.
  checkFinite(c.shutterOpen, obj, "shutterOpen");
  checkFinite(c.shutterClose, obj, "shutterClose");
  if (std::fabs(c.shutterOpen) > 3600 || std::fabs(c.shutterClose) > 3600)
    throw InputError(obj, "shutterOpen", str("[", c.shutterOpen, ", ", c.shutterClose, "] s is beyond an hour"));
  if (c.shutterClose < c.shutterOpen)
    throw InputError(obj, "shutterClose", str(c.shutterClose, " is before shutterOpen ", c.shutterOpen));
}

void validateLightDesc(const LightDesc& l, const std::string& obj, bool geometry) {
  checkTransform(l.xf, obj, "transform");
  checkWorldPosition(l.xf, obj);
  checkNonNegative(l.color, obj, "color");
  if (!std::isfinite(l.intensity) || l.intensity < 0)
    throw InputError(obj, "intensity", str(l.intensity, " must be finite and >= 0"));
  checkFinite(l.exposure, obj, "exposure");
  // 2^exposure must stay a finite float.
  if (std::fabs(l.exposure) > 100) throw InputError(obj, "exposure", str(l.exposure, " is outside [-100, 100]"));
  switch (l.type) {
    case LightType::Distant:
      if (!std::isfinite(l.angle) || l.angle < 0 || l.angle >= 180)
        throw InputError(obj, "angle", str(l.angle, " is outside [0, 180)"));
      break;
    case LightType::Sphere:
      checkSize(l.radius, obj, "radius");
      checkSize(l.radius * length(l.xf.vector(Vec3(1, 0, 0))), obj, "radius");  // in world units
      break;
    case LightType::Rect:
      checkSize(l.width, obj, "width");
      checkSize(l.height, obj, "height");
      checkSize(length(l.xf.vector(Vec3(l.width, 0, 0))), obj, "width");  // in world units
      checkSize(length(l.xf.vector(Vec3(0, l.height, 0))), obj, "height");
      break;
    case LightType::Disk:
      checkSize(l.radius, obj, "radius");
      checkSize(l.radius * length(l.xf.vector(Vec3(1, 0, 0))), obj, "radius");  // in world units
      checkSize(l.radius * length(l.xf.vector(Vec3(0, 1, 0))), obj, "radius");
      break;
    case LightType::Cylinder:
      checkSize(l.radius, obj, "radius");
      checkSize(l.length, obj, "length");
      checkSize(l.radius * length(l.xf.vector(Vec3(0, 1, 0))), obj, "radius");  // in world units
      checkSize(l.length * length(l.xf.vector(Vec3(1, 0, 0))), obj, "length");
      break;
    case LightType::Dome: break;
    case LightType::Mesh: {
      if (l.shaping.enabled) throw InputError(obj, "shaping", "is not supported on a mesh light");
      if (!geometry) break;
      validateMesh(l.mesh, obj, "points");
      const TriangleMesh world = l.mesh.transformed(l.xf);
      for (const Vec3& p : world.points)
        if (!(std::fabs(p.x) <= kMaxCoordinate && std::fabs(p.y) <= kMaxCoordinate && std::fabs(p.z) <= kMaxCoordinate))
          throw InputError(obj, "points", str("a point at ", fmt(p), " in world space is beyond +-", kMaxCoordinate));
      const double area = world.area();
      if (!(area > 0)) throw InputError(obj, "points", "the mesh has no area, so it cannot emit");
      // Its faces' areas are sampled in float (a face 10^19 across would be infinite).
      if (!(area <= 1e30)) throw InputError(obj, "points", str("the mesh's area ", area, " exceeds 1e30"));
      break;
    }
  }
  if (l.shaping.enabled) {
    checkFinite(l.shaping.coneAngle, obj, "shaping_cone_angle");
    checkFinite(l.shaping.coneSoftness, obj, "shaping_cone_softness");
    checkFinite(l.shaping.focus, obj, "shaping_focus");
    checkNonNegative(l.shaping.focusTint, obj, "shaping_focus_tint");
    checkFinite(l.shaping.iesAngleScale, obj, "shaping_ies_angle_scale");
    lightIesProfile(l, obj);  // it must read as a profile
  }
  {
    // The radiance color * intensity * 2^exposure, divided by the light's area when it
    // is normalised, must be a finite float too (1e38 x 2^100 gave an all-black image
    // of non-finite samples; so did normalising a sphere of radius 6e-39, whose area
    // underflows: the USD fuzzer's finding).
    const bool area = geometry || l.type != LightType::Mesh;  // else divided by its area later
    double peak = double(maxComponent(l.color)) * l.intensity * std::exp2(double(l.exposure)) /
                  (area ? normalizationArea(l) : 1.0);
    if (!(peak <= 1e30))
      throw InputError(obj, "intensity",
                       str("color ", fmt(l.color), " x intensity ", l.intensity, " x 2^exposure ", l.exposure,
                           l.normalize ? " / area" : "", " = ", peak, " exceeds 1e30"));
  }
}

void validateSceneDesc(const SceneDesc& desc) {
  const RenderSettings& s = desc.settings;
  checkInt(s.width, 1, 32768, "render", "width");
  checkInt(s.height, 1, 32768, "render", "height");
  {
    const PixelWindow w = renderWindow(s);
    if (!(0 <= w.x0 && w.x0 < w.x1 && w.x1 <= s.width && 0 <= w.y0 && w.y0 < w.y1 && w.y1 <= s.height))
      throw InputError("render", "crop",
                       str("pixels [", w.x0, ", ", w.x1, ") x [", w.y0, ", ", w.y1, ") are not a non-empty window of the ",
                           s.width, "x", s.height, " image"));
  }
  checkInt(s.spp, 1, 1000000, "render", "spp");
  if (s.maxDepth < 1) throw InputError("render", "maxDepth", str(s.maxDepth, " must be >= 1"));
  if (s.rrDepth < 0) throw InputError("render", "rrDepth", str(s.rrDepth, " must be >= 0"));
  if (s.threads < 0) throw InputError("render", "threads", str(s.threads, " must be >= 0 (0: all cores)"));
  checkInt(s.bundleSize, 1, 256, "render", "bundleSize");
  if (!std::isfinite(s.tau) || !(s.tau > 0)) throw InputError("render", "tau", str(s.tau, " must be finite and > 0"));
  if (!(s.daDepthFactor > 0) || !std::isfinite(s.daDepthFactor))
    throw InputError("render", "daDepthFactor", str(s.daDepthFactor, " must be a positive number"));
  if (s.daMinOrder < 0) throw InputError("render", "daMinOrder", str(s.daMinOrder, " must be >= 0"));
  if (s.explicitBounces < -1)
    throw InputError("render", "explicitBounces", str(s.explicitBounces, " must be >= -1 (-1: automatic; 0: switch as soon as the spread allows)"));
  if (!std::isfinite(s.lod) || s.lod < 0) throw InputError("render", "lod", str(s.lod, " must be finite and >= 0 (0: off)"));
  if (!(s.sunRegularization >= 0 && s.sunRegularization <= RenderSettings::kMaxSunRegularization))
    throw InputError("render", "sunRegularization",
                     str(s.sunRegularization, " must be in [0, ", RenderSettings::kMaxSunRegularization,
                         "] degrees (0: off)"));
  if (std::isnan(s.roulette) || s.roulette == 0 || s.roulette > RenderSettings::kMaxSplit)
    throw InputError("render", "roulette",
                     str(s.roulette, " must be in (0, ", RenderSettings::kMaxSplit, "] (above 1: splitting), or negative for automatic"));

  const CameraDesc& c = desc.camera;
  validateCameraDesc(c, "camera");
  {
    // The film window at unit distance, as Camera fits the aperture into the image: it
    // must stay finite through normalisation, i.e. the field of view must stay short of
    // 180 degrees (a focal length of 1e-37 gave NaN camera rays).
    double hAp = c.horizontalAperture, vAp = c.verticalAperture;
    double imAspect = double(s.width) / s.height;
    if (imAspect > hAp / vAp) hAp = vAp * imAspect; else vAp = hAp / imAspect;
    double f = c.focalLength;
    double wx = 0.5 * hAp / f + std::fabs(c.horizontalApertureOffset) / f;
    double wy = 0.5 * vAp / f + std::fabs(c.verticalApertureOffset) / f;
    if (!(wx <= 1e6 && wy <= 1e6))
      throw InputError("camera", "focalLength",
                       str(c.focalLength, " is too short for the aperture (", c.horizontalAperture, " x ",
                           c.verticalAperture, ", offsets ", c.horizontalApertureOffset, ", ",
                           c.verticalApertureOffset, "): the field of view reaches 180 degrees"));
  }

  for (size_t i = 0; i < desc.materials.size(); ++i)
    validateMaterialDesc(desc.materials[i], label(desc.materials[i].name, "materials", i));

  for (size_t i = 0; i < desc.meshes.size(); ++i) {
    const MeshDesc& m = desc.meshes[i];
    std::string obj = label(m.name, "meshes", i);
    validateMesh(m.mesh, obj);
    checkMaterialIndex(m.material, desc.materials.size(), obj);
    checkTransform(m.xf, obj, "transform");
    checkWorldPoints(m.mesh, m.xf, obj);
    if (m.shutterXf) {
      checkTransform(m.shutterXf->first, obj, "transform");
      checkWorldPoints(m.mesh, m.shutterXf->first, obj);
      checkTransform(m.shutterXf->second, obj, "transform");
      checkWorldPoints(m.mesh, m.shutterXf->second, obj);
    }
    checkInt(m.instanceId, -1, INT32_MAX, obj, "instanceId");
  }

  for (size_t i = 0; i < desc.lights.size(); ++i)
    validateLightDesc(desc.lights[i], label(desc.lights[i].name, "lights", i));

  for (size_t i = 0; i < desc.aggregates.size(); ++i) {
    const AggregateDesc& a = desc.aggregates[i];
    std::string obj = label(a.name, "aggregates", i);
    validateClosed(a.boundary, obj + ".boundary");
    validateAggregateParameters(a, obj);
    checkInt(a.instanceId, -1, INT32_MAX, obj, "instanceId");
    if (a.shutterXf) validateAggregateMotion(a, obj);
    for (size_t k = 0; k < a.prototypes.size(); ++k) {
      const GrainPrototypeDesc& p = a.prototypes[k];
      std::string pobj = p.name.empty() ? str(obj, ".prototypes[", k, "]") : p.name;
      validateClosed(p.mesh, pobj);
      checkMaterialIndex(p.material, desc.materials.size(), pobj);
    }
  }

  for (const InstancedGrainsDesc& g : desc.instancedGrains) {
    checkTransform(g.xf, g.name, "transform");
    validateInstancedGrains(g);
    for (size_t k = 0; k < g.prototypes.size(); ++k) {
      const GrainPrototypeDesc& p = g.prototypes[k];
      const std::string pobj = p.name.empty() ? str(g.name, ".prototypes[", k, "]") : p.name;
      validateClosed(p.mesh, pobj);
      checkMaterialIndex(p.material, desc.materials.size(), pobj);
    }
  }
}

void validateMaterialDesc(const MaterialDesc& m, const std::string& obj) {
  if (!isFinite(m.albedo) || minComponent(m.albedo) < 0 || maxComponent(m.albedo) > 1)
    throw InputError(obj, "albedo", str(fmt(m.albedo), " is outside [0, 1]"));
  if (!std::isfinite(m.ior) || m.ior < 1 || m.ior > 4) throw InputError(obj, "ior", str(m.ior, " is outside [1, 4]"));
  checkNonNegative(m.absorption, obj, "absorption");
  checkNonNegative(m.emission, obj, "emission");
  if (!std::isfinite(m.roughness) || m.roughness < 0 || m.roughness > 1)
    throw InputError(obj, "roughness", str(m.roughness, " is outside [0, 1]"));
  if (!std::isfinite(m.opacity) || m.opacity < 0 || m.opacity > 1)
    throw InputError(obj, "opacity", str(m.opacity, " is outside [0, 1]"));
  if (!std::isfinite(m.opacityThreshold) || m.opacityThreshold < 0 || m.opacityThreshold > 1)
    throw InputError(obj, "opacityThreshold", str(m.opacityThreshold, " is outside [0, 1]"));
  const std::pair<const TextureDesc*, const char*> textures[] = {
      {&m.albedoTexture, "albedoTexture"}, {&m.emissionTexture, "emissionTexture"}, {&m.opacityTexture, "opacityTexture"}};
  for (const auto& [t, attr] : textures) {
    if (!t->enabled()) continue;
    const std::string& o = t->source.empty() ? obj : t->source;
    if (m.type != MaterialType::Lambert)
      throw InputError(obj, attr, "textures apply to Lambert (diffuse) materials only");
    for (int c = 0; c < 4; ++c) {
      if (!std::isfinite(t->scale[c])) throw InputError(o, "inputs:scale", str(t->scale[c], " is not finite"));
      if (!std::isfinite(t->bias[c])) throw InputError(o, "inputs:bias", str(t->bias[c], " is not finite"));
    }
    if (t->channel < -1 || t->channel > 3) throw InputError(o, "outputs", str("channel ", t->channel, " is not r, g, b, a or rgb"));
  }
}

void validateAggregateParameters(const AggregateDesc& a, const std::string& obj) {
  checkTransform(a.xf, obj, "transform");
  checkWorldPoints(a.boundary, a.xf, obj);
  checkSize(a.grainRadius, obj, "grainRadius");
  if (!std::isfinite(a.packingRate) || !(a.packingRate > 0) || a.packingRate > 0.64f)
    throw InputError(obj, "packingRate", str(a.packingRate, " is outside (0, 0.64]"));
  checkInt(a.tileSpheres, 8, 100000, obj, "tileSpheres");
  if (a.prototypes.empty()) throw InputError(obj, "prototypes", "is empty (at least one grain prototype needed)");
  if (a.weights.size() != a.prototypes.size())
    throw InputError(obj, "weights",
                     str("has ", a.weights.size(), " entries but there are ", a.prototypes.size(), " prototypes"));
  bool anyPositive = false;
  for (size_t k = 0; k < a.weights.size(); ++k) {
    float w = a.weights[k];
    if (!std::isfinite(w) || w < 0) throw InputError(obj, "weights", str("weight ", k, " = ", w, " must be finite and >= 0"));
    anyPositive |= w > 0;
  }
  if (!anyPositive) throw InputError(obj, "weights", "are all zero");
  if (!a.sizes.empty()) {
    if (a.sizes.size() != a.prototypes.size())
      throw InputError(obj, "sizes", str("has ", a.sizes.size(), " entries but there are ", a.prototypes.size(), " prototypes"));
    float lo = kInf, hi = 0;
    for (size_t k = 0; k < a.sizes.size(); ++k) {
      float x = a.sizes[k];
      if (!std::isfinite(x) || x < 0.1f || x > 10.0f)
        throw InputError(obj, "sizes", str("size ", k, " = ", x, " is outside [0.1, 10]"));
      if (a.weights[k] > 0) lo = std::min(lo, x), hi = std::max(hi, x);
    }
    if (hi > 10.0f * lo)
      throw InputError(obj, "sizes", str("the largest grain (", hi, ") is more than 10 times the smallest (", lo, ")"));
  }
  if (!std::isfinite(a.sizeSpread) || a.sizeSpread < 0 || a.sizeSpread > 0.5f)
    throw InputError(obj, "sizeSpread", str(a.sizeSpread, " is outside [0, 0.5]"));
}

void validateAggregateMotion(const AggregateDesc& a, const std::string& obj) {
  for (const Transform* xf : {&a.shutterXf->first, &a.shutterXf->second}) {
    checkTransform(*xf, obj, "transform");
    checkWorldPoints(a.boundary, *xf, obj);
  }
  // Rays are mapped into the build by the blend's inverse (aggregate_motion.h): it must stay
  // invertible over the shutter, and not pinch the grains. det of the linear blend is a cubic
  // in s; a turn by θ pinches it to cos²(θ/2) across the turn's plane.
  const double ratio = minBlendDeterminantRatio(a.shutterXf->first, a.shutterXf->second);
  if (!(ratio >= kMinBlendDeterminantRatio))
    throw InputError(obj, "transform",
                     str("turns or flips too far over the shutter to blend its transforms at the open and close "
                         "linearly (the blend keeps ", ratio, " of the volume, under ", kMinBlendDeterminantRatio,
                         ": a turn of more than 120 degrees)"));
}

double minBlendDeterminantRatio(const Transform& a, const Transform& b) {
  auto det = [&](double s) { return Transform::blend(a, b, s).determinant3(); };
  const double d0 = det(0), d1 = det(1);
  if (!(d0 * d1 > 0)) return 0;  // a flip, or singular at an end
  // The cubic p(s) = c0 + c1 s + c2 s² + c3 s³ through its values at 0, 1/3, 2/3 and 1;
  // its least |p| on [0, 1] is at an end or where p' = c1 + 2 c2 s + 3 c3 s² vanishes.
  const double p1 = det(1.0 / 3), p2 = det(2.0 / 3);
  const double c0 = d0, c1 = (-11 * d0 + 18 * p1 - 9 * p2 + 2 * d1) / 2, c2 = (18 * d0 - 45 * p1 + 36 * p2 - 9 * d1) / 2,
               c3 = (-9 * d0 + 27 * p1 - 27 * p2 + 9 * d1) / 2;
  auto p = [&](double s) { return ((c3 * s + c2) * s + c1) * s + c0; };
  double least = std::min(std::fabs(d0), std::fabs(d1)), lowest = least;
  std::vector<double> roots;
  if (std::fabs(c3) > 1e-300) {
    const double disc = 4 * c2 * c2 - 12 * c3 * c1;
    if (disc >= 0) roots = {(-2 * c2 - std::sqrt(disc)) / (6 * c3), (-2 * c2 + std::sqrt(disc)) / (6 * c3)};
  } else if (std::fabs(c2) > 1e-300) {
    roots = {-c1 / (2 * c2)};
  }
  for (double s : roots)
    if (s > 0 && s < 1) lowest = std::min(lowest, p(s) * (d0 > 0 ? 1 : -1));
  // A sign change inside is caught as a negative lowest (relative to the ends' sign).
  return lowest / least;
}

TextureWrap textureWrapFromName(const std::string& name, const std::string& obj, const std::string& attr) {
  if (name == "useMetadata") return TextureWrap::UseMetadata;
  if (name == "black") return TextureWrap::Black;
  if (name == "clamp") return TextureWrap::Clamp;
  if (name == "repeat") return TextureWrap::Repeat;
  if (name == "mirror") return TextureWrap::Mirror;
  throw InputError(obj, attr, str("\"", name, "\" is not black, clamp, repeat, mirror or useMetadata"));
}

TextureColorSpace textureColorSpaceFromName(const std::string& name, const std::string& obj, const std::string& attr) {
  if (name == "auto") return TextureColorSpace::Auto;
  if (name == "raw") return TextureColorSpace::Raw;
  if (name == "sRGB") return TextureColorSpace::SRGB;
  throw InputError(obj, attr, str("\"", name, "\" is not auto, raw or sRGB"));
}

int textureChannelFromName(const std::string& name, const std::string& obj, const std::string& attr) {
  if (name == "rgb") return -1;
  if (name.size() == 1) {
    const size_t c = std::string("rgba").find(name[0]);
    if (c != std::string::npos) return int(c);
  }
  throw InputError(obj, attr, str("\"", name, "\" is not rgb, r, g, b or a"));
}

namespace {

// World bounds, in double, of points placed by xf.
void extendWorldBounds(const std::vector<Vec3>& points, const Transform& xf, Vec3d& lo, Vec3d& hi) {
  for (const Vec3& p : points) {
    const Vec3d w = xf.pointD(p);
    lo = {std::min(lo.x, w.x), std::min(lo.y, w.y), std::min(lo.z, w.z)};
    hi = {std::max(hi.x, w.x), std::max(hi.y, w.y), std::max(hi.z, w.z)};
  }
}
void extendWorldBounds(const TriangleMesh& m, const Transform& xf, Vec3d& lo, Vec3d& hi) {
  extendWorldBounds(m.points, xf, lo, hi);
}

Transform toRenderSpace(const Transform& xf, const Vec3d& origin) {
  if (origin == Vec3d{}) return xf;
  return Transform::translate(-origin.x, -origin.y, -origin.z) * xf;
}

}  // namespace

float checkedLensRadius(float focalLength, float fStop, const std::string& object, const std::string& attribute) {
  if (!std::isfinite(fStop) || fStop < 0)
    throw InputError(object, attribute, str(fStop, " must be finite and >= 0 (0: no depth of field)"));
  if (fStop > 0 && fStop < kFastestFStop)
    throw InputError(object, attribute,
                     str(fStop, " is below ", kFastestFStop, ", the fastest a lens in air can be (0: no depth of field)"));
  return lensRadiusFromFStop(focalLength, fStop);
}

Vec3d renderOrigin(const SceneDesc& desc) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  Vec3d lo{inf, inf, inf}, hi{-inf, -inf, -inf};
  for (const AggregateDesc& a : desc.aggregates) extendWorldBounds(a.boundary, a.xf, lo, hi);
  for (const InstancedGrainsDesc& g : desc.instancedGrains) extendWorldBounds(g.positions, g.xf, lo, hi);
  if (!(lo.x <= hi.x))
    for (const MeshDesc& m : desc.meshes)
      if (m.visible) extendWorldBounds(m.mesh, m.xf, lo, hi);
  Vec3d c = lo.x <= hi.x ? Vec3d{0.5 * (lo.x + hi.x), 0.5 * (lo.y + hi.y), 0.5 * (lo.z + hi.z)}
                         : desc.camera.cameraToWorld.pointD(Vec3(0.0f));
  // On a grid of whole units, as coarse as the content's extent (a power of two): a stage
  // moved by a multiple of it keeps its render space exactly, and an edit inside the scene
  // seldom moves the origin (which would build every aggregate anew).
  const double extent = lo.x <= hi.x ? std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z}) : 0.0;
  const double grid = extent > 1 && extent < 1e30 ? std::exp2(std::ceil(std::log2(extent))) : 1.0;
  c = {grid * std::nearbyint(c.x / grid), grid * std::nearbyint(c.y / grid), grid * std::nearbyint(c.z / grid)};
  if (!(std::isfinite(c.x) && std::isfinite(c.y) && std::isfinite(c.z))) return Vec3d{};
  return {c.x + 0.0, c.y + 0.0, c.z + 0.0};  // no -0: an origin of zero is recognised as such
}

CameraDesc toRenderSpace(const CameraDesc& camera, const Vec3d& origin) {
  CameraDesc c = camera;
  c.cameraToWorld = toRenderSpace(camera.cameraToWorld, origin);
  return c;
}

SceneDesc toRenderSpace(const SceneDesc& desc, const Vec3d& origin) {
  SceneDesc r = desc;
  if (origin == Vec3d{}) return r;
  r.camera = toRenderSpace(desc.camera, origin);
  auto shutterToRenderSpace = [&](std::optional<std::pair<Transform, Transform>>& xf) {
    if (xf) xf = std::make_pair(toRenderSpace(xf->first, origin), toRenderSpace(xf->second, origin));
  };
  for (MeshDesc& m : r.meshes) {
    m.xf = toRenderSpace(m.xf, origin);
    shutterToRenderSpace(m.shutterXf);
  }
  for (LightDesc& l : r.lights) l.xf = toRenderSpace(l.xf, origin);
  for (AggregateDesc& a : r.aggregates) {
    a.xf = toRenderSpace(a.xf, origin);
    shutterToRenderSpace(a.shutterXf);
  }
  for (InstancedGrainsDesc& g : r.instancedGrains) g.xf = toRenderSpace(g.xf, origin);
  return r;
}

void checkGrainPrecision(const AggregateDesc& a, const Vec3d& origin) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  Vec3d lo{inf, inf, inf}, hi{-inf, -inf, -inf};
  extendWorldBounds(a.boundary, a.xf, lo, hi);
  if (!(lo.x <= hi.x)) return;
  double far = 0, originFar = 0;
  for (int i = 0; i < 3; ++i) {
    far = std::max({far, std::fabs(lo[i]), std::fabs(hi[i])});
    originFar = std::max(originFar, std::fabs(origin[i]));
  }
  float smallest = 1;
  for (float s : a.sizes) smallest = std::min(smallest, s);
  const double radius = double(a.grainRadius) * smallest * (1.0 - a.sizeSpread);
  // Half a float spacing at the render-space coordinate, half a double spacing at the world one.
  const double floatRounding = far * std::ldexp(1.0, -24);
  const double doubleRounding = (far + originFar) * std::ldexp(1.0, -53);
  const double rounding = floatRounding + doubleRounding;
  if (!(rounding > kGrainPrecision * radius)) return;
  // Its own size, not its place, puts it that far: the grains are too small for float.
  double centreFar = 0, halfExtent = 0;
  for (int i = 0; i < 3; ++i) {
    centreFar = std::max(centreFar, std::fabs(0.5 * (lo[i] + hi[i])));
    halfExtent = std::max(halfExtent, 0.5 * (hi[i] - lo[i]));
  }
  if (doubleRounding <= floatRounding && centreFar <= halfExtent)
    throw InputError(a.name, "grainRadius",
                     str(radius, " is too small for the boundary's size: float positions across its ", 2 * halfExtent,
                         " units round by ", rounding, ", more than 1/", int(1 / kGrainPrecision),
                         " of a grain (raise grainRadius, or split the aggregate)"));
  const bool worldFar = doubleRounding > floatRounding;
  const std::string where =
      worldFar ? str("it lies ", far + originFar, " units from the world origin, where even double precision rounds by ")
               : str("it reaches ", far, " units from the render origin (the centre of the scene's aggregates), where float "
                     "rounds by ");
  throw InputError(a.name, "grainRadius",
                   str("grains of radius ", radius, " cannot be resolved: ", where, rounding, ", more than 1/",
                       int(1 / kGrainPrecision), " of a grain; ",
                       worldFar ? "move the stage nearer the world origin"
                                : "bring the aggregates nearer each other, or split this one"));
}

Technique techniqueFromName(const std::string& name, const std::string& obj) {
  if (name == "ept") return Technique::Ept;
  if (name == "ept+vpt") return Technique::EptVpt;
  if (name == "hybrid") return Technique::Hybrid;
  throw InputError(obj, "technique", str("\"", name, "\" is not one of ept, ept+vpt, hybrid"));
}

const char* techniqueName(Technique t) {
  switch (t) {
    case Technique::Ept: return "ept";
    case Technique::EptVpt: return "ept+vpt";
    case Technique::Hybrid: return "hybrid";
  }
  return "?";
}

ProxyUse proxyUseFromName(const std::string& name, const std::string& obj) {
  if (name == "off") return ProxyUse::Off;
  if (name == "auto") return ProxyUse::Auto;
  if (name == "on") return ProxyUse::On;
  throw InputError(obj, "proxies", str("\"", name, "\" is not one of off, auto, on"));
}

const char* proxyUseName(ProxyUse p) {
  switch (p) {
    case ProxyUse::Off: return "off";
    case ProxyUse::Auto: return "auto";
    case ProxyUse::On: return "on";
  }
  return "?";
}

MediumModel mediumModelFromName(const std::string& name, const std::string& obj) {
  if (name == "tt") return MediumModel::Tt;
  if (name == "exits") return MediumModel::Exits;
  throw InputError(obj, "medium_model", str("\"", name, "\" is not one of tt, exits"));
}

const char* mediumModelName(MediumModel m) { return m == MediumModel::Exits ? "exits" : "tt"; }

// ---- change detection ------------------------------------------------------------------

namespace {

// The number of fields of an aggregate (each array element counted): T{f, f, ...} with
// fields that convert to anything compiles up to that many and no further.
struct AnyField {
  template <class T>
  operator T() const;  // only in unevaluated operands
};

template <class T, class Seq, class = void>
struct BraceInitialisable : std::false_type {};
template <class T, size_t... I>
struct BraceInitialisable<T, std::index_sequence<I...>, std::void_t<decltype(T{(void(I), AnyField{})...})>>
    : std::true_type {};

template <class T, size_t N = 0>
constexpr size_t fieldCount() {
  if constexpr (BraceInitialisable<T, std::make_index_sequence<N + 1>>::value)
    return fieldCount<T, N + 1>();
  else
    return N;
}

// A field added to a description changes its count here and stops the build: compare it
// below (and decide what its change needs), then update the count.
static_assert(fieldCount<TriangleMesh>() == 3, "compare the new field in sameMesh");
static_assert(fieldCount<CameraDesc>() == 12, "compare the new field in sameCamera");
static_assert(fieldCount<TextureDesc>() == 14, "compare the new field in sameTexture (scale, bias: 4 each)");
static_assert(fieldCount<MaterialDesc>() == 13, "compare the new field in sameMaterial");
static_assert(fieldCount<LightDesc>() == 20, "compare the new field in sameLight");
static_assert(fieldCount<LightShaping>() == 8, "compare the new field in sameLight");
static_assert(fieldCount<MeshDesc>() == 9, "compare the new field in sameMeshDesc (or linkCategories)");
static_assert(fieldCount<GrainPrototypeDesc>() == 3, "compare the new field in sameAggregateInputs");
static_assert(fieldCount<AggregateDesc>() == 16, "compare the new field in sameAggregateInputs (or the id check, or linkCategories)");
static_assert(fieldCount<RenderSettings>() == 28, "compare the new field in sameViewSettings or settingsNeedBuild");
static_assert(fieldCount<SceneDesc>() == 7, "compare the new part in compareScenes");
static_assert(fieldCount<InstancedGrainsDesc>() == 11, "compare the new field in sameInstancedGrains (or the id check, or linkCategories)");

bool sameCamera(const CameraDesc& a, const CameraDesc& b) {
  return sameTransform(a.cameraToWorld, b.cameraToWorld) && a.focalLength == b.focalLength &&
         a.horizontalAperture == b.horizontalAperture && a.verticalAperture == b.verticalAperture &&
         a.horizontalApertureOffset == b.horizontalApertureOffset &&
         a.verticalApertureOffset == b.verticalApertureOffset && a.clipNear == b.clipNear && a.clipFar == b.clipFar &&
         a.lensRadius == b.lensRadius && a.focusDistance == b.focusDistance && a.shutterOpen == b.shutterOpen &&
         a.shutterClose == b.shutterClose;
}

bool sameTexture(const TextureDesc& a, const TextureDesc& b) {
  if (a.file != b.file || a.source != b.source || a.wrapS != b.wrapS || a.wrapT != b.wrapT ||
      a.colorSpace != b.colorSpace || a.channel != b.channel)
    return false;
  for (int c = 0; c < 4; ++c)
    if (!(a.scale[c] == b.scale[c]) || !(a.bias[c] == b.bias[c])) return false;
  return true;
}

}  // namespace

bool sameTransform(const Transform& a, const Transform& b) {
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j)
      if (!(a.m[i][j] == b.m[i][j])) return false;
  return true;
}

bool sameMesh(const TriangleMesh& a, const TriangleMesh& b) {
  return a.points == b.points && a.indices == b.indices && a.uvs == b.uvs;
}

bool sameMaterial(const MaterialDesc& a, const MaterialDesc& b) {
  return a.name == b.name && a.type == b.type && a.albedo == b.albedo && a.ior == b.ior &&
         a.absorption == b.absorption && a.emission == b.emission && a.roughness == b.roughness &&
         a.energyCompensation == b.energyCompensation && sameTexture(a.albedoTexture, b.albedoTexture) &&
         sameTexture(a.emissionTexture, b.emissionTexture) && sameTexture(a.opacityTexture, b.opacityTexture) &&
         a.opacity == b.opacity && a.opacityThreshold == b.opacityThreshold;
}

namespace {

bool sameLight(const LightDesc& a, const LightDesc& b) {
  return a.name == b.name && a.type == b.type && sameTransform(a.xf, b.xf) && a.color == b.color &&
         a.intensity == b.intensity && a.exposure == b.exposure && a.normalize == b.normalize && a.angle == b.angle &&
         a.radius == b.radius && a.width == b.width && a.height == b.height && a.length == b.length &&
         a.shaping.enabled == b.shaping.enabled && a.shaping.coneAngle == b.shaping.coneAngle &&
         a.shaping.coneSoftness == b.shaping.coneSoftness && a.shaping.focus == b.shaping.focus &&
         a.shaping.focusTint == b.shaping.focusTint && a.shaping.iesFile == b.shaping.iesFile &&
         a.shaping.iesAngleScale == b.shaping.iesAngleScale && a.shaping.iesNormalize == b.shaping.iesNormalize &&
         a.textureFile == b.textureFile && sameMesh(a.mesh, b.mesh) && a.doubleSided == b.doubleSided &&
         a.tintByMaterial == b.tintByMaterial && a.lightLink == b.lightLink && a.shadowLink == b.shadowLink &&
         a.shadows == b.shadows;
}

// Transforms at the shutter's open and close (MeshDesc::shutterXf, AggregateDesc::shutterXf).
bool sameShutterXf(const std::optional<std::pair<Transform, Transform>>& a,
                   const std::optional<std::pair<Transform, Transform>>& b) {
  return a.has_value() == b.has_value() &&
         (!a || (sameTransform(a->first, b->first) && sameTransform(a->second, b->second)));
}

bool sameMeshDesc(const MeshDesc& a, const MeshDesc& b) {
  return a.name == b.name && sameMesh(a.mesh, b.mesh) && sameTransform(a.xf, b.xf) && a.material == b.material &&
         a.visible == b.visible && a.id == b.id && a.instanceId == b.instanceId &&
         sameShutterXf(a.shutterXf, b.shutterXf);
}

// Settings Scene::setView applies (all but those of settingsNeedBuild).
bool sameViewSettings(const RenderSettings& a, const RenderSettings& b) {
  return a.width == b.width && a.height == b.height && a.spp == b.spp && a.seed == b.seed &&
         a.maxDepth == b.maxDepth && a.rrDepth == b.rrDepth && a.threads == b.threads && a.technique == b.technique &&
         a.bundleSize == b.bundleSize && a.tau == b.tau && a.explicitBounces == b.explicitBounces &&
         a.daDepthFactor == b.daDepthFactor && a.daMinOrder == b.daMinOrder && a.daInstanced == b.daInstanced &&
         a.roulette == b.roulette &&
         a.lod == b.lod && a.proxies == b.proxies && a.domeCameraVisible == b.domeCameraVisible &&
         a.sunRegularization == b.sunRegularization && a.switchForView == b.switchForView &&
         a.cropX0 == b.cropX0 && a.cropX1 == b.cropX1 && a.cropY0 == b.cropY0 && a.cropY1 == b.cropY1 &&
         a.cryptomatte == b.cryptomatte;
}

// The objects' light-link categories, in order (an object added or removed is another change).
template <class T>
bool sameLinkCategories(const std::vector<T>& a, const std::vector<T>& b) {
  for (size_t i = 0; i < std::min(a.size(), b.size()); ++i)
    if (a[i].linkCategories != b[i].linkCategories) return false;
  return true;
}

template <class T, class Same>
bool sameList(const std::vector<T>& a, const std::vector<T>& b, Same same) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (!same(a[i], b[i])) return false;
  return true;
}

// What Scene::build compares to lend an aggregate (the id only names it in the primId
// AOV): the AggregateDesc in render space (each scene's own origin) and, per prototype,
// its scene material's index (a prototype without one takes the default grain, indexed
// after the scene's own materials) and description.
bool sameAggregateInputs(const SceneDesc& da, const Vec3d& oa, const AggregateDesc& a, const SceneDesc& db,
                         const Vec3d& ob, const AggregateDesc& b) {
  if (a.name != b.name || !sameTransform(toRenderSpace(a.xf, oa), toRenderSpace(b.xf, ob)) || a.weights != b.weights ||
      !(a.grainRadius == b.grainRadius) || a.sizes != b.sizes || !(a.sizeSpread == b.sizeSpread) ||
      !(a.packingRate == b.packingRate) || a.seed != b.seed || a.tileSpheres != b.tileSpheres ||
      a.fineFieldBytes != b.fineFieldBytes || a.prototypes.size() != b.prototypes.size() ||
      !sameMesh(a.boundary, b.boundary))
    return false;
  for (size_t i = 0; i < a.prototypes.size(); ++i) {
    const GrainPrototypeDesc &pa = a.prototypes[i], &pb = b.prototypes[i];
    const int ma = pa.material >= 0 ? pa.material : int(da.materials.size());
    const int mb = pb.material >= 0 ? pb.material : int(db.materials.size());
    if (pa.name != pb.name || pa.material != pb.material || ma != mb || !sameMesh(pa.mesh, pb.mesh)) return false;
    if (pa.material >= 0 && !sameMaterial(da.materials[size_t(pa.material)], db.materials[size_t(pb.material)]))
      return false;
  }
  return true;
}

bool validMaterialIndices(const SceneDesc& d) {
  for (const AggregateDesc& a : d.aggregates)
    for (const GrainPrototypeDesc& p : a.prototypes)
      if (p.material >= int(d.materials.size())) return false;
  return true;
}

}  // namespace

bool sameInstancedGrains(const InstancedGrainsDesc& a, const InstancedGrainsDesc& b) {
  // Shared values are equal without a look; others byte for byte (a NaN equals itself).
  auto same = [](const auto& x, const auto& y) {
    return x.sharesWith(y) ||
           (x.size() == y.size() && (x.empty() || std::memcmp(x.data(), y.data(), x.size() * sizeof(x[0])) == 0));
  };
  if (a.name != b.name || !sameTransform(a.xf, b.xf) || a.prototypes.size() != b.prototypes.size() ||
      !same(a.protoIndices, b.protoIndices) || !same(a.scales, b.scales) || !same(a.positions, b.positions) ||
      !same(a.orientations, b.orientations) || !same(a.velocities, b.velocities) ||
      !same(a.angularVelocities, b.angularVelocities))
    return false;
  for (size_t k = 0; k < a.prototypes.size(); ++k)
    if (a.prototypes[k].material != b.prototypes[k].material || !sameMesh(a.prototypes[k].mesh, b.prototypes[k].mesh))
      return false;
  return true;
}

SceneChange SceneChanges::level() const {
  if (meshes || materials || media || renderSpace) return SceneChange::Everything;
  if (!aggregates.empty() || aggregateList || aggregateMotion || instancedGrains) return SceneChange::Aggregates;
  if (lights) return SceneChange::Lights;
  if (camera || settings) return SceneChange::View;
  return SceneChange::Unchanged;
}

bool settingsNeedBuild(const RenderSettings& a, const RenderSettings& b) {
  return (a.technique == Technique::Ept) != (b.technique == Technique::Ept) || a.mediumModel != b.mediumModel ||
         a.defaultLight != b.defaultLight || a.physicalSun != b.physicalSun;
}

SceneChanges compareScenes(const SceneDesc& before, const SceneDesc& after) {
  SceneChanges c;
  c.camera = !sameCamera(before.camera, after.camera);
  c.settings = !sameViewSettings(before.settings, after.settings);
  c.media = (before.settings.technique == Technique::Ept) != (after.settings.technique == Technique::Ept) ||
            before.settings.mediumModel != after.settings.mediumModel;
  c.lights = !sameList(before.lights, after.lights, sameLight) ||
             before.settings.defaultLight != after.settings.defaultLight ||
             before.settings.physicalSun != after.settings.physicalSun;
  c.meshes = !sameList(before.meshes, after.meshes, sameMeshDesc);
  // Light linking is the lights' business: the objects' categories rebuild no surface or grain.
  c.lights = c.lights || !sameLinkCategories(before.meshes, after.meshes) ||
             !sameLinkCategories(before.aggregates, after.aggregates) ||
             !sameLinkCategories(before.instancedGrains, after.instancedGrains);
  c.instancedGrains = before.instancedGrains.size() != after.instancedGrains.size();
  // Moving meshes are built at the shutter's ends, and moving grains' grids cover their
  // sweep over it (Scene::build).
  if (motionSpan(before.camera) != motionSpan(after.camera) || before.camera.shutterOpen != after.camera.shutterOpen)
    for (const MeshDesc& m : after.meshes) c.meshes = c.meshes || m.shutterXf.has_value();
  if (motionSpan(before.camera) != motionSpan(after.camera))
    for (const InstancedGrainsDesc& g : after.instancedGrains)
      c.instancedGrains = c.instancedGrains || !g.velocities.empty() || !g.angularVelocities.empty();
  for (size_t i = 0; i < after.instancedGrains.size() && !c.instancedGrains; ++i)
    c.instancedGrains = !sameInstancedGrains(before.instancedGrains[i], after.instancedGrains[i]) ||
                        before.instancedGrains[i].id != after.instancedGrains[i].id;
  // A moving aggregate is lent by its build and moves as the new description says: its
  // shutter transforms, and the shutter they span.
  if (before.camera.shutterOpen != after.camera.shutterOpen || before.camera.shutterClose != after.camera.shutterClose)
    for (const AggregateDesc& a : after.aggregates) c.aggregateMotion = c.aggregateMotion || a.shutterXf.has_value();
  for (size_t i = 0; i < std::min(before.aggregates.size(), after.aggregates.size()); ++i)
    c.aggregateMotion =
        c.aggregateMotion || !sameShutterXf(before.aggregates[i].shutterXf, after.aggregates[i].shutterXf);
  const Vec3d originBefore = renderOrigin(before), originAfter = renderOrigin(after);
  c.renderSpace = !(originBefore == originAfter);

  // A material that differs is the aggregates' business when grains alone use it (they
  // compare their prototypes' materials); anything else sees it through the surfaces.
  if (before.materials.size() != after.materials.size()) {
    c.materials = true;
  } else {
    std::vector<bool> grainOnly(after.materials.size(), true), used(after.materials.size(), false);
    for (const SceneDesc* d : {&before, &after}) {
      for (const MeshDesc& m : d->meshes)
        if (m.material >= 0 && size_t(m.material) < grainOnly.size()) grainOnly[size_t(m.material)] = false;
      for (const AggregateDesc& a : d->aggregates)
        for (const GrainPrototypeDesc& p : a.prototypes)
          if (p.material >= 0 && size_t(p.material) < used.size()) used[size_t(p.material)] = true;
    }
    for (size_t i = 0; i < after.materials.size() && !c.materials; ++i)
      c.materials = !(grainOnly[i] && used[i]) && !sameMaterial(before.materials[i], after.materials[i]);
  }

  // Each new aggregate is lent by an equal one of before, preferably at its own index.
  const bool comparable = validMaterialIndices(before) && validMaterialIndices(after);
  c.aggregateList = before.aggregates.size() > after.aggregates.size();
  for (size_t i = 0; i < after.aggregates.size(); ++i) {
    const AggregateDesc& a = after.aggregates[i];
    auto lends = [&](size_t j) {
      return comparable && sameAggregateInputs(before, originBefore, before.aggregates[j], after, originAfter, a);
    };
    if (i < before.aggregates.size() && lends(i)) {
      if (before.aggregates[i].id != a.id || before.aggregates[i].instanceId != a.instanceId) c.aggregateList = true;
      continue;
    }
    bool found = false;
    for (size_t j = 0; j < before.aggregates.size() && !found; ++j) found = j != i && lends(j);
    if (found)
      c.aggregateList = true;
    else
      c.aggregates.push_back(int(i));
  }
  return c;
}

std::string describeChanges(const SceneChanges& c) {
  auto join = [](const std::vector<std::string>& parts) {
    std::string s;
    for (size_t i = 0; i < parts.size(); ++i)
      s += (i == 0 ? "" : i + 1 == parts.size() ? " and " : ", ") + parts[i];
    return s;
  };
  switch (c.level()) {
    case SceneChange::Unchanged: return "unchanged";
    case SceneChange::View:
      return "new " + join(c.camera && c.settings ? std::vector<std::string>{"camera", "settings"}
                           : c.camera             ? std::vector<std::string>{"camera"}
                                                  : std::vector<std::string>{"settings"});
    default: break;
  }
  std::vector<std::string> parts;
  if (c.level() == SceneChange::Everything) {
    std::vector<std::string> why;
    if (c.meshes) why.push_back("meshes");
    if (c.materials) why.push_back("materials");
    if (c.media) why.push_back("media");
    if (c.renderSpace) why.push_back("render space");
    parts.push_back("everything (" + join(why) + ")");
  }
  if (c.lights) parts.push_back("lights");
  if (!c.aggregates.empty())
    parts.push_back(str(c.aggregates.size(), c.aggregates.size() == 1 ? " aggregate" : " aggregates"));
  if (c.instancedGrains) parts.push_back("explicit grains");
  else if (c.aggregateList && c.level() == SceneChange::Aggregates)
    parts.push_back("the list of aggregates");
  else if (c.aggregateMotion && c.aggregates.empty() && c.level() == SceneChange::Aggregates)
    parts.push_back("the aggregates' motion");
  return join(parts) + " changed";
}

void stillFrame(SceneDesc& desc) {
  desc.camera.shutterOpen = desc.camera.shutterClose = 0;
  for (MeshDesc& m : desc.meshes) m.shutterXf.reset();
  for (AggregateDesc& a : desc.aggregates) a.shutterXf.reset();
}

}  // namespace granular
