// compareScenes: every field of a description is compared, and each change is put in the
// category whose work it needs (a new view, new lights, some aggregates, everything); the
// aggregates it lists are those Scene::build makes anew given the previous scene.
#include <gtest/gtest.h>

#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "core/scene.h"
#include "core/shapes.h"

using namespace granular;

namespace {

// Two grain balls (each its own grain material, ids 1 and 2) on a ground (its own
// material), an unused material, a sun and a sky; all within one render-space grid cell,
// so that small edits keep the render origin.
SceneDesc twoBallsOnGround() {
  SceneDesc d;
  d.camera.cameraToWorld = Transform::lookAt(Vec3(0.5f, 1.0f, 7.0f), Vec3(0.5f, 0, 0), Vec3(0, 1, 0));
  d.camera.horizontalAperture = d.camera.verticalAperture = 40;
  d.settings.width = 24;
  d.settings.height = 16;
  d.settings.spp = 1;
  d.settings.technique = Technique::Ept;  // quick builds: no media

  MaterialDesc sand;
  sand.name = "sand";
  sand.type = MaterialType::Dielectric;
  sand.absorption = Vec3(0.02f, 0.04f, 0.1f);
  d.materials.push_back(sand);                  // 0: the first ball's grains
  MaterialDesc ground;
  ground.name = "ground";
  ground.albedoTexture.source = "/World/Looks/Ground/Diffuse";
  d.materials.push_back(ground);                // 1: the ground
  MaterialDesc salt = sand;
  salt.name = "salt";
  salt.ior = 1.54f;
  d.materials.push_back(salt);                  // 2: the second ball's grains
  MaterialDesc spare;
  spare.name = "spare";
  d.materials.push_back(spare);                 // 3: unused

  MeshDesc floor;
  floor.name = "floor";
  floor.mesh = makeBox(Vec3(-2, -1.2f, -2), Vec3(4, -1, 2));
  floor.mesh.uvs.assign(2 * floor.mesh.indices.size(), 0.5f);
  floor.material = 1;
  floor.id = 7;
  d.meshes.push_back(floor);

  LightDesc sun;
  sun.name = "sun";
  sun.intensity = 3;
  sun.xf = Transform::lookAt(Vec3(0.0f), Vec3(-0.4f, -1.0f, -0.5f), Vec3(0, 0, 1));
  d.lights.push_back(sun);
  LightDesc sky;
  sky.name = "sky";
  sky.type = LightType::Dome;
  sky.color = Vec3(0.5f, 0.6f, 0.8f);
  d.lights.push_back(sky);

  AggregateDesc ball;
  ball.name = "ball";
  ball.boundary = makeIcosphere(2);
  ball.grainRadius = 0.08f;
  ball.packingRate = 0.5f;
  ball.tileSpheres = 64;
  ball.seed = 3;
  ball.prototypes = {GrainPrototypeDesc{"rock", makeRock(1, 0.2f, 2), 0}};
  ball.weights = {1.0f};
  ball.id = 1;
  d.aggregates.push_back(ball);
  AggregateDesc ball2 = ball;
  ball2.name = "ball2";
  ball2.xf = Transform::translate(Vec3(2.2f, 0, 0));
  ball2.prototypes[0].material = 2;
  ball2.id = 2;
  d.aggregates.push_back(ball2);
  return d;
}

struct Edit {
  std::string what;
  std::function<void(SceneDesc&)> apply;
};

// Each edit, applied alone, is reported in `expected` (with these aggregates listed).
void expectEach(const std::vector<Edit>& edits, SceneChange expected, const std::vector<int>& aggregates = {}) {
  const SceneDesc base = twoBallsOnGround();
  for (const Edit& e : edits) {
    SceneDesc d = base;
    e.apply(d);
    const SceneChanges c = compareScenes(base, d);
    EXPECT_EQ(int(c.level()), int(expected)) << e.what << ": " << describeChanges(c);
    EXPECT_EQ(c.aggregates, aggregates) << e.what;
    EXPECT_FALSE(c.renderSpace) << e.what;
  }
}

}  // namespace

TEST(SceneChanges, AnEqualDescriptionIsUnchanged) {
  const SceneDesc a = twoBallsOnGround(), b = twoBallsOnGround();
  const SceneChanges c = compareScenes(a, b);
  EXPECT_EQ(int(c.level()), int(SceneChange::Unchanged));
  EXPECT_TRUE(c.aggregates.empty());
  EXPECT_EQ(describeChanges(c), "unchanged");
}

