// grain.h — grain prototypes and the per-grain random choices (Meng et al. 2015's
// stochastic grain model: grain type by the mixing weights, random rotation).
//
// Contract: a GrainPrototype is its mesh moved and scaled into the unit bounding
// sphere (centre at the origin, radius 1, outward winding) with its own Embree BVH, so
// a grain of bounding radius R at centre c with rotation Q maps a local point q to
// c + R Q q. GrainSelector draws a grain's prototype (by the mixing weights) and its
// uniform random rotation from a hash of (tile cell, sphere id, seed): deterministic,
// nothing stored per grain. Polydisperse aggregates: a tile sphere belongs to a size class
// (packing.h), and its grain is drawn among the prototypes of that size, by their weights.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "embree_util.h"
#include "math.h"
#include "rng.h"
#include "sampling.h"
#include "scene_desc.h"

namespace granular {

// Rays leave a grain hit offset by this many grain radii along its normal (EPT, the TT
// estimation in the unit sphere, and whoever traces paths through an aggregate).
constexpr float kGrainEps = 2e-4f;

struct GrainPrototype {
  std::string name;
  TriangleMesh mesh;        // in the unit bounding sphere
  int material = -1;        // scene material index
  EmbreeScene bvh;
  Vec3 fitCenter;           // bounding-sphere centre in the description's space
  float fitRadius = 1.0f;   // its radius there
  std::vector<Vec3> normals;     // unit face normals (triangleNormal), per triangle
  // Per triangle: a face of the convex hull (hullFaces). A ray that leaves the grain
  // through it cannot meet the grain again: all of it lies behind that plane.
  std::vector<uint8_t> hullFace;
};

// Per triangle of a closed, outward-wound mesh: 1 when no vertex lies in front of its
// plane by more than `tolerance` (in the mesh's units).
std::vector<uint8_t> hullFaces(const TriangleMesh& mesh, float tolerance);

// Normalises desc.mesh into its bounding sphere (Ritter's approximate minimal sphere,
// refined) and builds its BVH. The mesh must already be validated as closed.
GrainPrototype makeGrainPrototype(const EmbreeDevice& device, const GrainPrototypeDesc& desc);

// A ray against one grain: the prototype turned by `rotation` and scaled to bounding radius
// `radius`, the ray's origin oc relative to the grain's centre. Traced in the grain's frame,
// where the direction is scaled by 1/radius too, so t is the world ray's. On a hit: t, the
// prototype's triangle and its normal turned into the world (unit up to rounding).
bool tracePrototype(const GrainPrototype& proto, const Mat3& rotation, float radius, const Vec3& oc, const Vec3& d,
                    float tmin, float tmax, float& t, unsigned& prim, Vec3& ng);

struct GrainChoice {
  int prototype = 0;
  Mat3 rotation;
};

// An aggregate's size classes: its distinct prototype sizes (AggregateDesc::sizes, 1 when
// empty) among prototypes of weight > 0, in order of first appearance, each with the summed
// weight of its prototypes; classOf[i] is prototype i's class (-1: weight 0, never drawn).
// One class of size 1 is the monodisperse aggregate.
struct SizeClasses {
  std::vector<float> size;
  std::vector<double> weight;
  std::vector<int> classOf;
};
SizeClasses sizeClassesOf(const AggregateDesc& desc);
// The Sauter mean size s_32 = E[s³] / E[s²] of the grains an aggregate's tile would hold:
// its classes in proportion to their weights, each spread uniformly by ±sizeSpread
// (E[(1 + a u)³] = 1 + a², E[(1 + a u)²] = 1 + a²/3); exactly 1 for one size of 1. Also
// the mean grain volume's factor E[s³] (meanCube).
double sauterSizeOf(const AggregateDesc& desc, double* meanCube = nullptr);

class GrainSelector {
 public:
  GrainSelector() = default;
  GrainSelector(const std::vector<float>& weights, const SizeClasses& classes, uint64_t seed);
  // cell: the tile cell holding the sphere's centre; sphere: its index in the tile; cls:
  // its size class.
  GrainChoice choose(int64_t cx, int64_t cy, int64_t cz, int sphere, int cls = 0) const {
    uint64_t h = hashInts(seed_, uint64_t(cx), uint64_t(cy), uint64_t(cz), uint64_t(sphere));
    GrainChoice c;
    c.prototype = perClass_[size_t(cls)].sampleDiscrete(toUnitFloat(h));
    uint64_t h2 = mix64(h + 1), h3 = mix64(h + 2);
    c.rotation = sampleUniformRotation(toUnitFloat(h2), toUnitFloat(h2 << 24), toUnitFloat(h3));
    return c;
  }
  // choose()'s prototype alone (proxies need no rotation: their tables average over it).
  int prototype(int64_t cx, int64_t cy, int64_t cz, int sphere, int cls = 0) const {
    uint64_t h = hashInts(seed_, uint64_t(cx), uint64_t(cy), uint64_t(cz), uint64_t(sphere));
    return perClass_[size_t(cls)].sampleDiscrete(toUnitFloat(h));
  }

 private:
  std::vector<Distribution1D> perClass_;  // over all prototypes, the other classes' at 0
  std::vector<int> classOf_;
  uint64_t seed_ = 0;
};

}  // namespace granular
