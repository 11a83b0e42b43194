// Transform motion blur of procedural aggregates (aggregate_motion.h): an aggregate is built
// once at its transform and posed at each ray's time; its boundary moves as the same mesh
// moving over the shutter would, its grains with it, and a blurred image is the average of
// still ones across the shutter.
#include <gtest/gtest.h>

#include <cmath>

#include "core/aggregate_motion.h"
#include "core/error.h"
#include "core/render.h"
#include "core/rng.h"
#include "core/scene.h"
#include "core/scene_io.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;

namespace {

Transform turnY(double degrees) {
  const double a = degrees * kPiD / 180.0, c = std::cos(a), s = std::sin(a);
  Transform t;
  t.m[0][0] = c;
  t.m[0][2] = s;
  t.m[2][0] = -s;
  t.m[2][2] = c;
  return t;
}

constexpr float kOpen = -0.02f, kClose = 0.02f;

// A squashed ball of coarse grains, placed at the frame by xf, turning by 60 degrees and
// moving over the shutter.
AggregateDesc turningBall() {
  AggregateDesc a = granular::testing::smallAggregate(0.1f);
  const Transform shape = Transform::scale(Vec3(1.0f, 0.8f, 0.9f));
  a.xf = Transform::translate(Vec3(0.2f, 0.0f, 0.0f)) * turnY(10) * shape;
  a.shutterXf = std::make_pair(Transform::translate(Vec3(-0.3f, 0.1f, 0.0f)) * turnY(-20) * shape,
                               Transform::translate(Vec3(0.5f, -0.1f, 0.2f)) * turnY(40) * shape);
  return a;
}

SceneDesc withShutter(SceneDesc d) {
  d.camera.shutterOpen = kOpen;
  d.camera.shutterClose = kClose;
  d.materials.push_back(MaterialDesc{});  // the aggregate's prototypes' material 0
  d.materials.back().name = "grain";
  d.materials.back().type = MaterialType::Dielectric;
  return d;
}

// A ray from a sphere of radius 3 towards a point near the origin, at a time of the shutter.
Ray randomRay(Rng& rng) {
  Ray r;
  const float z = 2 * rng.next1D() - 1, phi = 2 * kPi * rng.next1D(), s = std::sqrt(std::max(0.0f, 1 - z * z));
  r.o = Vec3(s * std::cos(phi), z, s * std::sin(phi)) * 3.0f;
  const Vec3 target(rng.next1D() - 0.5f, rng.next1D() - 0.5f, rng.next1D() - 0.5f);
  r.d = normalize(target - r.o);
  r.time = kOpen + (kClose - kOpen) * rng.next1D();
  return r;
}

}  // namespace

TEST(AggregateMotion, TheBoundaryMovesAsTheSameMeshMovingOverTheShutter) {
  // Embree blends the moving mesh's vertices; the aggregate maps each ray by the blended
  // transform's inverse: the same surface at every time, hit at the same t with the same normal.
  const AggregateDesc a = turningBall();
  SceneDesc withAggregate = withShutter(SceneDesc{});
  withAggregate.aggregates = {a};
  SceneDesc withMesh = withShutter(SceneDesc{});
  MeshDesc m;
  m.name = "boundary";
  m.mesh = a.boundary;
  m.xf = a.xf;
  m.shutterXf = a.shutterXf;
  withMesh.meshes = {m};
  auto aggregateScene = Scene::build(withAggregate), meshScene = Scene::build(withMesh);
  Rng rng(11, 0);
  int hits = 0;
  for (int i = 0; i < 400; ++i) {
    const Ray r = randomRay(rng);
    Hit ha, hm;
    const bool fa = aggregateScene->intersectMedium(r, ha), fm = meshScene->intersect(r, hm);
    ASSERT_EQ(fa, fm) << "ray " << i;
    if (!fa) continue;
    ++hits;
    EXPECT_EQ(ha.kind, Hit::Boundary);
    EXPECT_NEAR(ha.t, hm.t, 2e-5f * hm.t) << "ray " << i;
    EXPECT_GT(dot(ha.ng, hm.ng), 0.9999f) << "ray " << i;
    // The point is in the medium just inside, at the ray's time only.
    const Vec3 in = ha.p + r.d * 1e-3f;
    EXPECT_EQ(aggregateScene->mediumAt(in, r.time), 0) << "ray " << i;
  }
  EXPECT_GT(hits, 200);
  // A ball's sweep is wider than the ball: some point is inside at the open, outside at the close.
  const AggregatePose open = AggregateMotion(a.xf, a.shutterXf->first, a.shutterXf->second, kOpen, kClose).at(kOpen);
  const Vec3 leftSide = open.pointToWorld(Vec3(0.2f - 0.9f, 0.0f, 0.0f));
  EXPECT_EQ(aggregateScene->mediumAt(leftSide, kOpen), 0);
  EXPECT_EQ(aggregateScene->mediumAt(leftSide, kClose), -1);
}

