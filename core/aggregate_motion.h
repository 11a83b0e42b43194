// aggregate_motion.h — transform motion blur of procedural aggregates.
//
// Contract: an aggregate is built once, at its transform xf (AggregateDesc::xf): its cells,
// distance field, grains and medium stay where that build put them, so its motion never
// rebuilds it nor changes its grains. Over the camera's shutter it moves as
// AggregateDesc::shutterXf says: its object-to-world transform blends linearly from the one
// at the shutter's open to the one at its close, M(s) = (1 − s) M_open + s M_close, s the
// ray's time over the shutter (clamped into it) — the blend Embree gives a moving mesh's
// vertices, so the boundary blurs as that mesh would. At time s the aggregate stands moved
// from its build by D(s) = M(s) xf⁻¹, itself the blend of D at the ends.
// AggregateMotion holds D at the ends; PosedAggregate is the aggregate at one time: its
// queries take world (render-space) rays and points, map them by D⁻¹ into the build, ask
// the aggregate and map its answers (t, normals, proxy centres, closest points) back. A
// still aggregate is asked directly: its answers are bit for bit the aggregate's.
// A blend of two rotations is not a rotation: between them the aggregate is pinched across
// the turn by cos(θ/2) at most (θ the turn over the shutter: 0.2% at 7.5°), grains and
// boundary alike, as the mesh would be (validateAggregateMotion refuses θ > 120°). Distances
// (closest point, signed distance, depth) are the build's: exact for translations and
// rotations, off by that factor in between. Proxy spheres keep their build radius.
#pragma once

#include "aggregate.h"

namespace granular {

// D at one time: world = toWorld · build + offset, build = toBuild · (world − offset).
struct AggregatePose {
  bool still = true;         // D is the identity: nothing is mapped
  bool translation = false;  // D is a translation by offset alone (linear parts exact identities)
  Mat3 toWorld, toBuild;     // linear parts of D and D⁻¹
  Vec3 offset;

  Vec3 pointToBuild(const Vec3& p) const { return translation ? p - offset : toBuild * (p - offset); }
  Vec3 pointToWorld(const Vec3& p) const { return translation ? p + offset : toWorld * p + offset; }
  Vec3 vectorToBuild(const Vec3& v) const { return translation ? v : toBuild * v; }
  // A build normal in the world (by D's inverse transpose), unit.
  Vec3 normalToWorld(const Vec3& n) const { return translation ? n : normalize(toBuild.transposeMul(n)); }
};

class AggregateMotion {
 public:
  AggregateMotion() = default;  // still
  // xf: the transform the aggregate is built at; atOpen, atClose: AggregateDesc::shutterXf;
  // the shutter in seconds about the frame (CameraDesc), open < close.
  AggregateMotion(const Transform& xf, const Transform& atOpen, const Transform& atClose, float shutterOpen,
                  float shutterClose);
  bool moving() const { return moving_; }
  // The pose at a ray's time (seconds about the frame, Ray::time).
  AggregatePose at(float time) const;
  // World bounds, over the whole shutter, of what lies within `built` in the build. Each
  // point moves along a segment (D is a blend), so the box's corners at both ends hold it.
  Bounds3 sweep(const Bounds3& built) const;

 private:
  bool moving_ = false, translation_ = false;
  Transform d0_, d1_;  // D at the shutter's open and close (rows 0-2 used)
  float open_ = 0, close_ = 0;
};

// An aggregate at one time of the shutter: Aggregate's queries (see there) on world rays
// and points. From an Aggregate alone (implicitly): still.
class PosedAggregate {
 public:
  PosedAggregate(const Aggregate& agg) : agg_(&agg) {}  // NOLINT: a still aggregate is posed as itself
  PosedAggregate(const Aggregate& agg, const AggregatePose& pose) : agg_(&agg), pose_(pose) {}

  const AggregatePose& pose() const { return pose_; }
  // Where a world point stands in the build (for what depends on distances alone).
  Vec3 toBuild(const Vec3& p) const { return pose_.still ? p : pose_.pointToBuild(p); }

  bool intersect(const Vec3& o, const Vec3& d, float tmin, float tmax, GrainHit& hit, const GrainHit* from = nullptr,
                 bool inside = false) const;
  bool occluded(const Vec3& o, const Vec3& d, float tmin, float tmax) const;
  bool intersectProxy(const Vec3& o, const Vec3& d, float tmin, float tmax, GrainHit& hit,
                      const GrainHit* skip = nullptr) const;
  ProxyShadow proxyTransmittance(const Vec3& o, const Vec3& d, float tmin, float tmax, const ProxyTables& tables,
                                 const GrainHit* skip, uint64_t seed) const;
  // t and entry in the world; the grain as the build names it (its cell and sphere).
  GrainFlight flightToGrain(const Vec3& o, const Vec3& d, const ProxyTables& tables, const GrainHit* from,
                            Rng& rng) const;
  Vec3 grainCenter(const GrainHit& g) const {
    return pose_.still ? agg_->grainCenter(g) : pose_.pointToWorld(agg_->grainCenter(g));
  }
  bool insideBoundary(const Vec3& p) const { return agg_->insideBoundary(toBuild(p)); }
  bool insideBoundaryFast(const Vec3& p) const { return agg_->insideBoundaryFast(toBuild(p)); }
  bool intersectBoundary(const Vec3& o, const Vec3& d, float tmin, float tmax, float& t, Vec3& ng) const;
  float closestBoundaryPoint(const Vec3& p, Vec3& closest) const;
  float boundaryDistance(const Vec3& p) const { return agg_->boundaryDistance(toBuild(p)); }

 private:
  // A world ray in the build: origin, unit direction, and the build's length per world
  // length along it (t_build = t_world · scale).
  struct BuildRay {
    Vec3 o, d;
    float scale = 1;
  };
  BuildRay toBuildRay(const Vec3& o, const Vec3& d) const;
  // Hit fields from the build back to the world.
  void hitToWorld(const BuildRay& r, GrainHit& hit, bool proxy) const;

  const Aggregate* agg_;
  AggregatePose pose_;
};

}  // namespace granular
