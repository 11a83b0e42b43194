// Light linking (LightDesc::lightLink, Scene::lightReaches): a light counts at a vertex only
// where it lights the vertex's object — sampled there (next-event estimation) or met by the
// direction sampled there (MIS's other half) — in every transport (EPT, proxies, the medium,
// DA), and each object picks among the lights that reach it.
#include <gtest/gtest.h>

#include "core/render.h"
#include "core/scene.h"
#include "core/scene_io.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;
using granular::testing::ChannelEstimate;

namespace {

// One object (material 0) seen from eye toward the origin (focal length 50, aperture 20),
// size x size pixels, under a white dome of radiance 1 and a normalised sun of irradiance 3
// and the given angle, whose light travels along sunDir.
SceneDesc oneObject(const Vec3& eye, int size, const std::string& name, const TriangleMesh& mesh,
                    const MaterialDesc& material, float sunAngle, const Vec3& sunDir, const Vec3& sunUp) {
  SceneDesc d;
  d.settings.width = d.settings.height = size;
  d.camera.cameraToWorld = Transform::lookAt(eye, Vec3(0, 0, 0), Vec3(0, 1, 0));
  d.camera.focalLength = 50;
  d.camera.horizontalAperture = d.camera.verticalAperture = 20;
  d.materials.push_back(material);
  MeshDesc object;
  object.name = name;
  object.mesh = mesh;
  object.material = 0;
  d.meshes.push_back(object);
  LightDesc dome;
  dome.name = "dome";
  dome.type = LightType::Dome;
  LightDesc sun;
  sun.name = "sun";
  sun.type = LightType::Distant;
  sun.angle = sunAngle;
  sun.intensity = 3;
  sun.normalize = true;
  sun.xf = Transform::lookAt(Vec3(0.0f), sunDir, sunUp);
  d.lights = {dome, sun};
  return d;
}

// A grey Lambert floor (a box's top, y = 0) seen from above under the dome, a sphere light
// beside the view and a 20° sun, 16 x 16 pixels. Nothing else: the floor's light is direct.
// Lights: dome, bulb, sun.
SceneDesc floorUnderThreeLights() {
  MaterialDesc grey;
  grey.name = "grey";
  grey.type = MaterialType::Lambert;
  grey.albedo = Vec3(0.5f);
  SceneDesc d = oneObject(Vec3(0, 4, 0.01f), 16, "floor", makeBox(Vec3(-3, -0.1f, -3), Vec3(3, 0, 3)), grey, 20,
                          Vec3(-0.3f, -1.0f, -0.4f), Vec3(0, 0, 1));
  d.settings.spp = 64;
  d.settings.seed = 5;
  LightDesc bulb;
  bulb.name = "bulb";
  bulb.type = LightType::Sphere;
  bulb.radius = 0.3f;
  bulb.intensity = 20;
  bulb.xf = Transform::translate(Vec3(1.5f, 1.0f, 0.2f));
  d.lights.insert(d.lights.begin() + 1, bulb);
  return d;
}

void expectSame(const ChannelEstimate& a, const ChannelEstimate& b, const char* what) {
  for (int c = 0; c < 3; ++c) {
    const double se = std::hypot(a.se[c], b.se[c]);
    ASSERT_GT(se, 0.0) << what;
    EXPECT_NEAR(a.mean[c], b.mean[c], 4 * se) << what << ", channel " << c;
  }
}

}  // namespace

