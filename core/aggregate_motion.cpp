// aggregate_motion.cpp — transform motion blur of procedural aggregates. See aggregate_motion.h.
#include "aggregate_motion.h"

#include <algorithm>
#include <cmath>

namespace granular {

namespace {

// Linear parts this close to the identity are rounding (D = M xf⁻¹ of a translated M).
constexpr double kIdentityTolerance = 1e-9;

bool linearIsIdentity(const Transform& d) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      if (std::fabs(d.m[i][j] - (i == j ? 1.0 : 0.0)) > kIdentityTolerance) return false;
  return true;
}

}  // namespace

AggregateMotion::AggregateMotion(const Transform& xf, const Transform& atOpen, const Transform& atClose,
                                 float shutterOpen, float shutterClose)
    : open_(shutterOpen), close_(shutterClose) {
  Transform inv;
  if (!(shutterClose > shutterOpen) || !xf.inverse(inv)) return;  // validateSceneDesc refuses a singular xf
  d0_ = atOpen * inv;
  d1_ = atClose * inv;
  translation_ = linearIsIdentity(d0_) && linearIsIdentity(d1_);
  if (translation_)
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) d0_.m[i][j] = d1_.m[i][j] = i == j ? 1.0 : 0.0;
  bool still = translation_;
  for (int i = 0; i < 3 && still; ++i) still = d0_.m[i][3] == 0 && d1_.m[i][3] == 0;
  moving_ = !still;
}

AggregatePose AggregateMotion::at(float time) const {
  AggregatePose pose;
  if (!moving_) return pose;
  pose.still = false;
  pose.translation = translation_;
  const double s = std::clamp((double(time) - open_) / (double(close_) - open_), 0.0, 1.0);
  const Transform blended = Transform::blend(d0_, d1_, s);
  const auto& d = blended.m;
  pose.offset = Vec3(float(d[0][3]), float(d[1][3]), float(d[2][3]));
  if (translation_) return pose;
  // The inverse of the linear part by cofactors (its determinant is bounded away from 0
  // over the shutter: validateAggregateMotion).
  const double det = d[0][0] * (d[1][1] * d[2][2] - d[1][2] * d[2][1]) -
                     d[0][1] * (d[1][0] * d[2][2] - d[1][2] * d[2][0]) +
                     d[0][2] * (d[1][0] * d[2][1] - d[1][1] * d[2][0]);
  const double r = 1.0 / det;
  const double inv[3][3] = {
      {(d[1][1] * d[2][2] - d[1][2] * d[2][1]) * r, (d[0][2] * d[2][1] - d[0][1] * d[2][2]) * r,
       (d[0][1] * d[1][2] - d[0][2] * d[1][1]) * r},
      {(d[1][2] * d[2][0] - d[1][0] * d[2][2]) * r, (d[0][0] * d[2][2] - d[0][2] * d[2][0]) * r,
       (d[0][2] * d[1][0] - d[0][0] * d[1][2]) * r},
      {(d[1][0] * d[2][1] - d[1][1] * d[2][0]) * r, (d[0][1] * d[2][0] - d[0][0] * d[2][1]) * r,
       (d[0][0] * d[1][1] - d[0][1] * d[1][0]) * r}};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      pose.toWorld.m[i][j] = float(d[i][j]);
      pose.toBuild.m[i][j] = float(inv[i][j]);
    }
  return pose;
}

Bounds3 AggregateMotion::sweep(const Bounds3& built) const {
  if (!moving_ || built.empty()) return built;
  Bounds3 b;
  for (const auto* d : {&d0_, &d1_})
    for (int c = 0; c < 8; ++c)
      b.extend(d->point(Vec3((c & 1) ? built.hi.x : built.lo.x, (c & 2) ? built.hi.y : built.lo.y,
                             (c & 4) ? built.hi.z : built.lo.z)));
  // Padded by more than the rounding of the mapped rays (the aggregate's own test is exact
  // in the build): a cull must never drop what the build's bounds would keep.
  const Vec3 pad = b.extent() * 1e-5f + Vec3(1e-6f * std::max(maxComponent(vabs(b.lo)), maxComponent(vabs(b.hi))));
  b.lo = b.lo - pad;
  b.hi = b.hi + pad;
  return b;
}

