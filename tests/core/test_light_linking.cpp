// Light linking (LightDesc::lightLink, Scene::lightReaches): a light counts at a vertex only
// where it lights the vertex's object — sampled there (next-event estimation) or met by the
// direction sampled there (MIS's other half) — in every transport (EPT, proxies, the medium,
// DA), and each object picks among the lights that reach it. Shadow linking
// (LightDesc::shadowLink, shadows; Scene::castsShadow): a light's shadow rays pass the
// objects that cast no shadow from it, in every kind of shadow ray, and its direct light
// stays whole: a sampled direction that meets such an object has the light past it
// counted where it was sampled (ept.h: addDirectPastNonCasters).
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

namespace {

// floorUnderThreeLights with a black slab (y 2.5 to 2.6) above it, out of the camera's
// view: its shadow from the sun covers half the floor in view, and it hides some of the
// dome (it lies above the bulb). Black, it returns no light: the floor's light is direct.
// round: a black ball of radius 0.9 instead (centre (1.5, 2.5, 1.5), also out of view):
// directions that cross its bounds' corners miss it.
// A mesh of its own black material (it returns no light), added to d.
void addBlack(SceneDesc& d, const std::string& name, const TriangleMesh& mesh) {
  MaterialDesc black;
  black.name = "black";
  black.type = MaterialType::Lambert;
  black.albedo = Vec3(0.0f);
  d.materials.push_back(black);
  MeshDesc m;
  m.name = name;
  m.mesh = mesh;
  m.material = int(d.materials.size()) - 1;
  d.meshes.push_back(m);
}

// A ball of radius r at c.
TriangleMesh ball(const Vec3& c, float r) {
  return makeIcosphere(3).transformed(Transform::translate(c) * Transform::scale(Vec3(r)));
}

SceneDesc floorUnderASlab(bool round = false) {
  SceneDesc d = floorUnderThreeLights();
  addBlack(d, "slab",
           round ? ball(Vec3(1.5f, 2.5f, 1.5f), 0.9f) : makeBox(Vec3(0.5f, 2.5f, 0.5f), Vec3(3.0f, 2.6f, 3.0f)));
  return d;
}

}  // namespace

TEST(ShadowLinking, AnObjectThatCastsNoShadowFromALightIsPassedByItsShadowRays) {
  // The slab, or the ball, casts no shadow from any light — left out of each light's shadow
  // link, or every light's shadows off: the floor is as without it. The floor's sampled
  // directions still meet it, so the floor counts the light they would bring past it
  // itself, by a shadow ray: without that the floor would be darker. A direction past the
  // ball's bounds that misses it meets the light later, which must not count again, or
  // the floor would be brighter.
  const ChannelEstimate open = granular::testing::renderEstimate(floorUnderThreeLights());
  for (bool ball : {false, true}) {
    const char* what = ball ? "ball" : "slab";
    SceneDesc excluded = floorUnderASlab(ball);
    for (LightDesc& l : excluded.lights) l.shadowLink = "casters";
    excluded.meshes[0].linkCategories = {"casters"};
    expectSame(granular::testing::renderEstimate(excluded), open, what);
    SceneDesc off = floorUnderASlab(ball);
    for (LightDesc& l : off.lights) l.shadows = false;
    expectSame(granular::testing::renderEstimate(off), open, what);
    EXPECT_LT(granular::testing::renderEstimate(floorUnderASlab(ball)).mean[1], (ball ? 0.95 : 0.8) * open.mean[1])
        << what;
  }
  // The slab in the links (the floor, which shades nothing, left out): its shadow is back,
  // as without shadow linking, though light sampling alone now carries the direct light.
  const ChannelEstimate shaded = granular::testing::renderEstimate(floorUnderASlab());
  EXPECT_LT(shaded.mean[1], 0.8 * open.mean[1]);
  SceneDesc casting = floorUnderASlab();
  for (LightDesc& l : casting.lights) l.shadowLink = "casters";
  casting.meshes[1].linkCategories = {"casters"};
  auto scene = Scene::build(casting);
  for (int i = 0; i < 3; ++i) EXPECT_TRUE(scene->shadowLinked(i)) << i;
  expectSame(granular::testing::renderEstimate(casting), shaded, "the slab alone in the shadow links");
}