TEST(AggregateMotion, GrainsAreHitWhereTheBuildsGrainsStandMovedByTheBlend) {
  // A world ray at time τ meets the grain the build holds along the ray mapped back by the
  // blend's inverse (computed here in double, by Transform), at the same point and normal.
  const AggregateDesc a = turningBall();
  SceneDesc d = withShutter(SceneDesc{});
  d.aggregates = {a};
  auto scene = Scene::build(d);
  const Aggregate& built = *scene->aggregates()[0];
  const Vec3d origin = scene->renderOrigin();
  ASSERT_TRUE(origin == Vec3d{});  // render space is world here: the transforms apply as they are
  Transform xfInv;
  ASSERT_TRUE(a.xf.inverse(xfInv));
  Rng rng(12, 0);
  int hits = 0;
  for (int i = 0; i < 300; ++i) {
    const Ray r = randomRay(rng);
    Hit h;
    const bool found = scene->intersect(r, h);
    const double s = (double(r.time) - kOpen) / (double(kClose) - kOpen);
    Transform toBuild;  // D⁻¹ = xf M(s)⁻¹
    ASSERT_TRUE((Transform::blend(a.shutterXf->first, a.shutterXf->second, s) * xfInv).inverse(toBuild));
    const Vec3 ob = toBuild.point(r.o), v = toBuild.vector(r.d);
    const float scale = length(v);
    GrainHit g;
    const bool foundBuilt = built.intersect(ob, v / scale, 0.0f, kInf, g);
    ASSERT_EQ(found, foundBuilt) << "ray " << i;
    if (!found) continue;
    ++hits;
    EXPECT_EQ(h.kind, Hit::Grain);
    EXPECT_NEAR(h.t, g.t / scale, 1e-4f * h.t) << "ray " << i;
    EXPECT_EQ(h.grain.sphere, g.sphere);
    const Vec3 n = normalize(Transform::normal(toBuild, g.ng));  // normals by the inverse transpose
    EXPECT_GT(dot(h.ng, n), 0.9999f) << "ray " << i;
  }
  EXPECT_GT(hits, 100);
}

