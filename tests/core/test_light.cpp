// Lights: numerical robustness of sampling and MIS for extreme geometry (tests mirror
// core/light.* and the MIS helper in core/sampling.h).
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>

#include "core/ies.h"
#include "core/image_io.h"
#include "core/light.h"
#include "core/render.h"
#include "core/sampling.h"
#include "core/scene.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;
using granular::testing::ChannelEstimate;
using granular::testing::imageEstimates;
using granular::testing::renderImage;

TEST(Light, PowerHeuristicSurvivesHugePdfs) {
  EXPECT_FLOAT_EQ(powerHeuristic(1.0f, 1.0f), 0.5f);
  EXPECT_NEAR(powerHeuristic(3.0f, 1.0f), 0.9f, 1e-6f);
  EXPECT_NEAR(powerHeuristic(1.0f, 3.0f), 0.1f, 1e-6f);
  // Squares of 1e20 overflowed to inf / inf = NaN.
  EXPECT_FLOAT_EQ(powerHeuristic(1e20f, 1.0f), 1.0f);
  EXPECT_NEAR(powerHeuristic(1.0f, 1e20f), 0.0f, 1e-30f);
  EXPECT_FLOAT_EQ(powerHeuristic(1e30f, 1e30f), 0.5f);
  EXPECT_FLOAT_EQ(powerHeuristic(kInf, 2.0f), 1.0f);
  EXPECT_FLOAT_EQ(powerHeuristic(0.0f, 0.0f), 0.0f);
  EXPECT_FLOAT_EQ(powerHeuristic(2.0f, 0.0f), 1.0f);
}

TEST(Light, SmallSphereFarAwaySamplesFiniteAndConsistent) {
  // radius 0.5 at distance 5000: sin² = 1e-8, below float's resolution around 1, so
  // cosMax rounded to 1 and the cone pdf was 1/0 (every sample NaN: a black image).
  LightDesc d;
  d.type = LightType::Sphere;
  d.radius = 0.5f;
  d.xf = Transform::translate(Vec3(0, 5000, 0));
  Light l = Light::fromDesc(d);
  const double sin2 = 0.25 / (5000.0 * 5000.0);
  const double solidAngle = 2 * 3.14159265358979 * sin2 / (1 + std::sqrt(1 - sin2));
  Rng rng(1);
  for (int i = 0; i < 100; ++i) {
    LightSample s;
    ASSERT_TRUE(l.sampleLi(Vec3(0.0f), rng.next1D(), rng.next1D(), s));
    ASSERT_TRUE(isFinite(s.wi) && std::isfinite(s.pdf) && s.pdf > 0);
    EXPECT_NEAR(s.pdf * solidAngle, 1.0, 1e-6);
    EXPECT_NEAR(l.pdfLi(Vec3(0.0f), s.wi, s.dist) * solidAngle, 1.0, 1e-6);
    EXPECT_GT(s.wi.y, 0.999999f);
    EXPECT_NEAR(s.dist, 4999.5f, 0.5f);
  }
}

namespace {

// An 8 × 8 EPT image, spp samples, of a floor (10 × 10, its top at y = 0; the default
// surface, Lambert of albedo 0.5) straight below the camera, whose view it fills. No light.
SceneDesc floorFromAbove(int spp) {
  SceneDesc s;
  s.settings.width = s.settings.height = 8;
  s.settings.spp = spp;
  s.settings.technique = Technique::Ept;
  s.camera.cameraToWorld = Transform::lookAt(Vec3(0, 2, 0), Vec3(0.0f), Vec3(0, 0, -1));
  s.camera.horizontalAperture = s.camera.verticalAperture = 10;
  MeshDesc floor;
  floor.name = "floor";
  floor.mesh = makeBox(Vec3(-5, -0.1f, -5), Vec3(5, 0, 5));
  s.meshes.push_back(floor);
  return s;
}

// A sun of `angle` degrees at the zenith, shining down on the floor.
LightDesc zenithSun(float angle, float intensity) {
  LightDesc sun;
  sun.name = "sun";
  sun.type = LightType::Distant;
  sun.angle = angle;
  sun.intensity = intensity;
  sun.xf = Transform::lookAt(Vec3(0.0f), Vec3(0, -1, 0), Vec3(0, 0, 1));
  return sun;
}

// A uniform dome.
LightDesc uniformSky(float intensity) {
  LightDesc sky;
  sky.name = "sky";
  sky.type = LightType::Dome;
  sky.intensity = intensity;
  return sky;
}

// A sphere light centred at `at`.
LightDesc sphereLight(const std::string& name, float radius, float intensity, const Vec3& at) {
  LightDesc bulb;
  bulb.name = name;
  bulb.type = LightType::Sphere;
  bulb.radius = radius;
  bulb.intensity = intensity;
  bulb.xf = Transform::translate(at);
  return bulb;
}

}  // namespace

TEST(Light, FloorUnderASmallSphereFarAwayHasTheAnalyticRadiance) {
  // A Lambert floor (albedo ρ) straight under a sphere of radiance L, radius r, at
  // height h: E = L π r²/h², so the floor's radiance is ρ L r²/h² (here 0.5 x 1e8 x 1e-8).
  SceneDesc s = floorFromAbove(16);
  s.lights.push_back(sphereLight("far bulb", 0.5f, 1e8f, Vec3(0, 5000, 0)));
  auto scene = Scene::build(s);
  Renderer r(*scene);
  ASSERT_TRUE(r.render(16));
  EXPECT_EQ(r.nonFiniteSamples(), 0);
  for (int y = 0; y < 8; ++y)
    // Light sampling leaves almost no variance here (cos θ ≥ 1 − 1e-9, MIS weight ≈ 1):
    // the standard error and float rounding bound the error (measuring to the sphere's
    // near surface instead of its centre would be off by 2e-4).
    for (int x = 0; x < 8; ++x)
      EXPECT_NEAR(r.film().mean(x, y).x, 0.5f, 4 * r.film().stdError(x, y) + 1e-5f) << x << "," << y;
}

TEST(Light, NormalisedTinyLightsOfZeroIntensityAreBlackNotNaN) {
  // The area of a sphere of radius 6e-37 underflows a float: 0 / 0 was NaN (USD fuzzer).
  LightDesc d;
  d.type = LightType::Sphere;
  d.radius = 5.7e-37f;
  d.intensity = 0;
  d.normalize = true;
  d.xf = Transform::translate(Vec3(0, 2, 0));
  LightSample s;
  Light sphere = Light::fromDesc(d);
  ASSERT_TRUE(sphere.sampleLi(Vec3(0.0f), 0.5f, 0.5f, s));
  EXPECT_TRUE(s.Li.x == 0 && s.Li.y == 0 && s.Li.z == 0) << s.Li.x;
  d.type = LightType::Rect;
  d.width = d.height = 1e-25f;
  Light rect = Light::fromDesc(d);
  Vec3 Le = rect.areaLe(Vec3(0, 2, 0), Vec3(0, 1, 0));
  EXPECT_TRUE(Le.x == 0 && Le.y == 0 && Le.z == 0) << Le.x;
  // A finite normalised light keeps its meaning: intensity is the power per area.
  d.type = LightType::Sphere;
  d.radius = 0.5f;
  d.intensity = kPi;
  Light unit = Light::fromDesc(d);
  EXPECT_NEAR(unit.areaLe(Vec3(0, 1.5f, 0), Vec3(0, 1, 0)).x, 1.0f, 1e-6f);  // π / (4π 0.25)
}

// ---- the dome's lat-long orientation ----------------------------------------------------

TEST(DomeTexture, IsOrientedAsUsdLuxStatesItAndSampledAsItIsLookedUp) {
  // UsdLuxDomeLight (after the OpenEXR specification; Storm draws it so): the image's top row
  // is the zenith (+Y), longitude 0 (+Z) its middle column, +π/2 (+X) its first quarter,
  // −π/2 (−X) its third, ±π (−Z) its left and right edges. A 16 × 8 texture whose red is
  // its column and green its row names the texel every direction reads.
  const std::string file = ::testing::TempDir() + "columns_rows.exr";
  Image img(16, 8, {"R", "G", "B"});
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 16; ++x) {
      img.at(x, y)[0] = float(x) + 1;
      img.at(x, y)[1] = float(y) + 1;
      img.at(x, y)[2] = 1;
    }
  writeExr(file, img);
  LightDesc d;
  d.type = LightType::Dome;
  d.textureFile = file;
  const Light dome = Light::fromDesc(d);
  auto texel = [&](const Vec3& dir) {
    const Vec3 L = dome.escapedLe(normalize(dir));
    return std::make_pair(int(L.x) - 1, int(L.y) - 1);
  };
  EXPECT_EQ(texel(Vec3(0.1f, 1, 0.1f)).second, 0);             // the zenith: the top row
  EXPECT_EQ(texel(Vec3(0.1f, -1, 0.1f)).second, 7);            // the nadir: the bottom row
  EXPECT_EQ(texel(Vec3(0.1f, 0.1f, 1)), std::make_pair(7, 3));   // +Z: the middle (u 0.484)
  EXPECT_EQ(texel(Vec3(1, 0.1f, 0.1f)), std::make_pair(4, 3));   // +X: the first quarter (0.266)
  EXPECT_EQ(texel(Vec3(-1, 0.1f, 0.1f)), std::make_pair(11, 3)); // −X: the third (0.734)
  EXPECT_EQ(texel(Vec3(0.1f, 0.1f, -1)), std::make_pair(0, 3));  // −Z: the edge (0.016)
  // Light sampling draws directions by the texels' luminance and reads them back the same
  // way: each sample's radiance is the texel of its direction, its pdf pdfLi's.
  Rng rng(5);
  for (int i = 0; i < 2000; ++i) {
    LightSample s;
    if (!dome.sampleLi(Vec3(0.0f), rng.next1D(), rng.next1D(), s)) continue;
    const Vec3 L = dome.escapedLe(s.wi);
    EXPECT_EQ(L.x, s.Li.x) << i;
    EXPECT_EQ(L.y, s.Li.y) << i;
    // The pdf's 1 / sin θ: near the poles acos loses digits on the way back, so there the
    // round trip is only good to a few percent.
    if (std::fabs(s.wi.y) < 0.95f) EXPECT_NEAR(dome.pdfLi(Vec3(0.0f), s.wi, kInf), s.pdf, 1e-3f * s.pdf) << i;
  }
}