TEST(SceneChanges, EveryCameraFieldIsAView) {
  expectEach({{"cameraToWorld", [](SceneDesc& d) { d.camera.cameraToWorld.m[0][3] += 0.1; }},
              {"focalLength", [](SceneDesc& d) { d.camera.focalLength = 35; }},
              {"horizontalAperture", [](SceneDesc& d) { d.camera.horizontalAperture = 30; }},
              {"verticalAperture", [](SceneDesc& d) { d.camera.verticalAperture = 30; }},
              {"horizontalApertureOffset", [](SceneDesc& d) { d.camera.horizontalApertureOffset = 1; }},
              {"verticalApertureOffset", [](SceneDesc& d) { d.camera.verticalApertureOffset = 1; }},
              {"clipNear", [](SceneDesc& d) { d.camera.clipNear = 0.01f; }},
              {"clipFar", [](SceneDesc& d) { d.camera.clipFar = 100; }},
              {"lensRadius", [](SceneDesc& d) { d.camera.lensRadius = 0.01f; }},
              {"focusDistance", [](SceneDesc& d) { d.camera.focusDistance = 3; }}},
             SceneChange::View);
  SceneDesc d = twoBallsOnGround();
  d.camera.focalLength = 35;
  const SceneChanges c = compareScenes(twoBallsOnGround(), d);
  EXPECT_TRUE(c.camera && !c.settings);
  EXPECT_EQ(describeChanges(c), "new camera");
}

TEST(SceneChanges, SettingsThatSetViewTakesAreAView) {
  expectEach({{"width", [](SceneDesc& d) { d.settings.width = 32; }},
              {"height", [](SceneDesc& d) { d.settings.height = 32; }},
              {"spp", [](SceneDesc& d) { d.settings.spp = 4; }},
              {"seed", [](SceneDesc& d) { d.settings.seed = 9; }},
              {"maxDepth", [](SceneDesc& d) { d.settings.maxDepth = 64; }},
              {"rrDepth", [](SceneDesc& d) { d.settings.rrDepth = 3; }},
              {"threads", [](SceneDesc& d) { d.settings.threads = 2; }},
              {"bundleSize", [](SceneDesc& d) { d.settings.bundleSize = 8; }},
              {"tau", [](SceneDesc& d) { d.settings.tau = 2; }},
              {"explicitBounces", [](SceneDesc& d) { d.settings.explicitBounces = 4; }},
              {"daDepthFactor", [](SceneDesc& d) { d.settings.daDepthFactor = 2; }},
              {"daMinOrder", [](SceneDesc& d) { d.settings.daMinOrder = 4; }},
              {"roulette", [](SceneDesc& d) { d.settings.roulette = 0.5f; }},
              {"lod", [](SceneDesc& d) { d.settings.lod = 0; }},
              {"proxies", [](SceneDesc& d) {
                 d.settings.proxies = d.settings.proxies == ProxyUse::Off ? ProxyUse::On : ProxyUse::Off;
               }},
              {"domeCameraVisible", [](SceneDesc& d) { d.settings.domeCameraVisible = false; }},
              {"sunRegularization", [](SceneDesc& d) { d.settings.sunRegularization = 0; }},
              {"cropX0", [](SceneDesc& d) { d.settings.cropX0 = 1; }},
              {"cropX1", [](SceneDesc& d) { d.settings.cropX1 = 1; }},
              {"cropY0", [](SceneDesc& d) { d.settings.cropY0 = 1; }},
              {"cropY1", [](SceneDesc& d) { d.settings.cropY1 = 1; }}},
             SceneChange::View);
  // Between two techniques that both use the media: a view too.
  SceneDesc a = twoBallsOnGround(), b = a;
  a.settings.technique = Technique::EptVpt;
  b.settings.technique = Technique::Hybrid;
  SceneChanges c = compareScenes(a, b);
  EXPECT_EQ(int(c.level()), int(SceneChange::View));
  EXPECT_FALSE(settingsNeedBuild(a.settings, b.settings));
  b.camera.clipNear = 0.5f;
  EXPECT_EQ(describeChanges(compareScenes(a, b)), "new camera and settings");
}