namespace {

// A box of sand grains sliding sideways by most of its width and turning by 8 degrees about
// y while the shutter is open, on a floor, under a sun and a sky (the moving mesh's test in
// test_scene.cpp, with an aggregate): blurred (built at mid-shutter, moving from `open` to
// `close`) or still, built at fraction f of the blend between them. The turn takes rays
// through the general mapping (aggregate_motion.h: t scaled, normals, proxy centres, closest
// boundary points), not a translation's shortcut.
SceneDesc slidingSand(Technique technique, bool blur, float f, uint64_t seed, int spp) {
  const Transform open = Transform::translate(Vec3(-0.6f, 0.0f, 0.0f)) * turnY(-4),
                  close = Transform::translate(Vec3(0.5f, 0.1f, 0.0f)) * turnY(4);
  SceneDesc s;
  s.settings.width = s.settings.height = 24;
  s.settings.spp = spp;
  s.settings.seed = seed;
  s.settings.technique = technique;
  if (technique != Technique::Ept) {
    // No switching measurement (one per position of a still box): fixed low orders, the
    // proxies carrying them, then the medium (VPT, and DA from a third of its usual depth:
    // the box is small). The 5-degree sun is narrow: level-of-detail paths enter the
    // medium at their first grain.
    s.settings.explicitBounces = 8;
    s.settings.proxies = ProxyUse::On;
    s.settings.daDepthFactor = 0.3f;
  }
  s.camera.cameraToWorld = Transform::lookAt(Vec3(0.0f, 1.5f, 4.0f), Vec3(0.0f, 0.0f, 0.0f), Vec3(0, 1, 0));
  s.camera.focalLength = 50;
  s.camera.horizontalAperture = s.camera.verticalAperture = 30;
  s.lights = granular::testing::sunAndSky();
  // The sun from behind, as bright as the sky: the sand's shadow falls on the floor in front
  // of it, in view.
  s.lights[0].xf = Transform::lookAt(Vec3(0.0f), Vec3(0.3f, -1.0f, 0.8f), Vec3(0, 0, 1));
  s.lights[0].intensity = 300;
  MaterialDesc sand;
  sand.name = "sand";
  sand.type = MaterialType::Dielectric;
  sand.absorption = Vec3(0.02f, 0.04f, 0.1f);
  s.materials.push_back(sand);
  MeshDesc floor;
  floor.name = "floor";
  floor.mesh = makeBox(Vec3(-3.0f, -0.8f, -3.0f), Vec3(3.0f, -0.5f, 3.0f));
  s.meshes = {floor};
  AggregateDesc box;
  box.name = "sand";
  box.boundary = makeBox(Vec3(-0.4f), Vec3(0.4f));
  box.grainRadius = 0.02f;
  box.tileSpheres = 64;
  box.prototypes = {GrainPrototypeDesc{"rock", makeRock(1, 0.2f, 2), 0}};
  box.weights = {1.0f};
  box.xf = Transform::blend(open, close, f);
  if (blur) {
    box.shutterXf = std::make_pair(open, close);
    s.camera.shutterOpen = kOpen;
    s.camera.shutterClose = kClose;
  }
  s.aggregates = {box};
  return s;
}

}  // namespace

TEST(AggregateMotion, ABlurredAggregateIsTheAverageOfItsShutterWithExplicitGrains) {
  const auto scene = [](bool blur, float f, uint64_t seed, int spp) {
    return slidingSand(Technique::Ept, blur, f, seed, spp);
  };
  EXPECT_GT(granular::testing::expectBlurIsTheShuttersAverage(scene, 256, "ept"), 8.0);
}

TEST(AggregateMotion, ABlurredAggregateIsTheAverageOfItsShutterWithTheHybrid) {
  const auto scene = [](bool blur, float f, uint64_t seed, int spp) {
    return slidingSand(Technique::Hybrid, blur, f, seed, spp);
  };
  EXPECT_GT(granular::testing::expectBlurIsTheShuttersAverage(scene, 256, "hybrid"), 8.0);
}

TEST(AggregateMotion, MotionNeverRebuildsTheAggregate) {
  // Its motion (shutter transforms, or the shutter they span) changes: the next build lends
  // the aggregate and moves it anew.
  SceneDesc d = slidingSand(Technique::Ept, true, 0.5f, 1, 1);
  auto first = Scene::build(d);
  SceneDesc moved = d;
  moved.aggregates[0].shutterXf->second = Transform::translate(Vec3(0.9f, 0.0f, 0.0f));
  SceneChanges c = compareScenes(d, moved);
  EXPECT_TRUE(c.aggregateMotion);
  EXPECT_TRUE(c.aggregates.empty());
  EXPECT_EQ(c.level(), SceneChange::Aggregates);
  EXPECT_EQ(describeChanges(c), "the aggregates' motion changed");
  auto second = Scene::build(moved, first.get());
  EXPECT_EQ(second->aggregatesBuilt(), 0);
  EXPECT_EQ(second->aggregatesReused(), 1);
  EXPECT_EQ(second->aggregates()[0].get(), first->aggregates()[0].get());
  // The new motion is the one used: at the shutter's close the box's right side is at 1.3.
  EXPECT_EQ(second->mediumAt(Vec3(1.25f, 0.0f, 0.0f), kClose), 0);
  EXPECT_EQ(first->mediumAt(Vec3(1.25f, 0.0f, 0.0f), kClose), -1);
  SceneDesc longer = d;
  longer.camera.shutterClose = 0.04f;
  EXPECT_TRUE(compareScenes(d, longer).aggregateMotion);
  EXPECT_FALSE(compareScenes(d, d).aggregateMotion);
}

