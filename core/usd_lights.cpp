// usd_lights.cpp — UsdLux lights on plain records (usd_lights.h).
#include "usd_lights.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "error.h"
#include "usd_implicit.h"

namespace granular {

namespace {

const char* const kIntensity = "inputs:intensity";
const char* const kExposure = "inputs:exposure";
const char* const kColor = "inputs:color";
const char* const kNormalize = "inputs:normalize";
const char* const kEnableTemperature = "inputs:enableColorTemperature";
const char* const kTemperature = "inputs:colorTemperature";
const char* const kAngle = "inputs:angle";
const char* const kTextureFile = "inputs:texture:file";
const char* const kTextureFormat = "inputs:texture:format";
const char* const kWidth = "inputs:width";
const char* const kHeight = "inputs:height";
const char* const kRadius = "inputs:radius";
const char* const kLength = "inputs:length";
const char* const kTreatAsPoint = "treatAsPoint";
const char* const kTreatAsLine = "treatAsLine";
const char* const kMaterialSyncMode = "light:materialSyncMode";
const char* const kConeAngle = "inputs:shaping:cone:angle";
const char* const kConeSoftness = "inputs:shaping:cone:softness";
const char* const kFocus = "inputs:shaping:focus";
const char* const kFocusTint = "inputs:shaping:focusTint";
const char* const kIesFile = "inputs:shaping:ies:file";
const char* const kIesAngleScale = "inputs:shaping:ies:angleScale";
const char* const kIesNormalize = "inputs:shaping:ies:normalize";
// ShapingAPI's inputs by the LightDesc field names core's checks use (validateLightDesc).
const std::pair<const char*, const char*> kShapingInputs[] = {
    {"shaping_cone_angle", kConeAngle},   {"shaping_cone_softness", kConeSoftness},
    {"shaping_focus", kFocus},            {"shaping_focus_tint", kFocusTint},
    {"shaping_ies_file", kIesFile},       {"shaping_ies_angle_scale", kIesAngleScale},
    {"shaping_ies_normalize", kIesNormalize}};
// Non-physical controls a path tracer of grains has no meaning for: warned about when set.
const char* const kDiffuse = "inputs:diffuse";
const char* const kSpecular = "inputs:specular";
// ShadowAPI: shadow:enable is honoured (LightDesc::shadows); the rest shape shadows in ways
// light transport has no meaning for: warned about when set off their fallbacks.
const char* const kShadowEnable = "inputs:shadow:enable";
const char* const kShadowColor = "inputs:shadow:color";
const char* const kShadowDistance = "inputs:shadow:distance";
const char* const kShadowFalloff = "inputs:shadow:falloff";
const char* const kShadowFalloffGamma = "inputs:shadow:falloffGamma";

// One lobe of the fit: a Gaussian with different widths below and above its mean.
double lobe(double lambda, double mean, double below, double above) {
  const double t = (lambda - mean) / (lambda < mean ? below : above);
  return std::exp(-0.5 * t * t);
}

// a < b element by element ("/A/B" before "/A_B", as "A" < "A_B"); an ancestor first.
bool pathLess(const std::string& a, const std::string& b) {
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    const size_t ei = std::min(a.find('/', i + 1), a.size()), ej = std::min(b.find('/', j + 1), b.size());
    const std::string x = a.substr(i, ei - i), y = b.substr(j, ej - j);
    if (x != y) return x < y;
    i = ei;
    j = ej;
  }
  return i == a.size() && j < b.size();
}

}  // namespace

void orderUsdLights(std::vector<LightDesc>& lights) {
  std::stable_sort(lights.begin(), lights.end(),
                   [](const LightDesc& a, const LightDesc& b) { return pathLess(a.name, b.name); });
}

const std::vector<std::string>& usdLightAttributeNames() {
  static const std::vector<std::string> names = {
      kIntensity,    kExposure,       kColor,        kNormalize,      kEnableTemperature,  kTemperature,
      kAngle,        kTextureFile,    kTextureFormat, kWidth,         kHeight,             kRadius,
      kLength,       kTreatAsPoint,   kTreatAsLine,  kConeAngle,      kConeSoftness,       kFocus,
      kFocusTint,    kIesFile,        kIesAngleScale, kIesNormalize,  kDiffuse,            kSpecular,
      kShadowEnable, kShadowColor,    kShadowDistance, kShadowFalloff, kShadowFalloffGamma, kMaterialSyncMode};
  return names;
}

