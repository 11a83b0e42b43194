// test_usd_lights.cpp — UsdLux lights on plain records: fallbacks per type, colour
// temperature, what is skipped or warned about, and errors named prim.attribute.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>

#include "core/error.h"
#include "core/usd_lights.h"
#include "usd_records.h"

using namespace granular;
using namespace granular::test;

namespace {

std::string errorOf(const UsdPrimRecord& r) {
  UsdWarnings w;
  return inputErrorOf([&] { lightFromUsd(r, w); });
}

}  // namespace

TEST(UsdLights, UnauthoredValuesTakeUsdLuxFallbacks) {
  UsdWarnings w;
  const LightDesc d = *lightFromUsd(usdRecord("/Sun", "DistantLight"), w);
  EXPECT_EQ(d.type, LightType::Distant);
  EXPECT_EQ(d.name, "/Sun");
  EXPECT_FLOAT_EQ(d.angle, 0.53f);
  EXPECT_FLOAT_EQ(d.intensity, 1.0f);
  EXPECT_FLOAT_EQ(d.exposure, 0.0f);
  EXPECT_FALSE(d.normalize);
  EXPECT_FLOAT_EQ(d.color.y, 1.0f);
  const LightDesc s = *lightFromUsd(usdRecord("/Bulb", "SphereLight"), w);
  EXPECT_FLOAT_EQ(s.radius, 0.5f);
  const LightDesc r = *lightFromUsd(usdRecord("/Panel", "RectLight"), w);
  EXPECT_FLOAT_EQ(r.width, 1.0f);
  EXPECT_FLOAT_EQ(r.height, 1.0f);
  const LightDesc dome = *lightFromUsd(usdRecord("/Sky", "DomeLight_1"), w);
  EXPECT_EQ(dome.type, LightType::Dome);
  EXPECT_TRUE(dome.textureFile.empty());
  EXPECT_TRUE(w.empty());
}

TEST(UsdLights, AuthoredValuesAreRead) {
  UsdWarnings w;
  const LightDesc d = *lightFromUsd(usdRecord("/Sun", "DistantLight",
                                              {{"inputs:angle", usdNumbers("float", {5})},
                                               {"inputs:intensity", usdNumbers("double", {3})},
                                               {"inputs:exposure", usdNumbers("float", {-1})},
                                               {"inputs:color", usdNumbers("color3f", {1, 0.5, 0.25})},
                                               {"inputs:normalize", usdNumbers("bool", {1})}}),
                                    w);
  EXPECT_FLOAT_EQ(d.angle, 5.0f);
  EXPECT_FLOAT_EQ(d.intensity, 3.0f);
  EXPECT_FLOAT_EQ(d.exposure, -1.0f);
  EXPECT_FLOAT_EQ(d.color.z, 0.25f);
  EXPECT_TRUE(d.normalize);
}

