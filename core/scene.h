// scene.h — the built scene: BVHs, aggregates, lights, materials and camera.
//
// Contract: Scene::build() turns a validated SceneDesc into everything the integrators
// query, in render space (world space less renderOrigin()): intersect() returns the
// nearest surface, grain or area light along a ray; occluded() answers shadow rays. Given the previous scene of the same stage, build()
// reuses each aggregate whose inputs (its AggregateDesc but the id, its prototypes'
// materials) are unchanged: no voxelising, no tile, no TT work for it; a light or camera
// edit then costs only the surfaces' BVH. Built aggregates are shared, immutable, between
// the two scenes. Grains are opaque to shadow rays (their interfaces are delta: light
// reaches through them only by path continuation). The scene is immutable once built and
// safe to query from many threads.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "aggregate.h"
#include "aggregate_motion.h"
#include "camera.h"
#include "cryptomatte.h"
#include "diffusion.h"
#include "embree_util.h"
#include "grain_density.h"
#include "heterogeneous_diffusion.h"
#include "heterogeneous_medium.h"
#include "instanced_grains.h"
#include "light.h"
#include "material.h"
#include "proxy.h"
#include "switching.h"
#include "scene_desc.h"
#include "texture.h"
#include "medium.h"
#include "vpt.h"

namespace granular {

struct Hit {
  enum Kind { Surface, Grain, AreaLight, Boundary, Proxy } kind = Surface;
  float t = kInf;
  Vec3 p;
  Vec3 ng;                  // unit, outward from the surface or grain
  int material = -1;
  int light = -1;           // AreaLight
  int aggregate = -1;       // Grain, Boundary
  float eps = 0;            // ray-offset scale at this hit
  float lengthScale = 1;    // world length of one unit of the object's own space (absorption)
  int primId = -1;          // the front end's id of the mesh or aggregate (primId AOV)
  // Surface: the mesh (Embree geometry id), its triangle and the barycentrics there
  // (textures).
  int geom = -1;
  unsigned prim = 0;
  float bu = 0, bv = 0;
  GrainHit grain;           // Grain, Proxy: which grain of the aggregate
  // A Grain of an instancer (aggregate -1): its index among Scene::instancedGrains() and
  // the grain's index in the instancer's arrays (grain.prototype: its prototype).
  int instancer = -1;
  int64_t instance = -1;
};

// The grain a path's next ray starts at (its last hit), inside it or leaving it: a hint
// that lets intersect() trace that grain alone or skip it (Aggregate::intersect).
struct GrainStart {
  int aggregate = -1;       // -1: the ray does not start at an aggregate's grain
  GrainHit grain;
  bool inside = false;
  int instancer = -1;       // or at instancer's grain `instance` (-1: none)
  int64_t instance = -1;
};

// How much of each aggregate a build makes. StandIns: aggregates the previous scene
// cannot lend are built as stand-ins (Aggregate::build: the boundary and the medium, no
// cells), and every path of the scene is traced through the equivalent media from the
// camera on (VPT and DA, no explicit grains): a first image in the time of the boundaries'
// BVHs and the cached TT parameters, for an interactive host to show while the full
// build runs. Technique Ept has no media: its builds are always full.
enum class SceneDetail { Full, StandIns };

// What a build says it is waiting for, a line at a time (Aggregate::build: work that
// the build cache does not hold), called on the building thread.
using BuildLog = std::function<void(const std::string&)>;

// A shadow ray's light and the object it leaves (Scene::linkObjectOf; -1: none), for
// shadow linking (Scene::castsShadow). light -1: every object blocks the ray.
struct ShadowCasters {
  int light = -1;
  int self = -1;
};

// Which objects a shadow ray passes (Scene::shadowPass): those whose entry of `row` (per
// object, Scene::linkObjectOf's numbering) is 1, but `self`. No row: none.
struct ShadowPass {
  const uint8_t* row = nullptr;
  int self = -1;
  bool operator()(int object) const { return row && object != self && row[object]; }
};

class Scene {
 public:
  static std::unique_ptr<Scene> build(const SceneDesc& desc, const Scene* previous = nullptr,
                                      SceneDetail detail = SceneDetail::Full, const BuildLog& log = nullptr);
  // Some aggregate is a stand-in (SceneDetail::StandIns): paths start in the media.
  bool standIns() const { return standIns_; }

  // Explicit grains (EPT): nearest surface, grain or area light.
  bool intersect(const Ray& ray, Hit& hit, const GrainStart* from = nullptr) const;
  // time: the ray's (Ray::time), where moving grains are. Every shadow ray (occluded,
  // transmittance, proxyTransmittance) is blocked by what would end a ray of intersect():
  // surfaces, grains, and area lights hit from their emitting side (Light::intersect), so
  // light sampling sees what BSDF and phase sampling see and their MIS weights agree.
  // casters: the light the ray is cast toward and the object it leaves; the objects that
  // cast no shadow from that light but that one (shadow linking: castsShadow) are passed.
  // The default: every object blocks.
  bool occluded(const Vec3& p, const Vec3& dir, float dist, float time = 0, ShadowCasters casters = {}) const;

