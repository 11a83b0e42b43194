// ppt.cpp — proxy path tracing (Müller et al. 2016, §4). See ppt.h.
#include "ppt.h"

#include <algorithm>
#include <cmath>

#include "ept.h"
#include "sampling.h"
#include "vpt.h"

namespace granular {

namespace {

constexpr float kMinNeeChance = 0.125f;

// Whether a proxy hit is the grain g (the same sphere of the same aggregate's cell, or the
// same instance).
bool sameGrain(const Hit& h, const GrainStart& g) {
  if (h.aggregate >= 0)
    return h.aggregate == g.aggregate && h.grain.sphere == g.grain.sphere && h.grain.cell[0] == g.grain.cell[0] &&
           h.grain.cell[1] == g.grain.cell[1] && h.grain.cell[2] == g.grain.cell[2];
  return h.instancer >= 0 && h.instancer == g.instancer && h.instance == g.instance;
}

// The world point of a local point on the unit sphere of a proxy.
Vec3 onSphere(const GrainHit& g, const ProxyFrame& frame, const Vec3& local) {
  return g.center + frame.toWorld(local) * g.radius;
}

// Scattering off the grain of a proxy the path met (hit): NEE, then the next direction.
void scatter(const Scene& scene, PathState& path, const Hit& hit, const ProxyTable& table, const ProxyFrame& frame,
             int b) {
  const GrainHit& g = hit.grain;
  GrainStart own;
  own.aggregate = hit.aggregate;
  own.grain = g;
  own.inside = false;
  own.instancer = hit.instancer;
  own.instance = hit.instance;
  const auto& lights = scene.lights();
  path.linkObject = scene.linkObjectOf(hit);
  const float seenSun = scene.settings().sunRegularizationHalfAngle();
  // Next-event estimation where light can still arrive: a shadow ray from deep inside
  // crosses about depth / λ grains, so it is made with probability q = exp(−depth / 4R),
  // at least kMinNeeChance, and weighted 1/q (unbiased; depth from the distance field).
  // Domes alone are found as well by sampling the table (their light arrives from every
  // side): no shadow rays (q = 0; MIS then gives sampling the whole weight).
  // An instancer's grains have no distance field: always (q = 1).
  float q = 0;
  if (scene.proxyLightSampling()) {
    q = 1.0f;
    if (hit.aggregate >= 0) {
      const float depth = std::max(0.0f, -scene.aggregateAt(hit.aggregate, path.ray.time).boundaryDistance(g.center));
      q = std::max(kMinNeeChance, std::exp(-depth / (4.0f * g.radius)));
    }
  }
  if (!lights.empty() && q > 0 && (q >= 1.0f || path.rng.next1D() < q)) {
    const int li = scene.pickLight(path.nextLightU(), path.linkObject);
    const float lightPick = scene.lightPick(li, path.linkObject) * q;
    LightSample ls;
    const float u1 = path.rng.next1D(), u2 = path.rng.next1D(), uExit = path.rng.next1D();
    // Narrow suns as the setting's disk (RenderSettings::sunRegularization): a table's
    // densest cells (a near-sphere's refraction, f ~ 50 sr⁻¹) met by a 0.53° sun are
    // fireflies, and a proxy's grain, drawn anew at each visit, holds no glint a pixel could
    // resolve, behind an explicit grain or not. Escapes after a proxy see the same disk
    // (escapedRadiance), so MIS stays whole.
    if (scene.lightReaches(li, path.linkObject) && lights[li].sampleLiSeen(g.center, u1, u2, seenSun, ls) &&
        !isBlack(ls.Li)) {
      const ProxyDirection d = table.eval(b, frame.toLocal(ls.wi));
      if (d.pdf > 0) {
        const Vec3 from = scene.beforeSurfaces(g.center, onSphere(g, frame, table.exitPoint(b, d, uExit)),
                                               path.ray.time);
        const float dist = std::isfinite(ls.dist) ? std::max(0.0f, ls.dist - g.radius) * (1.0f - 1e-4f) : kInf;
        const ProxyShadow tr = scene.proxyTransmittance(from, ls.wi, dist, &own, path.rng.nextU32(), path.ray.time,
                                                        ShadowCasters{li, path.linkObject});
        path.cost[0] += 1;
        if (!tr.blocked()) {
          const Vec3 c = path.beta * d.f * ls.Li *
                         (ls.delta ? 1.0f / lightPick : powerHeuristic(ls.pdf * lightPick, d.pdf) / (ls.pdf * lightPick));
          path.addThroughProxies(c, tr);
        }
      }
    }
  }
  ProxyDirection d;
  const float uBin = path.rng.next1D(), v1 = path.rng.next1D(), v2 = path.rng.next1D(), uSide = path.rng.next1D(),
              uExit = path.rng.next1D();
  if (!table.sample(b, uBin, v1, v2, uSide, d)) {
    path.alive = false;  // nothing leaves this grain
    return;
  }
  path.beta *= d.f / d.pdf;
  if (d.straight) {
    // The straight lobe: on along the same line from the exit the table gives, as a grain
    // missed is crossed — a delta event, so the last scattering (its pdf for MIS, whose
    // next-event estimation counted this lobe in its shadow ray) stays the path's.
    path.from = own;
    path.ray.o = scene.beforeSurfaces(g.center, onSphere(g, frame, table.exitPoint(b, d, uExit)), path.ray.time);
    path.ray.tmin = 0;
    path.ray.tmax = kInf;
    if (!isFinite(path.beta) || isBlack(path.beta)) path.alive = false;
    return;
  }
  const Vec3 wi = normalize(frame.toWorld(d.w));
  path.scattered(false, d.pdf, g.center, q, seenSun);
  path.inGrain = false;
  path.from = own;
  path.ray.o = scene.beforeSurfaces(g.center, onSphere(g, frame, table.exitPoint(b, d, uExit)), path.ray.time);
  path.ray.d = wi;
  path.ray.tmin = 0;
  path.ray.tmax = kInf;
  // Shadow linking: the direct light this direction brings past objects that cast no shadow.
  addDirectPastNonCasters(scene, path, path.beta, path.ray.o, wi, [&](const Vec3& c, float dist, ShadowCasters who) {
    path.addThroughProxies(c, scene.proxyTransmittance(path.ray.o, wi, dist, &own, path.rng.nextU32(), path.ray.time,
                                                       who));
  });
  path.coneSpread = std::max(path.coneSpread, kDiffuseConeSpread);
  path.depth += kProxyOrders;
  ++path.proxyVisits;
  if (!russianRoulette(scene, path) || !isFinite(path.beta) || isBlack(path.beta)) path.alive = false;
}

}  // namespace

bool entersProxies(const Scene& scene, const PathState& path) {
  return path.mode == kEpt && path.alive && !path.inGrain &&
         ((path.from.aggregate >= 0 && scene.useProxies(path.from.aggregate)) ||
          (path.from.instancer >= 0 && scene.instancedProxies(path.from.instancer)));
}

bool lowOrdersDone(const Scene& scene, const PathState& path) {
  const int set = scene.settings().explicitBounces;
  if (set >= 0) return path.depth >= set;
  const int a = path.from.aggregate, i = path.from.instancer;
  const bool instanced = a < 0 && i >= 0 && scene.instancedProxies(i);
  if (path.mode == kPpt) return path.proxyVisits >= (instanced ? scene.instancedProxyVisits(i) : scene.proxyVisits(a));
  if (instanced) return scene.instancedProxyVisits(i) == 0;
  if (a >= 0 && scene.useProxies(a)) return scene.proxyVisits(a) == 0;
  return path.depth >= scene.explicitBounces(a);
}

void pptStep(const Scene& scene, PathState& path) {
  path.addPendingStraight();  // the path goes on among proxies
  if (path.depth >= scene.settings().maxDepth) {
    path.alive = false;
    return;
  }
  for (int crossing = 0; crossing < kMaxProxyCrossings; ++crossing) {
    Hit hit;
    const bool starts = path.from.aggregate >= 0 || path.from.instancer >= 0;
    // The shortcut's first grain, known from the explicit ray (ept.h): no walk to it.
    bool found = crossing == 0 && path.firstGrainAt >= 0 && scene.firstGrainProxy(path.ray, path.firstGrain, hit);
    if (!found) {
      found = scene.intersectProxies(path.ray, hit, starts ? &path.from : nullptr);
      path.cost[0] += 1;
    }
    if (endsAtLight(scene, path, found, hit)) return;
    if (hit.kind != Hit::Proxy) {  // a surface, or an explicit grain of an instancer without proxies
      path.firstGrainAt = -1;
      shadeSurface(scene, path, hit, false);
      break;
    }
    const GrainHit& g = hit.grain;
    const ProxyFrame frame(path.ray.d, (hit.p - g.center) / g.radius);
    // The grain's size in its tables' unit: the aggregate's grain radius, or an instancer's
    // prototype's radius at scale 1 (Hit::lengthScale), i.e. the instance's scale.
    const ProxyTable& table =
        hit.aggregate >= 0
            ? scene.proxyTable(hit.aggregate, g.prototype,
                               g.radius / scene.aggregates()[size_t(hit.aggregate)]->grainRadius())
            : scene.instancedProxyTable(hit.instancer, g.prototype, g.radius / hit.lengthScale);
    const int b = table.bBin(frame.b);
    // The shortcut's first grain (ept.h): met for sure; the spheres before it crossed.
    bool first = false;
    if (path.firstGrainAt >= 0) {
      first = sameGrain(hit, path.firstGrain);
      if (!first && hit.t > path.firstGrainAt) path.firstGrainAt = -1;  // passed it: chance again
    }
    if (first || (path.firstGrainAt < 0 && path.rng.next1D() < table.hitProbability(b))) {
      path.firstGrainAt = -1;
      scatter(scene, path, hit, table, frame, b);
      break;
    }
    // The grain is missed: the ray crosses the sphere and goes on from its far side (or
    // from before a surface that cuts the sphere, Scene::beforeSurfaces).
    const float advance = std::max(sphereFarSide(path.ray.o - g.center, path.ray.d, g.radius), hit.t);
    const Vec3 farSide = scene.beforeSurfaces(path.ray.o, path.ray.o + path.ray.d * advance, path.ray.time);
    const float moved = length(farSide - path.ray.o);
    path.ray.o = farSide;
    if (path.firstGrainAt >= 0) path.firstGrainAt = std::max(0.0f, path.firstGrainAt - moved);
    path.ray.tmin = 0;
    path.from.aggregate = hit.aggregate;
    path.from.grain = g;
    path.from.inside = false;
    path.from.instancer = hit.instancer;
    path.from.instance = hit.instance;
  }
  // The level-of-detail shortcut leaves for the medium after the low orders (ept.h).
  if (path.shortcut && path.alive && scene.hasMedia() && lowOrdersDone(scene, path)) {
    path.pendingStraight = Vec3(0.0f);  // the medium counts those grains as scatterings
    enterMedia(scene, path);
  }
}

}  // namespace granular
