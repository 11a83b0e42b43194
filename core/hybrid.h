// hybrid.h — switching between EPT, VPT and DA, and Russian roulette on the high-order
// part (Meng et al. 2015's switch between EPT, VPT and DA, and its Russian roulette).
//
// Contract. traceBundle() traces the N paths of one pixel's bundle in lock-step with EPT.
// After each bounce k (once every live path has done its low orders, ppt.h:
// lowOrdersDone; switching.h) it measures σ_k, the root-mean-square distance of the N_k live paths'
// vertices to their centroid; once σ_k > τ R_max N_k / N (R_max: the largest grain
// radius) every live path switches to the equivalent media (VPT), as soon as it is out
// of the grain it is in. VPT hands a path to DA where diffusion.h says. With technique Ept nothing
// switches (the reference). Each path's radiance stays split by technique (AOVs).
//
// At the switch — and wherever a path enters the media on its own, by the level-of-detail
// shortcut (ept.h) — a path goes on as on average P_a continuations of weight 1/P_a each:
// Russian roulette when P_a < 1 (Meng et al. 2015: it survives with probability P_a),
// splitting when P_a > 1 (⌊P_a⌋ or ⌈P_a⌉ of them, the expected count P_a; set by hand,
// RenderSettings::roulette) — several continuations share one costly first grain. The
// continuations of a split are traced with the bundle, each on its own random stream, and
// added into their path's radiance at the end. Roulette inside the media sees the
// throughput before the 1/P_a (PathState::rrScale).
//
// tuneRoulette() is the pre-render: on about 1% of the pixels (at least 64) it traces
// bundles with P_a = 1 and averages over the pixels V_L = Var(L + H) − E[H²] and
// V_H = E[H²], where L is a path's low-order (EPT, PPT) radiance and H what it carries
// after it enters the media (VPT, DA; 0 for a path that never does), and the
// deterministic costs t_L, t_H (ray casts) of the two parts. A sample's variance at P_a
// is then exactly V_L + V_H/P_a (roulette adds E[H²](1/P_a − 1)) and its cost
// t_L + P_a t_H: Meng et al.'s product, least at P_a = sqrt(V_H t_L / (V_L t_H)), clamped
// into [0.05, 1] (1 when V_L ≤ 0 or nothing follows the switch). The tuning does not
// split: splitting's predicted gains did not show in the bench's error × time
// (bench/README.md). Deterministic given the seed.
#pragma once

#include <vector>

#include "camera.h"
#include "path_state.h"
#include "scene.h"

namespace granular {

struct BundleStats {
  int switchedAtBounce = -1;  // k at which the bundle switched to VPT, or -1
};

// A camera path of a scene of stand-ins (Scene::standIns) in the media from its start:
// VPT, in the medium that holds the camera, if any.
void startInMedia(const Scene& scene, PathState& path);

// Traces paths (already started, same pixel) to the end. pa: the expected continuations
// at the switch to VPT (above); a split's continuations are added into their path
// (PathState::L, cost) at the end, leaving paths as many as it came.
BundleStats traceBundle(const Scene& scene, std::vector<PathState>& paths, float pa);

struct RouletteTuning {
  float pa = 1;
  double VL = 0, VH = 0, tL = 0, tH = 0;  // the pre-render's averages (above)
  int pixels = 0;
};

RouletteTuning tuneRoulette(const Scene& scene);

// Meng et al.'s P_a of least (V_L + V_H/P_a)(t_L + P_a t_H), in [0.05, 1] (above).
float bestContinuations(const RouletteTuning& t);

}  // namespace granular