  // The equivalent media (VPT, DA): nearest surface, area light or aggregate boundary
  // (Hit::Boundary, ng outward); grains are not seen.
  bool intersectMedium(const Ray& ray, Hit& hit) const;
  // How far along a ray from o intersectMedium must search to decide a flight of length t
  // as an unbounded search would: a boundary crossing within a surface's offset of the
  // surface is the surface's (intersectMedium), so a little past t. A short search
  // traverses less of the scene's hierarchies.
  float flightReach(const Vec3& o, float t) const;
  // Transmittance of a shadow ray through the media: 0 if a surface blocks it, else the
  // product of exp(−σ_t ℓ) over the lengths ℓ it runs inside each aggregate's boundary.
  // Instancers' media are crossed by ratio tracking, from rng (without one: from a hash of the ray).
  Vec3 transmittance(const Vec3& p, const Vec3& dir, float dist, float time = 0, Rng* rng = nullptr,
                     ShadowCasters casters = {}) const;
  // Proxies (proxy.h; when useProxies()): nearest surface,
  // area light or proxy sphere entered (Hit::Proxy; its grain's prototype in hit.grain, p
  // on the sphere, ng the sphere's outward normal there). from: the sphere the ray leaves.
  bool intersectProxies(const Ray& ray, Hit& hit, const GrainStart* from = nullptr) const;
  // The proxy of the aggregate grain `met` that ray met explicitly first (the level-of-detail
  // shortcut's first grain, ept.h): as intersectProxies() would give it, where the ray
  // enters that grain's sphere — met with nothing before it (the explicit hit was the
  // nearest), so without a walk. False where the ray starts inside the sphere, or the
  // grain is an instancer's: the walk answers.
  bool firstGrainProxy(const Ray& ray, const GrainStart& met, Hit& hit) const;
  // Where a walk among proxies may place a path (ppt.h) on its way from `from` (a grain's
  // centre, or a point already placed) to `to` (on that grain's bounding sphere): `to`, or,
  // where a surface lies between, a little before the first one. A bounding sphere reaches
  // past a surface its aggregate stands on (a heap on the ground): a point on it beyond the
  // surface would start the path on the far side (under the ground, lit by the dome's
  // lower half). A segment outside the surfaces' bounds costs no ray query (intersectMeshes'
  // own test).
  Vec3 beforeSurfaces(const Vec3& from, const Vec3& to, float time) const;
  // Shadow rays among proxies: 0 if a surface blocks the ray, else the light's passage
  // through the proxy spheres on its line (ProxyShadow, proxy.h; Aggregate::
  // proxyTransmittance; seed: its roulette's random numbers).
  ProxyShadow proxyTransmittance(const Vec3& p, const Vec3& dir, float dist, const GrainStart* from, uint64_t seed,
                                 float time = 0, ShadowCasters casters = {}) const;
  // Paths go on among proxies after their first grain in some aggregate (useProxies(a)).
  // Their tables are built (or read from the disk cache) when first needed, by build() or
  // setView(): for every aggregate once any uses proxies or switching is measured.
  bool useProxies() const { return useProxies_; }
  // Switching per aggregate (switching.h; -1: a path not in an aggregate, which takes the
  // largest over them). With RenderSettings::explicitBounces automatic (-1) and media, the
  // proxy visits after the first grain before the medium are measured (switchMeasure);
  // RenderSettings::proxies On: every aggregate uses proxies; Auto: those whose medium is
  // biased after the first grain (measured visits > 0), and all under a narrow sun; Off:
  // none, and the explicit bounces are kProxyOrders per measured visit (ppt.h: what a visit
  // is worth against an explicit bounce). Without a measurement (explicitBounces set, or
  // no media) the visits are the setting's bounces over kProxyOrders.
  bool useProxies(int aggregate) const {
    return aggregate >= 0 ? aggregateProxies_[size_t(aggregate)] != 0 : useProxies_;
  }
  // The level-of-detail shortcut's first grain is a proxy (ept.h): the aggregate uses
  // proxies, or their tables are made anyway (for the switching measurement) and
  // RenderSettings::proxies is not Off.
  bool lodProxies(int aggregate) const {
    return useProxies(aggregate) || (settings_.proxies != ProxyUse::Off && !proxyTables_.empty());
  }
  int proxyVisits(int aggregate) const {
    return aggregate >= 0 ? proxyVisits_[size_t(aggregate)] : maxProxyVisits_;
  }
  int explicitBounces(int aggregate) const {
    return aggregate >= 0 ? aggregateBounces_[size_t(aggregate)] : explicitBounces_;
  }
  // Null when not measured (see above).
  const SwitchMeasure* switchMeasure(int aggregate) const { return switching_[size_t(aggregate)].get(); }
  // With RenderSettings::switchForView, the view measurement (switching.h:
  // measureViewSwitch) of each measured aggregate the camera sees, made at setView (from the
  // disk cache for a view measured before) or given by applyViewSwitch; the visits are then
  // the larger of the two choices (the dome's keeps what lights the rest of the scene). Null
  // when not made: off, not measured, not yet applied, or fewer than kMinViewEntries entries
  // (switchViews).
  const SwitchMeasure* viewSwitchMeasure(int aggregate) const { return viewSwitching_[size_t(aggregate)].get(); }
  static constexpr int kMinViewEntries = 16;
  // Per aggregate, the camera's entries into it for its view measurement (switching.h:
  // measureViewSwitch), from one pass over the centres of a kViewGrid² grid over the image:
  // those whose rays meet its boundary first (grains unseen), from outside, each with the
  // distant lights whose central ray leaves there unblocked by surfaces and the media's
  // boundaries. None for a moving aggregate, and none at all in a scene without distant
  // lights or domes, or with more than 32 lights.
  std::vector<SwitchView> switchViews() const;
  static constexpr int kViewGrid = 64;
  // The sun measurement, made under a narrow sun (narrowSun) whatever the camera: the view
  // measurement (measureViewSwitch) of each measured aggregate as each distant light sees
  // it, the radiance scattered back toward the sun. A dome's albedo averages over the
  // directions light leaves in, and the medium's error toward one of them can be far larger,
  // of either sign (bench/README.md, "The switch toward the sun").
  // Its visits are what it shows to be needed (switchVisitsShownNeeded: radiance toward one
  // direction is noisy, and nearly clear grains' too noisy to resolve), at least the dome's
  // choice: the candidates below that are not measured (sunSwitchOptionsFor), since they
  // could not raise it. The aggregate takes the largest of the dome's, the sun's and
  // (switchForView) the camera's choices. Only under a narrow sun, where every path goes on
  // among proxies after its first grain anyway: under a wide one the nearly clear scenes
  // need no proxies, and the measurement would cost seconds to ask for some. Made once per
  // scene (and per setMedium), cached on disk. Null when not made: no switching measurement, no narrow sun, no distant light of
  // non-zero radiance, fewer than kMinViewEntries entries, or the dome's choice the most
  // visits already (kSwitchVisits' last).
  const SwitchMeasure* sunSwitchMeasure(int aggregate) const {
    return size_t(aggregate) < sunSwitching_.size() && !switching_.empty() && switching_[size_t(aggregate)]
               ? sunSwitching_[size_t(aggregate)].get()
               : nullptr;
  }
  // The sun measurement's options for a measured aggregate: sunSwitchOptions(), its first
  // candidate the dome's choice (SwitchOptions::firstCandidate).
  SwitchOptions sunSwitchOptionsFor(int aggregate) const;
  // Per aggregate, the sun measurement's entries: per distant light of non-zero radiance, a
  // kViewGrid² orthographic grid of rays from the light over the aggregate's bounds, those
  // that meet its boundary first (grains unseen), with the distant lights that reach them
  // (as switchViews). None for a moving aggregate, or with more than 32 lights.
  std::vector<SwitchView> sunSwitchViews() const;
  // What carries the aggregate's low orders after its first grain, in words both front ends
  // print: "proxies for 8 visits, then the medium (measured: the medium's bias there −0.11%
  // ± 0.14%, right after the first grain −6.8%)", "explicit grains to bounce 16, then the
  // medium", "the medium"; the medium followed by " (exits)" in the exits model (vpt.h).
  std::string lowOrdersText(int aggregate) const;
  // Whether proxies make next-event estimation (ppt.h): for every light but domes.
  bool proxyLightSampling() const { return proxyLightSampling_; }
  // size: the grain's bounding radius in units of the aggregate's grain radius.
  const ProxyTable& proxyTable(int aggregate, int prototype, float size = 1.0f) const {
    return proxyTables_[size_t(aggregate)]->at(prototype, size);
  }
  const ProxyTables& proxyTables(int aggregate) const { return *proxyTables_[size_t(aggregate)]; }
  // Whether the medium of aggregate a takes a path over at a grain (vpt.h: enterMedia): the
  // exits model's (not a medium given directly, setMedium, whose flights the packing's would
  // not be), with its proxy tables made.
  bool takesOverAtGrains(int a) const {
    return a >= 0 && size_t(a) < proxyTables_.size() && size_t(a) < media_.size() && media_[size_t(a)].movesLight();
  }
  // The packing's flight in aggregate a (Aggregate::flightToGrain) along ray, past the grain
  // `from` where it is one of a's.
  GrainFlight flightToGrain(int a, const Ray& ray, const GrainStart& from, Rng& rng) const {
    return aggregateAt(a, ray.time).flightToGrain(ray.o, ray.d, *proxyTables_[size_t(a)],
                                                  from.aggregate == a ? &from.grain : nullptr, rng);
  }
  // Index of the aggregate whose boundary contains p at time (Ray::time), or -1.
  int mediumAt(const Vec3& p, float time = 0) const;
  // The exits model's move of a scattering's light (vpt.h): p + move, or p where a surface
  // lies between them (no grain lets light through a wall).
  Vec3 movedLight(const Vec3& p, const Vec3& move, float time) const;
  // The medium a path in medium m is in after such a move to q: m where q is still inside
  // its boundary (Aggregate::insideBoundaryFast), else mediumAt.
  int mediumAfterMove(int m, const Vec3& q, float time) const;
  // Aggregate a as it stands at a ray's time (aggregate_motion.h: AggregateDesc::shutterXf):
  // its queries on world (render-space) rays and points. What depends on where it is asks
  // this, not aggregates().
  PosedAggregate aggregateAt(int a, float time) const {
    const AggregateMotion& m = aggregateMotion_[size_t(a)];
    return m.moving() ? PosedAggregate(*aggregates_[size_t(a)], m.at(time)) : PosedAggregate(*aggregates_[size_t(a)]);
  }
  // Media exist (one per aggregate) when the technique uses them and some aggregate is
  // thicker than its mean free path (else EPT alone renders it: nothing to gain).
  bool hasMedia() const { return !media_.empty() || instancedMedia_ > 0; }
  const HomogeneousMedium& medium(int aggregate) const { return media_[aggregate]; }
  const MediumParams& mediumParams(int aggregate) const { return mediumParams_[aggregate]; }
  float maxGrainRadius() const { return maxGrainRadius_; }
  // Bounces a path not in an aggregate keeps explicit before it may enter a medium: the
  // settings' value, or with -1 the largest over the aggregates (explicitBounces(a)) and
  // over the instancers' media that keep them explicit (no proxies) of explicitBouncesFor.
  int explicitBounces() const { return explicitBounces_; }
  // Automatic low orders of an instancer's medium (no measured switching there yet; carried
  // by its proxies or explicit grains, instancedProxies()): a rule of albedo α_s and mean
  // cosine g in an object whose half thickness is depthMfp of its longest mean free path. The medium's
  // low-order error is an error in how much is absorbed near the surface (a Poisson
  // medium misses the packing's shadow hiding; bench/accuracy_matrix.py), largest where
  // grains absorb and scatter light back within few bounces:
  // - by x = (1 − α_s)(1 − g), worst channel: 0 for x ≤ 0.03, 16 from 0.04, 32 from
  //   0.10, linear between. Switching at once measured within 0.5% for IOR 1.31 rocks
  //   (x 0.025) and flakes (0.033), −0.9% for cube-like crystals (0.035; −0.4% with 15
  //   bounces, but a ramp that steep cut the hybrid bench's glass mixture, x 0.034, from
  //   4.4× to 2.5× at equal error), −0.6% for the base rocks (0.048) with 9, −1.0% for
  //   IOR 2.4 (0.14) with 16 and −0.4% with 32;
  // - thin objects, where every order stays near the surface: absorbing grains
  //   (α_s < kThinAlbedo) keep 32 bounces below 10 mean free paths, none from 20,
  //   linear between. A ball 25 grains across (6 mfp deep, α_s 0.89) measured −1.3%
  //   with 9 bounces, −0.4% with 16, −0.1% with 32; 50 across (15 mfp) −0.7% with 9.
  static int explicitBouncesFor(const Vec3& albedo, const Vec3& g, float depthMfp = kInf);
  static constexpr float kThinAlbedo = 0.96f;
  // A new view or new settings without rebuilding geometry, tiles, distance fields or TT
  // (a camera move in an interactive host). Not thread-safe: no render may be running.
  // The technique must keep needing media or not (else build anew); InputError on bad values.
  // With RenderSettings::switchForView the view measurement is made at once (Now: the
  // command line's, whose render waits for it) or left to be made apart (Apart: a
  // viewport's, whose camera must not wait seconds per move): the scene then renders with
  // the dome's and the sun's choices (provisional) until applyViewSwitch gives it the view's.
  enum class ViewSwitchTiming { Now, Apart };
  void setView(const CameraDesc& camera, const RenderSettings& settings,
               ViewSwitchTiming timing = ViewSwitchTiming::Now);
  // The view measurement setView(..., Apart) left to make: per aggregate the camera sees,
  // what measureViewSwitch reads, held by value or shared ownership, so that measure() may
  // run on any thread while this scene renders or takes another view (the scene itself must
  // outlive it: the views point at its lights). `view` names the view it was made for,
  // unique over every scene. Empty when nothing is left to measure.
  struct ViewSwitchWork {
    struct Item {
      size_t index = 0;  // the aggregate's
      std::shared_ptr<const Aggregate> aggregate;
      std::shared_ptr<const ProxyTables> tables;
      HomogeneousMedium medium;
      SwitchView view;
      uint64_t cacheKey = 0;
      // measureViewSwitch on what it holds (the sun measurement's too, with its options).
      std::shared_ptr<const SwitchMeasure> measure(int threads,
                                                   const SwitchOptions& options = viewSwitchOptions()) const;
    };
    uint64_t view = 0;
    int threads = 0;  // RenderSettings::threads
    std::vector<Item> items;
    bool empty() const { return items.empty(); }
    // The measurements, one per item, in its order (as setView(..., Now) makes them).
    std::vector<std::shared_ptr<const SwitchMeasure>> measure() const;
  };
  const ViewSwitchWork& pendingViewSwitch() const { return pendingViewSwitch_; }
  // Takes the measurements work.measure() made, when work was made for the view this scene
  // has now: the visits are chosen again with them, as setView(..., Now) would have chosen
  // (the same measurements, the same choice), nothing is left pending, and true is
  // returned. Else (a later view, another scene's work) nothing changes: false. Not
  // thread-safe, as setView.
  bool applyViewSwitch(const ViewSwitchWork& work,
                       const std::vector<std::shared_ptr<const SwitchMeasure>>& measures);
  // Replaces an aggregate's TT-derived medium by given RTE parameters, before rendering
  // (validation against other renderers, closed-form tests). Not thread-safe.
  void setMedium(int aggregate, const MediumParams& params);
  // DA: the depth below the boundary where it takes over (inf: the object is too thin
  // for DA, or it holds an emitter or the camera, a moving one anywhere in its sweep: DA
  // models light entering from outside and leaving towards the outside), its profile, and
  // the exit lobe (MaterialType::DiffusionExit) of the points where diffused light leaves.
  float diffusionDepth(int aggregate) const { return diffusionDepth_[aggregate]; }
  const DiffusionProfile& diffusionProfile(int aggregate) const { return diffusionProfiles_[aggregate]; }
  int diffusionExitMaterial() const { return diffusionExitMaterial_; }

