// ept.h — explicit path tracing (EPT) of surfaces and individual grains (seed §1.2).
//
// Contract: tracePath() returns the radiance arriving along a camera ray, estimated by
// unidirectional path tracing with next-event estimation and MIS (power heuristic) at
// non-delta surfaces, delta scattering at grain interfaces, Beer–Lambert absorption
// inside grains and Russian roulette on the throughput after rrDepth bounces. All
// randomness comes from the given Rng, so a path is a pure function of its seed.
#pragma once

#include "rng.h"
#include "scene.h"

namespace granular {

// What the first visible surface says about a pixel (the AOVs besides colour).
struct PrimaryInfo {
  bool hit = false;
  float depth = kInf;   // along the camera's view axis
  Vec3 normal;          // world geometric normal, facing the camera
  int kind = -1;        // Hit::Kind of the first hit
};

struct PathStats {
  int bounces = 0;
};

Vec3 tracePath(const Scene& scene, Ray ray, Rng& rng, PrimaryInfo* primary = nullptr, PathStats* stats = nullptr);

}  // namespace granular
