// path_state.h — one path as the integrators (ept.h, ppt.h, vpt.h, diffusion.h, hybrid.h)
// advance it, one event at a time.
//
// Contract: a PathState holds everything a path carries between events: its next ray,
// its own Rng (so a path is a pure function of its seed), throughput, the radiance it has
// gathered split by the transport that produced it (L[Transport]: the AOVs, summing to the
// beauty), the transport it is in, MIS and ray-cone state, and the deterministic cost the
// roulette's tuning reads. startPath() (ept.h) makes one; each step function reads and
// updates it and sets alive = false when the path ends.
#pragma once

#include "math.h"
#include "rng.h"
#include "scene.h"  // GrainStart

namespace granular {

// What the first visible surface says about a pixel (the AOVs besides colour).
struct PrimaryInfo {
  bool hit = false;
  float depth = kInf;   // along the camera's view axis
  Vec3 normal;          // world geometric normal, facing the camera
  int kind = -1;        // Hit::Kind of the first hit
  int primId = -1;      // the front end's id of what was hit
  Vec3 albedo;          // what a denoiser takes as its reflectance (ept.h: primaryAlbedo)
  int instanceId = -1, aggregateId = -1;       // Scene::identify
  uint32_t cryptomatte[2] = {0, 0};            // object and material ids (cryptomatte.h)
};

// Index of a contribution in PathState::L (the AOVs), and the transport a path is in:
// explicit grains, the media (VPT, DA), proxies (ppt.h).
enum Transport : int { kEpt = 0, kVpt = 1, kDa = 2, kPpt = 3 };
constexpr int kTransports = 4;

struct PathState {
  Ray ray;
  Rng rng;
  Vec3 beta{1.0f};
  Vec3 L[kTransports];     // radiance gathered by EPT, VPT, DA and PPT
  int depth = 0;           // scattering events so far (a proxy's counts kProxyOrders, ppt.h)
  int proxyVisits = 0;     // grains met among proxies after the first (ppt.h: lowOrdersDone)
  bool alive = true;
  // What the last scattering leaves for the emitter its sampled direction may meet (MIS
  // against that scattering's next-event estimation), set together by scattered().
  bool lastDelta = true;   // camera rays and delta bounces see emitters unweighted
  float lastPdf = 0;       // solid-angle pdf of the last sampled direction
  // The half-angle (radians) of the disk the last scattering's next-event estimation saw a
  // narrow sun as (0: exact): a rough grain's and a proxy's see it widened (ept.cpp,
  // chainHalfAngle; ppt.cpp), and an escape after them sees the same disk, so MIS stays whole.
  float lastSunHalfAngle = 0;
  Vec3 lastP;              // where that direction was sampled (for area-light MIS)
  // The normal above a surface that only reflects, over whose hemisphere the last
  // scattering's next-event estimation sampled a constant dome (Light::sampleLi; zero: the
  // whole sphere), so that an escape weighs the dome with the pdf it was sampled with.
  Vec3 lastAbove{0.0f};
  float lastNeeChance = 1; // the chance that next-event estimation was made there (MIS)
  // The object of the path's last scattering (Scene::linkObjectOf; -1: none yet, the
  // camera's): the lights its next-event estimate and the emitters its sampled direction
  // meets count only where they light it (Scene::lightReaches, light linking).
  int linkObject = -1;
  void scattered(bool delta, float pdf, const Vec3& at, float neeChance, float sunHalfAngle,
                 const Vec3& above = Vec3(0.0f)) {
    lastDelta = delta;
    lastPdf = pdf;
    lastP = at;
    lastAbove = above;
    lastNeeChance = neeChance;
    lastSunHalfAngle = sunHalfAngle;
  }
  // The uniform number that picks the light of the path's first next-event estimate, or
  // < 0 (then the generator's): a pixel's samples take theirs stratified (Renderer), so that
  // a light picked seldom (Scene::lightPick) is picked as often as its chance in every
  // pixel, not in none of its first samples (which adaptive sampling reads as no noise).
  float firstLightU = -1;
  float nextLightU() {
    const float u = firstLightU;
    firstLightU = -1;
    return u >= 0 ? u : rng.next1D();
  }
  bool inGrain = false;    // between entering and leaving a grain (EPT)
  GrainStart from;         // the grain the ray starts at (EPT: Scene::intersect's hint)
  Transport mode = kEpt;   // kEpt: explicit grains; kPpt: proxies; kVpt: equivalent media
  Transport credit = kEpt; // which AOV the path's radiance goes to (kDa after a DA step)
  int medium = -1;         // aggregate whose medium holds the path (kVpt), or -1
  bool grainFlight = false;  // its next flight is the packing's, from the grain `from` (vpt.h: enterMedia)
  bool switchPending = false;  // switch to kVpt once out of the current grain
  // Light the last next-event estimate among proxies found through grains' straight lobes
  // (ProxyShadow, proxy.h): added once the path goes on among proxies or ends, dropped if it
  // switches to the media, which count those grains as scatterings (ppt.h).
  Vec3 pendingStraight{0.0f};
  // A next-event estimate c (all but its shadow ray's factor) whose shadow ray crossed
  // proxies: what met no grain is added at once, what came through straight lobes held.
  void addThroughProxies(const Vec3& c, const ProxyShadow& shadow) {
    if (shadow.blocked()) return;
    L[credit] += c * shadow.unscattered;
    pendingStraight += c * (shadow.crossing - Vec3(shadow.unscattered));
  }
  void addPendingStraight() {
    L[credit] += pendingStraight;
    pendingStraight = Vec3(0.0f);
  }
  // The level-of-detail shortcut's first grain (ppt.h): the grain the explicit ray met,
  // which the proxy walk then meets for sure, `firstGrainAt` along the ray (-1: none).
  GrainStart firstGrain;
  float firstGrainAt = -1;
  bool enteredMedia = false;   // the roulette or split of its entry into the media is done (hybrid.h)
  int splitFrom = -1;          // a continuation of a split at the switch: its path's index (hybrid.h)
  // Russian roulette on the throughput (ept.h) sees beta × rrScale: P_a after the switch,
  // so that a split's continuations are cut as the path would be, not P_a times as often
  // (which would spend the noise that splitting saved), nor a roulette's survivors spared.
  float rrScale = 1;
  PrimaryInfo primary;
  // Ray cone (Akenine-Möller et al. 2019): footprint width at the ray origin and its
  // spread angle; for the level-of-detail shortcut (RenderSettings::lod).
  float coneWidth = 0, coneSpread = 0;
  bool touchedAggregate = false;  // a grain has been hit (the LOD test is at first contact)
  // The half-angle (radians) of the disk a smooth chain from the explicit grains the path
  // met sees a narrower sun as (RenderSettings::sunRegularization; 0: exact; -1: no grain
  // met yet), from the spread of its direction over the pixel's footprint (ept.cpp,
  // chainHalfAngle): at least the first grain's w / R (sunFirstSpread), more as the chain
  // bends through more faces (sunChainSpread, summed over its smooth grain interfaces).
  float sunHalfAngle = -1;
  float sunFirstSpread = 0, sunChainSpread = 0;
  bool shortcut = false;          // took the LOD shortcut: to the medium after this grain
  bool lost = false;              // ended by a numerical failure (a leak, endless crossings): counted
  bool daRefused = false;         // the curvature guard refused DA once: VPT to the end (vpt.cpp)
  int daRetryDepth = 0;           // an instancer's varying packing refused DA: not asked before this depth
  // Deterministic cost (ray casts, a grain traversal counted kGrainCastCost) spent in
  // the low-order (EPT) and high-order (VPT, DA) parts: the t_L and t_H of the roulette's P_a (hybrid.h).
  double cost[2] = {0, 0};

  Vec3 radiance() const { return L[0] + L[1] + L[2] + L[3]; }
};

}  // namespace granular