TEST(UsdLights, DisksCylindersAndShapingTakeUsdLuxFallbacksAndAuthoredValues) {
  UsdWarnings w;
  const LightDesc disk = *lightFromUsd(usdRecord("/Disk", "DiskLight"), w);
  EXPECT_EQ(disk.type, LightType::Disk);
  EXPECT_FLOAT_EQ(disk.radius, 0.5f);
  EXPECT_FALSE(disk.shaping.enabled);
  const LightDesc tube = *lightFromUsd(
      usdRecord("/Tube", "CylinderLight",
                {{"inputs:radius", usdNumbers("float", {0.1})}, {"inputs:length", usdNumbers("float", {3})}}),
      w);
  EXPECT_EQ(tube.type, LightType::Cylinder);
  EXPECT_FLOAT_EQ(tube.radius, 0.1f);
  EXPECT_FLOAT_EQ(tube.length, 3.0f);
  EXPECT_FLOAT_EQ(lightFromUsd(usdRecord("/Tube", "CylinderLight"), w)->length, 1.0f);
  EXPECT_TRUE(w.empty());
  // ShapingAPI: on where any of its inputs has a value, the others at UsdLux's fallbacks.
  const LightDesc spot =
      *lightFromUsd(usdRecord("/Spot", "SphereLight", {{"inputs:shaping:cone:angle", usdNumbers("float", {20})}}), w);
  EXPECT_TRUE(spot.shaping.enabled);
  EXPECT_FLOAT_EQ(spot.shaping.coneAngle, 20.0f);
  EXPECT_FLOAT_EQ(spot.shaping.coneSoftness, 0.0f);
  EXPECT_FLOAT_EQ(spot.shaping.focus, 0.0f);
  EXPECT_FLOAT_EQ(spot.shaping.focusTint.x, 0.0f);
  const LightDesc focused = *lightFromUsd(
      usdRecord("/Panel", "RectLight",
                {{"inputs:shaping:focus", usdNumbers("float", {4})},
                 {"inputs:shaping:focusTint", usdNumbers("color3f", {0.1, 0.2, 0.3})},
                 {"inputs:shaping:cone:softness", usdNumbers("float", {0.5})}}),
      w);
  EXPECT_TRUE(focused.shaping.enabled);
  EXPECT_FLOAT_EQ(focused.shaping.coneAngle, 90.0f);
  EXPECT_FLOAT_EQ(focused.shaping.coneSoftness, 0.5f);
  EXPECT_FLOAT_EQ(focused.shaping.focus, 4.0f);
  EXPECT_FLOAT_EQ(focused.shaping.focusTint.z, 0.3f);
  EXPECT_TRUE(w.empty());
  EXPECT_EQ(errorOf(usdRecord("/Tube", "CylinderLight", {{"inputs:length", usdNumbers("float", {0})}}))
                .rfind("/Tube.inputs:length: ", 0),
            0u);
  EXPECT_EQ(errorOf(usdRecord("/Spot", "DiskLight", {{"inputs:shaping:focusTint", usdNumbers("color3f", {-1, 0, 0})}}))
                .rfind("/Spot.inputs:shaping:focusTint: ", 0),
            0u);
}

TEST(UsdLights, AnIesProfileIsReadWithItsAngleScaleAndNormalisation) {
  namespace fs = std::filesystem;
  const std::string dir = (fs::temp_directory_path() / ("granular_usd_ies_" + std::to_string(::getpid()))).string();
  fs::create_directories(dir);
  const std::string good = dir + "/spot.ies", bad = dir + "/photo.ies";
  std::ofstream(good) << "IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 2 1 1 2 0 0 0\n1 1 10\n0 90\n0\n10 0\n";
  std::ofstream(bad) << "not a profile\n";
  UsdWarnings w;
  // As the asset resolver gives it: authored relative, resolved absolute.
  const LightDesc spot = *lightFromUsd(usdRecord("/Spot", "SphereLight",
                                                 {{"inputs:shaping:ies:file", usdText("asset", "spot.ies", good)},
                                                  {"inputs:shaping:ies:angleScale", usdNumbers("float", {0.5})},
                                                  {"inputs:shaping:ies:normalize", usdNumbers("bool", {1})}}),
                                       w);
  EXPECT_TRUE(w.empty());
  EXPECT_TRUE(spot.shaping.enabled);
  EXPECT_EQ(spot.shaping.iesFile, good);
  EXPECT_FLOAT_EQ(spot.shaping.iesAngleScale, 0.5f);
  EXPECT_TRUE(spot.shaping.iesNormalize);
  EXPECT_FLOAT_EQ(spot.shaping.coneAngle, 90.0f);  // the cone's fallback, as ShapingAPI's
  // Any of them turns shaping on, the others at their fallbacks.
  const LightDesc scaled =
      *lightFromUsd(usdRecord("/Spot", "RectLight", {{"inputs:shaping:ies:angleScale", usdNumbers("float", {2})}}), w);
  EXPECT_TRUE(scaled.shaping.enabled);
  EXPECT_TRUE(scaled.shaping.iesFile.empty());
  EXPECT_FALSE(scaled.shaping.iesNormalize);
  // Errors name the prim and the attribute: a missing file, one that is not a profile, a
  // scale that is not finite.
  EXPECT_EQ(errorOf(usdRecord("/Spot", "SphereLight", {{"inputs:shaping:ies:file", usdText("asset", "no/such.ies")}})),
            "/Spot.inputs:shaping:ies:file: \"no/such.ies\" cannot be found");
  EXPECT_EQ(errorOf(usdRecord("/Spot", "DiskLight", {{"inputs:shaping:ies:file", usdText("asset", "photo.ies", bad)}})),
            "/Spot.inputs:shaping:ies:file: \"" + bad + "\" has no TILT= line: it is not an IES LM-63 photometric file");
  EXPECT_EQ(errorOf(usdRecord("/Spot", "DiskLight",
                              {{"inputs:shaping:ies:angleScale", usdNumbers("float", {std::nan("")})}}))
                .rfind("/Spot.inputs:shaping:ies:angleScale: ", 0),
            0u);
  fs::remove_all(dir);
}

