// test_usd_camera.cpp — UsdGeomCamera on a plain record: fallbacks, the thin lens, and
// errors named prim.attribute.
#include <gtest/gtest.h>

#include "core/error.h"
#include "core/usd_camera.h"
#include "usd_records.h"

using namespace granular;
using namespace granular::test;

namespace {

std::string errorOf(const UsdPrimRecord& r) {
  return inputErrorOf([&] { cameraFromUsd(r); });
}

}  // namespace

TEST(UsdCamera, UnauthoredValuesTakeUsdGeomCameraFallbacks) {
  const CameraDesc c = cameraFromUsd(usdRecord("/Cam", "Camera"));
  EXPECT_FLOAT_EQ(c.focalLength, 50.0f);
  EXPECT_FLOAT_EQ(c.horizontalAperture, 20.955f);
  EXPECT_FLOAT_EQ(c.verticalAperture, 15.2908f);
  EXPECT_FLOAT_EQ(c.horizontalApertureOffset, 0.0f);
  EXPECT_FLOAT_EQ(c.clipNear, 1.0f);
  EXPECT_FLOAT_EQ(c.clipFar, 1000000.0f);
  EXPECT_FLOAT_EQ(c.lensRadius, 0.0f);
}

TEST(UsdCamera, FStopAndFocusDistanceMakeTheThinLens) {
  const CameraDesc c = cameraFromUsd(usdRecord("/Cam", "Camera",
                                               {{"focalLength", usdNumbers("float", {35})},
                                                {"fStop", usdNumbers("float", {2})},
                                                {"focusDistance", usdNumbers("float", {7})},
                                                {"clippingRange", usdNumbers("float2", {0.1, 50})}}));
  EXPECT_FLOAT_EQ(c.lensRadius, lensRadiusFromFStop(35.0f, 2.0f));
  EXPECT_FLOAT_EQ(c.focusDistance, 7.0f);
  EXPECT_FLOAT_EQ(c.clipNear, 0.1f);
  EXPECT_FLOAT_EQ(c.clipFar, 50.0f);
}

TEST(UsdCamera, BadValuesNameThePrimAndItsAttribute) {
  EXPECT_EQ(errorOf(usdRecord("/Cam", "Camera", {{"projection", usdText("token", "orthographic")}})),
            "/Cam.projection: orthographic cameras are not supported (use perspective)");
  EXPECT_EQ(errorOf(usdRecord("/Cam", "Camera", {{"fStop", usdNumbers("float", {2})}})),
            "/Cam.focusDistance: 0 must be > 0 when fStop is set");
  EXPECT_EQ(errorOf(usdRecord("/Cam", "Camera", {{"fStop", usdNumbers("float", {0.2})}})).rfind("/Cam.fStop: 0.2 is below", 0),
            0u);
  EXPECT_EQ(errorOf(usdRecord("/Cam", "Camera", {{"clippingRange", usdNumbers("float", {1})}})),
            "/Cam.clippingRange: has value 1, expected 2 numbers");
}