TEST(AggregateMotion, StillFrameDropsItAndAClosedShutterIgnoresIt) {
  SceneDesc d = slidingSand(Technique::Ept, true, 0.5f, 1, 1);
  SceneDesc still = d;
  stillFrame(still);
  EXPECT_FALSE(still.aggregates[0].shutterXf.has_value());
  EXPECT_EQ(still.camera.shutterClose, 0.0f);
  // Built with the transforms but the shutter closed: at xf whatever the ray's time.
  SceneDesc shut = d;
  shut.camera.shutterOpen = shut.camera.shutterClose = 0;
  auto scene = Scene::build(shut);
  const Vec3 centre = d.aggregates[0].xf.point(Vec3(0.0f));
  EXPECT_EQ(scene->mediumAt(centre, 0.0f), 0);
  EXPECT_EQ(scene->mediumAt(centre, kClose), 0);
  EXPECT_TRUE(scene->aggregateAt(0, kClose).pose().still);
}

TEST(AggregateMotion, NoDiffusionInAnAggregateThatSweepsOverAnEmitterOrTheCamera) {
  // DA is off in an aggregate holding an emitter or the camera (Hybrid.NoDiffusionIn...):
  // a moving one holds what it passes over at some time of the shutter, though not where
  // it is built (mid-shutter). The sand's box spans x in [-1.0, -0.2] at the open, [0.1,
  // 0.9] at the close and about [-0.45, 0.35] at mid-shutter.
  const SceneDesc base = slidingSand(Technique::Hybrid, true, 0.5f, 1, 1);
  ASSERT_TRUE(std::isfinite(Scene::build(base)->diffusionDepth(0)));  // DA by default
  auto daWith = [&](const std::function<void(SceneDesc&)>& change, bool blur = true) {
    SceneDesc d = blur ? base : slidingSand(Technique::Hybrid, false, 0.5f, 1, 1);
    change(d);
    return std::isfinite(Scene::build(d)->diffusionDepth(0));
  };
  LightDesc l;
  l.name = "bulb";
  l.type = LightType::Sphere;
  l.radius = 0.05f;
  l.xf = Transform::translate(Vec3(-0.75f, 0.0f, 0.0f));  // inside at the open only
  auto addLight = [&](SceneDesc& d) { d.lights.push_back(l); };
  EXPECT_FALSE(daWith(addLight));
  EXPECT_TRUE(daWith(addLight, false));  // the still sand never reaches it
  l.xf = Transform::translate(Vec3(0.0f, 1.0f, 0.0f));  // above the sweep, clear of it
  EXPECT_TRUE(daWith(addLight));
  l.type = LightType::Rect;
  l.width = l.height = 0.1f;
  l.xf = Transform::translate(Vec3(-0.75f, 0.0f, 0.1f));
  EXPECT_FALSE(daWith(addLight));
  auto addLamp = [](SceneDesc& d) {
    MaterialDesc lamp;
    lamp.name = "lamp";
    lamp.emission = Vec3(1.0f);
    d.materials.push_back(lamp);
    MeshDesc m;
    m.name = "lamp";
    m.mesh = makeBox(Vec3(0.72f, 0.02f, -0.03f), Vec3(0.78f, 0.08f, 0.03f));  // inside at the close only
    m.material = int(d.materials.size()) - 1;
    d.meshes.push_back(m);
  };
  EXPECT_FALSE(daWith(addLamp));
  EXPECT_TRUE(daWith(addLamp, false));
  auto cameraIn = [](SceneDesc& d) {
    d.camera.cameraToWorld = Transform::lookAt(Vec3(0.75f, 0.05f, 0.0f), Vec3(0.75f, 0.05f, -1.0f), Vec3(0, 1, 0));
  };
  EXPECT_FALSE(daWith(cameraIn));
  EXPECT_TRUE(daWith(cameraIn, false));
}