Vec3 blackbodyRgb(float kelvin) {
  const double t = std::clamp(double(kelvin), 1000.0, 10000.0);
  const double c2 = 1.4387769e-2;  // second radiation constant hc/k, m·K
  double X = 0, Y = 0, Z = 0;
  for (int nm = 380; nm <= 780; ++nm) {
    const double l = nm, m = nm * 1e-9;
    const double planck = 1.0 / (std::pow(m, 5) * std::expm1(c2 / (m * t)));  // up to a constant
    X += planck * (1.056 * lobe(l, 599.8, 37.9, 31.0) + 0.362 * lobe(l, 442.0, 16.0, 26.7) -
                   0.065 * lobe(l, 501.1, 20.4, 26.2));
    Y += planck * (0.821 * lobe(l, 568.8, 46.9, 40.5) + 0.286 * lobe(l, 530.9, 16.3, 31.1));
    Z += planck * (1.217 * lobe(l, 437.0, 11.8, 36.0) + 0.681 * lobe(l, 459.0, 26.0, 13.8));
  }
  // CIE XYZ to linear Rec.709 (IEC 61966-2-1).
  const double r = std::max(0.0, 3.2406 * X - 1.5372 * Y - 0.4986 * Z);
  const double g = std::max(0.0, -0.9689 * X + 1.8758 * Y + 0.0415 * Z);
  const double b = std::max(0.0, 0.0557 * X - 0.2040 * Y + 1.0570 * Z);
  const double luminance = 0.2126 * r + 0.7152 * g + 0.0722 * b;
  return Vec3(float(r / luminance), float(g / luminance), float(b / luminance));
}