TEST(UsdLights, OtherTypesAndUnsupportedAttributesAreWarnedAbout) {
  UsdWarnings w;
  EXPECT_FALSE(lightFromUsd(usdRecord("/Portal", "PortalLight"), w));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0], "/Portal: PortalLight lights are not supported; skipped");
  w.clear();
  EXPECT_TRUE(lightFromUsd(usdRecord("/Tube", "CylinderLight", {{"treatAsLine", usdNumbers("bool", {1})}}), w));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0], "/Tube.treatAsLine: not supported; rendered as a cylinder of inputs:radius");
  w.clear();
  const LightDesc sun =
      *lightFromUsd(usdRecord("/Sun", "DistantLight", {{"inputs:shaping:cone:angle", usdNumbers("float", {20})}}), w);
  EXPECT_FALSE(sun.shaping.enabled);
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0], "/Sun: ShapingAPI on a DistantLight is not supported; ignored");
  w.clear();
  EXPECT_TRUE(lightFromUsd(usdRecord("/Sky", "DomeLight", {{"inputs:shaping:ies:file", usdText("asset", "a.ies")}}), w));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0], "/Sky: ShapingAPI on a DomeLight is not supported; ignored");
  w.clear();
  EXPECT_TRUE(lightFromUsd(usdRecord("/Sun", "DistantLight",
                                     {{"inputs:diffuse", usdNumbers("float", {0})},
                                      {"inputs:specular", usdNumbers("float", {1})}}),
                           w));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0], "/Sun.inputs:diffuse: not supported (light reaches every surface as it is); ignored");
  w.clear();
  // ShadowAPI: enable is honoured; the shaping of shadows is warned about off its fallbacks.
  const LightDesc unshadowed = *lightFromUsd(
      usdRecord("/Sun", "DistantLight",
                {{"inputs:shadow:enable", usdNumbers("bool", {0})},
                 {"inputs:shadow:color", usdNumbers("color3f", {0, 0, 0})},
                 {"inputs:shadow:distance", usdNumbers("float", {-1})},
                 {"inputs:shadow:falloffGamma", usdNumbers("float", {1})}}),
      w);
  EXPECT_FALSE(unshadowed.shadows);
  EXPECT_TRUE(w.empty());
  EXPECT_TRUE(lightFromUsd(usdRecord("/Sun", "DistantLight"), w)->shadows);  // UsdLux's fallback
  EXPECT_TRUE(lightFromUsd(usdRecord("/Sun", "DistantLight",
                                     {{"inputs:shadow:color", usdNumbers("color3f", {0.2f, 0, 0})},
                                      {"inputs:shadow:distance", usdNumbers("float", {3})},
                                      {"inputs:shadow:falloff", usdNumbers("float", {1})},
                                      {"inputs:shadow:falloffGamma", usdNumbers("float", {2})}}),
                           w));
  ASSERT_EQ(w.size(), 4u);
  EXPECT_EQ(w[0], "/Sun.inputs:shadow:color: not supported (shadows are where the light does not reach); ignored");
  EXPECT_EQ(w[1], "/Sun.inputs:shadow:distance: not supported (shadows reach as far as the light); ignored");
  EXPECT_EQ(w[2], "/Sun.inputs:shadow:falloff: not supported (shadows reach as far as the light); ignored");
  EXPECT_EQ(w[3], "/Sun.inputs:shadow:falloffGamma: not supported (shadows reach as far as the light); ignored");
  w.clear();
  EXPECT_TRUE(lightFromUsd(usdRecord("/Bulb", "SphereLight", {{"treatAsPoint", usdNumbers("bool", {1})}}), w));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0], "/Bulb.treatAsPoint: not supported; rendered as a sphere of inputs:radius");
}