TEST(SceneChanges, SettingsThatBuildReadsAreNotAView) {
  const SceneDesc base = twoBallsOnGround();
  // The lights built: the default dome of a stage without light, delta suns widened.
  expectEach({{"defaultLight", [](SceneDesc& d) { d.settings.defaultLight = false; }},
              {"physicalSun", [](SceneDesc& d) { d.settings.physicalSun = false; }}},
             SceneChange::Lights);
  SceneDesc d = base;
  d.settings.defaultLight = false;
  EXPECT_TRUE(settingsNeedBuild(base.settings, d.settings));
  // Media for every aggregate, or none: everything, though no grain is made anew.
  d = base;
  d.settings.technique = Technique::Hybrid;
  const SceneChanges c = compareScenes(base, d);
  EXPECT_EQ(int(c.level()), int(SceneChange::Everything));
  EXPECT_TRUE(c.media && c.settings);
  EXPECT_TRUE(c.aggregates.empty());
  EXPECT_TRUE(settingsNeedBuild(base.settings, d.settings));
  EXPECT_EQ(describeChanges(c), "everything (media) changed");
}

TEST(SceneChanges, EveryLightFieldIsLights) {
  expectEach({{"name", [](SceneDesc& d) { d.lights[0].name = "sun2"; }},
              {"type", [](SceneDesc& d) { d.lights[0].type = LightType::Sphere; }},
              {"xf", [](SceneDesc& d) { d.lights[0].xf.m[1][2] += 0.1; }},
              {"color", [](SceneDesc& d) { d.lights[0].color.y = 0.9f; }},
              {"intensity", [](SceneDesc& d) { d.lights[0].intensity = 6; }},
              {"exposure", [](SceneDesc& d) { d.lights[0].exposure = 1; }},
              {"normalize", [](SceneDesc& d) { d.lights[0].normalize = true; }},
              {"angle", [](SceneDesc& d) { d.lights[0].angle = 1; }},
              {"radius", [](SceneDesc& d) { d.lights[0].radius = 2; }},
              {"width", [](SceneDesc& d) { d.lights[0].width = 2; }},
              {"height", [](SceneDesc& d) { d.lights[0].height = 2; }},
              {"textureFile", [](SceneDesc& d) { d.lights[1].textureFile = "sky.exr"; }},
              {"a light removed", [](SceneDesc& d) { d.lights.pop_back(); }},
              {"a light added", [](SceneDesc& d) { d.lights.push_back(d.lights[0]); }}},
             SceneChange::Lights);
  SceneDesc d = twoBallsOnGround();
  d.lights[0].intensity = 6;
  d.camera.focalLength = 35;  // a build applies the view too
  EXPECT_EQ(describeChanges(compareScenes(twoBallsOnGround(), d)), "lights changed");
}

TEST(SceneChanges, EveryInputOfAnAggregateListsIt) {
  expectEach({{"name", [](SceneDesc& d) { d.aggregates[1].name = "other"; }},
              {"boundary points", [](SceneDesc& d) { d.aggregates[1].boundary.points[3].x += 1e-3f; }},
              {"boundary indices", [](SceneDesc& d) { std::swap(d.aggregates[1].boundary.indices[0],
                                                                 d.aggregates[1].boundary.indices[1]); }},
              {"boundary uvs", [](SceneDesc& d) {
                 d.aggregates[1].boundary.uvs.assign(2 * d.aggregates[1].boundary.indices.size(), 0);
               }},
              {"xf", [](SceneDesc& d) { d.aggregates[1].xf.m[1][3] += 0.01; }},
              {"prototype name", [](SceneDesc& d) { d.aggregates[1].prototypes[0].name = "pebble"; }},
              {"prototype mesh", [](SceneDesc& d) { d.aggregates[1].prototypes[0].mesh.points[0].y *= 1.01f; }},
              {"prototype material", [](SceneDesc& d) { d.aggregates[1].prototypes[0].material = 0; }},
              {"prototype count", [](SceneDesc& d) {
                 d.aggregates[1].prototypes.push_back(d.aggregates[1].prototypes[0]);
                 d.aggregates[1].weights = {0.5f, 0.5f};
               }},
              {"weights", [](SceneDesc& d) { d.aggregates[1].weights = {2.0f}; }},
              {"grainRadius", [](SceneDesc& d) { d.aggregates[1].grainRadius = 0.05f; }},
              {"sizes", [](SceneDesc& d) { d.aggregates[1].sizes = {1.0f}; }},
              {"sizeSpread", [](SceneDesc& d) { d.aggregates[1].sizeSpread = 0.1f; }},
              {"packingRate", [](SceneDesc& d) { d.aggregates[1].packingRate = 0.55f; }},
              {"seed", [](SceneDesc& d) { d.aggregates[1].seed = 4; }},
              {"tileSpheres", [](SceneDesc& d) { d.aggregates[1].tileSpheres = 128; }}},
             SceneChange::Aggregates, {1});
  // The id only names it in the primId AOV: a build, but nothing made anew.
  SceneDesc d = twoBallsOnGround();
  d.aggregates[1].id = 11;
  const SceneChanges c = compareScenes(twoBallsOnGround(), d);
  EXPECT_EQ(int(c.level()), int(SceneChange::Aggregates));
  EXPECT_TRUE(c.aggregateList && c.aggregates.empty());
  EXPECT_EQ(describeChanges(c), "the list of aggregates changed");
}