PosedAggregate::BuildRay PosedAggregate::toBuildRay(const Vec3& o, const Vec3& d) const {
  BuildRay r;
  r.o = pose_.pointToBuild(o);
  if (pose_.translation) {
    r.d = d;
    return r;
  }
  const Vec3 v = pose_.toBuild * d;
  r.scale = length(v);
  r.d = r.scale > 0 ? v / r.scale : d;
  if (!(r.scale > 0) || !std::isfinite(r.scale)) r.scale = 1;
  return r;
}

void PosedAggregate::hitToWorld(const BuildRay& r, GrainHit& hit, bool proxy) const {
  hit.t /= r.scale;
  hit.ng = pose_.normalToWorld(hit.ng);
  if (proxy) hit.center = pose_.pointToWorld(hit.center);
}

bool PosedAggregate::intersect(const Vec3& o, const Vec3& d, float tmin, float tmax, GrainHit& hit,
                               const GrainHit* from, bool inside) const {
  if (pose_.still) return agg_->intersect(o, d, tmin, tmax, hit, from, inside);
  const BuildRay r = toBuildRay(o, d);
  if (!agg_->intersect(r.o, r.d, tmin * r.scale, tmax * r.scale, hit, from, inside)) return false;
  hitToWorld(r, hit, false);
  return true;
}

bool PosedAggregate::occluded(const Vec3& o, const Vec3& d, float tmin, float tmax) const {
  if (pose_.still) return agg_->occluded(o, d, tmin, tmax);
  const BuildRay r = toBuildRay(o, d);
  return agg_->occluded(r.o, r.d, tmin * r.scale, tmax * r.scale);
}

bool PosedAggregate::intersectProxy(const Vec3& o, const Vec3& d, float tmin, float tmax, GrainHit& hit,
                                    const GrainHit* skip) const {
  if (pose_.still) return agg_->intersectProxy(o, d, tmin, tmax, hit, skip);
  const BuildRay r = toBuildRay(o, d);
  if (!agg_->intersectProxy(r.o, r.d, tmin * r.scale, tmax * r.scale, hit, skip)) return false;
  hitToWorld(r, hit, true);
  return true;
}

ProxyShadow PosedAggregate::proxyTransmittance(const Vec3& o, const Vec3& d, float tmin, float tmax,
                                               const ProxyTables& tables, const GrainHit* skip, uint64_t seed) const {
  if (pose_.still) return agg_->proxyTransmittance(o, d, tmin, tmax, tables, skip, seed);
  const BuildRay r = toBuildRay(o, d);
  return agg_->proxyTransmittance(r.o, r.d, tmin * r.scale, tmax * r.scale, tables, skip, seed);
}

GrainFlight PosedAggregate::flightToGrain(const Vec3& o, const Vec3& d, const ProxyTables& tables,
                                          const GrainHit* from, Rng& rng) const {
  if (pose_.still) return agg_->flightToGrain(o, d, tables, from, rng);
  const BuildRay r = toBuildRay(o, d);
  GrainFlight f = agg_->flightToGrain(r.o, r.d, tables, from, rng);
  if (f.met()) {
    f.t /= r.scale;
    f.entry = pose_.pointToWorld(f.entry);
  }
  return f;
}

bool PosedAggregate::intersectBoundary(const Vec3& o, const Vec3& d, float tmin, float tmax, float& t,
                                       Vec3& ng) const {
  if (pose_.still) return agg_->intersectBoundary(o, d, tmin, tmax, t, ng);
  const BuildRay r = toBuildRay(o, d);
  if (!agg_->intersectBoundary(r.o, r.d, tmin * r.scale, tmax * r.scale, t, ng)) return false;
  t /= r.scale;
  ng = pose_.normalToWorld(ng);
  return true;
}

float PosedAggregate::closestBoundaryPoint(const Vec3& p, Vec3& closest) const {
  if (pose_.still) return agg_->closestBoundaryPoint(p, closest);
  const float z = agg_->closestBoundaryPoint(pose_.pointToBuild(p), closest);
  closest = pose_.pointToWorld(closest);
  return pose_.translation ? z : length(closest - p);
}

}  // namespace granular