std::optional<LightDesc> lightFromUsd(const UsdPrimRecord& r, UsdWarnings& warnings) {
  const std::string& path = r.path;
  LightDesc l;
  l.name = path;
  l.xf = r.xf;
  const std::string& type = r.typeName;
  if (type == "DistantLight") {
    l.type = LightType::Distant;
    l.angle = usdFloat(r, kAngle, 0.53f);
  } else if (type == "DomeLight" || type == "DomeLight_1") {
    l.type = LightType::Dome;
    const std::string format = usdToken(r, kTextureFormat, "automatic");
    if (format != "automatic" && format != "latlong")
      throw InputError(path, kTextureFormat, str("\"", format, "\" is not supported (use latlong)"));
    l.textureFile = usdFile(r, kTextureFile);
  } else if (type == "RectLight") {
    l.type = LightType::Rect;
    l.width = usdFloat(r, kWidth, 1.0f);
    l.height = usdFloat(r, kHeight, 1.0f);
    if (!usdAsset(r, kTextureFile).first.empty())
      warnings.push_back(str(path, ".", kTextureFile, ": rect light textures are not supported; ignored"));
  } else if (type == "SphereLight") {
    l.type = LightType::Sphere;
    l.radius = usdFloat(r, kRadius, 0.5f);
    if (usdBool(r, kTreatAsPoint, false))
      warnings.push_back(str(path, ".", kTreatAsPoint, ": not supported; rendered as a sphere of inputs:radius"));
  } else if (type == "DiskLight") {
    l.type = LightType::Disk;
    l.radius = usdFloat(r, kRadius, 0.5f);
  } else if (type == "CylinderLight") {
    l.type = LightType::Cylinder;
    l.radius = usdFloat(r, kRadius, 0.5f);
    l.length = usdFloat(r, kLength, 1.0f);
    if (usdBool(r, kTreatAsLine, false))
      warnings.push_back(str(path, ".", kTreatAsLine, ": not supported; rendered as a cylinder of inputs:radius"));
  } else if (type == "Mesh" || isUsdImplicitSurface(type)) {
    // MeshLightAPI: the front end's MeshPrim holds the triangles (granular_prims.h).
    l.type = LightType::Mesh;
    const std::string mode = usdToken(r, kMaterialSyncMode, "materialGlowTintsLight");
    if (mode != "materialGlowTintsLight" && mode != "independent" && mode != "noMaterialResponse")
      throw InputError(path, kMaterialSyncMode,
                       str("\"", mode, "\" is not one of materialGlowTintsLight, independent, noMaterialResponse"));
    l.tintByMaterial = mode == "materialGlowTintsLight";
  } else {
    warnings.push_back(str(path, ": ", type.empty() ? std::string("untyped") : type,
                           " lights are not supported; skipped"));
    return std::nullopt;
  }
  l.intensity = usdFloat(r, kIntensity, 1.0f);
  l.exposure = usdFloat(r, kExposure, 0.0f);
  l.color = usdColor(r, kColor, Vec3(1.0f));
  if (usdBool(r, kEnableTemperature, false)) {
    const float k = usdFloat(r, kTemperature, 6500.0f);
    if (!(std::isfinite(k) && k > 0)) throw InputError(path, kTemperature, str(k, " must be finite and > 0"));
    const Vec3 bb = blackbodyRgb(k);
    l.color = Vec3(l.color.x * bb.x, l.color.y * bb.y, l.color.z * bb.z);
  }
  l.normalize = usdBool(r, kNormalize, false);
  // ShapingAPI: on where any of its inputs has a value (applied, or authored).
  bool shaping = false;
  for (const auto& [field, name] : kShapingInputs) shaping = shaping || r.attributes.count(name);
  if (shaping && (l.type == LightType::Distant || l.type == LightType::Dome || l.type == LightType::Mesh)) {
    warnings.push_back(str(path, ": ShapingAPI on a ", l.type == LightType::Mesh ? "mesh light" : type.c_str(),
                           " is not supported; ignored"));
  } else if (shaping) {
    l.shaping.enabled = true;  // LightShaping's defaults are UsdLux's fallbacks
    l.shaping.coneAngle = usdFloat(r, kConeAngle, l.shaping.coneAngle);
    l.shaping.coneSoftness = usdFloat(r, kConeSoftness, l.shaping.coneSoftness);
    l.shaping.focus = usdFloat(r, kFocus, l.shaping.focus);
    l.shaping.focusTint = usdColor(r, kFocusTint, l.shaping.focusTint);
    l.shaping.iesFile = usdFile(r, kIesFile);
    l.shaping.iesAngleScale = usdFloat(r, kIesAngleScale, l.shaping.iesAngleScale);
    l.shaping.iesNormalize = usdBool(r, kIesNormalize, l.shaping.iesNormalize);
  }
  for (const char* multiplier : {kDiffuse, kSpecular})
    if (usdFloat(r, multiplier, 1.0f) != 1.0f)
      warnings.push_back(str(path, ".", multiplier, ": not supported (light reaches every surface as it is); ignored"));
  l.shadows = usdBool(r, kShadowEnable, true);
  if (usdColor(r, kShadowColor, Vec3(0.0f)) != Vec3(0.0f))
    warnings.push_back(str(path, ".", kShadowColor, ": not supported (shadows are where the light does not reach); ignored"));
  for (const auto& [name, fallback] : {std::pair{kShadowDistance, -1.0f}, std::pair{kShadowFalloff, -1.0f},
                                       std::pair{kShadowFalloffGamma, 1.0f}})
    if (usdFloat(r, name, fallback) != fallback)
      warnings.push_back(str(path, ".", name, ": not supported (shadows reach as far as the light); ignored"));
  l.lightLink = usdToken(r, kUsdLightLink, "");
  l.shadowLink = usdToken(r, kUsdShadowLink, "");
  validateUsdLight(l, path, l.type != LightType::Mesh);
  return l;
}

void validateUsdLight(const LightDesc& l, const std::string& path, bool geometry) {
  // Core's checks, in USD's names (a light's SceneDesc fields are its inputs).
  checkInUsdNames(path, [&] { validateLightDesc(l, path, geometry); }, [](const std::string& field) {
    for (const auto& [shapingField, name] : kShapingInputs)
      if (field == shapingField) return std::string(name);
    return field == "transform" || field == "points" || field.empty() ? field : "inputs:" + field;
  });
}

}  // namespace granular