// ---- a constant dome over a reflecting surface (Light::sampleLi's `above`) ----------------

TEST(ConstantDome, AboveAReflectingSurfaceItIsSampledOverTheHemisphereByCosine) {
  const Light dome = Light::fromDesc(uniformSky(2.0f));
  const Vec3 n = normalize(Vec3(0.3f, 1.0f, -0.2f));
  Rng rng(11);
  const int count = 4096;
  double pdfSum = 0;
  for (int i = 0; i < count; ++i) {
    LightSample s;
    ASSERT_TRUE(dome.sampleLi(Vec3(0.0f), rng.next1D(), rng.next1D(), s, n));
    const float c = dot(s.wi, n);
    ASSERT_GT(c, 0.0f) << i;  // never below the surface
    EXPECT_NEAR(s.pdf, c / kPi, 1e-5f) << i;
    EXPECT_NEAR(dome.pdfLi(Vec3(0.0f), s.wi, kInf, n), s.pdf, 1e-6f) << i;
    // What a reflection takes from it, Li cos / pdf, is the irradiance π L in every sample.
    EXPECT_NEAR(s.Li.x * c / s.pdf, 2.0 * kPiD, 1e-4) << i;
    // Uniform directions: the pdf integrates to 1 over the sphere.
    pdfSum += dome.pdfLi(Vec3(0.0f), sampleUniformSphere(rng.next1D(), rng.next1D()), kInf, n) / kUniformSpherePdf;
  }
  // pdf / (1/4π) is 4 cos θ on half the sphere: mean 1, standard deviation √(8/3 − 1).
  EXPECT_NEAR(pdfSum / count, 1.0, 4 * std::sqrt(8.0 / 3.0 - 1.0) / std::sqrt(double(count)));
  // Without a surface (a medium, a grain that transmits): the whole sphere.
  LightSample s;
  ASSERT_TRUE(dome.sampleLi(Vec3(0.0f), 0.3f, 0.9f, s));
  EXPECT_EQ(s.pdf, kUniformSpherePdf);
  EXPECT_EQ(dome.pdfLi(Vec3(0.0f), Vec3(0, -1, 0), kInf), kUniformSpherePdf);
  EXPECT_EQ(dome.pdfLi(Vec3(0.0f), -n, kInf, n), 0.0f);
}

TEST(ConstantDome, AFloorUnderItHasTheExactRadianceInEverySample) {
  // Light and BSDF sampling both draw cos θ / π over the floor's hemisphere, so each
  // strategy's sample, weighted by MIS, is ρ L / 2, whatever its direction: the floor's
  // radiance ρ L without noise. The dome sampled over the sphere (half its samples below
  // the floor) or weighed at an escape with another pdf than it was sampled with would
  // leave noise or a bias.
  SceneDesc d = floorFromAbove(16);
  d.lights = {uniformSky(0.8f)};
  auto scene = Scene::build(d);
  Renderer r(*scene);
  ASSERT_TRUE(r.render(d.settings.spp));
  EXPECT_EQ(r.nonFiniteSamples(), 0);
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 8; ++x) {
      EXPECT_NEAR(r.film().mean(x, y).x, 0.5f * 0.8f, 1e-5f) << x << "," << y;
      // Float rounding alone (the dome over the sphere: about 0.01 here).
      EXPECT_LT(r.film().stdError(x, y), 1e-4f) << x << "," << y;
    }
}

// ---- which light next-event estimation samples (Light::pickWeight, Scene::lightPick) ----

TEST(LightPick, WeightsAreIrradianceTimesTheRootOfConcentration) {
  const double pi = kPiD, tol = 1e-6;  // float radiance and cone angles against double
  auto weight = [](const LightDesc& d, const Vec3& at) { return Light::fromDesc(d).pickWeight(at); };
  // A sun of 20°, radiance 14 (grey): E = 14 Ω, Ω = 2π (1 − cos 10°).
  LightDesc sun;
  sun.type = LightType::Distant;
  sun.angle = 20;
  sun.intensity = 14;
  const double omegaSun = 2 * pi * (1 - std::cos(10 * pi / 180));
  EXPECT_NEAR(weight(sun, Vec3(0.0f)), 14 * omegaSun * std::sqrt(4 * pi / omegaSun), tol * 14);
  // The same irradiance normalised over the 0.53° sun: its weight grows as 1/√Ω.
  sun.angle = 0.53f;
  sun.normalize = true;
  const double omegaNarrow = 2 * pi * (1 - std::cos(0.265 * pi / 180));
  EXPECT_NEAR(weight(sun, Vec3(0.0f)) / (14 * std::sqrt(4 * pi / omegaNarrow)), 1.0, 1e-4);
  // A delta sun: its intensity is E, its Ω the widest cone still a delta (1 − cos = 1e-7).
  sun.angle = 0;
  EXPECT_NEAR(weight(sun, Vec3(0.0f)) / (14 * std::sqrt(4 * pi / (2 * pi * 1e-7))), 1.0, 1e-6);
  sun.intensity = 0;
  EXPECT_EQ(weight(sun, Vec3(0.0f)), 0.0);
  // A sphere of radius 0.5 seen from 10 away, and from inside (Ω = 2π, the half space).
  const LightDesc bulb = sphereLight("", 0.5f, 3, Vec3(0, 10, 0));
  const double omegaBulb = 2 * pi * (1 - std::sqrt(1 - 0.25 / 100));
  EXPECT_NEAR(weight(bulb, Vec3(0.0f)) / (3 * std::sqrt(4 * pi * omegaBulb)), 1.0, 1e-4);
  EXPECT_NEAR(weight(bulb, Vec3(0, 10.1f, 0)) / (3 * std::sqrt(4 * pi * 2 * pi)), 1.0, 1e-6);
  // A rect of 2 × 1 facing a point 5 away: Ω ≈ area / d².
  LightDesc panel;
  panel.type = LightType::Rect;
  panel.width = 2;
  panel.height = 1;
  panel.intensity = 2;
  panel.xf = Transform::translate(Vec3(0, 0, 5));
  EXPECT_NEAR(weight(panel, Vec3(0.0f)) / (2 * std::sqrt(4 * pi * 2.0 / 25)), 1.0, 1e-5);
  // A uniform dome: E = π L over Ω = 4π.
  LightDesc sky;
  sky.type = LightType::Dome;
  sky.color = Vec3(0.6f, 0.75f, 1.0f);
  sky.intensity = 0.8f;
  EXPECT_NEAR(weight(sky, Vec3(0.0f)), pi * 0.8 * (0.6 + 0.75 + 1.0) / 3, tol);
  // A textured dome lit over its upper half: mean L/2, mean square L²/2, so Ω = 2π and
  // E √(4π/Ω) = π L / √2, the rms radiance's π.
  const std::string file = ::testing::TempDir() + "half_sky.exr";
  Image half(16, 8, {"R", "G", "B"});
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 16; ++x)
      for (int c = 0; c < 3; ++c) half.at(x, y)[c] = 1.0f;
  writeExr(file, half);  // throws on failure
  sky.color = Vec3(1.0f);
  sky.intensity = 2;
  sky.textureFile = file;
  EXPECT_NEAR(weight(sky, Vec3(0.0f)), pi * 2 / std::sqrt(2.0), 1e-5);
}

namespace {

// The floor (albedo 0.5) under a 20° sun at the zenith (radiance 10) and a uniform dome of
// radiance 0.5, nothing else: its radiance is ρ/π (E_sun + π L_dome), E_sun = L_sun π
// sin²(10°) (a cone about the normal); a zero-intensity bulb under the floor, where it hides
// nothing.
SceneDesc sunSkyAndBlackBulb() {
  SceneDesc d = floorFromAbove(64);
  d.lights = {zenithSun(20, 10), uniformSky(0.5f), sphereLight("black bulb", 0.5f, 0, Vec3(0, -3, 0))};
  return d;
}

}  // namespace

TEST(LightPick, TheScenePicksInProportionAndNeverABlackLight) {
  SceneDesc d = sunSkyAndBlackBulb();
  auto scene = Scene::build(d);
  const Vec3 ref = Vec3(0.0f, -0.05f, 0.0f);  // the floor's centre
  const double w0 = scene->lights()[0].pickWeight(ref), w1 = scene->lights()[1].pickWeight(ref);
  EXPECT_NEAR(scene->lightPick(0), w0 / (w0 + w1), 1e-6);
  EXPECT_NEAR(scene->lightPick(1), w1 / (w0 + w1), 1e-6);
  EXPECT_EQ(scene->lightPick(2), 0.0f);
  EXPECT_GT(scene->lightPick(0), 0.5f);  // the sun: 10 × √(4π Ω) = 3.9 against the sky's π/2
  // pickLight over a fine grid of u: each light as often as its chance, the black bulb never.
  const int n = 1 << 16;
  int count[3] = {0, 0, 0};
  for (int i = 0; i < n; ++i) ++count[scene->pickLight((i + 0.5f) / n)];
  for (int l = 0; l < 3; ++l) EXPECT_NEAR(double(count[l]) / n, scene->lightPick(l), 2.0 / n) << "light " << l;
  // No light with a weight: every one alike.
  for (auto& l : d.lights) l.intensity = 0;
  auto dark = Scene::build(d);
  for (int l = 0; l < 3; ++l) EXPECT_NEAR(dark->lightPick(l), 1.0f / 3, 1e-6f);
}