TEST(SceneChanges, EveryFieldOfAGrainMaterialListsItsAggregate) {
  expectEach({{"name", [](SceneDesc& d) { d.materials[2].name = "sugar"; }},
              {"type", [](SceneDesc& d) { d.materials[2].type = MaterialType::Lambert; }},
              {"albedo", [](SceneDesc& d) { d.materials[2].albedo.x = 0.9f; }},
              {"ior", [](SceneDesc& d) { d.materials[2].ior = 1.31f; }},
              {"absorption", [](SceneDesc& d) { d.materials[2].absorption.z = 0.5f; }},
              {"emission", [](SceneDesc& d) { d.materials[2].emission.x = 1; }},
              {"roughness", [](SceneDesc& d) { d.materials[2].roughness = 0.3f; }},
              {"energyCompensation", [](SceneDesc& d) { d.materials[2].energyCompensation = false; }},
              {"albedoTexture", [](SceneDesc& d) { d.materials[2].albedoTexture.file = "a.exr"; }},
              {"emissionTexture", [](SceneDesc& d) { d.materials[2].emissionTexture.file = "e.exr"; }},
              {"opacityTexture", [](SceneDesc& d) { d.materials[2].opacityTexture.file = "o.exr"; }},
              {"opacity", [](SceneDesc& d) { d.materials[2].opacity = 0.5f; }},
              {"opacityThreshold", [](SceneDesc& d) { d.materials[2].opacityThreshold = 0.5f; }}},
             SceneChange::Aggregates, {1});
}

TEST(SceneChanges, AGrainRoughnessRebuildsTheAggregatesOfThatMaterialAsSceneBuildDoes) {
  const SceneDesc before = twoBallsOnGround();
  SceneDesc after = before;
  after.materials[0].roughness = 0.4f;  // the first ball's grains frosted
  const SceneChanges c = compareScenes(before, after);
  EXPECT_EQ(int(c.level()), int(SceneChange::Aggregates));
  EXPECT_EQ(c.aggregates, std::vector<int>{0});
  EXPECT_FALSE(c.materials || c.meshes || c.lights || c.camera || c.settings);
  EXPECT_EQ(describeChanges(c), "1 aggregate changed");
  // What Scene::build then makes anew.
  auto first = Scene::build(before);
  auto second = Scene::build(after, first.get());
  EXPECT_EQ(second->aggregatesBuilt(), 1);
  EXPECT_EQ(second->aggregatesReused(), 1);
  EXPECT_NE(second->aggregates()[0].get(), first->aggregates()[0].get());
  EXPECT_EQ(second->aggregates()[1].get(), first->aggregates()[1].get());
}

