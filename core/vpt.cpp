#include "vpt.h"

#include <cfloat>
#include <cmath>

#include "diffusion.h"
#include "ept.h"
#include "scene.h"

namespace granular {

MediumParams mediumFromRte(const Vec3& sigmaT, const Vec3& albedo, const PhaseTable& phase) {
  MediumParams m;
  m.sigmaT = sigmaT;
  m.albedo = albedo;
  m.phase = {phase, phase, phase};
  m.g = Vec3(phase.g);
  for (int c = 0; c < 3; ++c) {
    m.lambdaT[c] = sigmaT[c] > 0 ? 1.0f / sigmaT[c] : kInf;
    m.sigmaSReduced[c] = (1.0f - phase.g) * albedo[c] * sigmaT[c];
    m.sigmaA[c] = (1.0f - albedo[c]) * sigmaT[c];
    m.sigmaTReduced[c] = m.sigmaSReduced[c] + m.sigmaA[c];
    m.albedoReduced[c] = m.sigmaTReduced[c] > 0 ? m.sigmaSReduced[c] / m.sigmaTReduced[c] : albedo[c];
    m.sigmaTr[c] = std::sqrt(3.0f * m.sigmaA[c] * m.sigmaTReduced[c]);
  }
  return m;
}

HomogeneousMedium::HomogeneousMedium(const MediumParams& p, MediumModel model)
    : sigmaT_(p.sigmaT), albedo_(p.albedo), phase_(p.phase) {
  samePhase_ = phase_[0].density == phase_[1].density && phase_[0].density == phase_[2].density;
  bool moves = model == MediumModel::Exits && p.grainRadius > 0;
  for (const ExitMoves& e : p.combined.exits) moves = moves && !e.empty();
  for (int c = 0; c < 3; ++c) moves = moves && p.lambdaBeta[c] > 0 && p.lambdaBeta[c] < FLT_MAX;
  if (!moves) return;  // TT's medium (no grain met, or no moves estimated: a medium given directly)
  for (int c = 0; c < 3; ++c) sigmaT_[c] = 1.0f / (kExitFlight * p.lambdaBeta[c]);
  exits_ = std::make_shared<const std::array<ExitMoves, 3>>(p.combined.exits);
  moveRadius_ = p.grainRadius;
}

Vec3 HomogeneousMedium::exitMove(const Vec3& wi, const Vec3& wo, float uChannel, float u) const {
  if (!exits_) return Vec3(0.0f);
  const int c = std::min(int(uChannel * 3.0f), 2);
  return (*exits_)[size_t(c)].sample(wi, wo, u) * moveRadius_;
}

HomogeneousMedium::HomogeneousMedium(const Vec3& sigmaT, const Vec3& albedo, const PhaseTable& phase)
    : sigmaT_(sigmaT), albedo_(albedo), phase_{phase, phase, phase}, samePhase_(true) {}

float HomogeneousMedium::sampleDistance(float uChannel, float u) const {
  int c = std::min(int(uChannel * 3.0f), 2);
  float s = sigmaT_[c];
  if (s <= 0) return kInf;
  return -std::log1p(-u) / s;
}

float HomogeneousMedium::distancePdf(float t) const {
  float p = 0;
  for (int c = 0; c < 3; ++c) p += sigmaT_[c] * std::exp(-sigmaT_[c] * t);
  return p * (1.0f / 3.0f);
}

float HomogeneousMedium::survivalProbability(float s) const {
  float p = 0;
  for (int c = 0; c < 3; ++c) p += std::exp(-sigmaT_[c] * s);
  return p * (1.0f / 3.0f);
}

Vec3 HomogeneousMedium::phase(const Vec3& wi, const Vec3& wo) const {
  float mu = dot(wi, wo);
  if (samePhase_) return Vec3(phase_[0].eval(mu));
  return {phase_[0].eval(mu), phase_[1].eval(mu), phase_[2].eval(mu)};
}

float HomogeneousMedium::phasePdf(const Vec3& wi, const Vec3& wo) const { return average(phase(wi, wo)); }

Vec3 HomogeneousMedium::samplePhase(const Vec3& wi, float uChannel, float u1, float u2, Vec3& weight,
                                    float& pdf) const {
  int c = samePhase_ ? 0 : std::min(int(uChannel * 3.0f), 2);
  Vec3 wo = phase_[c].sample(wi, u1, u2);
  Vec3 p = phase(wi, wo);
  pdf = average(p);
  weight = pdf > 0 ? p / pdf : Vec3(0.0f);
  return wo;
}

float diffusionDepth(const MediumParams& p, float factor) {
  float depth = 0;
  for (int c = 0; c < 3; ++c) {
    float a = p.sigmaTReduced[c] > 0 ? 1.0f / p.sigmaTReduced[c] : kInf;
    float b = p.sigmaTr[c] > 0 ? 0.5f / p.sigmaTr[c] : kInf;
    depth = std::max(depth, std::min(a, b));
  }
  return factor * depth;
}

namespace {

// Is p more than depth below the boundary? The distance field answers within its band;
// beyond the band (where it is clamped) the exact point query does.
bool deeperThan(const Aggregate& agg, const Vec3& p, float depth) {
  Vec3 closest;
  if (agg.standIn()) return agg.closestBoundaryPoint(p, closest) > depth;  // no distance field
  float d = -agg.boundaryDistance(p);
  if (d > depth) return true;
  if (d < 0.99f * agg.distanceField().bandWidth()) return false;
  return agg.closestBoundaryPoint(p, closest) > depth;
}

// Russian roulette on the shadow ray of a scattering deep in its aggregate's medium. The
// ray runs at least the depth to the boundary inside, so its transmittance is at most
// exp(−σ_t,min · depth); the distance field estimates that depth for a lookup, where the
// ray costs a search of the surfaces and of each boundary crossing. The chance to trace
// it is min(1, that bound / kShadowRouletteBelow), the light found divided by it: unbiased
// whatever the estimate (a voxel off), which sets only how much variance it adds. That
// variance is small beside the walk's own (where it scatters and leaves), so the roulette
// starts at a bound of 1/2: shadow rays are a path's dearest part past its first grain
// (bench/README.md, "Hybrid speed-up").
constexpr float kShadowRouletteBelow = 0.5f;

float shadowChance(const Scene& scene, const PathState& path, const HomogeneousMedium& med, const Vec3& p) {
  const Aggregate& agg = *scene.aggregates()[path.medium];
  if (agg.standIn()) return 1.0f;  // no distance field
  DistanceField::NearestProbe probe(agg.distanceField());  // within a voxel: enough for a chance
  const float depth = -probe(scene.aggregateAt(path.medium, path.ray.time).toBuild(p));
  const float bound = std::exp(-minComponent(med.sigmaT()) * std::max(depth, 0.0f));
  return std::min(1.0f, bound / kShadowRouletteBelow);
}

}  // namespace

Vec3 mediumShadow(const Scene& scene, PathState& path, const Vec3& p, const Vec3& from, const Vec3& wi, float dist,
                  ShadowCasters who, const DiffusionBoundary* boundary, const Vec3& reducedBy) {
  Vec3 tr = scene.transmittance(from, wi, dist, path.ray.time, &path.rng, who);
  if (boundary && !isBlack(tr)) {
    // The flight to the own medium's boundary in the reduced medium (diffusion.h).
    float s;
    Vec3 ng;
    if (boundary->intersect(p, wi, dist, s, ng)) tr *= vexp(reducedBy * s);
  }
  return tr;
}

void mediumNee(const Scene& scene, PathState& path, const HomogeneousMedium& med, const Vec3& p,
               const DiffusionBoundary* boundary, const Vec3& reducedBy) {
  const auto& lights = scene.lights();
  const Vec3 wi = path.ray.d;
  // In its aggregate's own medium, not DA's reduced one (whose flight to the boundary is
  // given extinction back).
  const float chance = !boundary && path.medium >= 0 ? shadowChance(scene, path, med, p) : 1.0f;
  if (chance < 1.0f && path.rng.next1D() >= chance) return;
  if (!lights.empty()) {
    int li = scene.pickLight(path.nextLightU(), path.linkObject);
    const float lightPick = scene.lightPick(li, path.linkObject);
    LightSample ls;
    float u1 = path.rng.next1D(), u2 = path.rng.next1D();
    if (scene.lightReaches(li, path.linkObject) && lights[li].sampleLi(p, u1, u2, ls) && !isBlack(ls.Li)) {
      Vec3 f = med.phase(wi, ls.wi);
      float dist = std::isfinite(ls.dist) ? ls.dist * (1.0f - 1e-4f) : kInf;
      Vec3 from = p;
      if (med.movesLight() && !boundary) {
        // The exits model: the light leaves where the grain lets it out for this turn; the
        // shadow ray stops short of the light by the move (it may not pass the light).
        const Vec3 move = med.exitMove(wi, ls.wi, path.rng.next1D(), path.rng.next1D());
        from = scene.movedLight(p, move, path.ray.time);
        if (std::isfinite(dist)) dist = std::max(0.0f, dist - length(move));
      }
      const Vec3 Tr =
          mediumShadow(scene, path, p, from, ls.wi, dist, ShadowCasters{li, path.linkObject}, boundary, reducedBy);
      path.cost[1] += 1;
      if (!isBlack(Tr) && !isBlack(f)) {
        if (ls.delta) {
          path.L[path.credit] += path.beta * f * Tr * ls.Li / (lightPick * chance);
        } else {
          float lp = ls.pdf * lightPick;
          float w = powerHeuristic(lp, med.phasePdf(wi, ls.wi));
          path.L[path.credit] += path.beta * f * Tr * ls.Li * (w / (lp * chance));
        }
      }
    }
  }
}

namespace {

// Does DA take over at a scattering at p (vptStep's contract)? The curvature guard comes
// last and at most once per path: it costs five closest-point queries, and a path it
// refused mostly stays near the curved part it scatters in.
bool takesDiffusion(const Scene& scene, PathState& path, const Vec3& p) {
  const float daDepth = scene.diffusionDepth(path.medium);
  if (scene.settings().technique != Technique::Hybrid || !std::isfinite(daDepth) ||
      path.depth < scene.settings().daMinOrder || path.daRefused)
    return false;
  const Aggregate& agg = *scene.aggregates()[path.medium];
  // Depths and curvature do not change as the aggregate moves: asked where p stands in its build.
  const Vec3 pb = scene.aggregateAt(path.medium, path.ray.time).toBuild(p);
  if (!deeperThan(agg, pb, daDepth)) return false;
  path.cost[1] += 5;
  if (diffusionHolds(agg, pb, daDepth)) return true;
  path.daRefused = true;
  return false;
}

// DA at a scattering at p in instancer m's heterogeneous medium, where
// heterogeneous_diffusion.h's rule holds; true: the path went on by DA. A refusal for
// varying packing is asked again kDaRetryOrders scatterings later (the path may have
// diffused into a uniform part); one for curvature, never (as above).
constexpr int kDaRetryOrders = 8;

bool instancedDiffusion(const Scene& scene, PathState& path, int m, const Vec3& p) {
  const HeterogeneousDiffusion* da = scene.instancedDiffusion(m);
  if (!da || path.depth < scene.settings().daMinOrder || path.daRefused || path.depth < path.daRetryDepth)
    return false;
  path.cost[1] += 1;
  const HeterogeneousDecision d = da->decide(p, scene.settings().daDepthFactor);
  if (d.outcome == DiffusionOutcome::Varies) path.daRetryDepth = path.depth + kDaRetryOrders;
  if (d.outcome == DiffusionOutcome::Curved) path.daRefused = true;
  if (d.outcome != DiffusionOutcome::Takes) return false;
  // The local homogeneous medium: the reference's σ_t scaled to the region's packing f̄.
  const HomogeneousMedium& ref = scene.instancedMedium(m)->reference();
  const float k = d.packing / da->densityRef();
  const DiffusionProfile profile = da->referenceProfile().scaled(k);
  const SurfaceCutBoundary boundary(da->boundary(), scene, path.ray.time);
  diffusionStep(scene, path, p, DiffusionMedium{ref, ref.sigmaT() * k, profile, boundary});
  return true;
}

// Scattering at p inside medium med: NEE through the media, then a phase-sampled direction.
void scatterInMedium(const Scene& scene, PathState& path, const HomogeneousMedium& med, const Vec3& p) {
  mediumNee(scene, path, med, p);
  const Vec3 wi = path.ray.d;
  Vec3 weight;
  float pdf;
  float uc = path.rng.next1D(), u1 = path.rng.next1D(), u2 = path.rng.next1D();
  Vec3 wo = med.samplePhase(wi, uc, u1, u2, weight, pdf);
  path.beta *= weight;
  path.scattered(false, pdf, p, 1.0f, 0.0f);
  path.ray.o = p;
  if (med.movesLight()) {  // the exits model: on from where the grain lets the light out
    path.ray.o = scene.movedLight(p, med.exitMove(wi, wo, path.rng.next1D(), path.rng.next1D()), path.ray.time);
    path.medium = scene.mediumAfterMove(path.medium, path.ray.o, path.ray.time);
  }
  path.ray.d = wo;
  path.ray.tmin = 0;
  path.ray.tmax = kInf;
  // Shadow linking: the direct light this direction brings past objects that cast no shadow.
  if (pdf > 0)
    addDirectPastNonCasters(scene, path, path.beta, path.ray.o, wo, [&](const Vec3& c, float dist, ShadowCasters who) {
      path.L[path.credit] += c * mediumShadow(scene, path, p, path.ray.o, wo, dist, who);
    });
  ++path.depth;
  if (!russianRoulette(scene, path) || !isFinite(path.beta) || isBlack(path.beta) || pdf <= 0) path.alive = false;
}

}  // namespace

void enterMedia(const Scene& scene, PathState& path) {
  path.mode = path.credit = kVpt;
  path.medium = scene.mediumAt(path.ray.o, path.ray.time);
  path.grainFlight = path.from.aggregate == path.medium && scene.takesOverAtGrains(path.medium);
}

void vptStep(const Scene& scene, PathState& path) {
  if (path.depth >= scene.settings().maxDepth) {
    path.alive = false;
    return;
  }
  // The packing's flight (enterMedia): the aggregate whose grain it meets, at grainT along
  // the ray. It holds across its own boundary: a grain of the surface layer may stand out
  // of it, and the packing's flight meets it there too.
  int grainOf = -1;
  float grainT = kInf;
  if (path.grainFlight && path.medium >= 0) {
    const GrainFlight f = scene.flightToGrain(path.medium, path.ray, path.from, path.rng);
    grainOf = path.medium;
    grainT = f.t;
    path.cost[1] += f.steps;
  }
  path.grainFlight = false;
  // Boundary crossings are null events (index-matched interface): loop over them.
  for (int crossing = 0; crossing < 256; ++crossing) {
    // In a homogeneous medium the flight is drawn first: what lies past it cannot change
    // the event, so the scene is searched only that far (Scene::flightReach).
    const bool atGrain = grainOf >= 0;
    const int m = atGrain ? grainOf : path.medium;
    float t = atGrain ? grainT : kInf;
    if (!atGrain && m >= 0) t = scene.medium(m).sampleDistance(path.rng.next1D(), path.rng.next1D());
    Ray query = path.ray;
    if (std::isfinite(t)) query.tmax = std::min(query.tmax, scene.flightReach(query.o, t));
    Hit hit;
    bool found = scene.intersectMedium(query, hit);
    path.cost[1] += 1;
    if (m >= 0) {
      const HomogeneousMedium& med = scene.medium(m);
      float tHit = found ? hit.t : kInf;
      if (t < tHit) {
        // Scattering at t: weight α σ_t T(t) / p(t) per channel (vpt.h); at a grain the
        // packing's flight met, α alone.
        Vec3 p = path.ray.o + path.ray.d * t;
        path.beta *= atGrain ? med.albedo() : med.transmittance(t) * med.sigmaT() * med.albedo() / med.distancePdf(t);
        path.medium = m;
        path.linkObject = scene.aggregateLinkObject(m);
        if (takesDiffusion(scene, path, p)) {
          diffusionStep(scene, path, p);
          return;
        }
        scatterInMedium(scene, path, med, p);
        return;
      }
      if (!std::isfinite(tHit)) {  // a leak through the boundary (open by rounding): end the path
        path.alive = false;
        path.lost = true;
        return;
      }
      // Passing to the hit: weight T(s) / P(flight >= s) (the packing's flight: 1).
      if (!atGrain) path.beta *= med.transmittance(tHit) / med.survivalProbability(tHit);
    } else if (scene.hasMedia()) {
      // An instancer's heterogeneous medium (Scene::instancedGrains): spectral tracking
      // through it up to the hit or the end of its bounds, whose weight carries α_s at a
      // scattering (heterogeneous_medium.h); deep scatterings may go on by DA (above).
      int m;
      float t0, t1;
      const float tHit = found ? hit.t : kInf;
      if (scene.firstInstancedMedium(path.ray, tHit, m, t0, t1)) {
        const HeterogeneousMedium& med = *scene.instancedMedium(m);
        const float tEnd = std::min(tHit, t1);
        const MediumFlight flight = med.sampleFlight(path.ray, tEnd, path.rng, path.beta);
        path.cost[1] += 0.1 * double(flight.lookups);
        path.beta *= flight.weight;
        if (flight.scattered) {
          const Vec3 p = path.ray.o + path.ray.d * flight.t;
          path.linkObject = scene.instancerLinkObject(m);
          if (!instancedDiffusion(scene, path, m, p)) scatterInMedium(scene, path, med.reference(), p);
          return;
        }
        if (isBlack(path.beta)) {
          path.alive = false;
          return;
        }
        if (tEnd < tHit) {  // out of its bounds before the hit: go on along the same ray
          // Not from o + d tEnd as a new origin: rounded onto the bounds' face it finds them
          // again, as an empty interval, and never leaves.
          path.ray.tmin = tEnd;
          continue;
        }
      }
    }
    if (endsAtLight(scene, path, found, hit)) return;
    if (hit.kind == Hit::Boundary) {
      if (path.depth == 0) recordPrimary(scene, path, hit);  // a camera ray entering a medium (LOD)
      path.medium = dot(path.ray.d, hit.ng) < 0 ? hit.aggregate : -1;
      // The packing's flight goes on past its own boundary to the grain it met; with none
      // ahead, or at another aggregate's boundary, the media's flights take over.
      if (hit.aggregate != grainOf || !std::isfinite(grainT))
        grainOf = -1;
      else
        grainT -= hit.t;
      path.ray.o = offsetRayOrigin(hit.p, hit.ng, path.ray.d, hit.eps);
      path.ray.tmin = 0;
      continue;
    }
    if (path.depth == 0) recordPrimary(scene, path, hit);
    shadeSurface(scene, path, hit, true);
    return;
  }
  path.alive = false;  // crossings without end
  path.lost = true;
}

}  // namespace granular