TEST(LightPick, AFloorUnderASunAndADomeHasTheAnalyticRadiance) {
  // Light sampling by the weights, BSDF sampling, and their MIS weights (which use the same
  // chances) add up to the exact radiance: ρ/π (L_sun π sin²(10°) + π L_dome).
  SceneDesc d = sunSkyAndBlackBulb();
  auto scene = Scene::build(d);
  Renderer r(*scene);
  ASSERT_TRUE(r.render(d.settings.spp));
  EXPECT_EQ(r.nonFiniteSamples(), 0);
  const double s = std::sin(10 * kPiD / 180), expected = 0.5 / kPiD * (10 * kPiD * s * s + kPiD * 0.5);
  const ChannelEstimate e = imageEstimates(r.film().toImage(), {{0, 8, 0, 8}})[0];
  EXPECT_GT(e.se[0], 0.0);
  EXPECT_NEAR(e.mean[0], expected, 4 * e.se[0]) << "se " << e.se[0];
}

// ---- area lights block shadow rays as they end BSDF rays --------------------------------

TEST(AreaLightOcclusion, EveryShadowRayStopsWhereARayWouldEnd) {
  // A black bulb (sphere, radius 1, at y = 2) and a rect light at z = 5 emitting toward −z.
  SceneDesc d = floorFromAbove(4);
  LightDesc panel;
  panel.name = "panel";
  panel.type = LightType::Rect;
  panel.width = panel.height = 2;
  panel.xf = Transform::translate(Vec3(0, 1.5f, 5));
  d.lights = {sphereLight("bulb", 1, 0, Vec3(0, 2, 0)), panel};
  auto scene = Scene::build(d);
  const Vec3 up(0, 1, 0), along(0, 0, 1);
  // Through the bulb from the floor: blocked for every kind of shadow ray; beside it, not.
  EXPECT_TRUE(scene->occluded(Vec3(0, 0.01f, 0), up, kInf));
  EXPECT_TRUE(isBlack(scene->transmittance(Vec3(0, 0.01f, 0), up, kInf)));
  EXPECT_EQ(scene->proxyTransmittance(Vec3(0, 0.01f, 0), up, kInf, nullptr, 1).unscattered, 0.0f);
  EXPECT_FALSE(scene->occluded(Vec3(1.5f, 0.01f, 0), up, kInf));
  // Short of the bulb: not blocked.
  EXPECT_FALSE(scene->occluded(Vec3(0, 0.01f, 0), up, 0.9f));
  // The panel blocks from its emitting side only (its back neither emits nor blocks).
  EXPECT_TRUE(scene->occluded(Vec3(0, 1.5f, 0), along, 10));
  EXPECT_FALSE(scene->occluded(Vec3(0, 1.5f, 10), -along, 6));
  // A shadow ray toward a point sampled on a light, shortened as the integrators shorten
  // it, is not blocked by that light itself.
  for (int i = 0; i < 64; ++i) {
    LightSample ls;
    const Vec3 p(0.3f, 0.01f, -0.2f);
    ASSERT_TRUE(scene->lights()[1].sampleLi(p, (i + 0.5f) / 64, ((i * 37) % 64 + 0.5f) / 64, ls));
    EXPECT_FALSE(scene->occluded(p, ls.wi, ls.dist * (1.0f - 1e-4f))) << i;
  }
}

TEST(AreaLightOcclusion, AFloorUnderADomeASunAndABlackBulbHasTheAnalyticRadiance) {
  // The floor (albedo ρ = 0.5) under a uniform dome of radiance 1 and a 20° sun at the
  // zenith, with a black bulb of radius r = 1 centred on the camera, 2 above the floor (a
  // camera ray starts inside the sphere, which does not stop it). From every floor point in
  // view the bulb hides the whole sun (its half-angle is 30°, the sun's 10°, 8° off at
  // most) and the projected solid angle π (r/δ)² cos θ of the dome (a sphere wholly above
  // the horizon; δ the distance to its centre, cos θ = 2/δ), so the floor's radiance is
  // ρ (1 − (r/δ)² cos θ): 0.375 under the bulb's centre. With shadow rays crossing the bulb
  // and BSDF rays stopping on it, light sampling found the sun through it.
  SceneDesc d = floorFromAbove(256);
  d.lights = {uniformSky(1), zenithSun(20, 10), sphereLight("bulb", 1, 0, Vec3(0, 2, 0))};
  auto scene = Scene::build(d);
  Renderer r(*scene);
  ASSERT_TRUE(r.render(d.settings.spp));
  EXPECT_EQ(r.nonFiniteSamples(), 0);
  // The camera (focal length 50, aperture 10) sees the floor over [−0.2, 0.2]²; the exact
  // image mean by the midpoint rule over it (its integrand is smooth: error < 1e-6).
  double expected = 0;
  const int n = 200;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const double x = -0.2 + 0.4 * (i + 0.5) / n, z = -0.2 + 0.4 * (j + 0.5) / n;
      const double delta = std::sqrt(x * x + z * z + 4);
      expected += 0.5 * (1 - 2 / (delta * delta * delta)) / (n * n);
    }
  const ChannelEstimate e = imageEstimates(r.film().toImage(), {{0, 8, 0, 8}})[0];
  EXPECT_GT(e.se[0], 0.0);
  EXPECT_NEAR(e.mean[0], expected, 4 * e.se[0]) << "se " << e.se[0];
}

// ---- disk and cylinder lights, and shaping ----------------------------------------------

namespace {

// A disk of radius r centred at `at`, emitting straight down (its local −Z to world −Y).
LightDesc diskLight(const std::string& name, float r, float intensity, const Vec3& at) {
  LightDesc d = sphereLight(name, r, intensity, at);
  d.type = LightType::Disk;
  d.xf = Transform::lookAt(at, at - Vec3(0, 1, 0), Vec3(0, 0, 1));
  return d;
}

// A cylinder of radius r and length len along world X, centred at `at`.
LightDesc cylinderLight(const std::string& name, float r, float len, float intensity, const Vec3& at) {
  LightDesc d = sphereLight(name, r, intensity, at);
  d.type = LightType::Cylinder;
  d.length = len;
  return d;
}

// UsdLuxShapingAPI's factor for an emission direction θ off the axis and |n·ω| = c, as the
// schema states it (LightShaping, scene_desc.h), written out here on its own.
double shapingFactor(const LightShaping& s, double theta, double c) {
  const double cone = s.coneAngle * kPiD / 180, smooth = cone * (1 - s.coneSoftness);
  if (theta > cone) return 0;
  double f = 1;
  if (theta > smooth) {
    const double x = (cone - theta) / (cone - smooth);
    f = x * x * (3 - 2 * x);
  }
  return f * (s.focusTint.x + (1 - s.focusTint.x) * std::pow(c, s.focus));
}

// The mean radiance of the floor in floorFromAbove's view ([−0.2, 0.2]² of y = 0, albedo
// 0.5) under one area light of radiance 1: ρ/π ∫ cos θ_p cos θ_l / d² dA by the midpoint
// rule, over n × n floor points and the light's surface as `emitters` gives it (points,
// their normals, their areas); times the shaping's factor, and `weight` of the unit
// emission direction.
template <class Emitters>
double floorRadiance(const Emitters& emitters, int n, const LightShaping* shaping = nullptr,
                     const Vec3& axis = Vec3(0, -1, 0),
                     const std::function<double(double, double, double)>& weight = {}) {
  double sum = 0;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const double x = -0.2 + 0.4 * (i + 0.5) / n, z = -0.2 + 0.4 * (j + 0.5) / n;
      double E = 0;
      emitters([&](double qx, double qy, double qz, double nx, double ny, double nz, double dA) {
        const double wx = x - qx, wy = -qy, wz = z - qz, d = std::sqrt(wx * wx + wy * wy + wz * wz);
        const double cosL = (nx * wx + ny * wy + nz * wz) / d, cosP = qy / d;
        if (cosL <= 0 || cosP <= 0) return;
        double f = 1;
        if (shaping) {
          const double ca = (axis.x * wx + axis.y * wy + axis.z * wz) / d;
          f = shapingFactor(*shaping, std::acos(std::clamp(ca, -1.0, 1.0)), cosL);
        }
        if (weight) f *= weight(wx / d, wy / d, wz / d);
        E += f * cosL * cosP / (d * d) * dA;
      });
      sum += 0.5 / kPiD * E;
    }
  return sum / (n * n);
}

// A disk of radius r at height h over (cx, cz), facing down, in m × m polar cells.
auto diskEmitters(double r, double h, double cx, double cz, int m) {
  return [=](auto&& f) {
    for (int a = 0; a < m; ++a)
      for (int b = 0; b < m; ++b) {
        const double rho0 = r * a / m, rho1 = r * (a + 1) / m, phi = 2 * kPiD * (b + 0.5) / m;
        const double rho = 0.5 * (rho0 + rho1), dA = 0.5 * (rho1 * rho1 - rho0 * rho0) * 2 * kPiD / m;
        f(cx + rho * std::cos(phi), h, cz + rho * std::sin(phi), 0.0, -1.0, 0.0, dA);
      }
  };
}

// A render of floorFromAbove under `lights` against the floor radiance expected.
void expectFloorRadiance(const std::vector<LightDesc>& lights, double expected, int spp) {
  SceneDesc d = floorFromAbove(spp);
  d.lights = lights;
  auto scene = Scene::build(d);
  Renderer r(*scene);
  ASSERT_TRUE(r.render(d.settings.spp));
  EXPECT_EQ(r.nonFiniteSamples(), 0);
  const ChannelEstimate e = imageEstimates(r.film().toImage(), {{0, 8, 0, 8}})[0];
  EXPECT_GT(e.se[0], 0.0);
  // The midpoint rules' own error: within 7e-5 of the expected (against 3 × their cells).
  EXPECT_NEAR(e.mean[0], expected, 4 * e.se[0] + 2e-4 * expected) << "se " << e.se[0];
}