TEST(SceneChanges, SurfacesAndTheirMaterialsAreEverything) {
  std::vector<Edit> edits = {
      {"mesh name", [](SceneDesc& d) { d.meshes[0].name = "beach"; }},
      {"mesh points", [](SceneDesc& d) { d.meshes[0].mesh.points[0].y -= 0.01f; }},
      {"mesh indices", [](SceneDesc& d) { std::swap(d.meshes[0].mesh.indices[0], d.meshes[0].mesh.indices[1]); }},
      {"mesh uvs", [](SceneDesc& d) { d.meshes[0].mesh.uvs[3] = 0.25f; }},
      {"mesh xf", [](SceneDesc& d) { d.meshes[0].xf.m[0][0] = 1.01; }},
      {"mesh material", [](SceneDesc& d) { d.meshes[0].material = 3; }},
      {"mesh visible", [](SceneDesc& d) { d.meshes[0].visible = false; }},
      {"mesh id", [](SceneDesc& d) { d.meshes[0].id = 8; }},
      {"a mesh added", [](SceneDesc& d) { d.meshes.push_back(d.meshes[0]); }},
      {"material name", [](SceneDesc& d) { d.materials[1].name = "sand floor"; }},
      {"material type", [](SceneDesc& d) { d.materials[1].type = MaterialType::Dielectric; }},
      {"material albedo", [](SceneDesc& d) { d.materials[1].albedo.y = 0.1f; }},
      {"material ior", [](SceneDesc& d) { d.materials[1].ior = 1.2f; }},
      {"material absorption", [](SceneDesc& d) { d.materials[1].absorption.x = 1; }},
      {"material emission", [](SceneDesc& d) { d.materials[1].emission.z = 1; }},
      {"material roughness", [](SceneDesc& d) { d.materials[1].roughness = 0.5f; }},
      {"material energyCompensation", [](SceneDesc& d) { d.materials[1].energyCompensation = false; }},
      {"material opacity", [](SceneDesc& d) { d.materials[1].opacity = 0.5f; }},
      {"material opacityThreshold", [](SceneDesc& d) { d.materials[1].opacityThreshold = 0.5f; }},
      {"texture file", [](SceneDesc& d) { d.materials[1].albedoTexture.file = "beach.exr"; }},
      {"texture source", [](SceneDesc& d) { d.materials[1].albedoTexture.source = "/World/Looks/Beach"; }},
      {"texture wrapS", [](SceneDesc& d) { d.materials[1].albedoTexture.wrapS = TextureWrap::Clamp; }},
      {"texture wrapT", [](SceneDesc& d) { d.materials[1].albedoTexture.wrapT = TextureWrap::Mirror; }},
      {"texture colorSpace", [](SceneDesc& d) { d.materials[1].albedoTexture.colorSpace = TextureColorSpace::Raw; }},
      {"texture channel", [](SceneDesc& d) { d.materials[1].albedoTexture.channel = 3; }},
      {"emission texture", [](SceneDesc& d) { d.materials[1].emissionTexture.file = "glow.exr"; }},
      {"opacity texture", [](SceneDesc& d) { d.materials[1].opacityTexture.file = "mask.exr"; }},
      {"an unused material", [](SceneDesc& d) { d.materials[3].albedo = Vec3(0.2f); }},
      {"a material added", [](SceneDesc& d) { d.materials.push_back(d.materials[3]); }}};
  for (int k = 0; k < 4; ++k) {
    const std::string c = std::to_string(k);
    edits.push_back({"texture scale " + c, [k](SceneDesc& d) { d.materials[1].albedoTexture.scale[k] = 2; }});
    edits.push_back({"texture bias " + c, [k](SceneDesc& d) { d.materials[1].albedoTexture.bias[k] = 0.1f; }});
  }
  expectEach(edits, SceneChange::Everything);
  SceneDesc d = twoBallsOnGround();
  d.meshes[0].visible = false;
  d.materials[1].albedo.y = 0.1f;
  d.lights[0].intensity = 1;
  EXPECT_EQ(describeChanges(compareScenes(twoBallsOnGround(), d)),
            "everything (meshes and materials) and lights changed");
}

TEST(SceneChanges, AMaterialOfGrainsAndASurfaceIsEverythingAndListsTheAggregates) {
  SceneDesc before = twoBallsOnGround();
  before.meshes[0].material = 0;  // the ground shares the first ball's sand
  SceneDesc after = before;
  after.materials[0].roughness = 0.2f;
  const SceneChanges c = compareScenes(before, after);
  EXPECT_EQ(int(c.level()), int(SceneChange::Everything));
  EXPECT_TRUE(c.materials);
  EXPECT_EQ(c.aggregates, std::vector<int>{0});
  EXPECT_EQ(describeChanges(c), "everything (materials) and 1 aggregate changed");
}

TEST(SceneChanges, DefaultGrainsFollowTheMaterialCountAsSceneBuildDoes) {
  // A prototype without a material takes the default grain, indexed after the scene's
  // materials: another material count is another index, and Scene::build makes it anew.
  SceneDesc before = twoBallsOnGround();
  before.aggregates[1].prototypes[0].material = -1;
  SceneDesc after = before;
  after.materials.push_back(after.materials[3]);
  const SceneChanges c = compareScenes(before, after);
  EXPECT_TRUE(c.materials);
  EXPECT_EQ(c.aggregates, std::vector<int>{1});
  auto first = Scene::build(before);
  auto second = Scene::build(after, first.get());
  EXPECT_EQ(second->aggregatesBuilt(), 1);
  EXPECT_EQ(second->aggregates()[0].get(), first->aggregates()[0].get());
}

