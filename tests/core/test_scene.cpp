// Scene::build given the previous scene of the same stage: unchanged aggregates are
// reused (no voxelising, no TT work), changed ones are built anew, and the image is the
// one a fresh build gives, value for value.
#include <gtest/gtest.h>

#include <cstdlib>
#include <limits>

#include "core/error.h"
#include "core/render.h"
#include "core/scene.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;

namespace {

// Two sand balls side by side under a sun and a sky, small image.
SceneDesc twoBalls() {
  SceneDesc d = granular::testing::sandBallScene(Vec3(0.5f, 0.4f, 6.0f), 40.0f, 0.04f, 3, Vec3(0.5f, 0, 0));
  AggregateDesc second = d.aggregates[0];
  second.name = "ball2";
  second.seed = 5;
  second.xf = Transform::translate(Vec3(2.2f, 0, 0));
  d.aggregates.push_back(second);
  d.aggregates[0].id = 1;
  d.aggregates[1].id = 2;
  d.settings.width = 24;
  d.settings.height = 16;
  d.settings.spp = 2;
  return d;
}

Image renderScene(const Scene& scene) {
  Renderer r(scene);
  EXPECT_TRUE(r.render(scene.settings().spp));
  Image img = r.film().toImage();
  double sum = 0;  // the balls are lit: an image to compare, not two black ones
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) sum += img.at(x, y)[0];
  EXPECT_GT(sum / (img.width * img.height), 0.02);
  return img;
}

}  // namespace

TEST(SceneReuse, ALightEditVoxelisesNothingAndRendersAsAFreshBuild) {
  SceneDesc d = twoBalls();
  auto first = Scene::build(d);
  EXPECT_EQ(first->aggregatesBuilt(), 2);
  EXPECT_EQ(first->aggregatesReused(), 0);
  EXPECT_EQ(first->mediaDerived(), 2);
  d.lights[0].intensity *= 2;
  d.lights[0].xf = Transform::lookAt(Vec3(0.0f), Vec3(0.3f, -1.0f, -0.4f), Vec3(0, 0, 1));
  auto edited = Scene::build(d, first.get());
  EXPECT_EQ(edited->aggregatesBuilt(), 0);
  EXPECT_EQ(edited->aggregatesReused(), 2);
  EXPECT_EQ(edited->mediaDerived(), 0);
  for (int a = 0; a < 2; ++a) EXPECT_EQ(edited->aggregates()[a].get(), first->aggregates()[a].get());
  first.reset();  // the edited scene owns what it shares
  auto fresh = Scene::build(d);
  EXPECT_TRUE(granular::testing::sameImage(renderScene(*edited), renderScene(*fresh)));
}

TEST(SceneReuse, AMovedBoundaryRebuildsOnlyItsAggregate) {
  SceneDesc d = twoBalls();
  auto first = Scene::build(d);
  d.aggregates[1].xf = Transform::translate(Vec3(2.0f, 0.3f, 0));
  auto moved = Scene::build(d, first.get());
  EXPECT_EQ(moved->aggregatesBuilt(), 1);
  EXPECT_EQ(moved->aggregatesReused(), 1);
  EXPECT_EQ(moved->mediaDerived(), 1);
  EXPECT_EQ(moved->aggregates()[0].get(), first->aggregates()[0].get());
  EXPECT_NE(moved->aggregates()[1].get(), first->aggregates()[1].get());
  auto fresh = Scene::build(d);
  EXPECT_TRUE(granular::testing::sameImage(renderScene(*moved), renderScene(*fresh)));
}

TEST(SceneReuse, AnyInputOfAnAggregateOrItsGrainMaterialRebuildsIt) {
  const SceneDesc base = twoBalls();
  auto first = Scene::build(base);
  // Each edit touches the first ball only (the material edit: both share it).
  std::vector<std::pair<const char*, SceneDesc>> edits;
  auto edit = [&](const char* what) -> SceneDesc& { return edits.emplace_back(what, base).second; };
  edit("boundary point").aggregates[0].boundary.points[3].x += 1e-3f;
  edit("grain radius").aggregates[0].grainRadius = 0.05f;
  edit("packing rate").aggregates[0].packingRate = 0.55f;
  edit("seed").aggregates[0].seed = 4;
  edit("tile spheres").aggregates[0].tileSpheres = 64;
  edit("prototype mesh").aggregates[0].prototypes[0].mesh.points[0].y *= 1.01f;
  SceneDesc& twoRocks = edit("weights");
  twoRocks.aggregates[0].prototypes.push_back(twoRocks.aggregates[0].prototypes[0]);
  twoRocks.aggregates[0].weights = {0.5f, 0.5f};
  edit("grain material").materials[0].absorption.x *= 2;
  for (const auto& [what, d] : edits) {
    auto s = Scene::build(d, first.get());
    const bool both = std::string(what) == "grain material";
    EXPECT_EQ(s->aggregatesBuilt(), both ? 2 : 1) << what;
    EXPECT_EQ(s->aggregatesReused(), both ? 0 : 1) << what;
    EXPECT_NE(s->aggregates()[0].get(), first->aggregates()[0].get()) << what;
  }
  // The id only names the aggregate in the primId AOV: reused, and reported anew.
  SceneDesc renamed = base;
  renamed.aggregates[0].id = 11;
  auto s = Scene::build(renamed, first.get());
  EXPECT_EQ(s->aggregatesReused(), 2);
}