// Light l sampled from p at the midpoints of an m × m grid of (u1, u2): every stride-th
// sample accepted meets the light at its distance (intersect), where pdfLi agrees with its
// pdf (1 / pdf, its weight, within pdfTolerance of the largest) and areaLe with its
// radiance; and pdfLi integrates over the directions that meet the light, drawn uniform in
// the cone about the sphere (c, R) that bounds it, to the share of samples accepted (uniform
// directions against stratified points: two ways of measuring one area; the share on the
// grid is exact but for the cells its edge crosses: within 2 / m). Returns that share.
double expectSamplesMeetTheLight(const Light& l, const std::string& name, const Vec3& p, int m, int stride,
                                 float pdfTolerance, const Vec3& c, double R, uint64_t seed) {
  int accepted = 0;
  float largestWeight = 0;
  std::vector<LightSample> checked;
  for (int i = 0; i < m; ++i)
    for (int j = 0; j < m; ++j) {
      LightSample s;
      if (!l.sampleLi(p, (i + 0.5f) / m, (j + 0.5f) / m, s)) continue;
      ++accepted;
      largestWeight = std::max(largestWeight, 1.0f / s.pdf);
      if ((i * m + j) % stride == 0) checked.push_back(s);
    }
  EXPECT_GT(checked.size(), 1000u) << name;
  for (const LightSample& s : checked) {
    float t = 0;
    if (!l.intersect(Ray{p, s.wi, 1e-4f, kInf}, t)) {
      ADD_FAILURE() << name << ": a sample's direction misses the light";
      break;
    }
    EXPECT_NEAR(t, s.dist, 1e-4f * s.dist) << name;
    EXPECT_NEAR(1.0f / l.pdfLi(p, s.wi, t), 1.0f / s.pdf, pdfTolerance * largestWeight) << name;
    EXPECT_EQ(l.areaLe(p + s.wi * t, s.wi).x, s.Li.x) << name;
  }
  const double share = double(accepted) / (double(m) * m);
  const double sin2 = R * R / double(length2(c - p));
  const Frame toLight(normalize(c - p));
  Rng rng(seed);
  const int n = 1 << 19;
  double sum = 0, sum2 = 0;
  for (int k = 0; k < n; ++k) {
    const Vec3 w = toLight.toWorld(sampleUniformConeSin2(rng.next1D(), rng.next1D(), sin2));
    float t;
    if (!l.intersect(Ray{p, w, 0.0f, kInf}, t)) continue;
    const double v = l.pdfLi(p, w, t) / uniformConePdfSin2(sin2);
    sum += v;
    sum2 += v * v;
  }
  const double mean = sum / n, se = std::sqrt((sum2 / n - mean * mean) / n);
  EXPECT_NEAR(mean, share, 4 * se + 2.0 / m) << name << " se " << se;
  return share;
}

}  // namespace

TEST(DiskAndCylinderLights, SamplesMeetTheLightWhereTheirPdfSays) {
  // An elliptic disk (scaled 1 × 0.5, tilted) and a tilted cylinder, seen from a point off
  // their axes: a sampled direction meets the light at the sampled distance, where pdfLi,
  // areaLe and intersect agree with the sample; and the pdf integrates over the directions
  // meeting the light to the share of samples sampleLi accepts (uniform directions against
  // stratified points: two ways of measuring one area).
  LightDesc disk = diskLight("disk", 0.4f, 2, Vec3(0.3f, 2, -0.1f));
  disk.xf = Transform::lookAt(Vec3(0.3f, 2, -0.1f), Vec3(0.5f, 1, 0.2f), Vec3(0, 0, 1)) *
            Transform::scale(Vec3(1, 0.5f, 1));
  LightDesc tube = cylinderLight("tube", 0.2f, 1.5f, 2, Vec3(0.5f, 1.5f, 0.2f));
  tube.xf = Transform::lookAt(Vec3(0.5f, 1.5f, 0.2f), Vec3(0.8f, 0.5f, 0.7f), Vec3(0, 0, 1));
  const Vec3 p(-0.2f, 0.1f, 0.3f);
  for (const LightDesc& desc : {disk, tube}) {
    // Near a cylinder's silhouette a ray meets the side ill-conditioned (a few ulps move the
    // hit, its normal and cos θ_light by percents), where the weight is small: its 1 / pdf
    // within 0.1% of the largest. Every direction that meets the light lies in the cone
    // about its bounding sphere.
    const float R = desc.type == LightType::Disk ? desc.radius
                                                 : std::sqrt(0.25f * desc.length * desc.length + desc.radius * desc.radius);
    const double share = expectSamplesMeetTheLight(Light::fromDesc(desc), desc.name, p, 1024, 389, 1e-3f,
                                                   desc.xf.point(Vec3(0.0f)), R, 7);
    EXPECT_GT(share, 0.2) << desc.name;
  }
}

TEST(DiskAndCylinderLights, AFloorUnderEachAreaLightHasTheRadianceItsSurfaceGives) {
  // Light sampling, BSDF rays that meet the light and their MIS weights add up to the
  // floor's radiance, integrated here over the light's surface by the midpoint rule.
  const double disk = floorRadiance(diskEmitters(0.3, 1.0, 0.1, 0.0, 200), 24);
  expectFloorRadiance({diskLight("disk", 0.3f, 1, Vec3(0.1f, 1, 0))}, disk, 256);
  // A cylinder along X, above the floor but out of the camera's view (z = 0.5).
  const double r = 0.05, len = 1.0, h = 0.5, z0 = 0.5;
  const int m = 200;
  const double tube = floorRadiance(
      [&](auto&& f) {
        for (int a = 0; a < m; ++a)
          for (int b = 0; b < m; ++b) {
            const double s = -0.5 * len + len * (a + 0.5) / m, phi = 2 * kPiD * (b + 0.5) / m;
            const double ny = std::cos(phi), nz = std::sin(phi);
            f(s, h + r * ny, z0 + r * nz, 0.0, ny, nz, r * (2 * kPiD / m) * (len / m));
          }
      },
      24);
  expectFloorRadiance({cylinderLight("tube", float(r), float(len), 1, Vec3(0, float(h), float(z0)))}, tube, 2048);
  // A sphere of radius 0.1 close beside the view, wholly above the floor's horizon:
  // E = L π r² cos θ / D² at distance D from its centre. Shadow rays leave the floor from an
  // offset origin, which met this sphere short of the sampled point on 6% of them until
  // the light a ray is aimed at stopped counting as its blocker (Light::blocksShadowRay).
  const int n = 200;
  double bulb = 0;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const double x = -0.2 + 0.4 * (i + 0.5) / n, z = -0.2 + 0.4 * (j + 0.5) / n;
      const double D2 = x * x + 0.09 + (z - 0.4) * (z - 0.4), D = std::sqrt(D2);
      bulb += 0.5 / kPiD * kPiD * 0.01 * (0.3 / D) / D2 / (n * n);
    }
  expectFloorRadiance({sphereLight("bulb", 0.1f, 1, Vec3(0, 0.3f, 0.4f))}, bulb, 512);
}

TEST(DiskAndCylinderLights, ShapingConesAndFocusesWhatTheyEmit) {
  // A disk with a soft 20° cone and a tinted focus over the floor: the cone cuts what
  // leaves more than 20° off its axis, the focus weighs the rest by |n·ω|^focus.
  LightDesc spot = diskLight("spot", 0.3f, 1, Vec3(0.1f, 1, 0));
  spot.shaping.enabled = true;
  spot.shaping.coneAngle = 20;
  spot.shaping.coneSoftness = 0.5f;
  spot.shaping.focus = 8;
  spot.shaping.focusTint = Vec3(0.25f);
  const double expected = floorRadiance(diskEmitters(0.3, 1.0, 0.1, 0.0, 200), 24, &spot.shaping);
  const double unshaped = floorRadiance(diskEmitters(0.3, 1.0, 0.1, 0.0, 200), 24);
  EXPECT_LT(expected, 0.8 * unshaped);  // the shaping matters here
  expectFloorRadiance({spot}, expected, 256);
  // A sphere light (out of view) with a cone pointing away from the floor lights nothing
  // below it; without the cone it does.
  LightDesc up = sphereLight("up", 0.2f, 10, Vec3(0.6f, 1, 0));
  up.xf = Transform::lookAt(Vec3(0.6f, 1, 0), Vec3(0.6f, 2, 0), Vec3(0, 0, 1));
  up.shaping.enabled = true;
  up.shaping.coneAngle = 60;
  for (bool shaped : {true, false}) {
    up.shaping.enabled = shaped;
    SceneDesc d = floorFromAbove(16);
    d.lights = {up};
    auto scene = Scene::build(d);
    Renderer r(*scene);
    ASSERT_TRUE(r.render(16));
    const ChannelEstimate e = imageEstimates(r.film().toImage(), {{0, 8, 0, 8}})[0];
    if (shaped) EXPECT_EQ(e.mean[0], 0.0);
    else EXPECT_GT(e.mean[0], 0.1);
  }
}

// ---- IES profiles ----------------------------------------------------------------------

namespace {

// A .ies file (LM-63-2002, type C) in the temporary folder while the object lives: the
// vertical angles, the horizontal ones and the candela rows, as the file lists them.
struct IesFile {
  std::string path;
  IesFile(const std::string& name, const std::vector<double>& vertical, const std::vector<double>& horizontal,
          const std::vector<double>& candela) {
    path = (std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()) + ".ies")).string();
    std::ofstream f(path);
    f << "IESNA:LM-63-2002\n[TEST] test profile\nTILT=NONE\n1 -1 1 " << vertical.size() << " " << horizontal.size()
      << " 1 2 0 0 0\n1 1 10\n";
    for (double v : vertical) f << v << " ";
    f << "\n";
    for (double h : horizontal) f << h << " ";
    f << "\n";
    for (double c : candela) f << c << " ";
    f << "\n";
  }
  ~IesFile() { std::filesystem::remove(path); }
};

// Piecewise linear through (x[i], y[i]); 0 outside [x.front(), x.back()].
double piecewise(const std::vector<double>& x, const std::vector<double>& y, double at) {
  if (at < x.front() || at > x.back()) return 0;
  for (size_t i = 1; i < x.size(); ++i)
    if (at <= x[i]) return y[i - 1] + (y[i] - y[i - 1]) * (at - x[i - 1]) / (x[i] - x[i - 1]);
  return y.back();
}

}  // namespace

