// The camera (tests mirror core/camera.*): the pinhole's rays and random numbers, and the
// thin lens of depth of field (CameraDesc::lensRadius, focusDistance).
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "core/camera.h"
#include "core/error.h"
#include "core/render.h"
#include "core/scene.h"
#include "core/scene_io.h"
#include "core/shapes.h"

using namespace granular;

namespace {

CameraDesc lookingDownMinusZ(float lensRadius, float focus) {
  CameraDesc c;
  c.cameraToWorld = Transform::lookAt(Vec3(0.3f, -0.2f, 4.0f), Vec3(0.3f, -0.2f, 0.0f), Vec3(0, 1, 0));
  c.focalLength = 35;
  c.horizontalAperture = 36;
  c.verticalAperture = 24;
  c.lensRadius = lensRadius;
  c.focusDistance = focus;
  return c;
}

}  // namespace

TEST(Camera, APinholeDrawsTwoNumbersPerRayAsBefore) {
  Camera cam(lookingDownMinusZ(0.0f, 1.0f), 64, 48);
  EXPECT_FALSE(cam.hasLens());
  Rng a(7, 0), b(7, 0);
  Ray r = cam.sampleRay(5, 9, a);
  // The former call, generateRay(x + u, y + u), drew y's jitter first (GCC evaluates
  // arguments right to left): pinhole renders keep the samples they had before the lens.
  float fy = 9.0f + b.next1D();
  float fx = 5.0f + b.next1D();
  Ray ref = cam.generateRay(fx, fy);
  EXPECT_EQ(a.next1D(), b.next1D());  // the streams stay in step: pinhole images keep their samples
  EXPECT_EQ(r.o, ref.o);
  EXPECT_EQ(r.d, ref.d);
  EXPECT_EQ(cam.coneWidth(), 0.0f);
  EXPECT_EQ(cam.coneSpread(), cam.pixelSpreadAngle());
}

TEST(Camera, ThinLensRaysMeetOnThePlaneInFocus) {
  const float radius = 0.2f, focus = 3.0f;
  Camera pin(lookingDownMinusZ(0.0f, focus), 64, 48), lens(lookingDownMinusZ(radius, focus), 64, 48);
  ASSERT_TRUE(lens.hasLens());
  Rng rng(3, 0);
  double sumR2 = 0;
  const int n = 4000;
  for (int i = 0; i < n; ++i) {
    float px = 64 * rng.next1D(), py = 48 * rng.next1D();
    Ray p = pin.generateRay(px, py), l = lens.generateRay(px, py, rng.next1D(), rng.next1D());
    // Where each ray reaches view depth `focus` (the camera looks down −Z from z = 4).
    Vec3 fp = p.o + p.d * ((4.0f - focus - p.o.z) / p.d.z), fl = l.o + l.d * ((4.0f - focus - l.o.z) / l.d.z);
    EXPECT_NEAR(length(fp - fl), 0.0f, 2e-5f * focus) << i;
    // The lens point: on the lens disk in the camera's plane.
    Vec3 off = l.o - pin.position();
    EXPECT_NEAR(off.z, 0.0f, 1e-6f);
    ASSERT_LE(length(off), radius * (1 + 1e-5f));
    sumR2 += double(length2(off));
    // The clip range stays along the view axis: tmin reaches view depth clipNear.
    EXPECT_NEAR((l.d * l.tmin).z, -lookingDownMinusZ(radius, focus).clipNear, 1e-7f);
  }
  // Uniform over the disk: E|o|² = r²/2, variance r⁴/12.
  const double mean = sumR2 / n, se = radius * radius / std::sqrt(12.0 * n);
  EXPECT_NEAR(mean, 0.5 * radius * radius, 4 * se);
  // The cone narrows to the pixel's footprint at the plane in focus.
  EXPECT_NEAR(lens.coneWidth() + lens.coneSpread() * focus, pin.pixelSpreadAngle() * focus, 1e-6f);
}

namespace {

// A small emissive square 6 units from a camera in the dark: its image with a lens focused
// at 2 units is a blur of the same total power (each lens point weighs the same).
double renderSquare(float lensRadius, double& peak, int& lit, double& se) {
  SceneDesc s;
  s.settings.width = 48;
  s.settings.height = 48;
  s.settings.spp = 64;
  s.settings.seed = 2;
  s.settings.defaultLight = false;
  s.settings.technique = Technique::Ept;
  s.camera = lookingDownMinusZ(lensRadius, 2.0f);
  s.camera.cameraToWorld = Transform::lookAt(Vec3(0, 0, 6), Vec3(0, 0, 0), Vec3(0, 1, 0));
  s.camera.horizontalAperture = s.camera.verticalAperture = 12;
  MaterialDesc glow;
  glow.name = "glow";
  glow.albedo = Vec3(0.0f);
  glow.emission = Vec3(1.0f);
  s.materials.push_back(glow);
  MeshDesc m;
  m.name = "square";
  m.mesh = makeBox(Vec3(-0.15f, -0.15f, -0.01f), Vec3(0.15f, 0.15f, 0.0f));
  m.material = 0;
  s.meshes.push_back(m);
  auto scene = Scene::build(s);
  Renderer r(*scene);
  EXPECT_TRUE(r.render(64));
  Image img = r.film().toImage();
  double sum = 0, var = 0;
  peak = 0;
  lit = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      double v = img.at(x, y)[1];
      sum += v;
      var += v * (1.0 - v) / 64.0;  // a sample sees the emitter (radiance 1) or not
      peak = std::max(peak, v);
      lit += v > 0.01;
    }
  se = std::sqrt(var);
  return sum;
}

}  // namespace