  // The world position of render space's origin (scene_desc.h: renderOrigin): every
  // position the scene holds or returns (hits, bounds, lights, camera) is relative to it.
  const Vec3d& renderOrigin() const { return renderOrigin_; }
  const Camera& camera() const { return camera_; }
  const RenderSettings& settings() const { return settings_; }
  const Material& material(int i) const { return materials_[i]; }
  // The material at a hit with its textures applied (albedo, emission; Hit::Surface of a
  // textured mesh, made in storage), else material(hit.material). footprint: the ray
  // cone's width there in world units, from which the texture filter's width follows.
  const Material& shadingMaterial(const Hit& hit, float footprint, std::optional<Material>& storage) const;
  // Probability that a cut-out surface is there (MaterialDesc::opacity, opacityThreshold)
  // at barycentrics (bu, bv) of triangle prim of mesh geom; 1 for other surfaces. Rays and
  // shadow rays pass a cut-out surface by a hash of the ray and the triangle, so a pass is
  // reproducible and independent between rays.
  float presence(int geom, unsigned prim, float bu, float bv) const;

  // Who a hit belongs to, for the compositing AOVs (film.h): the front end's instance index
  // and aggregate id (-1: not instanced, not an aggregate's), and the Cryptomatte ids of its
  // object — the mesh's, aggregate's (grain, boundary, proxy) or area light's name — and of
  // its material: the mesh's or grain prototype's material name (the defaults:
  // "default_surface", "default_grain"); at a boundary, the material of the aggregate's
  // prototype of largest weight; an area light's own name (it has no material).
  struct HitIdentity {
    int instanceId = -1, aggregateId = -1;
    uint32_t cryptomatte[kCryptomatteTypes] = {0, 0};
  };
  HitIdentity identify(const Hit& hit) const;
  // Every name identify() can give a type's ids, sorted, each once: its manifest's names.
  const std::vector<std::string>& cryptomatteNames(CryptomatteType type) const {
    return cryptomatteNames_[int(type)];
  }
  // Warnings from textures (texture.h) for the front ends to show.
  const std::vector<std::string>& textureWarnings() const;
  const std::vector<Light>& lights() const { return lights_; }
  // Light sampling picks light i with probability lightPick(i), in proportion to its
  // weight from the centre of the scene's surfaces and aggregates (Light::pickWeight);
  // pickLight(u) is that choice for a uniform u. Every light equally when no weight is > 0.
  // With light linking, a vertex of `object` (linkObjectOf) picks among the lights that
  // light it alone, in the same proportions; -1: among all.
  float lightPick(int i, int object = -1) const { return pickFor(object).discreteProb(i); }
  int pickLight(float u, int object = -1) const { return pickFor(object).sampleDiscrete(u); }
  // Those chances for the front ends' logs, "sun 87.6%, sky 12.4%"; "" with one light or none.
  const std::string& lightPicksText() const { return lightPicksText_; }
  // The lights' IES profiles (LightShaping::iesFile) for the logs: "/World/Spot: spot.ies
  // (37 × 1 angles, peak 2400 cd, mean 310 cd)"; "" when no light has one.
  const std::string& iesProfilesText() const { return iesProfilesText_; }
  const std::vector<int>& infiniteLights() const { return infiniteLights_; }
  // Light linking (LightDesc::lightLink). The objects a path's vertices belong to: each
  // visible mesh by its geometry id, then each aggregate, then each instancer; -1 the
  // camera's, which sees every light. lightReaches(i, o): light i counts at a vertex of o.
  int linkObjectOf(const Hit& hit) const;
  int aggregateLinkObject(int a) const { return linkMeshes_ + a; }
  int instancerLinkObject(int k) const { return linkMeshes_ + int(aggregates_.size()) + k; }
  // For the front ends' logs: "/World/Rim lights 2 of 14 objects" per linked light, "; "
  // between them; "" when no light is linked.
  const std::string& lightLinksText() const { return lightLinksText_; }
  bool lightReaches(int light, int object) const {
    return unlit_.empty() || object < 0 || !unlit_[size_t(light) * size_t(linkObjects_) + size_t(object)];
  }
  // Shadow linking (LightDesc::shadowLink, shadows): whether object o (as linkObjectOf)
  // casts shadows from light i, i.e. blocks the shadow rays cast toward it. An object's
  // shadow on itself stays (a shadow ray leaving it is blocked by it as usual): an
  // aggregate's light transport is made of it.
  bool castsShadow(int light, int object) const {
    const uint8_t* passes = shadowPasses(light);
    return !passes || object < 0 || !passes[object];
  }
  // A light some object casts no shadow from; whether any light is.
  bool shadowLinked(int light) const { return size_t(light) < nonCasters_.size() && !nonCasters_[size_t(light)].empty(); }
  bool anyShadowLinked() const { return !nonCasters_.empty(); }
  // Whether the segment from x (a vertex of object `self`) along dir over dist meets the
  // bounds of another object that casts no shadow from light i. A direction sampled by
  // scattering there would meet what the light's shadow rays pass, so the vertex counts the
  // light that direction brings itself, by a shadow ray (ept.h: addDirectPastNonCasters),
  // and the emitter the path meets later is not counted again. Elsewhere the two
  // strategies see the same blockers and MIS is as usual. A function of the vertex and
  // the direction alone, so that both places agree on it.
  bool crossesNonCaster(int light, int self, const Vec3& x, const Vec3& dir, float dist) const;
  // For the front ends' logs: "/World/Key: 3 of 14 objects cast shadows" per shadow-linked
  // light, "; " between them; "" when none is.
  const std::string& shadowLinksText() const { return shadowLinksText_; }
  const std::vector<std::shared_ptr<const Aggregate>>& aggregates() const { return aggregates_; }
  // Explicit grains from simulations (SceneDesc::instancedGrains), in render space. A
  // grain's absorption is per its prototype's bounding radius at scale 1 (the instancer's
  // units times its transform's scale): grains of one material scaled up absorb more across.
  // EPT traces them grain by grain (intersect, occluded). With a technique that uses media, an instancer thicker than its mean free
  // path also has its equivalent heterogeneous medium (heterogeneous_medium.h: σ_t follows
  // the grains' packing rate, grain_density.h; α_s and phase by TT for its prototypes at
  // the bulk's packing rate and the grains' sizes). In the media (VPT: intersectMedium,
  // transmittance) such an instancer is that medium and no longer grains: a path enters it
  // where the hybrid switches it (after the explicit bounces, as for aggregates), or at its
  // first grain by the level-of-detail shortcut. DA in it where it is close enough to
  // homogeneous (instancedDiffusion).
  // Media of instancers are assumed not to overlap: a segment is tracked through the
  // first medium whose bounds it enters, up to their exit.
  // Proxies (ppt.h) carry the low orders after an instancer's first grain as an aggregate's
  // (instancedProxies): the grains' bounding spheres at their positions and times, each
  // prototype's tables at the grains' scales (absorption grows with the scale). Used where
  // the instancer has a medium and RenderSettings::proxies is On, or Auto where its medium
  // asks for low orders (explicitBouncesFor: the rule on its albedo and depth; no switching
  // measurement for them) or the sun is narrow. Visits: those bounces over kProxyOrders.
  const std::vector<std::shared_ptr<const InstancedGrains>>& instancedGrains() const { return instanced_; }
  // Instancer i's medium, or null (technique ept, or thinner than its mean free path).
  const HeterogeneousMedium* instancedMedium(int i) const {
    return builtInstanced_[size_t(i)].medium ? &builtInstanced_[size_t(i)].medium->medium : nullptr;
  }
  // The first instancer medium whose bounds the ray enters within [ray.tmin, tmax): its
  // index and the parameters where the ray is inside those bounds; false: none.
  bool firstInstancedMedium(const Ray& ray, float tmax, int& index, float& t0, float& t1) const;
  // Of instancer i (which has a medium): the grains' mean bounding radius (world), and the
  // total diffuse reflectance of its bulk's medium (the albedo AOV, as an aggregate's).
  float instancedGrainRadius(int i) const { return builtInstanced_[size_t(i)].medium->meanRadius; }
  Vec3 instancedDiffuseReflectance(int i) const { return builtInstanced_[size_t(i)].medium->diffuseReflectance; }
  // DA in instancer i's medium (heterogeneous_diffusion.h: its level-set boundary and the
  // rule for where DA holds), or null: no medium, technique not hybrid,
  // RenderSettings::daInstanced off, or the camera or an emitter inside it (as for
  // aggregates). Made when first asked for (build or setView), then lent to later builds.
  const HeterogeneousDiffusion* instancedDiffusion(int i) const {
    return instancedDa_.empty() || !instancedDa_[size_t(i)] ? nullptr : builtInstanced_[size_t(i)].diffusion.get();
  }
  int instancedGrainsBuilt() const { return instancedBuilt_; }  // built anew, not lent by the previous scene
  // Instancer i's set-up beyond its grid (InstancedGrains::stats): its packing-rate grid's
  // stats (null: no medium), and the seconds its medium and its proxy tables took this
  // build (0: none, or lent by the previous scene).
  const GrainDensityStats* instancedDensityStats(int i) const {
    const auto& m = builtInstanced_[size_t(i)].medium;
    return m ? &m->density.stats : nullptr;
  }
  double instancedMediumSeconds(int i) const { return builtInstanced_[size_t(i)].mediumSeconds; }
  double instancedTablesSeconds(int i) const { return builtInstanced_[size_t(i)].tablesSeconds; }
  bool instancedProxies(int i) const { return instancedProxies_[size_t(i)] != 0; }
  // In lowOrdersText()'s words: "proxies for 8 visits, then its heterogeneous medium (the
  // rule for 16 bounces)", "explicit grains to bounce 16, then …", "grain by grain (…)".
  std::string instancedLowOrdersText(int i) const;
  // Whether DA takes the deep paths of instancer i's medium, in words both front ends print:
  // "DA where the medium is deep and its packing uniform within ±10% over the diffusion's
  // reach", "no DA (…why)".
  std::string instancedDiffusionText(int i) const;
  int instancedProxyVisits(int i) const { return instancedProxyVisits_[size_t(i)]; }
  // Instancer i's table of a prototype, for a grain of that scale (InstancedGrainsDesc::scales).
  const ProxyTable& instancedProxyTable(int i, int prototype, float scale) const {
    return builtInstanced_[size_t(i)].proxies->at(prototype, scale);
  }
  double buildSeconds() const { return buildSeconds_; }
  // Of this build's aggregates: how many were voxelised anew, how many were taken from the
  // previous scene unchanged; and how many media were derived from TT parameters anew.
  int aggregatesBuilt() const { return aggregatesBuilt_; }
  int standInsBuilt() const { return standInsBuilt_; }  // built as stand-ins (not counted above)
  int aggregatesReused() const { return aggregatesReused_; }
  int mediaDerived() const { return mediaDerived_; }
  // The scene had no light and settings().defaultLight added the default dome (front ends
  // warn about it).
  bool defaultLightAdded() const { return defaultLightAdded_; }
  // Delta suns (distant lights of angle 0) made the physical sun, a disk of kSunAngle
  // degrees and the same irradiance, because the scene has smooth dielectric grains:
  // light refracted through a grain can never reach a delta light (no connection exists
  // through a smooth interface, and a path hits it with probability 0), so explicit
  // grains would lose all of it while the medium's emitter sampling keeps it. Front ends
  // warn once with these lights' names.
  const std::vector<std::string>& widenedSuns() const { return widenedSuns_; }
  // The front ends' warning line about them ("" when none).
  std::string widenedSunsWarning() const;
  static constexpr float kSunAngle = 0.53f;
  // A sun of under kNarrowSunAngle degrees lights smooth dielectric grains (widened delta
  // suns included): explicit grains reach it only by hitting its disk, with probability
  // ~ its solid angle per bounce, so at any practical sample count they miss most of its
  // light (a slab of light sand under the 0.53° sun: 55% too dark at 64 spp with 18
  // explicit bounces, 9% with the first grain alone; bench/README.md, "Narrow suns").
  // Paths that take the level-of-detail shortcut then enter the medium at their first
  // grain instead of after it and the explicit bounces: the medium samples the sun. It
  // is 4–9% darker than explicit grains under a directional sun (the first grains'
  // shadowing, which the medium averages), against 55% lost at 64 spp before.
  bool narrowSun() const { return narrowSun_; }
  static constexpr float kNarrowSunAngle = 5.0f;

