// Stress: extreme inputs through Scene::build and the renderer with every technique, at
// tiny sizes (the fast subset of bench/stress.py, which runs the full sweep as separate
// processes with timeouts and peak RSS). Each case must either render with every sample
// finite, or be refused with an InputError where that is the documented outcome.
#include <gtest/gtest.h>

#include <cctype>
#include <chrono>
#include <iterator>
#include <functional>

#include "core/error.h"
#include "core/render.h"
#include "core/scene.h"
#include "core/shapes.h"

using namespace granular;

namespace {

// A ball of rock grains (R = 0.05, f = 0.6, absorbing IOR 1.5) over a floor, dome + sun,
// as bench/stress.py's base case, at 8x6 pixels and 2 spp.
SceneDesc baseScene() {
  SceneDesc s;
  s.settings.width = 8;
  s.settings.height = 6;
  s.settings.spp = 2;
  s.settings.seed = 1;
  s.camera.cameraToWorld = Transform::lookAt(Vec3(0.4f, 0.9f, 3.4f), Vec3(0.0f), Vec3(0, 1, 0));
  s.camera.focalLength = 35;
  s.camera.horizontalAperture = 36;
  s.camera.verticalAperture = 27;
  s.camera.clipNear = 0.01f;
  s.camera.clipFar = 100;
  MaterialDesc sand;
  sand.name = "sand";
  sand.type = MaterialType::Dielectric;
  sand.ior = 1.5f;
  sand.absorption = Vec3(0.1f, 0.2f, 0.4f);
  s.materials.push_back(sand);
  MaterialDesc floor;
  floor.name = "floor";
  s.materials.push_back(floor);
  MeshDesc m;
  m.name = "floor";
  m.mesh = makeBox(Vec3(-4, -1.3f, -4), Vec3(4, -1.0f, 4));
  m.material = 1;
  s.meshes.push_back(m);
  LightDesc dome;
  dome.name = "sky";
  dome.type = LightType::Dome;
  dome.color = Vec3(0.5f, 0.6f, 0.8f);
  s.lights.push_back(dome);
  LightDesc sun;
  sun.name = "sun";
  sun.type = LightType::Distant;
  sun.angle = 2;
  sun.intensity = 3;
  sun.xf = Transform::lookAt(Vec3(0.0f), Vec3(-0.4f, -1.0f, -0.3f), Vec3(0, 1, 0));
  s.lights.push_back(sun);
  AggregateDesc a;
  a.name = "ball";
  a.boundary = makeIcosphere(2);
  a.grainRadius = 0.05f;
  a.packingRate = 0.6f;
  a.seed = 1;
  a.tileSpheres = 64;
  a.prototypes = {GrainPrototypeDesc{"rock", makeRock(1, 0.2f, 1), 0}};
  a.weights = {1.0f};
  s.aggregates.push_back(a);
  return s;
}

void scaleScene(SceneDesc& s, float k) {
  Transform S = Transform::scale(Vec3(k));
  s.camera.cameraToWorld = S * s.camera.cameraToWorld * Transform::scale(Vec3(1.0f / k));
  s.camera.clipNear *= k;
  s.camera.clipFar *= k;
  for (MeshDesc& m : s.meshes) m.xf = S * m.xf;
  for (LightDesc& l : s.lights) {
    if (l.type == LightType::Sphere) {
      l.xf = Transform::translate(l.xf.point(Vec3(0.0f)) * k);
      l.radius *= k;
    }
  }
  for (AggregateDesc& a : s.aggregates) {
    a.xf = S * a.xf;
    a.grainRadius *= k;
  }
}

void cameraInside(SceneDesc& s) {
  s.camera.cameraToWorld = Transform::lookAt(Vec3(0.1f, 0.05f, 0.2f), Vec3(0.3f, -0.2f, -1), Vec3(0, 1, 0));
}

void lightInside(SceneDesc& s) {
  LightDesc bulb;
  bulb.name = "bulb";
  bulb.type = LightType::Sphere;
  bulb.xf = Transform::translate(Vec3(0, 0.1f, 0));
  bulb.radius = 0.15f;
  bulb.intensity = 20;
  s.lights = {bulb};
}

struct StressCase {
  const char* name;
  std::function<void(SceneDesc&)> edit;
  const char* refusedAttribute = nullptr;  // refused with an InputError naming it (documented)
};

const StressCase kCases[] = {
    {"packing 0.01", [](SceneDesc& s) { s.aggregates[0].packingRate = 0.01f; }},
    {"packing 0.64", [](SceneDesc& s) { s.aggregates[0].packingRate = 0.64f; }},
    {"absorption 0", [](SceneDesc& s) { s.materials[0].absorption = Vec3(0.0f); }},
    {"absorption 1e30", [](SceneDesc& s) { s.materials[0].absorption = Vec3(1e30f); }},
    {"absorption 0, 1e6, 1e30", [](SceneDesc& s) { s.materials[0].absorption = Vec3(0.0f, 1e6f, 1e30f); }},
    {"ior 1", [](SceneDesc& s) { s.materials[0].ior = 1.0f; }},
    {"ior 4", [](SceneDesc& s) { s.materials[0].ior = 4.0f; }},
    {"grain radius 1e-5 (too many tiles)", [](SceneDesc& s) { s.aggregates[0].grainRadius = 1e-5f; }, "grainRadius"},
    {"grain radius 0.5", [](SceneDesc& s) { s.aggregates[0].grainRadius = 0.5f; }},
    {"camera inside", cameraInside},
    {"sphere light inside", lightInside},
    {"small sphere light 5000 away",
     [](SceneDesc& s) {
       LightDesc lamp;
       lamp.name = "far lamp";
       lamp.type = LightType::Sphere;
       lamp.radius = 0.5f;
       lamp.intensity = 1e7f;
       lamp.xf = Transform::translate(Vec3(0, 5000, 0));
       s.lights.push_back(lamp);
     }},
    {"grazing face",
     [](SceneDesc& s) {
       s.aggregates[0].boundary = makeBox(Vec3(-1, -0.25f, -1), Vec3(1, 0.25f, 1));
       s.camera.cameraToWorld = Transform::lookAt(Vec3(0, 0.25f, 3), Vec3(0, 0.25f, 0), Vec3(0, 1, 0));
       s.lights[1].angle = 0;
       s.lights[1].xf = Transform::lookAt(Vec3(0.0f), Vec3(1, -1e-4f, 0.2f), Vec3(0, 1, 0));
     }},
    {"axis-aligned rays",
     [](SceneDesc& s) {
       s.aggregates[0].boundary = makeBox(Vec3(-1), Vec3(1));
       s.camera.cameraToWorld = Transform::lookAt(Vec3(0, 0, 4), Vec3(0.0f), Vec3(0, 1, 0));
       s.lights[1].angle = 0;  // a sun straight down: shadow rays along an axis too
       s.lights[1].xf = Transform::lookAt(Vec3(0.0f), Vec3(0, -1, 0), Vec3(0, 0, 1));
     }},
    {"scale 1e6", [](SceneDesc& s) { scaleScene(s, 1e6f); }},
    {"scale 1e-6", [](SceneDesc& s) { scaleScene(s, 1e-6f); }},
    {"scale 1e-6, camera and light inside",
     [](SceneDesc& s) {
       cameraInside(s);
       lightInside(s);
       scaleScene(s, 1e-6f);
     }},
};

}  // namespace