TEST(SceneReuse, AnEptSceneLendsItsGrainsButNotAMediumItNeverDerived) {
  SceneDesc d = twoBalls();
  d.settings.technique = Technique::Ept;
  auto ept = Scene::build(d);
  EXPECT_EQ(ept->mediaDerived(), 0);
  d.settings.technique = Technique::Hybrid;
  auto hybrid = Scene::build(d, ept.get());
  EXPECT_EQ(hybrid->aggregatesBuilt(), 0);
  EXPECT_EQ(hybrid->mediaDerived(), 2);
  ASSERT_TRUE(hybrid->hasMedia());
  auto fresh = Scene::build(d);
  EXPECT_TRUE(granular::testing::sameImage(renderScene(*hybrid), renderScene(*fresh)));
}

// Embree aborts the process on a ray it deems invalid (not finite, or beyond ~1.8e18): the
// scene answers such rays "no hit" instead, whatever input made them.
TEST(Scene, RaysEmbreeWouldRefuseHitNothing) {
  SceneDesc d = twoBalls();
  auto scene = Scene::build(d);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (const Vec3& o : {Vec3(1e30f, 0, 0), Vec3(nan, 0, 0), Vec3(0, 0, -kInf)}) {
    Ray r;
    r.o = o;
    r.d = Vec3(0, 0, 1);
    Hit hit;
    EXPECT_FALSE(scene->intersect(r, hit));
    EXPECT_FALSE(scene->intersectMedium(r, hit));
    EXPECT_FALSE(scene->occluded(o, r.d, 10.0f));
  }
}

// Render space: a stage far from the world origin is built near zero (scene_desc.h), so its
// grains are the same grains and the image the same, value for value.
TEST(Scene, AStageMovedFarFromTheOriginRendersTheSameImage) {
  SceneDesc d = twoBalls();
  auto near = Scene::build(d);
  const Image a = renderScene(*near);
  for (double far : {1e3, 1e6}) {
    SceneDesc m = d;
    const Transform move = Transform::translate(far, -far, far);
    m.camera.cameraToWorld = move * m.camera.cameraToWorld;
    for (auto& l : m.lights) l.xf = move * l.xf;
    for (auto& x : m.meshes) x.xf = move * x.xf;
    for (auto& g : m.aggregates) g.xf = move * g.xf;
    auto moved = Scene::build(m);
    EXPECT_EQ(moved->renderOrigin().x - near->renderOrigin().x, far);
    const Image b = renderScene(*moved);
    EXPECT_EQ(a.pixels, b.pixels) << far;
  }
}

// A floor 10^10 units wide under a dome is lit as one 10 units wide: its triangles' normals
// (cross products of edges whose squares leave float) once came out zero, and every ray
// leaving the floor met it again.
TEST(Scene, ASceneScaledUpBeyondFloatSquaresIsLitAsAtUnitScale) {
  auto floorUnderDome = [](double s) {
    SceneDesc d;
    d.settings.width = 16;
    d.settings.height = 12;
    d.settings.spp = 64;
    d.settings.technique = Technique::Ept;
    d.camera.cameraToWorld = Transform::scale(Vec3(float(s))) * Transform::lookAt(Vec3(0, 2, 3), Vec3(0), Vec3(0, 1, 0));
    d.camera.clipNear = 1e-3f;
    MeshDesc floor;
    floor.name = "floor";
    floor.mesh = makeBox(Vec3(-5, -0.1f, -5), Vec3(5, 0, 5));
    floor.xf = Transform::scale(Vec3(float(s)));
    d.meshes.push_back(floor);
    LightDesc dome;
    dome.name = "sky";
    dome.type = LightType::Dome;
    d.lights.push_back(dome);
    auto scene = Scene::build(d);
    Renderer r(*scene);
    EXPECT_TRUE(r.render(d.settings.spp));
    const Image img = r.film().toImage();
    double sum = 0;
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x) sum += img.at(x, y)[0];
    return sum / (img.width * img.height);
  };
  const double unit = floorUnderDome(1), big = floorUnderDome(1e9);
  EXPECT_GT(unit, 0.2);  // the grey floor under a white sky, and the sky
  // The same random numbers over the same geometry, scaled: only float rounding may differ.
  EXPECT_NEAR(big, unit, 1e-4 * unit);
}

