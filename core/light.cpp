#include "light.h"

#include <mutex>

#include "embree_util.h"
#include "error.h"
#include "image_io.h"

namespace granular {

namespace {

// One Embree device for every mesh light while any lives (an instancer may make many).
EmbreeDevice meshLightDevice() {
  static std::mutex mutex;
  static std::weak_ptr<std::remove_pointer_t<RTCDevice>> shared;
  std::lock_guard<std::mutex> lock(mutex);
  EmbreeDevice d = shared.lock();
  if (!d) shared = d = makeEmbreeDevice();
  return d;
}

}  // namespace

// A mesh light's triangles in world space, each one's unit front normal, the distribution
// that picks them by area and their BVH (which lets a one-sided mesh's back faces through).
struct MeshEmitter {
  TriangleMesh world;
  std::vector<Vec3> normals;
  std::vector<float> areas;
  Distribution1D byArea;
  float area = 0;
  bool twoSided = false;
  Bounds3 bounds;
  EmbreeDevice device;
  EmbreeScene bvh;

  // Rejects a hit on a face's back (one-sided): the back neither emits nor blocks.
  static void backFaces(const RTCFilterFunctionNArguments* args) {
    const auto* e = static_cast<const MeshEmitter*>(args->geometryUserPtr);
    for (unsigned i = 0; i < args->N; ++i) {
      if (args->valid[i] != -1) continue;
      const Vec3& n = e->normals[RTCHitN_primID(args->hit, args->N, i)];
      const Vec3 d(RTCRayN_dir_x(args->ray, args->N, i), RTCRayN_dir_y(args->ray, args->N, i),
                   RTCRayN_dir_z(args->ray, args->N, i));
      if (!(dot(d, n) < 0)) args->valid[i] = 0;
    }
  }