TEST(Camera, DefocusSpreadsAnEmittersLightWithoutLosingIt) {
  double peakPin, peakLens, sePin, seLens;
  int litPin, litLens;
  const double pin = renderSquare(0.0f, peakPin, litPin, sePin), lens = renderSquare(0.25f, peakLens, litLens, seLens);
  std::printf("square: pinhole sum %.3f ± %.3f (%d pixels, peak %.2f), lens sum %.3f ± %.3f (%d pixels, peak %.2f)\n",
              pin, sePin, litPin, peakPin, lens, seLens, litLens, peakLens);
  // The blur circle at 6 units of a lens of radius 0.25 focused at 2: 2·0.25·(6 − 2)/2 = 1
  // unit across, wider than the 0.3-unit square: more pixels, a lower peak.
  EXPECT_GT(litLens, 2 * litPin);
  EXPECT_LT(peakLens, 0.5 * peakPin);
  // Power: the square subtends a slightly smaller solid angle from lens points 0.25 off axis
  // (a cos³ factor, 0.26% at the rim), within three standard errors of the two renders.
  EXPECT_NEAR(lens, pin, 0.003 * pin + 3 * std::sqrt(sePin * sePin + seLens * seLens));
}

TEST(Camera, BadLensValuesAreRefusedByName) {
  SceneDesc s;
  s.camera = lookingDownMinusZ(-0.1f, 1.0f);
  try {
    validateSceneDesc(s);
    FAIL() << "a negative lens radius passed";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("camera.lensRadius"), std::string::npos) << e.what();
  }
  s.camera = lookingDownMinusZ(0.1f, 0.0f);
  try {
    validateSceneDesc(s);
    FAIL() << "a lens focused at 0 passed";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("camera.focusDistance"), std::string::npos) << e.what();
  }
  // JSON: UsdGeomCamera's fStop and focusDistance, the radius from the focal length.
  SceneDesc j = parseSceneJson(R"({"camera": {"focal_length": 50, "f_stop": 2.5, "focus_distance": 3}})", "test");
  EXPECT_FLOAT_EQ(j.camera.lensRadius, 0.05f * 50 / 2.5f);
  EXPECT_FLOAT_EQ(j.camera.focusDistance, 3.0f);
  for (const char* bad : {R"({"camera": {"f_stop": -1}})", R"({"camera": {"f_stop": 2, "focus_distance": 0}})",
                          R"({"camera": {"f_stop": 1e-15, "focus_distance": 0.1}})"}) {
    try {
      parseSceneJson(bad, "test");
      FAIL() << bad;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("camera.f"), std::string::npos) << e.what();
    }
  }
}

// No lens in air is faster than f/0.5: a wider lens (an fStop of 1e-15 once made camera
// rays start 10^15 units away and aborted the process inside Embree) is refused, whoever
// sets the radius.
TEST(Camera, ALensWiderThanFHalfIsRefused) {
  EXPECT_FLOAT_EQ(checkedLensRadius(50, 0.5f, "/World/Camera", "fStop"), 0.05f * 50 / 0.5f);
  EXPECT_EQ(checkedLensRadius(50, 0, "/World/Camera", "fStop"), 0.0f);
  for (float bad : {1e-15f, 0.49f, -1.0f, std::numeric_limits<float>::quiet_NaN()}) {
    try {
      checkedLensRadius(50, bad, "/World/Camera", "fStop");
      FAIL() << bad;
    } catch (const InputError& e) {
      EXPECT_EQ(e.object(), "/World/Camera");
      EXPECT_EQ(e.attribute(), "fStop");
    }
  }
  SceneDesc d;
  d.camera.focalLength = 50;
  d.camera.focusDistance = 1;
  d.camera.lensRadius = lensRadiusFromFStop(50, 0.5f);
  EXPECT_NO_THROW(validateSceneDesc(d));
  d.camera.lensRadius = lensRadiusFromFStop(50, 1e-15f);
  EXPECT_THROW(validateSceneDesc(d), InputError);
}