TEST(IesProfiles, ScaleWhatALightEmitsByTheCandelaOfItsOwnFrame) {
  // A profile without symmetry (rows at φ = 0°, 90°, 180° and 270°, closed back to the
  // first at 360°; each linear over θ ∈ [0°, 180°]) on a sphere light turned and tilted:
  // each direction's radiance is the light's times the candela at its θ off the light's −Z
  // and its φ from +X toward +Y, the frame read back from the light's transform here.
  const std::vector<double> vertical = {0, 60, 120, 180}, horizontal = {0, 90, 180, 270};
  const std::vector<std::vector<double>> rows = {{8, 4, 2, 1}, {2, 6, 1, 3}, {5, 5, 0, 9}, {1, 7, 3, 3}};
  std::vector<double> candela;
  for (const auto& r : rows) candela.insert(candela.end(), r.begin(), r.end());
  const IesFile file("asymmetric", vertical, horizontal, candela);
  LightDesc d = sphereLight("bulb", 0.1f, 2, Vec3(0.0f));
  d.xf = Transform::lookAt(Vec3(0.3f, 0.2f, 0.1f), Vec3(1, -1, 0.5f), Vec3(0, 0, 1));
  d.shaping.enabled = true;
  d.shaping.coneAngle = 180;  // no cone: every direction
  d.shaping.iesFile = file.path;
  const Vec3 X = normalize(d.xf.vector(Vec3(1, 0, 0))), Y = normalize(d.xf.vector(Vec3(0, 1, 0))),
             Z = normalize(d.xf.vector(Vec3(0, 0, 1)));
  auto expected = [&](const Vec3& w, float angleScale) {
    const double theta = std::acos(std::clamp(double(-dot(w, Z)), -1.0, 1.0));
    double phi = std::atan2(double(dot(w, Y)), double(dot(w, X))) * 180 / kPiD;
    phi = std::fmod(phi + 360, 360);
    double t = theta;
    if (angleScale > 0) t = theta / angleScale;
    if (angleScale < 0) t = kPiD + (theta - kPiD) / -angleScale;
    if (t < 0 || t > kPiD) return 0.0;
    const int j = std::min(int(phi / 90), 3);
    const double a = piecewise(vertical, rows[j], t * 180 / kPiD), b = piecewise(vertical, rows[(j + 1) % 4], t * 180 / kPiD);
    return a + (b - a) * (phi - 90 * j) / 90;
  };
  Rng rng(3);
  for (float angleScale : {0.0f, 0.6f, -0.7f}) {
    d.shaping.iesAngleScale = angleScale;
    const Light l = Light::fromDesc(d);
    int lit = 0;
    for (int i = 0; i < 400; ++i) {
      const Vec3 w = sampleUniformSphere(rng.next1D(), rng.next1D());
      const Vec3 q = d.xf.point(Vec3(0.0f)) + w * 0.1f;
      const double want = 2 * expected(w, angleScale);
      EXPECT_NEAR(l.areaLe(q, -w).x, want, 1e-4 * (1 + want)) << "angleScale " << angleScale << " w " << w.x << " " << w.y << " " << w.z;
      lit += want > 0;
    }
    EXPECT_GT(lit, angleScale == 0 ? 390 : 100);  // the mapped angles leave some directions dark
  }
  // Normalised: divided by the profile's mean, here ∫ I dω / 4π by a fine midpoint rule.
  double sum = 0;
  const int n = 1000, m = 360;
  for (int i = 0; i < n; ++i)
    for (int k = 0; k < m; ++k) {
      const double theta = kPiD * (i + 0.5) / n, phi = 2 * kPiD * (k + 0.5) / m;
      const Vec3 w = X * float(std::sin(theta) * std::cos(phi)) + Y * float(std::sin(theta) * std::sin(phi)) -
                     Z * float(std::cos(theta));
      sum += expected(normalize(w), 0) * std::sin(theta) * (kPiD / n) * (2 * kPiD / m);
    }
  const double mean = sum / (4 * kPiD);
  d.shaping.iesAngleScale = 0;
  d.shaping.iesNormalize = true;
  const Light normalized = Light::fromDesc(d);
  for (int i = 0; i < 100; ++i) {
    const Vec3 w = sampleUniformSphere(rng.next1D(), rng.next1D());
    const Vec3 q = d.xf.point(Vec3(0.0f)) + w * 0.1f;
    EXPECT_NEAR(normalized.areaLe(q, -w).x, 2 * expected(w, 0) / mean, 1e-4 * (1 + 2 * expected(w, 0) / mean));
  }
}

TEST(IesProfiles, LightSamplingWeighsALightByItsBeamTowardThePointNeverBelowItsMean) {
  // A normalised narrow downlight on a sphere light: seen from a point on its axis it
  // weighs its peak over its mean; from a point off its beam (at the same distance, the
  // same solid angle), its mean, as a light without a profile of the same radiance would.
  const std::vector<double> vertical = {0, 5, 10, 90}, candela = {100, 50, 1, 1};
  const IesFile file("narrow", vertical, {0}, candela);
  LightDesc spot = sphereLight("spot", 0.05f, 1, Vec3(0, 2, 0));
  spot.xf = Transform::lookAt(Vec3(0, 2, 0), Vec3(0, 0, 0), Vec3(0, 0, 1));  // −Z down
  spot.shaping.enabled = true;
  spot.shaping.coneAngle = 180;
  spot.shaping.iesFile = file.path;
  spot.shaping.iesNormalize = true;
  LightDesc plain = spot;
  plain.shaping = LightShaping();
  const Light l = Light::fromDesc(spot), p = Light::fromDesc(plain);
  const double mean = readIesFile(file.path)->meanIntensity();
  const Vec3 onAxis(0, 0, 0), offBeam(2, 2, 0);  // both 2 from the light
  EXPECT_NEAR(l.pickWeight(onAxis) / p.pickWeight(onAxis), 100 / mean, 1e-3 * 100 / mean);
  EXPECT_NEAR(l.pickWeight(offBeam) / p.pickWeight(offBeam), 1.0, 1e-4);
  EXPECT_GT(100 / mean, 20);  // the beam matters here
}

TEST(IesProfiles, AFloorUnderAnIesDiskHasTheRadianceItsCandelaGive) {
  // A downlight's axial profile, bright at 0°, dark at 20°, bright again at 30°: a disk
  // facing the floor draws its rings there (θ reaches 34° at the view's corners), and light
  // sampling, BSDF rays that meet the disk and MIS add up to the integral over its surface.
  const std::vector<double> vertical = {0, 10, 20, 30, 40, 90}, candela = {100, 80, 30, 60, 10, 0};
  const IesFile file("downlight", vertical, {0}, candela);
  LightDesc spot = diskLight("downlight", 0.05f, 0.01f, Vec3(0.05f, 0.4f, 0));
  spot.shaping.enabled = true;
  spot.shaping.iesFile = file.path;
  // The candela toward a unit emission direction w off the disk's axis (world −Y).
  auto profile = [&](double angleScale, double scale) {
    return [&vertical, &candela, angleScale, scale](double wx, double wy, double wz) {
      const double theta = std::acos(std::clamp(-wy, -1.0, 1.0)) / angleScale;
      (void)wx, (void)wz;
      return scale * piecewise(vertical, candela, theta * 180 / kPiD);
    };
  };
  // Its mean over the lower hemisphere, ∫ I sin θ dθ (midpoint rule).
  double mean = 0;
  for (int i = 0; i < 90000; ++i) {
    const double theta = (i + 0.5) * kPiD / 180 / 1000;
    mean += piecewise(vertical, candela, theta * 180 / kPiD) * std::sin(theta) * kPiD / 180 / 1000;
  }
  struct Case {
    float angleScale;
    bool normalize;
    double scale;
  };
  const double unshaped = floorRadiance(diskEmitters(0.05, 0.4, 0.05, 0.0, 60), 48);
  for (const Case& c : {Case{0, false, 0.01}, Case{0.5f, false, 0.01}, Case{0, true, 0.01 / mean}}) {
    spot.shaping.iesAngleScale = c.angleScale;
    spot.shaping.iesNormalize = c.normalize;
    const double expected = floorRadiance(diskEmitters(0.05, 0.4, 0.05, 0.0, 60), 48, nullptr, Vec3(0, -1, 0),
                                          profile(c.angleScale > 0 ? c.angleScale : 1, c.scale));
    // The profile's shape matters: its peak everywhere would give far more.
    EXPECT_LT(expected, 0.8 * unshaped * c.scale * candela[0]) << expected / (unshaped * c.scale * candela[0]);
    expectFloorRadiance({spot}, expected, 256);
  }
}

// ---- the default light of a stage without any ------------------------------------------

namespace {

SceneDesc unlitGround() {
  SceneDesc d;
  d.settings.width = 8;
  d.settings.height = 8;
  d.settings.spp = 4;
  d.camera.cameraToWorld = Transform::lookAt(Vec3(0, 2, 0), Vec3(0, 0, 0), Vec3(0, 0, -1));
  MeshDesc ground;
  ground.name = "ground";
  ground.mesh.points = {Vec3(-10, 0, -10), Vec3(10, 0, -10), Vec3(10, 0, 10), Vec3(-10, 0, 10)};
  ground.mesh.indices = {0, 2, 1, 0, 3, 2};
  MaterialDesc white;
  white.name = "white";
  white.albedo = Vec3(0.5f);
  ground.material = 0;
  d.materials.push_back(white);
  d.meshes.push_back(ground);
  return d;
}

}  // namespace

TEST(DefaultLight, AStageWithoutLightsIsLitByAWhiteDomeOfRadianceOne) {
  // A Lambert floor of albedo 0.5 under a uniform dome of radiance 1 reflects 0.5 exactly
  // (the upper hemisphere sees nothing but the dome), in every sample (ConstantDome).
  SceneDesc d = unlitGround();
  auto scene = Scene::build(d);
  EXPECT_TRUE(scene->defaultLightAdded());
  Renderer r(*scene);
  ASSERT_TRUE(r.render(4));
  double sum = 0, var = 0;
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 8; ++x) {
      Vec3 c = r.film().mean(x, y);
      EXPECT_EQ(c.x, c.y);  // white
      sum += c.x;
      var += double(r.film().stdError(x, y)) * r.film().stdError(x, y);
    }
  const double mean = sum / 64, se = std::sqrt(var) / 64;
  EXPECT_LT(se, 1e-5);  // float rounding
  EXPECT_NEAR(mean, 0.5, 1e-5);
}