class Stress : public ::testing::TestWithParam<size_t> {};

TEST_P(Stress, RendersFiniteOrIsRefusedClearly) {
  const StressCase& c = kCases[GetParam()];
  for (Technique t : {Technique::Ept, Technique::EptVpt, Technique::Hybrid}) {
    SCOPED_TRACE(std::string(c.name) + ", " + techniqueName(t));
    SceneDesc d = baseScene();
    c.edit(d);
    d.settings.technique = t;
    auto t0 = std::chrono::steady_clock::now();
    std::unique_ptr<Scene> scene;
    try {
      scene = Scene::build(d);
    } catch (const InputError& e) {
      ASSERT_NE(c.refusedAttribute, nullptr) << e.what();
      EXPECT_EQ(e.attribute(), c.refusedAttribute) << e.what();
      continue;
    }
    EXPECT_EQ(c.refusedAttribute, nullptr) << "expected an InputError";
    Renderer r(*scene);
    ASSERT_TRUE(r.render(2));
    EXPECT_EQ(r.nonFiniteSamples(), 0);
    EXPECT_EQ(r.lostPaths(), 0);
    for (int y = 0; y < d.settings.height; ++y)
      for (int x = 0; x < d.settings.width; ++x) {
        Vec3 m = r.film().mean(x, y);
        ASSERT_TRUE(isFinite(m) && minComponent(m) >= 0) << x << "," << y;
      }
    double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_LT(seconds, 60.0);  // bounded (the full sweep's budget per case is larger)
  }
}

INSTANTIATE_TEST_SUITE_P(Cases, Stress, ::testing::Range<size_t>(0, std::size(kCases)),
                         [](const ::testing::TestParamInfo<size_t>& info) {
                           std::string n;
                           for (const char* p = kCases[info.param].name; *p; ++p)
                             n += std::isalnum((unsigned char)*p) ? *p : '_';
                           return n;
                         });