TEST(LightLinking, ALightThatDoesNotLightAnObjectIsNeitherSampledNorMetThere) {
  // The bulb and the sun light nothing the floor is in: the floor is as under the dome alone,
  // with the bulb there but black (a light's body still hides what lies behind it). Were
  // either sampled there, or met by the directions the floor samples (MIS's other half:
  // Lambert's cosine lobe meets both), it would be brighter; under all three it is 2x so.
  SceneDesc linked = floorUnderThreeLights();
  linked.lights[1].lightLink = linked.lights[2].lightLink = "elsewhere";
  SceneDesc domeAlone = floorUnderThreeLights();
  domeAlone.lights[1].intensity = 0;
  domeAlone.lights.resize(2);
  const ChannelEstimate l = granular::testing::renderEstimate(linked);
  const ChannelEstimate a = granular::testing::renderEstimate(domeAlone);
  const ChannelEstimate all = granular::testing::renderEstimate(floorUnderThreeLights());
  expectSame(l, a, "both excluded");
  EXPECT_GT(all.mean[0], 2.0 * a.mean[0]);
  // A light the floor is linked to counts as if unlinked (the same image: its pick is the
  // same as without linking when every light reaches the floor).
  SceneDesc included = floorUnderThreeLights();
  included.lights[1].lightLink = "floorLights";
  included.meshes[0].linkCategories = {"floorLights"};
  const Image x = granular::testing::renderImage(included), y = granular::testing::renderImage(floorUnderThreeLights());
  EXPECT_TRUE(granular::testing::sameImage(x, y));
}

TEST(LightLinking, EachObjectPicksAmongTheLightsThatReachItAlone) {
  // The sun linked away from the floor, which the dome and the bulb still light: the floor
  // picks between those two in the proportions of the scene without the sun, and is as
  // quiet as that scene. Picked among all three, most of its light samples would go to the
  // sun and count nothing there (bench/README, "Light linking": 2.9 times the noise).
  SceneDesc linked = floorUnderThreeLights();
  linked.lights[2].lightLink = "elsewhere";
  SceneDesc withoutSun = floorUnderThreeLights();
  withoutSun.lights.resize(2);
  auto scene = Scene::build(linked), reference = Scene::build(withoutSun);
  Hit floor;
  floor.kind = Hit::Surface;
  floor.geom = 0;
  const int object = scene->linkObjectOf(floor);
  EXPECT_EQ(scene->lightPick(2, object), 0.0f);
  EXPECT_GT(scene->lightPick(2), 0.5f);  // the scene's own pick (the camera's, unlinked): mostly the sun
  for (int i = 0; i < 2; ++i) EXPECT_NEAR(scene->lightPick(i, object), reference->lightPick(i), 1e-6f) << i;
  const ChannelEstimate l = granular::testing::renderEstimate(linked);
  const ChannelEstimate r = granular::testing::renderEstimate(withoutSun);
  expectSame(l, r, "the sun linked away");
  EXPECT_LT(l.se[0], 1.2 * r.se[0]);
}

TEST(LightLinking, AnAggregateTheSunDoesNotLightIsLitByTheSkyAloneInEveryTransport) {
  // A sand ball alone under the sun and the sky; the sun lights no object. Each technique's
  // image is the sky's alone: explicit grains, and the hybrid with proxies after the first
  // grain, then the medium and DA.
  for (Technique t : {Technique::Ept, Technique::Hybrid}) {
    SceneDesc linked = granular::testing::sandBallScene(Vec3(0, 0.3f, 4.0f), 30.0f, 0.05f, 3);
    linked.settings.width = linked.settings.height = 12;
    linked.settings.spp = 32;
    linked.settings.technique = t;
    linked.settings.proxies = ProxyUse::On;
    linked.lights[0].normalize = true;  // a sun of irradiance 3: without linking it dominates
    SceneDesc skyAlone = linked, both = linked;
    linked.lights[0].lightLink = "rim";
    skyAlone.lights.erase(skyAlone.lights.begin());
    const ChannelEstimate l = granular::testing::renderEstimate(linked);
    const ChannelEstimate s = granular::testing::renderEstimate(skyAlone);
    expectSame(l, s, t == Technique::Ept ? "ept" : "hybrid");
    EXPECT_GT(granular::testing::renderEstimate(both).mean[0], 1.2 * s.mean[0]);  // the sky fills most of it
  }
}