TEST(DefaultLight, OffRendersBlackAndAnyLightOrEmitterReplacesIt) {
  SceneDesc off = unlitGround();
  off.settings.defaultLight = false;
  auto dark = Scene::build(off);
  EXPECT_FALSE(dark->defaultLightAdded());
  Renderer r(*dark);
  ASSERT_TRUE(r.render(4));
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 8; ++x) EXPECT_EQ(luminance(r.film().mean(x, y)), 0.0f);

  SceneDesc lit = unlitGround();
  LightDesc sun;
  sun.name = "sun";
  lit.lights.push_back(sun);
  EXPECT_FALSE(Scene::build(lit)->defaultLightAdded());

  SceneDesc glowing = unlitGround();
  glowing.materials[0].emission = Vec3(1.0f);
  EXPECT_FALSE(Scene::build(glowing)->defaultLightAdded());
}

namespace {

// The unlit ground with a delta sun (irradiance 3 along the slanted direction) and, off
// camera, a small aggregate whose grains are of `grain` type.
SceneDesc sunAndGrains(MaterialType grain) {
  SceneDesc d = unlitGround();
  LightDesc sun;
  sun.name = "sun";
  sun.type = LightType::Distant;
  sun.angle = 0;
  sun.intensity = 3;
  sun.xf = Transform::lookAt(Vec3(0.0f), Vec3(-0.3f, -1.0f, 0.2f), Vec3(0, 0, 1));
  d.lights.push_back(sun);
  MaterialDesc m;
  m.name = "grain";
  m.type = grain;
  d.materials.push_back(m);
  AggregateDesc a;
  a.name = "pebbles";
  a.boundary = makeIcosphere(2);
  a.xf = Transform::translate(Vec3(40, 1, 0));
  a.grainRadius = 0.1f;
  a.tileSpheres = 64;
  a.prototypes = {GrainPrototypeDesc{"pebble", makeIcosphere(1), 1}};
  a.weights = {1};
  d.aggregates.push_back(a);
  return d;
}

}  // namespace

TEST(PhysicalSun, ADeltaSunOverSmoothGrainsBecomesADiskOfTheSameIrradiance) {
  SceneDesc d = sunAndGrains(MaterialType::Dielectric);
  auto scene = Scene::build(d);
  ASSERT_EQ(scene->widenedSuns(), std::vector<std::string>{"sun"});
  EXPECT_NE(scene->widenedSunsWarning().find("sun is rendered as the physical sun, a disk of 0.53 degrees"),
            std::string::npos)
      << scene->widenedSunsWarning();
  const Light& sun = scene->lights()[0];
  // Irradiance on a plane facing the sun, E = E[Li cos / pdf] over the disk's samples. With
  // Li = E / (π sin²h) and pdf = 1 / (2π (1 − cos h)), each sample is E cos θ · 2 / (1 + cos h),
  // within (1 − cos h) / (1 + cos h) ≈ h²/4 = 5.3e-6 of E for any θ in the disk: so is the
  // mean, whatever the sample points (the float pdf was 2.5e-3 off).
  const Vec3 toSun = normalize(Vec3(0.3f, 1.0f, -0.2f));
  const double h = 0.5 * 0.53 * kPiD / 180;
  const int n = 4096;
  double sum = 0;
  for (int i = 0; i < n; ++i) {
    LightSample s;
    ASSERT_TRUE(sun.sampleLi(Vec3(0.0f), (i + 0.5f) / n, float((i * 0.618034) - std::floor(i * 0.618034)), s));
    ASSERT_FALSE(s.delta);
    ASSERT_GT(dot(s.wi, toSun), std::cos(h) - 1e-6);
    sum += double(s.Li.x) * dot(s.wi, toSun) / s.pdf;
  }
  const double bound = (1 - std::cos(h)) / (1 + std::cos(h)) + 1e-6;  // + float rounding of wi and Li
  EXPECT_NEAR(sum / n, 3.0, 3.0 * bound);
}

TEST(PhysicalSun, LambertGrainsOrTheSettingOffKeepTheDeltaSun) {
  auto lambert = Scene::build(sunAndGrains(MaterialType::Lambert));
  EXPECT_TRUE(lambert->widenedSuns().empty());
  EXPECT_EQ(lambert->widenedSunsWarning(), "");
  SceneDesc off = sunAndGrains(MaterialType::Dielectric);
  off.settings.physicalSun = false;
  auto kept = Scene::build(off);
  EXPECT_TRUE(kept->widenedSuns().empty());
  LightSample s;
  ASSERT_TRUE(kept->lights()[0].sampleLi(Vec3(0.0f), 0.5f, 0.5f, s));
  EXPECT_TRUE(s.delta);
  // On the ground (no grain in view), the disk and the delta sun give the same image
  // within the disk's sampling noise: only the penumbrae, which are not in view, differ.
  SceneDesc on = sunAndGrains(MaterialType::Dielectric);
  auto widened = Scene::build(on);
  Renderer a(*widened), b(*kept);
  ASSERT_TRUE(a.render(4));
  ASSERT_TRUE(b.render(4));
  Image ia = a.film().toImage(), ib = b.film().toImage();
  double ma = 0, mb = 0;
  for (int y = 0; y < ia.height; ++y)
    for (int x = 0; x < ia.width; ++x) {
      ma += ia.at(x, y)[0];
      mb += ib.at(x, y)[0];
    }
  // Lambert 0.5 under E = 3 at cos θ_s = 0.96: L = 0.5/π · 3 · 0.96 per pixel, exactly for
  // the delta. A disk sample at angle ≤ h from the sun's centre changes the ground's cosine
  // by at most tan θ_s · h = 1.35e-3 relative, a spread of at most that / √3 per sample
  // (uniform in the disk's extent), averaged over spp × pixels samples: 4 standard errors.
  const Vec3 toSun = normalize(Vec3(0.3f, 1.0f, -0.2f));
  const double expected = 0.5 / kPiD * 3.0 * toSun.y * ia.width * ia.height;
  const double h = 0.5 * 0.53 * kPiD / 180, tanSun = std::sqrt(1 - toSun.y * toSun.y) / toSun.y;
  const double samples = double(on.settings.spp) * ia.width * ia.height;
  EXPECT_NEAR(mb, expected, 1e-5 * expected);  // float sums of exact values
  EXPECT_NEAR(ma, expected, 4 * tanSun * h / std::sqrt(3.0) / std::sqrt(samples) * expected);
}

namespace {

// A heap of smooth glass grains under a normalised sun of `angle` degrees (irradiance 3),
// nothing else: every path that reaches the sun does so by a chain of smooth bounces.
SceneDesc glassUnderSun(float angle, float regularization) {
  SceneDesc d = sunAndGrains(MaterialType::Dielectric);
  d.meshes.clear();  // no ground: no surface samples the sun
  d.aggregates[0].xf = Transform();
  d.settings.width = d.settings.height = 16;
  d.settings.spp = 8;
  d.settings.technique = Technique::Ept;
  d.settings.sunRegularization = regularization;
  d.camera.cameraToWorld = Transform::lookAt(Vec3(0, 1.5f, 3), Vec3(0.0f), Vec3(0, 1, 0));
  LightDesc& sun = d.lights[0];
  sun.angle = angle;
  sun.normalize = true;
  sun.xf = Transform::lookAt(Vec3(0.0f), Vec3(-0.2f, -1.0f, -0.6f), Vec3(0, 0, 1));
  return d;
}

// The glass heap under the 0.53° sun regularised to `degrees` renders as under a sun of
// that angle and the same irradiance, unregularised, to float rounding; and not as under the
// 0.53° sun exact. The grains' roughness as given.
void expectTheRegularisedSunIsTheWiderDisk(float degrees, float roughness) {
  auto scene = [roughness](float angle, float regularization) {
    SceneDesc d = glassUnderSun(angle, regularization);
    for (MaterialDesc& m : d.materials)
      if (m.name == "grain") m.roughness = roughness;
    return d;
  };
  const Image narrow = renderImage(scene(0.53f, degrees));
  const Image wide = renderImage(scene(degrees, 0.0f));
  const Image exact = renderImage(scene(0.53f, 0.0f));
  double sum = 0, differs = 0;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x)
      for (int c = 0; c < 3; ++c) {
        const float a = narrow.at(x, y)[c], b = wide.at(x, y)[c];
        ASSERT_NEAR(a, b, 1e-5f * std::max(1.0f, b)) << x << ", " << y;
        sum += a;
        differs += a != exact.at(x, y)[c];
      }
  EXPECT_GT(sum / (16 * 16 * 3), 0.01);  // the heap is lit
  EXPECT_GT(differs, 0);                 // and the setting changed what its grains saw
}

}  // namespace

TEST(SunRegularization, ASmoothChainFromAGrainSeesTheNarrowSunAsTheWiderDisk) {
  // Smooth grains admit no next-event estimation, and escapes draw no random number: with
  // the 0.53° sun regularised to 5°, the same paths meet the sun where a 5° sun of the same
  // irradiance stands, with the same radiance.
  expectTheRegularisedSunIsTheWiderDisk(5.0f, 0.0f);
}

TEST(SunRegularization, RoughGrainsSeeTheNarrowSunAsTheWiderDisk) {
  // Rough grains smaller than a pixel: their next-event estimation samples the 0.53° sun
  // regularised to 10° as that disk, and a direction their lobe samples that escapes meets
  // the same disk with that disk's MIS weights (PathState::lastSunHalfAngle): the same
  // paths and weights as under a 10° sun. With escapes after a rough grain seeing the sun
  // as it is, the images differ.
  expectTheRegularisedSunIsTheWiderDisk(10.0f, 0.3f);
}