TEST(UsdLights, LightAndShadowLinkCollectionsNamedByTheFrontEndLinkTheLight) {
  UsdWarnings w;
  const LightDesc all = *lightFromUsd(usdRecord("/Sun", "DistantLight"), w);
  EXPECT_EQ(all.lightLink, "");  // no collection named: it holds every prim
  const LightDesc linked = *lightFromUsd(
      usdRecord("/Sun", "DistantLight",
                {{kUsdLightLink, usdText("token", "/Sun.collection:lightLink")},
                 {kUsdShadowLink, usdText("token", "/Sun.collection:shadowLink")}}),
      w);
  EXPECT_EQ(linked.lightLink, "/Sun.collection:lightLink");
  EXPECT_EQ(linked.shadowLink, "/Sun.collection:shadowLink");
  EXPECT_EQ(all.shadowLink, "");
  EXPECT_TRUE(w.empty());
  EXPECT_EQ(errorOf(usdRecord("/Sun", "DistantLight", {{kUsdShadowLink, usdNumbers("float", {1})}})),
            "/Sun.collection:shadowLink: has value 1, expected a token");
  EXPECT_EQ(errorOf(usdRecord("/Sun", "DistantLight", {{kUsdLightLink, usdNumbers("float", {1})}})),
            "/Sun.collection:lightLink: has value 1, expected a token");
}

TEST(UsdLights, ColourTemperatureMultipliesTheColourByABlackbodyOfLuminanceOne) {
  for (float k : {1000.0f, 2700.0f, 6500.0f, 10000.0f}) {
    const Vec3 c = blackbodyRgb(k);
    EXPECT_NEAR(0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z, 1.0f, 1e-5f) << k;
    EXPECT_GE(c.z, 0.0f);
  }
  // Warmer is redder; beyond the range it holds its ends.
  EXPECT_GT(blackbodyRgb(2000).x, blackbodyRgb(4000).x);
  EXPECT_LT(blackbodyRgb(2000).z, blackbodyRgb(4000).z);
  EXPECT_FLOAT_EQ(blackbodyRgb(20000).z, blackbodyRgb(10000).z);
  UsdWarnings w;
  const LightDesc d = *lightFromUsd(usdRecord("/Lamp", "SphereLight",
                                              {{"inputs:enableColorTemperature", usdNumbers("bool", {1})},
                                               {"inputs:colorTemperature", usdNumbers("float", {3000})},
                                               {"inputs:color", usdNumbers("color3f", {0.5, 1, 1})}}),
                                    w);
  EXPECT_FLOAT_EQ(d.color.x, 0.5f * blackbodyRgb(3000).x);
  EXPECT_FLOAT_EQ(d.color.z, blackbodyRgb(3000).z);
  // Not enabled: the temperature means nothing.
  const LightDesc off = *lightFromUsd(usdRecord("/Lamp", "SphereLight", {{"inputs:colorTemperature", usdNumbers("float", {3000})}}), w);
  EXPECT_FLOAT_EQ(off.color.x, 1.0f);
}