TEST(SceneChanges, AggregatesRemovedOrReorderedAreLentAsSceneBuildLendsThem) {
  const SceneDesc before = twoBallsOnGround();
  SceneDesc swapped = before;
  std::swap(swapped.aggregates[0], swapped.aggregates[1]);
  SceneChanges c = compareScenes(before, swapped);
  EXPECT_EQ(int(c.level()), int(SceneChange::Aggregates));
  EXPECT_TRUE(c.aggregateList && c.aggregates.empty());
  auto first = Scene::build(before);
  auto second = Scene::build(swapped, first.get());
  EXPECT_EQ(second->aggregatesBuilt(), 0);
  EXPECT_EQ(second->aggregatesReused(), 2);

  SceneDesc removed = before;
  removed.aggregates.pop_back();
  c = compareScenes(before, removed);
  EXPECT_TRUE(c.aggregateList && c.aggregates.empty());
  EXPECT_EQ(int(c.level()), int(SceneChange::Aggregates));

  SceneDesc added = before;
  added.aggregates.push_back(before.aggregates[0]);
  added.aggregates.back().name = "ball3";
  added.aggregates.back().xf = Transform::translate(Vec3(1.1f, 1.5f, 0));
  c = compareScenes(before, added);
  EXPECT_EQ(c.aggregates, std::vector<int>{2});
  EXPECT_FALSE(c.aggregateList);
  EXPECT_EQ(describeChanges(c), "1 aggregate changed");
}

namespace {

SceneDesc moved(SceneDesc d, double x) {
  const Transform move = Transform::translate(x, 0.0, 0.0);
  d.camera.cameraToWorld = move * d.camera.cameraToWorld;
  for (MeshDesc& m : d.meshes) m.xf = move * m.xf;
  for (LightDesc& l : d.lights) l.xf = move * l.xf;
  for (AggregateDesc& a : d.aggregates) a.xf = move * a.xf;
  return d;
}

}  // namespace

// Aggregates are compared where Scene::build compares them: in render space, each
// description with its own render origin.
TEST(SceneChanges, AggregatesCompareInRenderSpaceAsSceneBuildDoes) {
  const SceneDesc before = twoBallsOnGround();
  auto first = Scene::build(before);
  // The stage moved by a multiple of its render-space grid: the grains stay where they
  // were in render space, the rest is built anew.
  SceneDesc after = moved(before, 1000.0);
  ASSERT_FALSE(renderOrigin(before) == renderOrigin(after));
  SceneChanges c = compareScenes(before, after);
  EXPECT_TRUE(c.renderSpace && c.meshes && c.lights && c.camera);
  EXPECT_EQ(int(c.level()), int(SceneChange::Everything));
  EXPECT_TRUE(c.aggregates.empty());
  EXPECT_EQ(Scene::build(after, first.get())->aggregatesBuilt(), 0);
  // Moved by less than the grid: the grains move in render space too.
  after = moved(before, 1000.3);
  c = compareScenes(before, after);
  EXPECT_EQ(c.aggregates, (std::vector<int>{0, 1}));
  EXPECT_EQ(Scene::build(after, first.get())->aggregatesBuilt(), 2);
  // One ball moves and takes the render origin with it: the other, still in the world,
  // moves in render space.
  SceneDesc far = twoBallsOnGround();
  far.meshes.clear();
  far.aggregates[0].xf = Transform::translate(Vec3(20, 0, 0));
  far.aggregates[1].xf = Transform::translate(Vec3(22.2f, 0, 0));
  SceneDesc farther = far;
  farther.aggregates[1].xf = Transform::translate(Vec3(40, 0, 0));
  ASSERT_FALSE(renderOrigin(far) == renderOrigin(farther));
  c = compareScenes(far, farther);
  EXPECT_TRUE(c.renderSpace);
  EXPECT_EQ(c.aggregates, (std::vector<int>{0, 1}));
  auto farScene = Scene::build(far);
  EXPECT_EQ(Scene::build(farther, farScene.get())->aggregatesBuilt(), 2);
}

TEST(SceneChanges, ANaNNeverEqualsItself) {
  SceneDesc d = twoBallsOnGround();
  d.lights[0].intensity = std::numeric_limits<float>::quiet_NaN();
  EXPECT_TRUE(compareScenes(d, d).lights);
}