 private:
  // Parts of intersect()/intersectMedium(): nearest hit below tmax (which they lower).
  // proxyMode: instancers that use proxies are not seen as grains (intersectProxies).
  bool intersectSurfaces(const Ray& ray, const Vec3& invD, Hit& hit, float& tmax,
                         bool mediaMode = false, bool proxyMode = false) const;  // invD: 1 / ray.d
  bool intersectAreaLights(const Ray& ray, Hit& hit, float& tmax) const;
  // Some area light within (0, dist) of p along dir (a shadow ray to a light's own surface
  // stops short of it: its dist is shortened by the caller).
  bool areaLightsOccluded(const Vec3& p, const Vec3& dir, float dist) const;
  // With kAreaLightBvhMin area lights or more, both ask a BVH over their bounds (Embree
  // user geometry, one primitive per light, built by buildLights) instead of every light.
  static constexpr size_t kAreaLightBvhMin = 8;
  void buildAreaLightBvh();
  static void areaLightBounds(const RTCBoundsFunctionArguments* args);
  static void areaLightIntersect(const RTCIntersectFunctionNArguments* args);
  static void areaLightOccluded(const RTCOccludedFunctionNArguments* args);
  EmbreeScene areaLightBvh_;
  void finishHit(const Ray& ray, Hit& hit) const;  // position and ray-offset scale
  // A surface hit's ray offset at p, reached over t (finishHit).
  float surfaceOffset(const Vec3& p, float t) const;
  void grainHit(Hit::Kind kind, int aggregate, const GrainHit& g, Hit& hit) const;  // Grain or Proxy
  // An instancer's grain (Grain) or its sphere (Proxy): all but the normal and centre.
  void instancedHit(Hit::Kind kind, int instancer, int64_t instance, int prototype, float t, float radius,
                    Hit& hit) const;
  // Meshes, explicit grains from instancers (which every transport sees as surfaces) and
  // area lights (areaLightsOccluded). mediaMode: instancers with a medium are that medium
  // (transmittance), not grains.
  ShadowPass shadowPass(ShadowCasters c) const { return ShadowPass{shadowPasses(c.light), c.self}; }
  bool surfacesOccluded(const Vec3& p, const Vec3& dir, float dist, float time, bool mediaMode = false,
                        bool proxyMode = false, ShadowPass passes = {}) const;
  bool intersectMeshes(const Ray& ray, const Vec3& invD, Hit& hit, float& tmax) const;
  bool intersectInstancedGrains(const Ray& ray, const Vec3& invD, Hit& hit, float& tmax, bool mediaMode,
                                bool proxyMode = false) const;
  // Nearest proxy sphere of the instancers that use proxies (Hit::Proxy, aggregate −1).
  bool intersectInstancedProxies(const Ray& ray, const Vec3& invD, Hit& hit, float& tmax,
                                 const GrainStart* from) const;
  void updateDiffusionDepths();  // from the media, the emitters inside and the camera