TEST(UsdLights, BadValuesNameThePrimAndItsAttribute) {
  EXPECT_EQ(errorOf(usdRecord("/L", "SphereLight", {{"inputs:enableColorTemperature", usdNumbers("bool", {1})},
                                                    {"inputs:colorTemperature", usdNumbers("float", {0})}})),
            "/L.inputs:colorTemperature: 0 must be finite and > 0");
  EXPECT_EQ(errorOf(usdRecord("/L", "SphereLight", {{"inputs:intensity", usdText("token", "bright")}})),
            "/L.inputs:intensity: has value 'bright', expected a number");
  EXPECT_EQ(errorOf(usdRecord("/L", "SphereLight", {{"inputs:intensity", usdNumbers("float", {-2})}})),
            "/L.inputs:intensity: -2 must be finite and >= 0");
  EXPECT_EQ(errorOf(usdRecord("/L", "DistantLight", {{"inputs:angle", usdNumbers("float", {180})}})),
            "/L.inputs:angle: 180 is outside [0, 180)");
  EXPECT_EQ(errorOf(usdRecord("/L", "RectLight", {{"inputs:width", usdNumbers("float", {0})}})).rfind("/L.inputs:width: ", 0),
            0u);
  EXPECT_EQ(errorOf(usdRecord("/Sky", "DomeLight", {{"inputs:texture:format", usdText("token", "cubeMapVerticalCross")}})),
            "/Sky.inputs:texture:format: \"cubeMapVerticalCross\" is not supported (use latlong)");
  EXPECT_EQ(errorOf(usdRecord("/Sky", "DomeLight", {{"inputs:texture:file", usdText("asset", "no/such.exr")}})),
            "/Sky.inputs:texture:file: \"no/such.exr\" cannot be found");
  EXPECT_EQ(errorOf(usdRecord("/L", "SphereLight", {{"inputs:color", usdNumbers("color3f", {1, 1})}})),
            "/L.inputs:color: has value (1, 1), expected 3 numbers");
  // A long value is cut for the message at a character's start, never inside a UTF-8
  // character (fuzz_usd_stage: the Python front end could not decode the message).
  const std::string word = "\xc3\xa9t\xc3\xa9";  // "été": 5 bytes, 3 characters
  std::string longText;
  for (int i = 0; i < 20; ++i) longText += word;
  const std::string e = errorOf(usdRecord("/L", "SphereLight", {{"inputs:intensity", usdText("token", longText)}}));
  const std::string shown = e.substr(e.find('\'') + 1, e.find("...") - e.find('\'') - 1);
  EXPECT_LE(shown.size(), 56u) << e;
  EXPECT_EQ(longText.compare(0, shown.size(), shown), 0) << e;
  EXPECT_NE((static_cast<unsigned char>(longText[shown.size()]) & 0xC0), 0x80u) << e;  // cut before a character
}

TEST(UsdLights, ASurfaceWithMeshLightApiIsAMeshLightTintedAsItsSyncModeSays) {
  // Its triangles come from the front end's MeshPrim (granular_prims.h): none yet.
  UsdWarnings w;
  for (const char* type : {"Mesh", "Sphere", "Cube"}) {
    const LightDesc l = *lightFromUsd(usdRecord("/Panel", type, {{"inputs:intensity", usdNumbers("float", {3})}}), w);
    EXPECT_EQ(l.type, LightType::Mesh) << type;
    EXPECT_FLOAT_EQ(l.intensity, 3.0f);
    EXPECT_TRUE(l.tintByMaterial);  // MeshLightAPI's fallback: materialGlowTintsLight
    EXPECT_TRUE(l.mesh.points.empty());
  }
  for (const char* mode : {"independent", "noMaterialResponse"})
    EXPECT_FALSE(lightFromUsd(usdRecord("/Panel", "Mesh", {{"light:materialSyncMode", usdText("token", mode)}}), w)
                     ->tintByMaterial)
        << mode;
  EXPECT_TRUE(w.empty());
  const LightDesc shaped =
      *lightFromUsd(usdRecord("/Panel", "Mesh", {{"inputs:shaping:cone:angle", usdNumbers("float", {20})}}), w);
  EXPECT_FALSE(shaped.shaping.enabled);
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0], "/Panel: ShapingAPI on a mesh light is not supported; ignored");
  EXPECT_EQ(errorOf(usdRecord("/Panel", "Mesh", {{"light:materialSyncMode", usdText("token", "glow")}})),
            "/Panel.light:materialSyncMode: \"glow\" is not one of materialGlowTintsLight, independent, "
            "noMaterialResponse");
  EXPECT_EQ(errorOf(usdRecord("/Panel", "Mesh", {{"inputs:intensity", usdNumbers("float", {-1})}})),
            "/Panel.inputs:intensity: -1 must be finite and >= 0");
}