TEST(ShadowLinking, EveryShadowRayPassesWhatCastsNoShadowFromItsLight) {
  // On one line: an instancer's grain, a sand ball (grains, proxies, medium) and a wall.
  // Three suns, each whose shadows one of them alone casts, and the sky, whose shadows all
  // cast; and a sun whose shadows none casts.
  SceneDesc d = granular::testing::sandBallScene(Vec3(0, 0.3f, 4.0f), 30.0f, 0.05f, 3);
  d.settings.technique = Technique::Hybrid;
  d.settings.proxies = ProxyUse::On;
  MeshDesc wall;
  wall.name = "wall";
  wall.mesh = makeBox(Vec3(-1, -1, 3), Vec3(1, 1, 3.1f));
  wall.linkCategories = {"wall"};
  d.meshes.push_back(wall);
  InstancedGrainsDesc grains;
  grains.name = "grains";
  GrainPrototypeDesc round;
  round.name = "round";
  round.mesh = makeIcosphere(2);
  round.material = 0;
  grains.prototypes = {round};
  grains.positions.push_back(Vec3(0, 0, -5));
  grains.protoIndices.push_back(0);
  grains.linkCategories = {"grains"};
  d.instancedGrains.push_back(grains);
  d.aggregates[0].linkCategories = {"ball"};
  const LightDesc sun = d.lights[0], sky = d.lights[1];
  d.lights.clear();
  for (const char* caster : {"wall", "ball", "grains", "nothing"}) {
    LightDesc l = sun;
    l.name = caster;
    l.shadowLink = caster;
    d.lights.push_back(l);
  }
  d.lights.push_back(sky);
  auto scene = Scene::build(d);
  const Vec3 o(0, 0, -7), dir(0, 0, 1);
  const float dist = 14;
  const int wallSun = 0, ballSun = 1, grainsSun = 2, noneSun = 3, skyLight = 4;
  EXPECT_FALSE(scene->shadowLinked(skyLight));
  auto toward = [](int light) { return ShadowCasters{light, -1}; };
  // Explicit grains and surfaces (EPT): each caster alone blocks its sun.
  for (int l : {wallSun, ballSun, grainsSun, skyLight, -1})
    EXPECT_TRUE(scene->occluded(o, dir, dist, 0, toward(l))) << l;
  EXPECT_FALSE(scene->occluded(o, dir, dist, 0, toward(noneSun)));
  // The media (VPT, DA): the ball's medium, the wall.
  EXPECT_EQ(scene->transmittance(o, dir, dist, 0, nullptr, toward(noneSun)), Vec3(1.0f));
  // Too few grains for a medium of their own: to the media, the instancer's grain is a surface.
  EXPECT_EQ(scene->transmittance(o, dir, dist, 0, nullptr, toward(grainsSun)), Vec3(0.0f));
  EXPECT_EQ(scene->transmittance(o, dir, dist, 0, nullptr, toward(wallSun)), Vec3(0.0f));
  const Vec3 throughBall = scene->transmittance(o, dir, dist, 0, nullptr, toward(ballSun));
  EXPECT_GT(maxComponent(throughBall), 0.0f);  // exp(−σ_t 2): small, not 0
  EXPECT_LT(maxComponent(throughBall), 1e-3f);
  EXPECT_EQ(scene->transmittance(o, dir, dist, 0, nullptr, toward(skyLight)), Vec3(0.0f));
  // Proxies: the ball's spheres (the instancer has no medium, so no proxies: its grain is
  // a surface to them).
  const ProxyShadow none = scene->proxyTransmittance(o, dir, dist, nullptr, 7, 0, toward(noneSun));
  EXPECT_EQ(none.crossing, Vec3(1.0f));
  EXPECT_EQ(none.unscattered, 1.0f);
  EXPECT_TRUE(scene->proxyTransmittance(o, dir, dist, nullptr, 7, 0, toward(wallSun)).blocked());
  EXPECT_TRUE(scene->proxyTransmittance(o, dir, dist, nullptr, 7, 0, toward(grainsSun)).blocked());
  const ProxyShadow ball = scene->proxyTransmittance(o, dir, 7.0f, nullptr, 7, 0, toward(ballSun));
  EXPECT_LT(maxComponent(ball.crossing), 1.0f);  // 40 grains deep: attenuated, if not ended by roulette
  // A shadow ray leaving the ball is blocked by the ball even from the sun no object casts
  // shadows from: an object's shadow on itself stays (its light transport).
  const int self = scene->aggregateLinkObject(0);
  EXPECT_TRUE(scene->castsShadow(ballSun, self));
  EXPECT_FALSE(scene->castsShadow(noneSun, self));
  EXPECT_TRUE(scene->castsShadow(skyLight, self));
  const ShadowCasters fromBall{noneSun, self};
  EXPECT_TRUE(scene->occluded(o, dir, dist, 0, fromBall));
  EXPECT_EQ(scene->transmittance(o, dir, dist, 0, nullptr, fromBall), throughBall);
  EXPECT_LT(maxComponent(scene->proxyTransmittance(o, dir, 7.0f, nullptr, 7, 0, fromBall).crossing), 1.0f);
  // A scattering counts a light itself where the segment to it meets the bounds of another
  // object that casts no shadow from it: for the sun none casts, across the wall or the
  // ball; along the ray from inside the ball toward +z, the wall's bounds only.
  EXPECT_TRUE(scene->crossesNonCaster(noneSun, -1, o, dir, dist));
  EXPECT_FALSE(scene->crossesNonCaster(noneSun, -1, o, Vec3(0, 1, 0), kInf));     // up from below the line: nothing
  EXPECT_FALSE(scene->crossesNonCaster(skyLight, -1, o, dir, dist));             // every object casts
  EXPECT_FALSE(scene->crossesNonCaster(noneSun, self, Vec3(0.0f), dir, 2.0f));   // within the ball, its own
  EXPECT_TRUE(scene->crossesNonCaster(noneSun, self, Vec3(0.0f), dir, kInf));    // then the wall
  EXPECT_FALSE(scene->crossesNonCaster(wallSun, self, Vec3(0.0f), dir, kInf));   // the wall casts its sun's shadows
  EXPECT_EQ(scene->shadowLinksText(),
            "wall: 1 of 3 objects cast shadows; ball: 1 of 3 objects cast shadows; grains: 1 of 3 objects cast "
            "shadows; nothing: 0 of 3 objects cast shadows");
}