TEST(SunGuidedFresnel, AGlintIsTheSunsFresnelShareInHalfTheSamples) {
  // A smooth glass plane (one open face: what refracts in never comes back) seen at 45° in
  // the mirror direction of a 20° sun, through a field of view of 1.1°: every pixel's
  // expectation is F(45°) L_sun. Chosen with the chance F, a sample would hold L_sun one
  // time in 1/F ≈ 20, a pixel's relative spread √((1 − F) / F) / √spp = 0.54 at 64 samples;
  // toward the sun the mirror is chosen half the time, weighted 2F: a spread of 1 / √spp
  // = 0.125.
  SceneDesc d = unlitGround();
  d.materials[0].type = MaterialType::Dielectric;
  d.materials[0].ior = 1.5f;
  d.settings.width = d.settings.height = 16;
  d.settings.spp = 64;
  d.settings.technique = Technique::Ept;
  d.camera.cameraToWorld = Transform::lookAt(Vec3(0, 5, 5), Vec3(0.0f), Vec3(0, 1, 0));
  d.camera.horizontalAperture = d.camera.verticalAperture = 1.0f;  // mm, at 50 mm
  LightDesc sun;
  sun.name = "sun";
  sun.type = LightType::Distant;
  sun.angle = 20;
  sun.intensity = 3;
  sun.normalize = true;  // irradiance 3: L_sun = 3 / (π sin² 10°)
  sun.xf = Transform::lookAt(Vec3(0.0f), Vec3(0, -1, 1), Vec3(0, 0, 1));
  d.lights.push_back(sun);
  auto scene = Scene::build(d);
  Renderer r(*scene);
  ASSERT_TRUE(r.render(d.settings.spp));
  const double h = 10.0 * kPiD / 180, Lsun = 3.0 / (kPiD * std::sin(h) * std::sin(h));
  const double expected = fresnelDielectric(std::cos(float(kPiD / 4)), 1.5f) * Lsun;
  double sum = 0, sum2 = 0;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x) {
      const double v = r.film().mean(x, y).x;
      ASSERT_TRUE(std::isfinite(v));
      sum += v;
      sum2 += v * v;
    }
  const double mean = sum / 256, spread = std::sqrt(std::max(0.0, sum2 / 256 - mean * mean)) / mean;
  // F varies by ±2% over the view's ±0.55°, evenly about its middle.
  EXPECT_NEAR(mean, expected, expected * (4 * spread / 16 + 0.005));
  EXPECT_LT(spread, 0.2);  // 0.125 expected; 0.54 with the choice left to F
  EXPECT_GT(spread, 0.06);
}

TEST(SunRegularization, ProxiesSeeTheSettingsDisk) {
  // The glass heap among proxies to the end of the path (no medium), its first grain
  // explicit or, through the level-of-detail shortcut, a proxy too: the proxies' next-event
  // estimation samples the 0.53° sun regularised to 10° as that disk, and their sampled
  // directions that escape meet it there, with the MIS weights of that disk. The same paths
  // as under a 10° sun of the same irradiance, unregularised, so the images agree to float
  // rounding. (With escapes after a proxy seeing the sun as it is, the two strategies
  // disagree: the image read 3% dark, two standard errors; before proxies saw the disk
  // where the first grain took the shortcut, that image was the exact sun's.)
  for (const float lod : {0.0f, 1000.0f}) {
    auto proxies = [lod](float angle, float regularization) {
      SceneDesc d = glassUnderSun(angle, regularization);
      d.settings.technique = Technique::EptVpt;
      d.settings.proxies = ProxyUse::On;
      d.settings.explicitBounces = 1 << 20;  // never the medium
      d.settings.lod = lod;                  // 1000: every first grain is below the footprint
      d.settings.spp = 64;
      return d;
    };
    auto scene = Scene::build(proxies(0.53f, 10.0f));
    ASSERT_TRUE(scene->useProxies());
    ASSERT_TRUE(scene->proxyLightSampling());
    Renderer r(*scene);
    ASSERT_TRUE(r.render(64));
    const Image regularised = r.film().toImage();
    const Image wide = renderImage(proxies(10.0f, 0.0f));
    double proxyLight = 0, explicitLight = 0, total = 0;
    for (int y = 0; y < 16; ++y)
      for (int x = 0; x < 16; ++x) {
        for (int c = 0; c < 3; ++c) {
          const float a = regularised.at(x, y)[c], b = wide.at(x, y)[c];
          ASSERT_NEAR(a, b, 1e-5f * std::max(1.0f, b)) << x << ", " << y << " lod " << lod;
        }
        proxyLight += regularised.at(x, y)[regularised.channelIndex("ppt.G")];
        explicitLight += regularised.at(x, y)[regularised.channelIndex("ept.G")];
        total += regularised.at(x, y)[1];
      }
    EXPECT_GT(proxyLight, 0.5 * total) << "the test would not exercise the proxies; lod " << lod;
    if (lod > 0) EXPECT_EQ(explicitLight, 0.0) << "a first grain stayed explicit";
  }
}

TEST(SunRegularization, WhatTheCameraSeesOfTheSunStaysExact) {
  // The camera looks straight at the 0.53° sun (a field of view of 1.1°, the heap out of
  // sight): its pixels hold the sun's own radiance, regularised or not, and none beyond its
  // disk is lit.
  SceneDesc d = glassUnderSun(0.53f, 5.0f);
  d.camera.cameraToWorld = Transform::lookAt(Vec3(0, 10, 0), Vec3(0.2f, 11.0f, 0.6f), Vec3(0, 1, 0));
  d.camera.horizontalAperture = d.camera.verticalAperture = 1.0f;  // mm, at 50 mm
  SceneDesc off = d;
  off.settings.sunRegularization = 0;
  const Image a = renderImage(d), b = renderImage(off);
  double lit = 0;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x) {
      EXPECT_EQ(a.at(x, y)[0], b.at(x, y)[0]) << x << ", " << y;
      lit += a.at(x, y)[0] > 0;
    }
  // The disk covers π/4 (0.265 / 0.573)² ≈ 17% of the square view, fully lit pixels and
  // its edge's; a 5° disk would cover all of it.
  EXPECT_GT(lit, 0.1 * 256);
  EXPECT_LT(lit, 0.4 * 256);
}

TEST(SunRegularization, AGrainThePixelsResolveKeepsItsSharpGlint) {
  // The widening is bounded by the spread of a chain's direction over a pixel's footprint:
  // w / R of normals, turned twice by each reflection and by a fraction at each refraction.
  // Seen from 0.4 away through a 0.1 mm aperture at 50 mm (a footprint of 5e-5, 2 w / R =
  // 0.057°), a grain's chains see the 0.53° sun as it is, the setting on or off, unless they
  // bend through some nine faces (at 0.3 mm six of the 768 values differed: long chains
  // that spread wider than the sun). Through a 20 mm aperture (a footprint of R / 10,
  // 2 w / R = 11°) the setting counts.
  auto closeUp = [](float aperture, float regularization) {
    SceneDesc d = glassUnderSun(0.53f, regularization);
    d.camera.cameraToWorld = Transform::lookAt(Vec3(0, 0.6f, 1.2f), Vec3(0.0f), Vec3(0, 1, 0));
    d.camera.horizontalAperture = d.camera.verticalAperture = aperture;
    LightDesc sky;  // so that every pixel sees something through its chains
    sky.name = "sky";
    sky.type = LightType::Dome;
    sky.intensity = 0.2f;
    d.lights.push_back(sky);
    return renderImage(d);
  };
  const Image a = closeUp(0.1f, 5.0f), b = closeUp(0.1f, 0.0f);
  double sum = 0;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x)
      for (int c = 0; c < 3; ++c) {
        EXPECT_EQ(a.at(x, y)[c], b.at(x, y)[c]) << x << ", " << y;
        sum += a.at(x, y)[c];
      }
  EXPECT_GT(sum, 0);
  const Image wideOn = closeUp(20.0f, 5.0f), wideOff = closeUp(20.0f, 0.0f);
  bool differs = false;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x) differs = differs || wideOn.at(x, y)[0] != wideOff.at(x, y)[0];
  EXPECT_TRUE(differs);
}

namespace {

// A valley of two panels, y = 0.5 |x| over x, z in [−0.3, 0.3] (points relative to the
// light's origin), wound to face down: a convex height field, so a direction from below
// meets it at most once on its front and one from above at most once on its back.
LightDesc valleyLight(const std::string& name, float intensity, const Transform& xf, bool doubleSided = false) {
  LightDesc l;
  l.name = name;
  l.type = LightType::Mesh;
  l.intensity = intensity;
  l.xf = xf;
  l.doubleSided = doubleSided;
  l.mesh.points = {Vec3(-0.3f, 0.15f, -0.3f), Vec3(0, 0, -0.3f), Vec3(0.3f, 0.15f, -0.3f),
                   Vec3(-0.3f, 0.15f, 0.3f),  Vec3(0, 0, 0.3f),  Vec3(0.3f, 0.15f, 0.3f)};
  l.mesh.indices = {0, 1, 4, 0, 4, 3, 1, 2, 5, 1, 5, 4};
  return l;
}

// The valley at `at` in m × m cells per panel, for floorRadiance.
auto valleyEmitters(double ax, double ay, double az, int m) {
  return [=](auto&& f) {
    const double s = 1 / std::sqrt(1.25), dA = (0.3 / m) * (0.6 / m) * std::sqrt(1.25);
    for (int side : {-1, 1})
      for (int a = 0; a < m; ++a)
        for (int b = 0; b < m; ++b) {
          const double x = side * 0.3 * (a + 0.5) / m, z = -0.3 + 0.6 * (b + 0.5) / m;
          f(ax + x, ay + 0.5 * std::fabs(x), az + z, side * 0.5 * s, -s, 0.0, dA);
        }
  };
}

// A world-space mesh's triangles, each cut into k² (k along each edge) whose centroids
// stand for them, for floorRadiance (front faces: counter-clockwise).
auto meshEmitters(const TriangleMesh& m, int k) {
  return [&m, k](auto&& f) {
    for (size_t t = 0; t < m.numTriangles(); ++t) {
      const Vec3 a = m.points[m.indices[3 * t]], b = m.points[m.indices[3 * t + 1]], c = m.points[m.indices[3 * t + 2]];
      const Vec3 cr = cross(b - a, c - a);
      const double area = 0.5 * length(cr) / (k * k);
      const Vec3 n = normalize(cr);
      const Vec3 u = (b - a) / float(k), v = (c - a) / float(k);
      // The k(k + 1)/2 sub-triangles that point as the triangle does, and the k(k − 1)/2
      // between them that point the other way.
      for (int i = 0; i < k; ++i)
        for (int j = 0; i + j < k; ++j) {
          const Vec3 o = a + u * float(i) + v * float(j), up = o + (u + v) / 3.0f, down = o + (u + v) * (2.0f / 3.0f);
          f(up.x, up.y, up.z, n.x, n.y, n.z, area);
          if (i + j < k - 1) f(down.x, down.y, down.z, n.x, n.y, n.z, area);
        }
    }
  };
}

}  // namespace