TEST(Scene, AggregatesBuiltSideBySideAreThoseBuiltOneAtATime) {
  // Scene::build builds the balls concurrently; with a memory cap below one build's
  // estimate (GRANULAR_BUILD_MEMORY_MB) they are built one after the other. The same
  // aggregates either way: the same image, bit for bit, and the scene keeps their order.
  const SceneDesc d = twoBalls();
  ASSERT_GT(Aggregate::estimateBuildBytes(d.aggregates[0]), 1e3);
  auto together = Scene::build(d);
  const char* old = std::getenv("GRANULAR_BUILD_MEMORY_MB");
  const std::string saved = old ? old : "";
  setenv("GRANULAR_BUILD_MEMORY_MB", "0.0001", 1);
  auto alone = Scene::build(d);
  if (old) setenv("GRANULAR_BUILD_MEMORY_MB", saved.c_str(), 1);
  else unsetenv("GRANULAR_BUILD_MEMORY_MB");
  ASSERT_EQ(together->aggregates().size(), 2u);
  EXPECT_EQ(together->aggregates()[0]->name(), "ball");
  EXPECT_EQ(together->aggregates()[1]->name(), "ball2");
  EXPECT_EQ(together->aggregatesBuilt(), 2);
  EXPECT_TRUE(granular::testing::sameImage(renderScene(*together), renderScene(*alone)));
  // An error of either is the build's, as from a sequential build: the first one's.
  SceneDesc bad = d;
  bad.aggregates[1].grainRadius = 1e-7f;  // too many cells
  bad.aggregates[0].grainRadius = 2e-7f;
  try {
    Scene::build(bad);
    FAIL() << "built";
  } catch (const InputError& e) {
    EXPECT_EQ(e.object(), "ball");
  }
}

TEST(Scene, AMovingMeshBlursAsTheAverageOfTheShutter) {
  // A box sliding sideways by most of its width while the shutter is open, on a floor, under
  // a sun and a sky: the blurred image equals the average of 16 still images across the
  // shutter (a translation: Embree's linear motion is exact), per block and channel.
  const Vec3 from(-0.6f, 0.0f, 0.0f), to(0.5f, 0.1f, 0.0f);
  const float open = -0.02f, close = 0.02f;
  auto scene = [&](bool blur, float f, uint64_t seed, int spp) {
    SceneDesc s;
    s.settings.width = s.settings.height = 24;
    s.settings.spp = spp;
    s.settings.seed = seed;
    s.settings.technique = Technique::Ept;
    s.camera.cameraToWorld = Transform::lookAt(Vec3(0.0f, 1.5f, 4.0f), Vec3(0.0f, 0.0f, 0.0f), Vec3(0, 1, 0));
    s.camera.focalLength = 50;
    s.camera.horizontalAperture = s.camera.verticalAperture = 30;
    s.lights = granular::testing::sunAndSky();
    MeshDesc floor;
    floor.name = "floor";
    floor.mesh = makeBox(Vec3(-3.0f, -0.8f, -3.0f), Vec3(3.0f, -0.5f, 3.0f));
    MeshDesc box;
    box.name = "box";
    box.mesh = makeBox(Vec3(-0.4f), Vec3(0.4f));
    box.xf = Transform::translate(from + (to - from) * f);
    if (blur) {
      box.shutterXf = std::make_pair(Transform::translate(from), Transform::translate(to));
      s.camera.shutterOpen = open;
      s.camera.shutterClose = close;
    }
    s.meshes = {floor, box};
    return s;
  };
  EXPECT_GT(granular::testing::expectBlurIsTheShuttersAverage(scene, 256, "moving box"), 8.0);
  // Without an open shutter the transforms at its ends are not used: the still image at xf.
  const auto windows = granular::testing::blocks(24, 4);
  const auto still = granular::testing::renderEstimates(scene(false, 0.5f, 9, 256), windows);
  SceneDesc shut = scene(true, 0.5f, 9, 256);
  shut.camera.shutterOpen = shut.camera.shutterClose = 0;
  const auto atXf = granular::testing::renderEstimates(shut, windows);
  for (size_t b = 0; b < windows.size(); ++b) EXPECT_EQ(atXf[b].mean[0], still[b].mean[0]);
}
