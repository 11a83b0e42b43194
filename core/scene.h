// scene.h — the built scene: BVHs, aggregates, lights, materials and camera.
//
// Contract: Scene::build() turns a validated SceneDesc into everything the integrators
// query: intersect() returns the nearest surface, grain or area light along a ray;
// occluded() answers shadow rays. Grains are opaque to shadow rays (their interfaces
// are delta: light reaches through them only by path continuation). The scene is
// immutable once built and safe to query from many threads.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "aggregate.h"
#include "camera.h"
#include "embree_util.h"
#include "light.h"
#include "material.h"
#include "scene_desc.h"

namespace granular {

struct Hit {
  enum Kind { Surface, Grain, AreaLight } kind = Surface;
  float t = kInf;
  Vec3 p;
  Vec3 ng;                  // unit, outward from the surface or grain
  int material = -1;
  int light = -1;           // AreaLight
  int aggregate = -1;       // Grain
  float eps = 0;            // ray-offset scale at this hit
  float lengthScale = 1;    // world length of one unit of the object's own space (absorption)
};

class Scene {
 public:
  static std::unique_ptr<Scene> build(const SceneDesc& desc);

  bool intersect(const Ray& ray, Hit& hit) const;
  bool occluded(const Vec3& p, const Vec3& dir, float dist) const;

  const Camera& camera() const { return camera_; }
  const RenderSettings& settings() const { return settings_; }
  const Material& material(int i) const { return materials_[i]; }
  const std::vector<Light>& lights() const { return lights_; }
  const std::vector<int>& infiniteLights() const { return infiniteLights_; }
  const std::vector<std::unique_ptr<Aggregate>>& aggregates() const { return aggregates_; }
  double buildSeconds() const { return buildSeconds_; }

 private:
  Camera camera_;
  RenderSettings settings_;
  std::vector<Material> materials_;
  std::vector<Light> lights_;
  std::vector<int> infiniteLights_, areaLights_;
  std::vector<std::unique_ptr<Aggregate>> aggregates_;
  std::vector<TriangleMesh> worldMeshes_;   // per Embree geometry id
  std::vector<int> meshMaterial_;
  EmbreeDevice device_;
  EmbreeScene surfaces_;
  float sceneScale_ = 1;
  double buildSeconds_ = 0;
};

}  // namespace granular