TEST(MeshLights, SamplesMeetTheLightWhereTheirPdfSays) {
  // The valley turned and moved, seen from below its front (one-sided) and from above its
  // back (double-sided): a sample meets the light at its distance, where pdfLi and areaLe
  // agree with it; the pdf integrates over the directions that meet the light to the share
  // of samples accepted; the radiance is intensity / area when normalised.
  const Vec3 at(0.2f, 1.5f, -0.1f);
  const Transform xf = Transform::lookAt(at, at + Vec3(0.3f, -0.2f, -1), Vec3(0, 1, 0));
  LightDesc below = valleyLight("below", 2, xf), above = valleyLight("above", 2, xf, true);
  above.normalize = true;
  const double area = 2 * 0.3 * 0.6 * std::sqrt(1.25);
  EXPECT_NEAR(normalizationArea(above), area, 1e-5 * area);
  for (const auto& [desc, p] : {std::pair{below, Vec3(-0.1f, 0.4f, 0.2f)}, std::pair{above, Vec3(0.1f, 2.6f, -0.3f)}}) {
    const Light l = Light::fromDesc(desc);
    const double share = expectSamplesMeetTheLight(l, desc.name, p, 512, 97, 1e-4f, xf.point(Vec3(0, 0.075f, 0)), 0.45, 11);
    EXPECT_GT(share, 0.99) << desc.name;  // every face turns its emitting side to p
    LightSample s;
    ASSERT_TRUE(l.sampleLi(p, 0.3f, 0.6f, s));
    EXPECT_FLOAT_EQ(s.Li.y, desc.normalize ? float(2 / area) : 2.0f) << desc.name;
  }
  // One-sided, its back neither emits nor blocks: from above nothing is sampled or met.
  const Light oneSided = Light::fromDesc(below);
  LightSample s;
  int sampled = 0;
  for (int i = 0; i < 64; ++i) sampled += oneSided.sampleLi(Vec3(0.1f, 2.6f, -0.3f), (i + 0.5f) / 64, 0.5f, s);
  EXPECT_EQ(sampled, 0);
  float t;
  EXPECT_FALSE(oneSided.intersect(Ray{Vec3(0.2f, 2.6f, -0.1f), Vec3(0, -1, 0), 0.0f, kInf}, t));
  EXPECT_TRUE(oneSided.intersect(Ray{Vec3(0.2f, 0.5f, -0.1f), Vec3(0, 1, 0), 0.0f, kInf}, t));
}

TEST(MeshLights, AFloorUnderAMeshLightHasTheRadianceItsFacesGive) {
  // Light sampling, BSDF rays that meet the faces and their MIS weights add up to the
  // floor's radiance integrated over the faces by the midpoint rule. Over the view, the
  // camera above sees the light's backs, which let its rays through. Beside the view, the
  // same valley flipped to face up and double-sided lights the floor as much.
  const double over = floorRadiance(valleyEmitters(0.1, 0.8, 0.0, 100), 24);
  expectFloorRadiance({valleyLight("valley", 1, Transform::translate(Vec3(0.1f, 0.8f, 0)))}, over, 256);
  const double beside = floorRadiance(valleyEmitters(0.1, 0.8, 0.5, 100), 24);
  expectFloorRadiance({valleyLight("valley", 1, Transform::translate(Vec3(0.1f, 0.8f, 0.5f)))}, beside, 256);
  LightDesc flipped = valleyLight("flipped", 1, Transform::translate(Vec3(0.1f, 0.8f, 0.5f)), true);
  flipped.mesh.flip();
  expectFloorRadiance({flipped}, beside, 256);
  // A closed ball of 320 faces 0.2 above the floor beside the view: shadow rays leave the
  // floor from an offset origin and, toward a point near its silhouette, meet the ball a
  // little short of it; they counted as blocked (6.6% dark) until faces met within the
  // tolerance of the end stopped blocking.
  LightDesc ball;
  ball.name = "ball";
  ball.type = LightType::Mesh;
  ball.mesh = makeIcosphere(2);
  for (Vec3& p : ball.mesh.points) p *= 0.1f;
  ball.xf = Transform::translate(Vec3(0, 0.3f, 0.4f));
  const TriangleMesh world = ball.mesh.transformed(ball.xf);
  expectFloorRadiance({ball}, floorRadiance(meshEmitters(world, 16), 24), 1024);
}

TEST(MeshLights, AreRefusedWithoutAreaOrWithShaping) {
  using granular::testing::errorOf;
  LightDesc l = valleyLight("flat", 1, Transform());
  for (Vec3& p : l.mesh.points) p.y = 0.0f, p.z = 0.0f;  // every triangle a segment
  EXPECT_EQ(errorOf([&] { validateLightDesc(l, "/World/Flat"); }),
            "/World/Flat.points: the mesh has no area, so it cannot emit");
  l = valleyLight("empty", 1, Transform());
  l.mesh = TriangleMesh();
  EXPECT_EQ(errorOf([&] { validateLightDesc(l, "/World/Empty"); }), "/World/Empty.faceVertexIndices: has no triangles");
  l = valleyLight("huge", 1, Transform());
  for (Vec3& p : l.mesh.points) p *= 3e15f;  // within the coordinates' bound, 10^30 across in area
  EXPECT_EQ(errorOf([&] { validateLightDesc(l, "/World/Huge"); }).find("/World/Huge.points: the mesh's area "), 0u);
  l = valleyLight("shaped", 1, Transform());
  l.shaping.enabled = true;
  EXPECT_EQ(errorOf([&] { validateLightDesc(l, "/World/Shaped"); }),
            "/World/Shaped.shaping: is not supported on a mesh light");
}

TEST(AreaLightOcclusion, ManyLightsAreFoundThroughTheirBvhAsOneByOne) {
  // 24 area lights of every kind scattered in a box (past Scene::kAreaLightBvhMin, so the
  // scene asks its BVH over them): random rays meet the nearest light at the distance the
  // lights, asked one by one, give; shadow rays are blocked exactly when some light met one
  // by one blocks them (a ray aimed at a point sampled on a light passes that light).
  SceneDesc d = floorFromAbove(1);
  d.meshes.clear();
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-3.0f, 3.0f);
  for (int i = 0; i < 24; ++i) {
    const Vec3 at(u(rng), u(rng), u(rng));
    LightDesc l;
    switch (i % 5) {
      case 0: l = sphereLight("s" + std::to_string(i), 0.3f, 1, at); break;
      case 1: l = diskLight("d" + std::to_string(i), 0.4f, 1, at); break;
      case 2: l = cylinderLight("c" + std::to_string(i), 0.1f, 0.8f, 1, at); break;
      case 3: l = valleyLight("v" + std::to_string(i), 1, Transform::translate(at)); break;
      default:
        l.name = "r" + std::to_string(i);
        l.type = LightType::Rect;
        l.width = 0.6f;
        l.height = 0.3f;
        break;
    }
    if (i % 5 != 3) l.xf = Transform::lookAt(at, at + Vec3(u(rng), u(rng), u(rng)), Vec3(0.3f, 1, 0.1f));
    d.lights.push_back(l);
  }
  auto scene = Scene::build(d);
  const auto& lights = scene->lights();
  ASSERT_EQ(lights.size(), 24u);
  int met = 0, blocked = 0;
  for (int k = 0; k < 4096; ++k) {
    // From anywhere in the box (the scene's render space) toward near a random light's centre.
    const Vec3 o = lights[0].bounds().center() + Vec3(u(rng), u(rng), u(rng));
    const Vec3 toward = lights[size_t(k * 7 % 24)].bounds().center() + Vec3(u(rng), u(rng), u(rng)) * 0.1f;
    if (!(length2(toward - o) > 1e-4f)) continue;
    const Vec3 dir = normalize(toward - o);
    float nearest = kInf;
    int which = -1;
    for (int li = 0; li < 24; ++li) {
      float t;
      if (lights[li].intersect(Ray{o, dir, 0.0f, nearest}, t) && t < nearest) nearest = t, which = li;
    }
    Hit hit;
    const bool found = scene->intersect(Ray{o, dir, 0.0f, kInf}, hit, nullptr);
    ASSERT_EQ(found, which >= 0) << k;
    if (!found) continue;
    ++met;
    EXPECT_EQ(hit.kind, Hit::AreaLight);
    EXPECT_EQ(hit.light, which) << k;
    EXPECT_EQ(hit.t, nearest) << k;
    EXPECT_TRUE(scene->occluded(o, dir, kInf));
    EXPECT_FALSE(scene->occluded(o, dir, nearest * 0.999f));
    // Toward a point sampled on light k % 24, shortened as the integrators shorten it.
    LightSample ls;
    const int target = k % 24;
    if (!lights[target].sampleLi(o, 0.37f, 0.61f, ls)) continue;
    const float dist = ls.dist * (1.0f - 1e-4f);
    bool byOne = false;
    for (int li = 0; li < 24 && !byOne; ++li) {
      float t;
      if (li == target) continue;
      byOne = lights[li].intersect(Ray{o, ls.wi, 0.0f, dist}, t);
    }
    blocked += byOne;
    EXPECT_EQ(scene->occluded(o, ls.wi, dist), byOne) << k;
  }
  EXPECT_GT(met, 1000);
  EXPECT_GT(blocked, 50);
}
