// hybrid.h — switching between EPT, VPT and DA, and Russian roulette on the high-order
// part (Meng et al. 2015's switch between EPT, VPT and DA, and its Russian roulette).
//
// Contract. traceBundle() traces the N paths of one pixel's bundle in lock-step with EPT.
// After each bounce k (once every live path has done its low orders, ppt.h:
// lowOrdersDone; switching.h) it measures σ_k, the root-mean-square distance of the N_k live paths'
// vertices to their centroid; once σ_k > τ R_max N_k / N (R_max: the largest grain
// radius) every live path switches to the equivalent media (VPT), as soon as it is out
// of the grain it is in. At the switch a path survives with probability P_a (weight
// 1/P_a). VPT hands a path to DA where diffusion.h says. With technique Ept nothing
// switches (the reference). Each path's radiance stays split by technique (AOVs).
//
// tuneRoulette() is the pre-render: on about 1% of the pixels (at least 64) it traces
// bundles with P_a = 1, averages the per-pixel variance V_L of the low-order (EPT) part,
// the second moment V_H of the high-order (VPT + DA) part — the term that Russian roulette
// scales by 1/P_a — and their deterministic costs t_L, t_H (ray casts), and returns
// P_a = sqrt(V_H t_L / (V_L t_H)) clamped into [0.05, 1], the minimiser of
// (V_L + V_H/P_a)(t_L + P_a t_H). Deterministic given the seed.
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

// Traces paths (already started, same pixel) to the end. pa: survival probability at the
// switch to VPT.
BundleStats traceBundle(const Scene& scene, std::vector<PathState>& paths, float pa);

struct RouletteTuning {
  float pa = 1;
  double VL = 0, VH = 0, tL = 0, tH = 0;
  int pixels = 0;
};

RouletteTuning tuneRoulette(const Scene& scene);

}  // namespace granular