TEST(AggregateMotion, JsonShutterTransformsReadAndAreChecked) {
  const std::string head = R"({"camera": {"shutter_open": -0.01, "shutter_close": 0.01},
    "aggregates": [{"name": "castle", "boundary": {"box": {}}, "prototypes": [{"shape": {"icosphere": {}}}],
                    "transform": {"translate": [0, 1, 0]}, "grain_radius": 0.1)";
  const SceneDesc d = parseSceneJson(
      head + R"(, "shutter_transforms": [{"translate": [-1, 1, 0]}, {"translate": [1, 1, 0], "rotate": [30, 0, 1, 0]}]}]})",
      "scene.json");
  ASSERT_TRUE(d.aggregates[0].shutterXf.has_value());
  EXPECT_TRUE(sameTransform(d.aggregates[0].shutterXf->first, Transform::translate(Vec3(-1, 1, 0))));
  EXPECT_NEAR(d.aggregates[0].shutterXf->second.m[0][2], 0.5, 1e-12);  // sin 30°
  EXPECT_FALSE(parseSceneJson(head + "}]}", "scene.json").aggregates[0].shutterXf.has_value());
  auto error = [&](const std::string& tail) {
    return granular::testing::errorOf([&] { parseSceneJson(head + tail, "scene.json"); });
  };
  EXPECT_NE(error(R"(, "shutter_transforms": [{"translate": [0, 0, 0]}]}]})").find("castle.shutter_transforms: expected"),
            std::string::npos);
  const std::string text = error(R"(, "shutter_transforms": [[1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1], )"
                                 R"([1,0,0,"x", 0,1,0,0, 0,0,1,0, 0,0,0,1]]}]})");
  EXPECT_NE(text.find("castle.shutter_transforms: expected a number"), std::string::npos) << text;
  const std::string singular = error(R"(, "shutter_transforms": [{}, {"scale": 0}]}]})");
  EXPECT_NE(singular.find("castle.shutter_transforms: is singular"), std::string::npos) << singular;
  const std::string turn = error(R"(, "shutter_transforms": [{"rotate": [-80, 0, 1, 0]}, {"rotate": [80, 0, 1, 0]}]}]})");
  EXPECT_NE(turn.find("castle.shutter_transforms: turns or flips too far"), std::string::npos) << turn;
  // Through the description alone (a USD front end's): the prim and its transform.
  SceneDesc bad = d;
  bad.aggregates[0].shutterXf->second.m[1][3] = std::nan("");
  const std::string e = granular::testing::errorOf([&] { validateSceneDesc(bad); });
  EXPECT_NE(e.find("castle.transform: is not finite"), std::string::npos) << e;
  bad.aggregates[0].shutterXf->second = Transform::scale(Vec3(-1, 1, 1));  // a mirror between the ends
  EXPECT_NE(granular::testing::errorOf([&] { validateSceneDesc(bad); }).find("castle.transform: turns or flips"),
            std::string::npos);
}

TEST(AggregateMotion, TheBlendsDeterminantIsBoundedExactly) {
  // A turn by θ keeps cos²(θ/2) of the volume at mid-shutter; a translation all of it.
  for (double deg : {0.0, 30.0, 90.0, 120.0, 170.0})
    EXPECT_NEAR(minBlendDeterminantRatio(turnY(-deg / 2), turnY(deg / 2)), std::pow(std::cos(deg * kPiD / 360), 2), 1e-9)
        << deg;
  EXPECT_NEAR(minBlendDeterminantRatio(Transform::translate(Vec3(-5.0f)), Transform::translate(Vec3(3.0f))), 1.0,
              1e-12);
  // Growing from 1 to 2: least at the open end.
  EXPECT_NEAR(minBlendDeterminantRatio(Transform(), Transform::scale(Vec3(2.0f))), 1.0, 1e-12);
  EXPECT_LE(minBlendDeterminantRatio(Transform(), Transform::scale(Vec3(1, 1, -1))), 0.0);
}
