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
// folded into their path's radiance at the end.
//
// tuneRoulette() is the pre-render: on about 1% of the pixels (at least 64) it traces
// bundles with two continuations per path entering the media, and from them, averaged over the
// pixels: V_0, the variance of a sample that no P_a changes (the low-order part and the
// continuations' mean given the state at the switch, Var(L + E[H|s])); V_1 = E[Var(H|s)],
// the continuations' own variance (half the mean squared difference of the two);
// H_2 = E[H²] and H_12 = E[E[H|s]²] (the mean product of the two); and the
// deterministic costs t_L, t_H (ray casts) of the parts before and after the switch.
// A sample's variance at P_a is
//   P_a ≤ 1:  V_0 + V_1 + H_2 (1/P_a − 1)                       (roulette)
//   P_a ≥ 1:  V_0 + V_1/P_a + H_12 f(1 − f)/P_a²,  f = P_a − ⌊P_a⌋  (splitting)
// and its cost t_L + P_a t_H; the tuned P_a minimises their product over [0.05, 1]. That
// is Meng et al.'s (V_L + V_H/P_a)(t_L + P_a t_H) with V_L = V_0 + V_1 − H_2 and
// V_H = H_2, whose minimiser is sqrt(V_H t_L / (V_L t_H)). The splitting branch predicts a
// split's variance well (tests/core/test_hybrid.cpp), but the gains it promised on the
// bench's scenes did not show in their error × time (bench/README.md), so the tuning does
// not split. Deterministic given the seed.
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
// at the switch to VPT (above). fold: a split's continuations are added into their path
// (PathState::L, cost) and removed, leaving paths as it came; else they stay after the N
// paths, each naming its path (PathState::splitFrom).
BundleStats traceBundle(const Scene& scene, std::vector<PathState>& paths, float pa, bool fold = true);

struct RouletteTuning {
  float pa = 1;
  double V0 = 0, V1 = 0, H2 = 0, H12 = 0, tL = 0, tH = 0;  // the pre-render's averages (above)
  int pixels = 0;
  // A sample's variance and cost at pa by the model above.
  double variance(double pa) const;
  double cost(double pa) const { return tL + pa * tH; }
};

RouletteTuning tuneRoulette(const Scene& scene);

// The P_a in [0.05, 1] of least variance × cost by t's model (on a grid of 0.01; 1
// without high-order work or noise).
float bestContinuations(const RouletteTuning& t);

}  // namespace granular