  Camera camera_;
  RenderSettings settings_;
  std::vector<Material> materials_;
  std::vector<Light> lights_;
  Distribution1D lightPick_;
  std::string lightPicksText_, iesProfilesText_;
  std::vector<int> infiniteLights_, areaLights_;
  std::vector<std::shared_ptr<const Aggregate>> aggregates_;
  // Per aggregate: its motion over the shutter, and its world bounds over it (culling).
  std::vector<AggregateMotion> aggregateMotion_;
  std::vector<Bounds3> aggregateBounds_;
  // A moving aggregate that the segment meets at no time of the shutter (its bounds over
  // it): not worth posing. Still ones are left to their own queries' bounds tests.
  bool missesMoving(size_t a, const Vec3& o, const Vec3& d, float tmin, float tmax) const {
    float t0, t1;
    return aggregateMotion_[a].moving() &&
           !aggregateBounds_[a].intersect(o, Vec3(1.0f / d.x, 1.0f / d.y, 1.0f / d.z), tmin, tmax, t0, t1);
  }
  // Per aggregate, what a later build(desc, this) compares and reuses.
  struct BuiltAggregate {
    AggregateDesc desc;                         // compared without its id (the primId AOV's)
    std::vector<int> materials;                 // scene material of each prototype
    std::vector<MaterialDesc> materialDescs;    // their descriptions (TT depends on them)
    std::shared_ptr<const Aggregate> aggregate;
    bool hasMedium = false;                     // TT-derived (before any setMedium)
    MediumParams medium;
    double mediumSauterSize = 0;                // the Sauter size it was derived with
    std::shared_ptr<const ProxyTables> proxies;  // made when first needed (updateProxyTables)
    std::shared_ptr<const SwitchMeasure> switching;  // likewise (updateSwitching)
    uint64_t switchKey = 0;                          // its cache key (the view measurement's too)
    bool mediumReplaced = false;                     // setMedium: switching is not lent
  };
  // fullOnly: a stand-in is not lent (its medium is, through `medium`).
  const BuiltAggregate* findBuilt(const AggregateDesc& desc, const std::vector<int>& materials,
                                  const std::vector<MaterialDesc>& materialDescs, bool fullOnly = false) const;
  // The steps of build(), in its order.
  struct DefaultMaterials {
    int surface = -1, grain = -1;  // indices of what unassigned surfaces and grains get
  };
  DefaultMaterials buildMaterials(const SceneDesc& desc);  // the scene's, the defaults, DA's exit
  void buildSurfaceMaps(const SceneDesc& desc);            // textures and cut-outs
  Bounds3 buildMeshes(const SceneDesc& desc, int defaultSurface);  // the surfaces' BVH; their bounds
  void buildAggregates(const SceneDesc& desc, int defaultGrain, const Scene* previous, Bounds3& all, bool standIns,
                       const BuildLog& log);
  // The previous scene's aggregate when unchanged (else entry.aggregate stays null).
  BuiltAggregate lend(const SceneDesc& desc, const AggregateDesc& a, int defaultGrain, const Scene* previous,
                      bool standIn);
  // Builds the entries' aggregates that were not lent, several at once under a memory cap.
  void buildConcurrently(const SceneDesc& desc, std::vector<BuiltAggregate>& entries, bool standIns,
                         const BuildLog& log);
  void addMedium(const AggregateDesc& a, BuiltAggregate& entry);
  // Explicit grains: lent by the previous scene when their description and materials are
  // unchanged, else built (their grid in parallel); extends `all` by their bounds.
  void buildInstancedGrains(const SceneDesc& desc, int defaultGrain, const Scene* previous, Bounds3& all);  // derived by TT unless lent
  std::vector<LightDesc> buildLights(const SceneDesc& desc, const Bounds3& all);  // returns them as built
  void findEmittersInside(const SceneDesc& desc, const std::vector<LightDesc>& lights);  // emitterInside_
  std::vector<BuiltAggregate> built_;
  struct InstancedMedium {
    GrainDensity density;
    MediumParams params;  // TT, at the bulk's packing rate (params.packingRate)
    HeterogeneousMedium medium;
    Vec3 diffuseReflectance;  // DiffusionProfile(params)'s
    float meanRadius = 0, maxRadius = 0;  // the grains' bounding radii (world)
  };
  struct BuiltInstanced {
    std::shared_ptr<const InstancedGrains> grains;
    std::shared_ptr<const InstancedMedium> medium;  // null: none (yet)
    std::vector<int> materials;               // scene material of each prototype
    std::vector<MaterialDesc> materialDescs;  // compared when lending
    std::vector<float> lengthScale;           // per prototype: its world radius at scale 1
    float worldScale = 1;                     // world length of one unit of the instancer's space
    std::shared_ptr<const ProxyTables> proxies;  // per prototype and scale (null: none made yet)
    // DA's boundary and rule in medium (null: none made yet; made when the settings ask for
    // DA there, lent with an unchanged medium).
    std::shared_ptr<const HeterogeneousDiffusion> diffusion;
    Bounds3 bounds;                           // world (render space)
    int id = -1;
    double mediumSeconds = 0, tablesSeconds = 0;  // this build's (instancedMediumSeconds)
  };
  std::vector<BuiltInstanced> builtInstanced_;
  std::vector<std::shared_ptr<const InstancedGrains>> instanced_;
  std::vector<HitIdentity> instancedIdentity_;
  // Light linking (lightReaches): per light and object, 1 where the light does not count;
  // empty when every light lights everything. Per object, the index of its light pick among
  // linkPicks_ (one per set of lights that reach an object).
  std::vector<uint8_t> unlit_;
  int linkMeshes_ = 0, linkObjects_ = 0;
  std::string lightLinksText_;
  // Shadow linking (castsShadow): per light and object, 1 where the object casts no shadow
  // from the light (empty when every object casts every shadow).
  std::vector<uint8_t> unshadowed_;
  std::string shadowLinksText_;
  // The row of unshadowed_ for light i, or null where every object blocks its shadow rays.
  const uint8_t* shadowPasses(int light) const {
    return light < 0 || !shadowLinked(light) ? nullptr : &unshadowed_[size_t(light) * size_t(linkObjects_)];
  }
  // Per light, the objects that cast no shadow from it, with their bounds (over the
  // shutter), and the union of those bounds: crossesNonCaster's test. Past
  // kListedNonCasters objects the union alone answers (conservatively: a direction that
  // crosses it is counted at its scattering, which is right if needless).
  struct NonCaster {
    int object;
    Bounds3 bounds;
  };
  static constexpr size_t kListedNonCasters = 64;
  std::vector<std::vector<NonCaster>> nonCasters_;
  std::vector<Bounds3> nonCasterBounds_;
  Bounds3 linkObjectBounds(int object) const;
  std::vector<float> pickWeights_;  // lightPick_'s weights
  std::vector<Distribution1D> linkPicks_;
  std::vector<int> objectPick_;
  const Distribution1D& pickFor(int object) const {
    return object < 0 || objectPick_.empty() ? lightPick_ : linkPicks_[size_t(objectPick_[size_t(object)])];
  }
  Bounds3 instancedBounds_;
  int instancedBuilt_ = 0;
  int instancedMedia_ = 0;  // instancers with a medium
  std::vector<char> instancedDa_;  // per instancer: DA in its medium (instancedDiffusion)
  std::vector<char> instancedEmitterInside_;  // an emitter inside its medium: no DA there
  // The medium of an instancer's grains (see instancedGrains()), or null when it is thinner
  // than its mean free path.
  std::shared_ptr<const InstancedMedium> buildInstancedMedium(const InstancedGrains& grains,
                                                             const std::vector<int>& materials, float worldScale) const;
  int aggregatesBuilt_ = 0, standInsBuilt_ = 0, aggregatesReused_ = 0, mediaDerived_ = 0;
  std::vector<MediumParams> mediumParams_;
  std::vector<std::shared_ptr<const ProxyTables>> proxyTables_;  // per aggregate
  std::vector<HomogeneousMedium> media_;
  std::vector<float> diffusionDepth_;
  std::vector<bool> emitterInside_;        // an emitter reaches into the aggregate: no DA there
  std::vector<DiffusionProfile> diffusionProfiles_;
  // DA's medium per aggregate: its medium's, or in the exits model the medium that diffuses
  // as that walk does (tt.h: exitsDiffusionMedium).
  std::vector<float> daDepthUnit_;  // diffusionDepth() at factor 1
  void setDiffusion(size_t aggregate);
  int diffusionExitMaterial_ = -1;
  bool mediaNeeded_ = false;
  float maxGrainRadius_ = 0;
  int explicitBounces_ = 0, maxProxyVisits_ = 0;
  std::vector<int> proxyVisits_, aggregateBounces_;
  std::vector<char> aggregateProxies_, instancedProxies_;
  std::vector<int> instancedProxyVisits_, instancedBounces_;
  std::vector<std::shared_ptr<const SwitchMeasure>> switching_, viewSwitching_, sunSwitching_;
  // The distant lights (bits of lights_) whose central ray leaves a boundary hit unblocked.
  uint32_t distantLightsReaching(const Hit& hit) const;
  // Proxies and switching per aggregate, from the settings and the media: the tables and
  // measurements they need (lent by an unchanged aggregate, else cached on disk or made).
  void updateSwitching(ViewSwitchTiming timing = ViewSwitchTiming::Now);
  // The view's measurements applyViewSwitch took for viewId_ (per aggregate; empty: none),
  // and what setView(..., Apart) left to measure.
  std::vector<std::shared_ptr<const SwitchMeasure>> viewMeasured_;
  ViewSwitchWork pendingViewSwitch_;
  uint64_t viewId_ = 0;  // this view's, unique over every scene (setView, build)
  void updateProxyTables();
  void updateInstancedProxyTables();
  void measureSwitching(size_t aggregate);
  ViewSwitchWork::Item viewSwitchItem(size_t aggregate, const SwitchView& view) const;
  std::shared_ptr<const SwitchMeasure> measureViewSwitching(size_t aggregate, const SwitchView& view,
                                                            const SwitchOptions& options) const;
  bool useProxies_ = false, proxyLightSampling_ = false;
  std::vector<TriangleMesh> worldMeshes_;   // per Embree geometry id (moving: at the shutter's open)
  std::vector<TriangleMesh> worldMeshesAtClose_;  // per geometry id: at the shutter's close; empty when still
  bool movingMeshes_ = false;
  float shutterOpen_ = 0, shutterClose_ = 0;
  // A ray's time as Embree's, [0, 1] over the shutter (0 without blur).
  float shutterFraction(float time) const {
    return movingMeshes_ ? std::clamp((time - shutterOpen_) / (shutterClose_ - shutterOpen_), 0.0f, 1.0f) : 0.0f;
  }
  // Textures and cut-outs (indices into textures_; -1: none) of each material.
  struct SurfaceMaps {
    int albedo = -1, emission = -1, opacity = -1;
    float opacityConstant = 1, opacityThreshold = 0;
    bool cutout = false;
  };
  std::vector<SurfaceMaps> surfaceMaps_;
  std::unique_ptr<Textures> textures_;
  // Of a ray cone's footprint, the texture filter's share: max(1/8, 1/√spp) (scene.cpp).
  float textureFilterScale_ = 1;
  // The Embree filter of a cut-out mesh finds the scene and its geometry id here.
  struct CutoutFilterData {
    const Scene* scene;
    int geom;
  };
  std::vector<CutoutFilterData> cutoutData_;  // one per mesh, reserved before any is used
  static void cutoutFilter(const RTCFilterFunctionNArguments* args);
  void buildShadowLinks(const std::vector<const std::vector<std::string>*>& categories,
                        const std::vector<LightDesc>& lights);
  void surfaceUv(int geom, unsigned prim, float bu, float bv, float& u, float& v) const;
  std::vector<int> meshMaterial_, meshId_;
  std::vector<int> aggregateId_;
  // identify(): per mesh (geometry id), aggregate and light, and per material the id of its name.
  void buildIdentities(const SceneDesc& desc, const std::vector<LightDesc>& lights);
  void buildLightLinks(const SceneDesc& desc, const std::vector<LightDesc>& lights);
  std::vector<HitIdentity> meshIdentity_, aggregateIdentity_, lightIdentity_;
  std::vector<uint32_t> materialCryptomatte_;
  std::vector<std::string> cryptomatteNames_[kCryptomatteTypes];
  EmbreeDevice device_;
  EmbreeScene surfaces_;
  Bounds3 surfaceBounds_;  // of every visible mesh (empty: none), to skip surfaces_ cheaply
  Vec3d renderOrigin_;
  float sceneScale_ = 1;
  double buildSeconds_ = 0;
  bool defaultLightAdded_ = false;
  std::vector<std::string> widenedSuns_;
  bool narrowSun_ = false;
  bool standIns_ = false;
};

}  // namespace granular
