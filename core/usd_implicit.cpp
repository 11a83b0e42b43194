// usd_implicit.cpp — UsdGeom's implicit surfaces (usd_implicit.h).
#include "usd_implicit.h"

#include <cmath>

#include "error.h"
#include "shapes.h"

namespace granular {

namespace {

constexpr int kSegments = 64;

float positive(const UsdPrimRecord& r, const char* name, float fallback) {
  const float v = usdFloat(r, name, fallback);
  if (!(std::isfinite(v) && v > 0)) throw InputError(r.path, name, str(v, " must be finite and > 0"));
  return v;
}

// makeLathe's +Y axis turned onto UsdGeom's `axis` by a cyclic permutation (a rotation).
TriangleMesh alongAxis(TriangleMesh m, const UsdPrimRecord& r) {
  const std::string axis = usdToken(r, "axis", "Z");
  if (axis != "X" && axis != "Y" && axis != "Z")
    throw InputError(r.path, "axis", str("\"", axis, "\" is not X, Y or Z"));
  for (Vec3& p : m.points) {
    if (axis == "Z") p = Vec3(p.z, p.x, p.y);
    else if (axis == "X") p = Vec3(p.y, p.z, p.x);
  }
  return m;
}

}  // namespace

bool isUsdImplicitSurface(const std::string& t) {
  return t == "Cube" || t == "Sphere" || t == "Cylinder" || t == "Cone" || t == "Capsule";
}

const std::vector<std::string>& usdImplicitAttributeNames() {
  static const std::vector<std::string> names = {"size", "radius", "height", "axis"};
  return names;
}

TriangleMesh implicitSurfaceFromUsd(const UsdPrimRecord& r) {
  const std::string& t = r.typeName;
  if (t == "Cube") {
    const float h = 0.5f * positive(r, "size", 2.0f);
    return makeBox(Vec3(-h), Vec3(h));
  }
  if (t == "Sphere") {
    const float radius = positive(r, "radius", 1.0f);
    TriangleMesh m = makeUVSphere(kSegments, kSegments / 2);
    for (Vec3& p : m.points) p = p * radius;
    return m;
  }
  if (t == "Cylinder" || t == "Cone") {
    const float h = positive(r, "height", 2.0f), radius = positive(r, "radius", 1.0f);
    return alongAxis(makeLathe({{radius, -0.5f * h}, {t == "Cone" ? 0.0f : radius, 0.5f * h}}, kSegments), r);
  }
  if (t == "Capsule") {
    const float h = positive(r, "height", 1.0f), radius = positive(r, "radius", 0.5f);
    std::vector<std::pair<float, float>> profile;
    const int rings = kSegments / 4;  // per hemisphere
    for (int i = 0; i <= rings; ++i) {  // bottom pole to equator
      const double a = -0.5 * kPiD + 0.5 * kPiD * i / rings;
      profile.emplace_back(float(radius * std::cos(a)), float(-0.5 * h + radius * std::sin(a)));
    }
    for (int i = 0; i <= rings; ++i) {  // equator to top pole
      const double a = 0.5 * kPiD * i / rings;
      profile.emplace_back(float(radius * std::cos(a)), float(0.5 * h + radius * std::sin(a)));
    }
    profile.front().first = profile.back().first = 0.0f;  // poles
    return alongAxis(makeLathe(profile, kSegments), r);
  }
  throw InputError(r.path, "", str("a ", t, " is not an implicit surface"));
}

}  // namespace granular