TEST(ShadowLinking, AnObjectThatCastsNoShadowOnAnAggregateIsPassedInEveryTransport) {
  // The sand ball under the sun and the sky, and a big black ball out of view above it that
  // hides the sun and most of the sky. Left out of both lights' shadow links, the black
  // ball changes nothing: at every vertex (a smooth grain's, a proxy's, the medium's, DA's)
  // light sampling passes it, and a sampled direction that meets it, or crosses its bounds,
  // has the light past it counted there. In the links it shades the ball. Explicit grains
  // alone, and then proxies after the first grain, and the hybrid.
  for (int variant = 0; variant < 3; ++variant) {
    const char* what = variant == 0 ? "explicit grains" : variant == 1 ? "ept, proxies" : "hybrid";
    SceneDesc plain = granular::testing::sandBallScene(Vec3(0, 0.3f, 4.0f), 30.0f, 0.05f, 3);
    plain.settings.width = plain.settings.height = 12;
    plain.settings.spp = 32;
    plain.settings.technique = variant < 2 ? Technique::Ept : Technique::Hybrid;
    plain.settings.proxies = variant == 0 ? ProxyUse::Off : ProxyUse::On;
    plain.lights[0].normalize = true;  // a sun of irradiance 3
    SceneDesc shaded = plain;
    addBlack(shaded, "blocker", ball(Vec3(0.0f, 4.2f, 0.0f), 2.4f));
    SceneDesc linked = shaded;
    linked.aggregates[0].linkCategories = {"casters"};
    for (LightDesc& l : linked.lights) l.shadowLink = "casters";
    const ChannelEstimate open = granular::testing::renderEstimate(plain);
    expectSame(granular::testing::renderEstimate(linked), open, what);
    const ChannelEstimate dark = granular::testing::renderEstimate(shaded);
    EXPECT_LT(dark.mean[1], 0.95 * open.mean[1]) << what;
  }
}

TEST(ShadowLinking, JsonScenesNameTheObjectsThatCastALightsShadows) {
  const std::string scene = R"({
    "meshes": [{"name": "floor", "shape": {"box": {"lo": [-1, -1, -1], "hi": [1, 0, 1]}}},
               {"name": "wall", "shape": {"box": {"lo": [-1, 0, -1], "hi": [1, 1, -0.9]}}}],
    "lights": [{"name": "sky", "type": "dome", "shadows": false},
               {"name": "rim", "type": "distant", "light_link": {"exclude": ["floor"]},
                "shadow_link": {"exclude": ["wall"]}}]
  })";
  const SceneDesc d = parseSceneJson(scene, "shadows.json");
  EXPECT_FALSE(d.lights[0].shadows);
  EXPECT_EQ(d.lights[0].shadowLink, "");
  EXPECT_TRUE(d.lights[1].shadows);
  EXPECT_EQ(d.lights[1].lightLink, "rim");
  EXPECT_EQ(d.lights[1].shadowLink, "rim:shadow");
  EXPECT_EQ(d.meshes[0].linkCategories, std::vector<std::string>{"rim:shadow"});
  EXPECT_EQ(d.meshes[1].linkCategories, std::vector<std::string>{"rim"});
  std::string bad = scene;
  bad.replace(bad.find("\"exclude\": [\"wall\"]"), 19, "\"exclude\": [\"wal\"] ");
  EXPECT_EQ(granular::testing::errorOf([&] { parseSceneJson(bad, "shadows.json"); }),
            "rim.shadow_link.exclude: \"wal\" is no mesh, aggregate or instanced grains of the scene");
  SceneDesc relinked = d;
  relinked.lights[1].shadowLink = "";
  EXPECT_EQ(compareScenes(d, relinked).level(), SceneChange::Lights);
  relinked = d;
  relinked.lights[0].shadows = true;
  EXPECT_EQ(compareScenes(d, relinked).level(), SceneChange::Lights);
}