  // The nearest emitting face along r in (r.tmin, r.tmax): its distance and triangle.
  bool intersect(const Ray& r, float& t, unsigned& prim) const {
    if (!traceable(r.o, r.d, r.tmin, r.tmax)) return false;
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRayHit rh = makeRayHit(r.o, r.d, r.tmin, r.tmax);
    rtcIntersect1(bvh.get(), &ctx, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID || !(rh.ray.tfar > r.tmin)) return false;
    t = rh.ray.tfar;
    prim = rh.hit.primID;
    return true;
  }
};

namespace {

// Lat-long mapping of a dome direction (dome space, +Y up), as UsdLuxDomeLight states it
// after the OpenEXR specification (and as Storm draws it): longitude λ = atan2(x, z), 0
// toward +Z and π/2 toward +X, runs from +π at u = 0 to −π at u = 1, so +Z is the
// image's middle column and +X its first quarter; v runs from the zenith (0) to the nadir (1).
void dirToUV(const Vec3& d, float& u, float& v) {
  u = 0.5f - std::atan2(d.x, d.z) * (0.5f * kInvPi);
  v = std::acos(std::min(1.0f, std::max(-1.0f, d.y))) * kInvPi;
}
Vec3 uvToDir(float u, float v) {
  float lambda = (0.5f - u) * 2.0f * kPi, theta = v * kPi;
  float s = std::sin(theta);
  return {s * std::sin(lambda), std::cos(theta), s * std::cos(lambda)};
}

// A sun's half-angle, and whether it is so small that the sun is a delta light.
float sunHalfAngle(const LightDesc& d) { return 0.5f * d.angle * kPi / 180.0f; }
// A sun whose 1 − cos of its half-angle is below this is a delta light.
constexpr float kPointLikeSunOneMinusCos = 1e-7f;
bool pointLikeSun(float half) { return std::cos(half) > 1.0f - kPointLikeSunOneMinusCos; }

}  // namespace

bool isDeltaSun(const LightDesc& d) { return d.type == LightType::Distant && pointLikeSun(sunHalfAngle(d)); }

double normalizationArea(const LightDesc& d) {
  if (!d.normalize) return 1.0;
  switch (d.type) {
    case LightType::Distant: {
      float half = sunHalfAngle(d);
      return pointLikeSun(half) ? 1.0 : kPiD * std::sin(double(half)) * std::sin(double(half));  // irradiance = intensity
    }
    case LightType::Sphere: {
      float r = d.radius * length(d.xf.vector(Vec3(1, 0, 0)));  // uniform scale scales the radius
      return 4.0 * kPiD * double(r) * r;
    }
    case LightType::Rect:
    case LightType::Disk: {
      // |u × v| of its edges (rect) or semi-axes (disk), π times that for the disk.
      const bool rect = d.type == LightType::Rect;
      Vec3 u = d.xf.vector(Vec3(rect ? d.width : d.radius, 0, 0)), v = d.xf.vector(Vec3(0, rect ? d.height : d.radius, 0));
      double cx = double(u.y) * v.z - double(u.z) * v.y, cy = double(u.z) * v.x - double(u.x) * v.z,
             cz = double(u.x) * v.y - double(u.y) * v.x;
      return (rect ? 1.0 : kPiD) * std::sqrt(cx * cx + cy * cy + cz * cz);
    }
    case LightType::Cylinder:  // its side: the caps do not emit
      return 2.0 * kPiD * double(d.radius) * length(d.xf.vector(Vec3(0, 1, 0))) * double(d.length) *
             length(d.xf.vector(Vec3(1, 0, 0)));
    case LightType::Mesh: return d.mesh.transformed(d.xf).area();  // its world area, front faces
    case LightType::Dome: break;
  }
  return 1.0;
}

Light Light::fromDesc(const LightDesc& d) {
  Light l;
  l.type_ = d.type;
  // In double, then to float: validateSceneDesc bounds the quotient, so it fits.
  const Vec3 L0 = d.color * (d.intensity * std::exp2(d.exposure));
  const double area = normalizationArea(d);
  const Vec3 L(float(double(L0.x) / area), float(double(L0.y) / area), float(double(L0.z) / area));
  switch (d.type) {
    case LightType::Distant: {
      l.dir_ = normalize(d.xf.vector(Vec3(0, 0, 1)));
      float half = sunHalfAngle(d);
      l.cosMax_ = pointLikeSun(half) ? 1.0f : std::cos(half);  // 1: a delta light
      // The cone's pdf from sin² (sampling.h): with 1 − cosMax in float the 0.53° sun's pdf
      // disagreed with its normalisation, π sin², by 0.25%.
      l.sunSin2_ = std::sin(double(half)) * std::sin(double(half));
      l.radiance_ = L;
      break;
    }
    case LightType::Sphere: {
      l.center_ = d.xf.point(Vec3(0.0f));
      l.radius_ = d.radius * length(d.xf.vector(Vec3(1, 0, 0)));  // uniform scale scales it
      l.radiance_ = L;
      break;
    }
    case LightType::Rect: {
      l.corner_ = d.xf.point(Vec3(-0.5f * d.width, -0.5f * d.height, 0));
      l.edgeU_ = d.xf.vector(Vec3(d.width, 0, 0));
      l.edgeV_ = d.xf.vector(Vec3(0, d.height, 0));
      Vec3 c = cross(l.edgeU_, l.edgeV_);
      l.area_ = length(c);
      l.normal_ = normalize(d.xf.vector(Vec3(0, 0, -1)));
      l.radiance_ = L;
      break;
    }
    case LightType::Disk: {
      l.center_ = d.xf.point(Vec3(0.0f));
      l.edgeU_ = d.xf.vector(Vec3(d.radius, 0, 0));
      l.edgeV_ = d.xf.vector(Vec3(0, d.radius, 0));
      l.area_ = kPi * length(cross(l.edgeU_, l.edgeV_));
      l.normal_ = normalize(d.xf.vector(Vec3(0, 0, -1)));
      l.radiance_ = L;
      break;
    }
    case LightType::Cylinder: {
      // Its cross-section a circle: a scale across the axis is taken from local Y.
      l.center_ = d.xf.point(Vec3(0.0f));
      const Vec3 along = d.xf.vector(Vec3(d.length, 0, 0)), y = d.xf.vector(Vec3(0, 1, 0));
      l.halfLength_ = 0.5f * length(along);
      l.axis_ = normalize(along);
      l.radius_ = d.radius * length(y);
      const Vec3 across = y - l.axis_ * dot(y, l.axis_);
      l.across1_ = length2(across) > 0 ? normalize(across) : Frame(l.axis_).s;
      l.across2_ = cross(l.axis_, l.across1_);
      l.area_ = 2.0f * kPi * l.radius_ * (2.0f * l.halfLength_);
      l.radiance_ = L;
      break;
    }
    case LightType::Mesh: {
      auto e = std::make_shared<MeshEmitter>();
      e->world = d.mesh.transformed(d.xf);
      e->twoSided = d.doubleSided;
      std::vector<float>& areas = e->areas;
      areas.resize(e->world.numTriangles());
      e->normals.resize(areas.size());
      double total = 0;
      for (size_t t = 0; t < areas.size(); ++t) {
        const Vec3 &a = e->world.points[e->world.indices[3 * t]], &b = e->world.points[e->world.indices[3 * t + 1]],
                   &c = e->world.points[e->world.indices[3 * t + 2]];
        const Vec3 n = cross(b - a, c - a);
        areas[t] = 0.5f * length(n);
        e->normals[t] = areas[t] > 0 ? n / (2.0f * areas[t]) : Vec3(0.0f);
        total += areas[t];
        for (const Vec3* v : {&a, &b, &c}) e->bounds.extend(*v);
      }
      e->area = float(total);
      e->byArea = Distribution1D(areas);
      e->device = meshLightDevice();
      e->bvh = makeEmbreeScene(e->device);
      attachTriangleMesh(e->device.get(), e->bvh.get(), e->world, e->twoSided ? nullptr : &MeshEmitter::backFaces,
                         e.get());
      rtcCommitScene(e->bvh.get());
      l.center_ = e->bounds.center();
      l.area_ = e->area;
      l.emitter_ = std::move(e);
      l.radiance_ = L;
      break;
    }
    case LightType::Dome: {
      l.radiance_ = L;
      l.toWorld_ = d.xf;
      if (!d.xf.inverse(l.toLocal_)) throw InputError(d.name, "transform", "is singular");
      if (!d.textureFile.empty()) {
        // Errors name the light and its texture input (UsdLux), as textures name theirs.
        const char* const attribute = "inputs:texture:file";
        uint64_t nonFinite = 0;
        Image img;
        try {
          img = readImageRGB(d.textureFile, &nonFinite);
        } catch (const InputError& e) {
          throw InputError(d.name, attribute, e.detail());
        }
        // Zeroed, a NaN or infinite texel would be a hole in the sky nobody asked for.
        if (nonFinite)
          throw InputError(d.name, attribute,
                           str("\"", d.textureFile, "\" has ", nonFinite,
                               " texel values that are not finite (NaN or infinity)"));
        l.texW_ = img.width;
        l.texH_ = img.height;
        l.texels_ = std::make_shared<std::vector<float>>(std::move(img.pixels));
        std::vector<float> f(size_t(l.texW_) * l.texH_);
        for (int y = 0; y < l.texH_; ++y) {
          float s = std::sin(kPi * (y + 0.5f) / l.texH_);  // lat-long area element
          for (int x = 0; x < l.texW_; ++x) {
            const float* t = &(*l.texels_)[(size_t(y) * l.texW_ + x) * 3];
            f[size_t(y) * l.texW_ + x] = (t[0] + t[1] + t[2]) * s + 1e-6f;
          }
        }
        l.dist_ = std::make_shared<Distribution2D>(f, l.texW_, l.texH_);
        double sumL2 = 0, sumA = 0;
        for (int y = 0; y < l.texH_; ++y) {
          const double a = std::sin(kPiD * (y + 0.5) / l.texH_);  // each texel's solid angle, to a factor
          for (int x = 0; x < l.texW_; ++x) {
            const float* t = &(*l.texels_)[(size_t(y) * l.texW_ + x) * 3];
            const double v = average(L * Vec3(t[0], t[1], t[2]));
            sumL2 += v * v * a;
            sumA += a;
          }
        }
        l.domeRms_ = sumA > 0 ? std::sqrt(sumL2 / sumA) : 0.0;
      }
      break;
    }
  }
  if (d.shaping.enabled && d.type != LightType::Distant && d.type != LightType::Dome && d.type != LightType::Mesh) {
    l.shaped_ = true;
    l.shapeAxis_ = normalize(d.xf.vector(Vec3(0, 0, -1)));
    l.coneAngle_ = std::clamp(d.shaping.coneAngle, 0.0f, 180.0f) * (kPi / 180.0f);
    l.coneSmooth_ = l.coneAngle_ * (1.0f - std::clamp(d.shaping.coneSoftness, 0.0f, 1.0f));
    l.focus_ = std::max(d.shaping.focus, 0.0f);
    l.focusTint_ = d.shaping.focusTint;
    l.ies_ = lightIesProfile(d, d.name);
    if (l.ies_) {
      if (!d.xf.inverse(l.toLocal_)) throw InputError(d.name, "transform", "is singular");
      l.iesAngleScale_ = d.shaping.iesAngleScale;
      const double mean = l.ies_->meanIntensity();
      l.iesScale_ = !d.shaping.iesNormalize ? 1.0f : mean > 0 ? float(1.0 / mean) : 0.0f;
    }
  }
  return l;
}

std::shared_ptr<const IesProfile> lightIesProfile(const LightDesc& d, const std::string& object) {
  if (d.shaping.iesFile.empty()) return nullptr;
  try {
    return readIesFile(d.shaping.iesFile);
  } catch (const InputError& e) {
    throw InputError(object, "shaping_ies_file", str("\"", d.shaping.iesFile, "\" ", e.detail()));
  }
}

Vec3 Light::centre() const { return type_ == LightType::Rect ? corner_ + (edgeU_ + edgeV_) * 0.5f : center_; }

float Light::iesFactor(const Vec3& w) const {
  // The emission direction in the light's own frame (UsdLux: θ off its −Z, φ from +X to
  // +Y), θ mapped by angleScale (LightShaping, scene_desc.h).
  const Vec3 local = toLocal_.vector(w);
  const float theta = std::atan2(std::sqrt(local.x * local.x + local.y * local.y), -local.z);
  const float s = iesAngleScale_;
  const float t = s > 0 ? theta / s : s < 0 ? kPi + (theta - kPi) / -s : theta;
  if (!(t >= 0.0f && t <= kPi)) return 0.0f;
  return ies_->intensity(t, std::atan2(local.y, local.x)) * iesScale_;
}

float Light::facingHalf(const Vec3& p) const {
  const Vec3 r = p - center_;
  return std::atan2(dot(r, across2_), dot(r, across1_));
}

Vec3 Light::surfaceNormal(const Vec3& q) const {
  switch (type_) {
    case LightType::Sphere: {
      const Vec3 n = q - center_;
      return length2(n) > 0 ? normalize(n) : shapeAxis_;
    }
    case LightType::Cylinder: {
      const Vec3 r = q - center_, across = r - axis_ * dot(r, axis_);
      return length2(across) > 0 ? normalize(across) : across1_;
    }
    default: return normal_;
  }
}

Vec3 Light::emitted(const Vec3& q, const Vec3& w) const {
  if (!shaped_) return radiance_;
  // The cone (LightShaping): 1 up to coneSmooth_, smoothstep down to 0 at coneAngle_.
  const float theta = std::acos(std::clamp(dot(shapeAxis_, w), -1.0f, 1.0f));
  if (theta > coneAngle_) return Vec3(0.0f);
  float cone = 1.0f;
  if (theta > coneSmooth_) {
    const float x = (coneAngle_ - theta) / (coneAngle_ - coneSmooth_);
    cone = x * x * (3.0f - 2.0f * x);
  }
  if (ies_) cone *= iesFactor(w);
  if (focus_ <= 0) return radiance_ * cone;
  const float f = std::pow(std::fabs(dot(surfaceNormal(q), w)), focus_);
  return radiance_ * (focusTint_ + (Vec3(1.0f) - focusTint_) * f) * cone;
}

double Light::pickWeight(const Vec3& ref) const {
  // An IES profile scales the light by its candela: by those toward ref where its beam
  // points there (a spot aimed at the scene is picked for its beam, up to ~100 times its
  // mean), never by less than their mean (ref is one point: the beam may light others).
  double profile = 1.0;
  if (ies_) {
    profile = ies_->meanIntensity() * iesScale_;
    const Vec3 d = ref - centre();
    if (length2(d) > 0) profile = std::max(profile, double(iesFactor(normalize(d))));
  }
  const double L = std::max(0.0, double(average(radiance_))) * profile;
  // E √(4π/Ω) = L √(4π Ω) for a light of uniform radiance L over Ω.
  auto cone = [L](double omega) { return L * std::sqrt(4.0 * kPiD * omega); };
  switch (type_) {
    case LightType::Distant: {
      if (cosMax_ < 1.0f) return cone(2.0 * kPiD * coneOneMinusCos(sunSin2_));
      return L * std::sqrt(4.0 * kPiD / (2.0 * kPiD * double(kPointLikeSunOneMinusCos)));  // delta: L is E
    }
    case LightType::Sphere: {
      const double d2 = double(length2(center_ - ref)), r2 = double(radius_) * radius_;
      return cone(2.0 * kPiD * coneOneMinusCos(d2 > r2 ? r2 / d2 : 1.0));
    }
    case LightType::Rect:
    case LightType::Disk: {
      const Vec3 c = centre(), d = ref - c;
      const double d2 = double(length2(d));
      const double omega = d2 > 0 ? double(area_) * std::fabs(double(dot(normal_, d))) / (d2 * std::sqrt(d2)) : 2.0 * kPiD;
      return cone(std::min(omega, 2.0 * kPiD));
    }
    case LightType::Cylinder: {
      // Its silhouette from ref: 2 r × length × the sine between the axis and the view.
      const Vec3 d = ref - center_;
      const double d2 = double(length2(d));
      if (!(d2 > 0)) return cone(2.0 * kPiD);
      const double c = double(dot(axis_, d)) / std::sqrt(d2), sine = std::sqrt(std::max(0.0, 1.0 - c * c));
      return cone(std::min(4.0 * double(radius_) * halfLength_ * sine / d2, 2.0 * kPiD));
    }
    case LightType::Mesh: {
      // The solid angle its emitting faces subtend from ref, face by face (their overlaps
      // counted twice, as a bound should).
      const MeshEmitter& e = *emitter_;
      double omega = 0;
      for (size_t t = 0; t < e.normals.size(); ++t) {
        const Vec3 c = (e.world.points[e.world.indices[3 * t]] + e.world.points[e.world.indices[3 * t + 1]] +
                        e.world.points[e.world.indices[3 * t + 2]]) /
                       3.0f;
        const Vec3 d = ref - c;
        const double d2 = double(length2(d)), cosL = double(dot(e.normals[t], d));
        if (!(d2 > 0)) return cone(2.0 * kPiD);
        if (cosL > 0 || e.twoSided) omega += double(e.areas[t]) * std::fabs(cosL) / (d2 * std::sqrt(d2));
      }
      return cone(std::min(omega, 2.0 * kPiD));
    }
    case LightType::Dome:
      // E = π × mean radiance, Ω = 4π mean² / mean square: E √(4π/Ω) = π × the rms radiance.
      return kPiD * (texels_ ? domeRms_ : L);
  }
  return 0.0;
}

Vec3 Light::domeLookup(const Vec3& localDir) const {
  if (!texels_) return radiance_;
  float u, v;
  dirToUV(localDir, u, v);
  int x = std::min(std::max(int(u * texW_), 0), texW_ - 1);
  int y = std::min(std::max(int(v * texH_), 0), texH_ - 1);
  const float* t = &(*texels_)[(size_t(y) * texW_ + x) * 3];
  return radiance_ * Vec3(t[0], t[1], t[2]);
}

bool Light::sampleLi(const Vec3& p, float u1, float u2, LightSample& s, const Vec3& above) const {
  switch (type_) {
    case LightType::Distant: {
      if (cosMax_ >= 1.0f) {
        s.wi = dir_; s.pdf = 0; s.delta = true; s.Li = radiance_; s.dist = kInf;
        return true;
      }
      Frame f(dir_);
      s.wi = f.toWorld(sampleUniformConeSin2(u1, u2, sunSin2_));
      s.pdf = uniformConePdfSin2(sunSin2_);
      s.Li = radiance_;
      s.delta = false;
      s.dist = kInf;
      return true;
    }
    case LightType::Sphere: {
      Vec3 toC = center_ - p;
      float d2 = length2(toC);
      float r2 = radius_ * radius_;
      if (d2 <= r2 * 1.0001f) return false;  // inside the emitter: it faces away
      float d = std::sqrt(d2);
      // sin² of the cone in double: a small sphere far away (d > ~4000 r) has a cone too
      // narrow for cosMax in float (it gave pdf = 1/0 and NaN samples).
      double sin2 = double(r2) / double(d2);
      Frame f(toC / d);
      s.wi = f.toWorld(sampleUniformConeSin2(u1, u2, sin2));
      Ray r{p, s.wi, 0.0f, kInf};
      float t;
      if (!intersect(r, t)) t = d * float(std::sqrt(std::max(0.0, 1.0 - sin2)));  // grazing the silhouette
      s.dist = t;
      s.pdf = uniformConePdfSin2(sin2);
      s.Li = emitted(p + s.wi * t, -s.wi);
      s.delta = false;
      return true;
    }
    case LightType::Rect: {
      Vec3 q = corner_ + edgeU_ * u1 + edgeV_ * u2;
      Vec3 w = q - p;
      float d2 = length2(w);
      if (d2 <= 0) return false;
      float d = std::sqrt(d2);
      w /= d;
      float cosL = -dot(w, normal_);
      if (cosL <= 0) return false;  // one-sided
      s.wi = w;
      s.dist = d;
      s.pdf = d2 / (cosL * area_);
      s.Li = emitted(q, -w);
      s.delta = false;
      return true;
    }
    case LightType::Disk:
    case LightType::Cylinder: {
      Vec3 q, n;
      if (type_ == LightType::Disk) {
        const Vec3 c = sampleConcentricDisk(u1, u2);
        q = center_ + edgeU_ * c.x + edgeV_ * c.y;
        n = normal_;
      } else {
        // The half of the side that faces p (facingHalf): every point p sees lies in it.
        const float phi = facingHalf(p) + kPi * (u2 - 0.5f);
        n = across1_ * std::cos(phi) + across2_ * std::sin(phi);
        q = center_ + axis_ * ((2.0f * u1 - 1.0f) * halfLength_) + n * radius_;
      }
      Vec3 w = q - p;
      const float d2 = length2(w);
      if (!(d2 > 0)) return false;
      const float d = std::sqrt(d2);
      w /= d;
      const float cosL = -dot(w, n);
      if (cosL <= 0) return false;  // its back (a disk) or its far side (a cylinder)
      s.wi = w;
      s.dist = d;
      s.pdf = d2 / (cosL * (type_ == LightType::Cylinder ? 0.5f * area_ : area_));
      s.Li = emitted(q, -w);
      s.delta = false;
      return true;
    }
    case LightType::Mesh: {
      // A face by its area (sampleContinuous: the offset within its bin is uniform again),
      // then a point uniform in it.
      const MeshEmitter& e = *emitter_;
      float binPdf;
      int t = 0;
      const float x = e.byArea.sampleContinuous(u1, &binPdf, &t);
      const float v1 = std::clamp(x * float(e.byArea.size()) - float(t), 0.0f, 1.0f);
      const float su = std::sqrt(v1);
      const Vec3 &a = e.world.points[e.world.indices[3 * size_t(t)]],
                 &b = e.world.points[e.world.indices[3 * size_t(t) + 1]],
                 &c = e.world.points[e.world.indices[3 * size_t(t) + 2]];
      const Vec3 q = a * (1.0f - su) + b * (su * (1.0f - u2)) + c * (su * u2);
      Vec3 w = q - p;
      const float d2 = length2(w);
      if (!(d2 > 0)) return false;
      const float d = std::sqrt(d2);
      w /= d;
      float cosL = -dot(w, e.normals[size_t(t)]);
      if (e.twoSided) cosL = std::fabs(cosL);
      if (!(cosL > 0)) return false;  // the face's back
      s.wi = w;
      s.dist = d;
      s.pdf = d2 / (cosL * e.area);
      s.Li = radiance_;
      s.delta = false;
      return true;
    }
    case LightType::Dome: {
      if (!dist_) {
        if (length2(above) > 0) {
          s.wi = Frame(above).toWorld(sampleCosineHemisphere(u1, u2));
          s.pdf = cosineHemispherePdf(dot(s.wi, above));
          if (!(s.pdf > 0)) return false;
        } else {
          s.wi = sampleUniformSphere(u1, u2);
          s.pdf = kUniformSpherePdf;
        }
        s.Li = radiance_;
      } else {
        float u, v, pdfUV;
        dist_->sample(u1, u2, u, v, &pdfUV);
        Vec3 local = uvToDir(u, v);
        float sinT = std::sin(v * kPi);
        if (sinT <= 0 || pdfUV <= 0) return false;
        s.wi = normalize(toWorld_.vector(local));
        s.pdf = pdfUV / (2.0f * kPi * kPi * sinT);
        s.Li = domeLookup(local);
      }
      s.dist = kInf;
      s.delta = false;
      return true;
    }
  }
  return false;
}

Vec3 Light::escapedLe(const Vec3& dir) const {
  if (type_ == LightType::Dome) return domeLookup(normalize(toLocal_.vector(dir)));
  if (type_ == LightType::Distant && cosMax_ < 1.0f && dot(dir, dir_) >= cosMax_) return radiance_;
  return Vec3(0.0f);
}

namespace {

// The cone a sun narrower than halfAngle is seen as: its cosine and sin², or false where
// the light is seen as it is.
bool widenedCone(LightType type, float cosMax, float halfAngle, float& cosWide, double& sin2Wide) {
  if (type != LightType::Distant || cosMax >= 1.0f || !(halfAngle > 0)) return false;
  cosWide = std::cos(halfAngle);
  if (cosMax <= cosWide) return false;
  const double s = std::sin(double(halfAngle));
  sin2Wide = s * s;
  return true;
}

}  // namespace

Vec3 Light::escapedLeSeen(const Vec3& dir, float halfAngle, float* pdf, const Vec3& above) const {
  float cosWide;
  double sin2Wide;
  if (!widenedCone(type_, cosMax_, halfAngle, cosWide, sin2Wide)) {
    if (pdf) *pdf = pdfLi(Vec3(0.0f), dir, kInf, above);  // an infinite light's: independent of the point
    return escapedLe(dir);
  }
  const bool inside = dot(dir, dir_) >= cosWide;
  if (pdf) *pdf = inside ? uniformConePdfSin2(sin2Wide) : 0.0f;
  // Irradiance L π sin²(half-angle) (normalizationArea), spread over the wider disk.
  return inside ? radiance_ * float(sunSin2_ / sin2Wide) : Vec3(0.0f);
}

bool Light::sampleLiSeen(const Vec3& p, float u1, float u2, float halfAngle, LightSample& s,
                         const Vec3& above) const {
  float cosWide;
  double sin2Wide;
  if (!widenedCone(type_, cosMax_, halfAngle, cosWide, sin2Wide)) return sampleLi(p, u1, u2, s, above);
  s.wi = Frame(dir_).toWorld(sampleUniformConeSin2(u1, u2, sin2Wide));
  s.pdf = uniformConePdfSin2(sin2Wide);
  s.Li = radiance_ * float(sunSin2_ / sin2Wide);
  s.delta = false;
  s.dist = kInf;
  return true;
}

float Light::pdfLi(const Vec3& p, const Vec3& wi, float dist, const Vec3& above) const {
  switch (type_) {
    case LightType::Distant:
      return (cosMax_ < 1.0f && dot(wi, dir_) >= cosMax_) ? uniformConePdfSin2(sunSin2_) : 0.0f;
    case LightType::Sphere: {
      float d2 = length2(center_ - p), r2 = radius_ * radius_;
      if (d2 <= r2 * 1.0001f) return 0.0f;
      return uniformConePdfSin2(double(r2) / double(d2));
    }
    case LightType::Rect:
    case LightType::Disk: {
      float cosL = -dot(wi, normal_);
      return cosL > 0 ? dist * dist / (cosL * area_) : 0.0f;
    }
    case LightType::Cylinder: {
      float cosL = -dot(wi, surfaceNormal(p + wi * dist));
      return cosL > 0 ? dist * dist / (cosL * 0.5f * area_) : 0.0f;
    }
    case LightType::Mesh: {
      // The face the direction meets about dist away (the hit the caller found, from an
      // origin that may sit a little off p): its cosine.
      float t;
      unsigned prim;
      if (!emitter_->intersect(Ray{p, wi, 0.0f, dist * 1.001f + 1e-6f}, t, prim)) return 0.0f;
      const float cosL = std::fabs(dot(wi, emitter_->normals[prim]));
      return cosL > 0 ? t * t / (cosL * emitter_->area) : 0.0f;
    }
    case LightType::Dome: {
      if (!dist_) return length2(above) > 0 ? cosineHemispherePdf(dot(wi, above)) : kUniformSpherePdf;
      Vec3 local = normalize(toLocal_.vector(wi));
      float u, v;
      dirToUV(local, u, v);
      float sinT = std::sin(v * kPi);
      return sinT > 0 ? dist_->pdf(u, v) / (2.0f * kPi * kPi * sinT) : 0.0f;
    }
  }
  return 0.0f;
}

bool Light::intersect(const Ray& r, float& t) const {
  if (type_ == LightType::Mesh) {
    unsigned prim;
    return emitter_->intersect(r, t, prim);
  }
  if (type_ == LightType::Sphere) {
    Vec3 oc = r.o - center_;
    float b = dot(oc, r.d), c = length2(oc) - radius_ * radius_;
    float disc = b * b - c;
    if (disc < 0) return false;
    float sq = std::sqrt(disc);
    float t0 = -b - sq, t1 = -b + sq;
    if (t0 > r.tmin && t0 < r.tmax) { t = t0; return true; }
    if (t1 > r.tmin && t1 < r.tmax && c > 0) { t = t1; return true; }
    return false;
  }
  if (type_ == LightType::Rect || type_ == LightType::Disk) {
    // One-sided: the back neither emits nor blocks. (a, b): the hit in units of the edges
    // from the corner (rect) or of the semi-axes from the centre (disk).
    const float denom = dot(r.d, normal_);
    if (denom >= 0) return false;
    const Vec3 o = type_ == LightType::Rect ? corner_ : center_;
    const float tt = dot(o - r.o, normal_) / denom;
    if (!(tt > r.tmin && tt < r.tmax)) return false;
    const Vec3 q = r.o + r.d * tt - o;
    const float a = dot(q, edgeU_) / length2(edgeU_), b = dot(q, edgeV_) / length2(edgeV_);
    if (type_ == LightType::Rect ? (a < 0 || a > 1 || b < 0 || b > 1) : a * a + b * b > 1) return false;
    t = tt;
    return true;
  }
  if (type_ == LightType::Cylinder) {
    // The side's outer surface only: where the ray enters the infinite cylinder (the near
    // root, by the closest approach as for spheres), within its length.
    const Vec3 oc = r.o - center_;
    const Vec3 o2 = oc - axis_ * dot(oc, axis_), d2 = r.d - axis_ * dot(r.d, axis_);
    const float a = length2(d2);
    if (!(a > 0)) return false;  // along the axis
    const float along = -dot(o2, d2) / a;
    const Vec3 closest = o2 + d2 * along;
    const float disc = radius_ * radius_ - length2(closest);
    if (disc < 0) return false;
    const float tt = along - std::sqrt(disc / a);
    if (!(tt > r.tmin && tt < r.tmax)) return false;
    if (std::fabs(dot(oc + r.d * tt, axis_)) > halfLength_) return false;
    t = tt;
    return true;
  }
  return false;
}

Bounds3 Light::bounds() const {
  Bounds3 b;
  switch (type_) {
    case LightType::Sphere:
      b.extend(center_ - Vec3(radius_));
      b.extend(center_ + Vec3(radius_));
      break;
    case LightType::Rect:
      for (float u : {0.0f, 1.0f})
        for (float v : {0.0f, 1.0f}) b.extend(corner_ + edgeU_ * u + edgeV_ * v);
      break;
    case LightType::Disk: {  // the box of its rim: ± |each axis's reach| about the centre
      const Vec3 r(std::hypot(edgeU_.x, edgeV_.x), std::hypot(edgeU_.y, edgeV_.y), std::hypot(edgeU_.z, edgeV_.z));
      b.extend(center_ - r);
      b.extend(center_ + r);
      break;
    }
    case LightType::Cylinder:
      for (float s : {-1.0f, 1.0f}) {
        b.extend(center_ + axis_ * (s * halfLength_) - Vec3(radius_));
        b.extend(center_ + axis_ * (s * halfLength_) + Vec3(radius_));
      }
      break;
    case LightType::Mesh: b = emitter_->bounds; break;
    default: break;
  }
  return b;
}

bool Light::blocksShadowRay(Ray r) const {
  const bool aimed = std::isfinite(r.tmax);
  const float tol = 1e-3f * r.tmax;
  float t;
  if (type_ == LightType::Mesh) {
    if (aimed) r.tmax -= tol;
    return intersect(r, t);
  }
  return intersect(r, t) && !(aimed && endsOn(r.o + r.d * r.tmax, tol));
}

bool Light::endsOn(const Vec3& e, float tol) const {
  switch (type_) {
    case LightType::Sphere: return std::fabs(length(e - center_) - radius_) <= tol;
    case LightType::Rect:
    case LightType::Disk: {
      const Vec3 o = type_ == LightType::Rect ? corner_ : center_, q = e - o;
      if (std::fabs(dot(q, normal_)) > tol) return false;
      const float lu = length(edgeU_), lv = length(edgeV_);
      const float a = dot(q, edgeU_) / (lu * lu), b = dot(q, edgeV_) / (lv * lv);
      const float ta = tol / lu, tb = tol / lv;
      if (type_ == LightType::Rect) return a >= -ta && a <= 1 + ta && b >= -tb && b <= 1 + tb;
      return a * a + b * b <= (1 + std::max(ta, tb)) * (1 + std::max(ta, tb));
    }
    case LightType::Cylinder: {
      const Vec3 q = e - center_;
      const float along = dot(q, axis_);
      return std::fabs(along) <= halfLength_ + tol && std::fabs(length(q - axis_ * along) - radius_) <= tol;
    }
    default: return false;
  }
}

Vec3 Light::areaLe(const Vec3& q, const Vec3& dir) const { return emitted(q, -dir); }

}  // namespace granular
