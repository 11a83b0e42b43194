#include "ept.h"

#include <optional>

#include "ppt.h"
#include "vpt.h"

namespace granular {

void addAreaLightHit(const Scene& scene, PathState& path, const Hit& hit) {
  const Vec3& dir = path.ray.d;
  if (!scene.lightReaches(hit.light, path.linkObject)) return;
  const Light& light = scene.lights()[hit.light];
  float w = 1.0f;
  const float dist = length(hit.p - path.lastP);
  // Past an object that casts no shadow from it, the last scattering counted it already
  // (addDirectPastNonCasters); the camera sees it.
  if (path.depth > 0 && scene.crossesNonCaster(hit.light, path.linkObject, path.lastP, dir, dist)) return;
  if (!path.lastDelta) {
    w = powerHeuristic(path.lastPdf, light.pdfLi(path.lastP, dir, dist) * scene.lightPick(hit.light, path.linkObject) *
                                         path.lastNeeChance);
  }
  path.L[path.credit] += path.beta * light.areaLe(hit.p, dir) * w;
}

Vec3 primaryAlbedo(const Scene& scene, const Hit& hit) {
  switch (hit.kind) {
    case Hit::Surface: {
      if (hit.material < 0) return Vec3(1.0f);
      std::optional<Material> storage;
      const Material& m = scene.shadingMaterial(hit, 0.0f, storage);
      return m.type == MaterialType::Lambert ? m.albedo : Vec3(1.0f);
    }
    case Hit::Grain:
    case Hit::Boundary:
    case Hit::Proxy: {
      if (hit.instancer >= 0 && scene.instancedMedium(hit.instancer))
        return scene.instancedDiffuseReflectance(hit.instancer);
      if (!scene.hasMedia() || hit.aggregate < 0) return Vec3(1.0f);
      return scene.diffusionProfile(hit.aggregate).diffuseReflectance;
    }
    case Hit::AreaLight: return Vec3(1.0f);
  }
  return Vec3(1.0f);
}

void recordPrimary(const Scene& scene, PathState& path, const Hit& hit) {
  if (path.primary.hit) return;
  path.primary.albedo = primaryAlbedo(scene, hit);
  path.primary.hit = true;
  path.primary.depth = scene.camera().viewDepth(hit.p);
  path.primary.normal = dot(hit.ng, path.ray.d) > 0 ? -hit.ng : hit.ng;
  path.primary.kind = int(hit.kind);
  path.primary.primId = hit.primId;
  const Scene::HitIdentity who = scene.identify(hit);
  path.primary.instanceId = who.instanceId;
  path.primary.aggregateId = who.aggregateId;
  path.primary.cryptomatte[0] = who.cryptomatte[0];
  path.primary.cryptomatte[1] = who.cryptomatte[1];
}

PathState startPath(const Ray& ray, uint64_t rngSeed, float spread, float width) {
  PathState p;
  p.ray = ray;
  p.rng = Rng(rngSeed, 0);
  p.lastP = ray.o;
  p.coneSpread = spread;
  p.coneWidth = width;
  return p;
}

Vec3 escapedRadiance(const Scene& scene, const PathState& path, const Vec3& dir) {
  Vec3 L(0.0f);
  const bool camera = path.depth == 0;
  // A smooth chain from a grain sees narrow suns widened (RenderSettings::sunRegularization);
  // after a rough grain or a proxy, as their light sampling saw them, for MIS.
  const float halfAngle = path.lastDelta ? path.sunHalfAngle : path.lastSunHalfAngle;
  for (int li : scene.infiniteLights()) {
    const Light& light = scene.lights()[li];
    if (camera && light.type() == LightType::Dome && !scene.settings().domeCameraVisible) continue;
    if (!scene.lightReaches(li, path.linkObject)) continue;
    // Past an object that casts no shadow from it, the last scattering counted it already.
    if (!camera && scene.crossesNonCaster(li, path.linkObject, path.lastP, dir, kInf)) continue;
    float lightPdf = 0;
    Vec3 Le = light.escapedLeSeen(dir, halfAngle, path.lastDelta ? nullptr : &lightPdf, path.lastAbove);
    if (isBlack(Le)) continue;
    float w = 1.0f;
    if (!path.lastDelta)
      w = powerHeuristic(path.lastPdf, lightPdf * scene.lightPick(li, path.linkObject) * path.lastNeeChance);
    L += Le * w;
  }
  return L;
}

namespace {

// Whether a smooth chain that leaves in world direction dir, seeing narrow suns widened to
// halfAngle, would find a sun there that counts at linkObject (escapedRadiance).
bool escapesToSun(const Scene& scene, const Vec3& dir, float halfAngle, int linkObject) {
  for (int li : scene.infiniteLights()) {
    const Light& light = scene.lights()[li];
    if (light.type() == LightType::Distant && scene.lightReaches(li, linkObject) &&
        !isBlack(light.escapedLeSeen(dir, halfAngle)))
      return true;
  }
  return false;
}

// The sun a smooth chain sees (RenderSettings::sunRegularization): as wide as the setting,
// or as the spread of the chain's direction over the pixel's footprint, whichever is less.
// A footprint w on a grain of radius R spans normals over w / R; a reflection turns its
// ray by twice the normal's turn, a refraction by |1 − cos θ_i / (η cos θ_t)| of it
// (Snell's law differentiated), and a chain's turns add up. The pixel already spreads the
// chain's light over that angle, so widening the sun up to it only moves light within the
// footprint: a grain the pixels resolve keeps its sharp glint. At least the first grain's
// w / R (its mirror's half-spread), as the rule was before it counted the chain's bends.
float chainHalfAngle(const Scene& scene, float firstSpread, float chainSpread) {
  return std::min(scene.settings().sunRegularizationHalfAngle(), std::max(firstSpread, 0.5f * chainSpread));
}

// How much a smooth interface turns a ray per turn of its normal (above): 2 for the mirror,
// |1 − cos θ_i / (η cos θ_t)| for the refraction (η = n_t / n_i), large at grazing exits.
float bendPerNormalTurn(const Material& m, const Vec3& wo, const Vec3& wi, bool transmitted) {
  if (!transmitted) return 2.0f;
  const float eta = wo.z > 0 ? m.ior : 1.0f / m.ior;
  return std::fabs(1.0f - std::fabs(wo.z) / (eta * std::max(std::fabs(wi.z), 1e-4f)));
}

// A smooth dielectric's choice between reflection and refraction, made toward the suns.
// A smooth chain reaches a sun only by leaving in its disk, and of the two branches one
// leaves the object: the mirror from outside, the refraction from inside. Chosen with the
// chance F (or 1 − F) it arrives rarely and bright — a glint off a grain's face is taken
// one sample in 1/F ≈ 25 —, the fireflies of a narrow sun. Where that branch's direction
// lies in a sun's disk (as widened after it: spreadHere, the footprint's w / R on a grain)
// it is chosen with probability at least ½, weighted by its Fresnel chance over that
// (Material::sampleSmooth): the same expectation, the sun's light spread over more
// samples. Elsewhere the choice is F's, bit for bit.
bool sampleSmoothTowardSuns(const Scene& scene, const PathState& path, const Material& m, const Frame& frame,
                            const Vec3& wo, float spreadHere, float uLobe, BsdfSample& bs) {
  const Material::SmoothBranches b = m.smoothBranches(wo);
  const float F = b.F;
  float pReflect = F;
  if (F > 0 && F < 1 && !scene.infiniteLights().empty()) {
    const bool outside = wo.z > 0;
    const Vec3& leaving = outside ? b.reflected : b.refracted;
    // The disk the branch would see: 0 (exact) before any grain, where spreadHere is 0 too.
    const float half = chainHalfAngle(scene, path.sunFirstSpread,
                                      path.sunChainSpread + spreadHere * bendPerNormalTurn(m, wo, leaving, !outside));
    if (escapesToSun(scene, frame.toWorld(leaving), half, path.linkObject)) pReflect = outside ? std::max(F, 0.5f) : std::min(F, 0.5f);
  }
  return Material::sampleSmooth(b, pReflect, uLobe, bs);
}

}  // namespace

bool endsAtLight(const Scene& scene, PathState& path, bool found, const Hit& hit) {
  if (found && hit.kind != Hit::AreaLight) return false;
  if (found) addAreaLightHit(scene, path, hit);
  else path.L[path.credit] += path.beta * escapedRadiance(scene, path, path.ray.d);
  path.alive = false;
  return true;
}

bool russianRoulette(const Scene& scene, PathState& path) {
  if (path.depth < scene.settings().rrDepth) return true;
  // Survive with probability min(1, max throughput): bright paths are never cut. The
  // throughput before the switch's roulette or splitting (PathState::rrScale).
  float q = 1.0f - maxComponent(path.beta) * path.rrScale;
  if (q > 0) {
    if (path.rng.next1D() < q) return false;
    path.beta /= (1.0f - q);
  }
  return true;
}

void shadeSurface(const Scene& scene, PathState& path, const Hit& hit, bool mediaMode) {
  const auto& lights = scene.lights();
  const Ray& ray = path.ray;
  // Ray cone: the footprint here (|·|: a lens's cone crosses its focus), the texture
  // filter's width and the next segment's starting width.
  const float footprint = std::fabs(path.coneWidth + path.coneSpread * hit.t);
  std::optional<Material> textured;  // made only for a textured hit
  const Material& m = scene.shadingMaterial(hit, footprint, textured);
  // The object whose light links hold here; DA's exit (a surface of no mesh) keeps the
  // aggregate it leaves.
  if (hit.kind != Hit::Surface || hit.geom >= 0) path.linkObject = scene.linkObjectOf(hit);
  bool inside = dot(ray.d, hit.ng) > 0;
  if (inside && m.type == MaterialType::Dielectric && !isBlack(m.absorption)) {
    // Beer–Lambert over the segment just travelled inside (object units -> world).
    path.beta *= vexp(m.absorption * (-hit.t / hit.lengthScale));
  }
  if (!isBlack(m.emission) && !inside) path.L[path.credit] += path.beta * m.emission;

  Frame frame(hit.ng);
  Vec3 wo = frame.toLocal(-ray.d);
  double& cost = path.cost[path.mode == kVpt ? 1 : 0];

  // A grain's footprint in normals (chainHalfAngle); the first grain sets the least widening.
  const float spreadHere = hit.kind == Hit::Grain && hit.grain.radius > 0 ? footprint / hit.grain.radius : 0.0f;
  if (hit.kind == Hit::Grain && path.sunHalfAngle < 0) {
    path.sunFirstSpread = spreadHere;
    path.sunHalfAngle = chainHalfAngle(scene, path.sunFirstSpread, path.sunChainSpread);
  }
  // A rough grain's highlight moves across the footprint with its normal as a mirror's
  // does (twice the normal's turn), so it sees a narrow sun as a smooth chain that bounced
  // here would: a grain below the pixel's size shows its highlight as a few bright samples
  // under the 0.53° sun otherwise. Independent of the light's direction, so that an escape
  // after this vertex finds the same disk (lastSunHalfAngle). Meshes see the sun exact.
  const float roughHalfAngle =
      hit.kind == Hit::Grain && !m.isDelta()
          ? chainHalfAngle(scene, path.sunFirstSpread, path.sunChainSpread + 2.0f * spreadHere)
          : 0.0f;
  // A surface that only reflects sees a constant dome over its hemisphere (Light::sampleLi).
  const Vec3 above = !m.twoSided() && wo.z > 0 ? hit.ng : Vec3(0.0f);
  // A shadow ray from o along d over dist, as the path's mode sees the scene (the media,
  // proxies or grains), adding c times what passes.
  auto addShadowed = [&](const Vec3& c, const Vec3& o, const Vec3& d, float dist, ShadowCasters casters) {
    if (mediaMode)
      path.L[path.credit] += c * scene.transmittance(o, d, dist, ray.time, &path.rng, casters);
    else if (path.mode == kPpt)
      path.addThroughProxies(c, scene.proxyTransmittance(o, d, dist, nullptr, path.rng.nextU32(), ray.time, casters));
    else if (!scene.occluded(o, d, dist, ray.time, casters))
      path.L[path.credit] += c;
  };
  if (!m.isDelta() && !lights.empty() && (wo.z > 0 || m.twoSided())) {
    // Next-event estimation: one light, picked by Scene::lightPick.
    int li = scene.pickLight(path.nextLightU(), path.linkObject);
    const float lightPick = scene.lightPick(li, path.linkObject);
    LightSample ls;
    float u1 = path.rng.next1D(), u2 = path.rng.next1D();
    if (scene.lightReaches(li, path.linkObject) && lights[li].sampleLiSeen(hit.p, u1, u2, roughHalfAngle, ls, above) &&
        !isBlack(ls.Li)) {
      Vec3 wiLocal = frame.toLocal(ls.wi);
      float bsdfPdf;
      Vec3 f = m.eval(wo, wiLocal, &bsdfPdf);
      if (!isBlack(f)) {
        Vec3 origin = offsetRayOrigin(hit.p, hit.ng, ls.wi, hit.eps);
        float dist = std::isfinite(ls.dist) ? ls.dist * (1.0f - 1e-4f) : kInf;
        const Vec3 c = path.beta * f * ls.Li *
                       (ls.delta ? 1.0f / lightPick : powerHeuristic(ls.pdf * lightPick, bsdfPdf) / (ls.pdf * lightPick));
        addShadowed(c, origin, ls.wi, dist, ShadowCasters{li, path.linkObject});
        cost += mediaMode || path.mode == kPpt || scene.aggregates().empty() ? 1 : kGrainCastCost;
      }
    }
  }

  BsdfSample bs;
  float uLobe = path.rng.next1D(), u1 = path.rng.next1D(), u2 = path.rng.next1D();
  const bool sampled = m.isDelta() ? sampleSmoothTowardSuns(scene, path, m, frame, wo, spreadHere, uLobe, bs)
                                    : m.sample(wo, uLobe, u1, u2, bs);
  if (!sampled) {
    path.alive = false;
    return;
  }
  path.beta *= bs.weight;
  Vec3 wi = frame.toWorld(bs.wi);
  // Ray cone: the footprint grows along the segment; delta bounces keep the spread
  // (flat-interface approximation), others widen it.
  path.coneWidth = footprint;
  if (!bs.delta) path.coneSpread = std::max(path.coneSpread, std::min(kDiffuseConeSpread, m.lobeSpread()));
  path.scattered(bs.delta, bs.pdf, hit.p, 1.0f, roughHalfAngle, above);
  if (hit.kind == Hit::Grain && bs.delta) {
    path.sunChainSpread += spreadHere * bendPerNormalTurn(m, wo, bs.wi, bs.transmitted);
    path.sunHalfAngle = chainHalfAngle(scene, path.sunFirstSpread, path.sunChainSpread);
  }
  // Inside a grain after this bounce when the new direction heads into it.
  path.inGrain = hit.kind == Hit::Grain && dot(wi, hit.ng) < 0;
  path.from.aggregate = hit.kind == Hit::Grain ? hit.aggregate : -1;
  path.from.instancer = hit.kind == Hit::Grain ? hit.instancer : -1;
  path.from.instance = hit.kind == Hit::Grain ? hit.instance : -1;
  if (hit.kind == Hit::Grain) {
    path.from.grain = hit.grain;
    path.from.inside = path.inGrain;
  }
  path.ray.o = offsetRayOrigin(hit.p, hit.ng, wi, hit.eps);
  path.ray.d = wi;
  path.ray.tmin = 0;
  path.ray.tmax = kInf;
  // Shadow linking: the direct light this direction brings past objects that cast no
  // shadow, by the shadow ray next-event estimation casts here.
  addDirectPastNonCasters(scene, path, path.beta, path.ray.o, wi, [&](const Vec3& c, float dist, ShadowCasters who) {
    addShadowed(c, path.ray.o, wi, dist, who);
  });
  ++path.depth;
  if (!russianRoulette(scene, path) || !isFinite(path.beta) || isBlack(path.beta)) path.alive = false;
}

void eptStep(const Scene& scene, PathState& path) {
  if (path.depth >= scene.settings().maxDepth) {
    path.alive = false;
    return;
  }
  Hit hit;
  bool found = scene.intersect(path.ray, hit, &path.from);
  path.cost[0] += scene.aggregates().empty() ? 1 : kGrainCastCost;
  if (!found) {
    path.L[path.credit] += path.beta * escapedRadiance(scene, path, path.ray.d);
    path.alive = false;
    return;
  }
  if (path.depth == 0) recordPrimary(scene, path, hit);
  if (hit.kind == Hit::AreaLight) {
    addAreaLightHit(scene, path, hit);
    path.alive = false;
    return;
  }
  // An aggregate's grain, or an instancer's that has a medium.
  const bool mediumGrain =
      hit.kind == Hit::Grain && (hit.aggregate >= 0 || (hit.instancer >= 0 && scene.instancedMedium(hit.instancer)));
  if (mediumGrain && !path.touchedAggregate) {
    path.touchedAggregate = true;
    // Level of detail: grains well below the footprint here look like their medium.
    float lod = scene.settings().lod;
    float footprint = std::fabs(path.coneWidth + path.coneSpread * hit.t);
    const float radius = hit.aggregate >= 0 ? scene.aggregates()[hit.aggregate]->grainRadius()
                                            : scene.instancedGrainRadius(hit.instancer);
    if (lod > 0 && scene.hasMedia() && radius < lod * footprint) {
      path.shortcut = true;
      // Where the grains have proxies (Scene::lodProxies) the first grain is one too: a
      // grain narrower than the footprint shows the pixel its average over orientations
      // and entry points, which its proxy table holds, and a proxy samples every light
      // (narrow suns included), at a fraction of an explicit grain's cost. The path goes on
      // among them from here, where the first sphere it enters is met as a proxy — the
      // first grain, so not a visit after it.
      if (hit.aggregate >= 0 ? scene.lodProxies(hit.aggregate) : scene.instancedProxies(hit.instancer)) {
        path.mode = path.credit = kPpt;
        path.from = GrainStart();
        path.proxyVisits = -1;
        // The ray is known to meet this grain (and to miss those before it): its proxy is
        // met for sure, not by the chance hit(b), and without a walk to it (ppt.h).
        path.firstGrain.aggregate = hit.aggregate;
        path.firstGrain.grain = hit.grain;
        path.firstGrain.instancer = hit.instancer;
        path.firstGrain.instance = hit.instance;
        path.firstGrainAt = hit.t;
        return;
      }
      // Else under a narrow sun the medium takes the path at the first grain's surface (the
      // ray goes on from there): only the medium can sample the sun (Scene::narrowSun). A
      // grain of the surface layer may stick out of the boundary: the path then enters the
      // medium where its ray crosses the boundary.
      if (scene.narrowSun()) {
        path.mode = path.credit = kVpt;
        path.medium =
            hit.aggregate >= 0 && scene.aggregateAt(hit.aggregate, path.ray.time).insideBoundary(hit.p) ? hit.aggregate : -1;
        path.ray.o = hit.p;
        path.ray.tmin = 0;
        path.ray.tmax = kInf;
        return;
      }
    }
  }
  shadeSurface(scene, path, hit, false);
  // Out of its first grain, a path goes on among proxies (ppt.h) when the scene has them.
  if (hit.kind == Hit::Grain && entersProxies(scene, path)) {
    path.mode = path.credit = kPpt;
    return;
  }
  // The shortcut keeps the first grain and the low orders explicit (ppt.h, lowOrdersDone:
  // the medium misses the packing's shadow hiding), then leaves for the medium.
  if (path.shortcut && path.alive && !path.inGrain && lowOrdersDone(scene, path)) {
    enterMedia(scene, path);
  }
}

}  // namespace granular
