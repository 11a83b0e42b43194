// test_usd_lights.cpp — UsdLux lights on plain records: fallbacks per type, colour
// temperature, what is skipped or warned about, and errors named prim.attribute.
#include <gtest/gtest.h>

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

TEST(UsdLights, OtherTypesAndUnsupportedAttributesAreWarnedAbout) {
  UsdWarnings w;
  EXPECT_FALSE(lightFromUsd(usdRecord("/Disk", "DiskLight"), w));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0], "/Disk: DiskLight lights are not supported; skipped");
  w.clear();
  EXPECT_TRUE(lightFromUsd(usdRecord("/Bulb", "SphereLight", {{"treatAsPoint", usdNumbers("bool", {1})}}), w));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0], "/Bulb.treatAsPoint: not supported; rendered as a sphere of inputs:radius");
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
}