TEST(LightLinking, JsonScenesNameTheObjectsALightLights) {
  const std::string scene = R"({
    "meshes": [{"name": "floor", "shape": {"box": {"lo": [-1, -1, -1], "hi": [1, 0, 1]}}},
               {"name": "wall", "shape": {"box": {"lo": [-1, 0, -1], "hi": [1, 1, -0.9]}}}],
    "aggregates": [{"name": "pile", "boundary": {"box": {"lo": [-0.2, 0, -0.2], "hi": [0.2, 0.2, 0.2]}},
                    "grain_radius": 0.02, "prototypes": [{"name": "g", "shape": {"icosphere": {"subdivisions": 1}}}]}],
    "lights": [{"name": "sky", "type": "dome"},
               {"name": "rim", "type": "distant", "light_link": {"exclude": ["floor"]}},
               {"name": "key", "type": "sphere", "light_link": {"include": ["pile", "wall"], "exclude": ["wall"]}}]
  })";
  const SceneDesc d = parseSceneJson(scene, "linking.json");
  EXPECT_EQ(d.lights[0].lightLink, "");
  EXPECT_EQ(d.lights[1].lightLink, "rim");
  EXPECT_EQ(d.lights[2].lightLink, "key");
  EXPECT_EQ(d.meshes[0].linkCategories, std::vector<std::string>{});
  EXPECT_EQ(d.meshes[1].linkCategories, std::vector<std::string>{"rim"});
  EXPECT_EQ(d.aggregates[0].linkCategories, (std::vector<std::string>{"rim", "key"}));
  std::string bad = scene;
  bad.replace(bad.find("\"exclude\": [\"floor\"]"), 20, "\"exclude\": [\"flor\"] ");
  EXPECT_EQ(granular::testing::errorOf([&] { parseSceneJson(bad, "linking.json"); }),
            "rim.light_link.exclude: \"flor\" is no mesh, aggregate or instanced grains of the scene");
}

TEST(LightLinking, ObjectsCategoriesAreTheLightsChangeNotTheSurfacesOrGrains) {
  // Relinking rebuilds the lights alone: no surface BVH, no voxelising.
  SceneDesc a = granular::testing::sandBallScene(Vec3(0, 0.3f, 4.0f), 30.0f, 0.05f, 3);
  MeshDesc floor;
  floor.name = "floor";
  floor.mesh = makeBox(Vec3(-3, -1.2f, -3), Vec3(3, -1, 3));
  a.meshes.push_back(floor);
  SceneDesc b = a;
  b.meshes[0].linkCategories = {"sun"};
  b.aggregates[0].linkCategories = {"sun"};
  b.lights[0].lightLink = "sun";
  const SceneChanges c = compareScenes(a, b);
  EXPECT_TRUE(c.lights);
  EXPECT_FALSE(c.meshes);
  EXPECT_TRUE(c.aggregates.empty());
  EXPECT_EQ(c.level(), SceneChange::Lights);
  SceneDesc only = a;
  only.aggregates[0].linkCategories = {"x"};
  EXPECT_EQ(compareScenes(a, only).level(), SceneChange::Lights);
}

TEST(LightLinking, ASmoothSurfaceAimsItsFresnelChoiceOnlyAtSunsThatLightIt) {
  // A glass ball under a dome and a 30° sun behind the camera that is linked away from it.
  // Where a branch of the ball's smooth choice would leave into the sun, the choice leans
  // toward that branch (ept.cpp, sampleSmoothTowardSuns), which is worth it only for a sun
  // that counts there: linked away, the ball's choices are its Fresnel chances, and its
  // image is that of the scene without the sun, value for value (glass samples no light).
  MaterialDesc glass;
  glass.name = "glass";
  glass.type = MaterialType::Dielectric;
  glass.ior = 1.5f;
  SceneDesc withSun = oneObject(Vec3(0, 0, 4), 12, "ball", makeIcosphere(3), glass, 30, Vec3(0, -0.2f, -1),
                                Vec3(0, 1, 0));  // the sun from behind the camera
  withSun.settings.spp = 16;
  SceneDesc linkedAway = withSun, withoutSun = withSun;
  linkedAway.lights[1].lightLink = "elsewhere";
  withoutSun.lights.resize(1);
  const Image a = granular::testing::renderImage(linkedAway), b = granular::testing::renderImage(withoutSun);
  EXPECT_TRUE(granular::testing::sameImage(a, b));
  EXPECT_FALSE(granular::testing::sameImage(granular::testing::renderImage(withSun), b));  // the sun shows
}
