// ppt.h — proxy path tracing (PPT; Müller et al. 2016, §4): the low orders of a path in an
// aggregate, after its first grain, scatter off the grains' bounding spheres at their true
// positions by each prototype's tabulated grain scattering (proxy.h), not by tracing the
// grains. The positions keep the packing's gaps, hence the shadowing between neighbouring
// grains that the memoryless medium (VPT) averages away; a proxy costs a sphere test and a
// table lookup instead of a grain's BVH and its chain of refractions.
//
// Contract: pptStep() advances a path (PathState::mode kPpt) by one event. It walks to the
// nearest surface, area light or proxy sphere the ray enters (not the sphere it leaves,
// PathState::from). At a sphere, the ray meets its grain with the table's chance hit(b),
// else it crosses the sphere unchanged and the walk goes on. A path the level-of-detail
// shortcut sent here (ept.h; PathState::firstGrain) meets the grain its explicit ray met for
// sure, where the ray enters that grain's sphere, without walking the spheres before it
// (Scene::firstGrainProxy; the walk where that cannot be had): the ray is known to meet that
// grain and to miss those before it.
// A grain met scatters:
//  - next-event estimation: one light (Scene::pickLight), sampled from the sphere's
//    centre; the table's f_c toward it, the shadow ray leaving from that direction's exit
//    point and crossing other proxies with their chance of letting it through
//    (Scene::proxyTransmittance: grains missed, or met and left straight on); MIS by the
//    power heuristic against the table's pdf, delta lights unweighted. Smooth grains'
//    tables are smooth in direction, so delta and narrow suns are reached like any light;
//    a narrow sun as the setting's disk (RenderSettings::sunRegularization: a proxy holds
//    no glint a pixel could resolve), and so do escapes after a proxy (lastSunHalfAngle);
//  - the next direction from the table (weight f_c / pdf), leaving from its exit point; or
//    the straight lobe (proxy.h): on along the same line, a delta event that is not a visit
//    and keeps the last scattering's pdf for MIS (its next-event estimate counted the lobe).
// What a shadow ray found through other grains' straight lobes is the path's only while
// it goes on among proxies: the equivalent medium counts every grain met as a scattering
// (tt.h), and light through a straight lobe is then its forward-scattered light. So it is
// held (PathState::pendingStraight) until the next proxy step or the path's end, and
// dropped when the path switches to the media; the light that met no grain is added at
// once. Without that, that light is counted twice where the medium takes over
// (bench/README.md, "Straight through flat grains").
// Surfaces are shaded as EPT shades them, shadow rays crossing proxies as above. The path
// leaves PPT for the media at the hybrid's switch (hybrid.h) or, when it took the
// level-of-detail shortcut, at once, both once lowOrdersDone() (below).
// Radiance goes to PathState::L[kPpt] (the AOV ppt.*), a low-order part as EPT's is.
// The same for an instancer's grains (Scene::instancedProxies): spheres at the simulation's
// positions (InstancedGrains::intersectProxy, proxyTransmittance), NEE at every visit (no
// distance field to say how deep a grain lies).
#pragma once

#include "path_state.h"

namespace granular {

void pptStep(const Scene& scene, PathState& path);

// What a proxy's scattering counts as scattering events (PathState::depth: against
// Scene::explicitBounces(), Russian roulette's rrDepth, maxDepth; PathState::proxyVisits
// counts the visits themselves): a grain visit is ~3.3
// explicit bounces (interfaces), but the bias the medium leaves after K proxy visits is
// that of ~2K explicit bounces (the IOR 2.4 ball of the accuracy matrix: −1.2% after 8
// visits, −0.6% after 16; explicit grains −1.1% after 16 bounces, −0.35% after 32), so a
// visit counts 2.
constexpr int kProxyOrders = 2;

// After an explicit grain bounce: whether the path goes on among proxies (its grain's
// aggregate uses them, Scene::useProxies(a); the path out of its grain and in EPT).
bool entersProxies(const Scene& scene, const PathState& path);

// Whether a path (not in the media) has done the low orders that stay discrete before the
// medium may take it (the hybrid's switch, the level-of-detail shortcut), by the aggregate
// of its last grain (Scene::proxyVisits, explicitBounces; switching.h):
//  - with RenderSettings::explicitBounces set: its depth has reached them;
//  - among proxies: its visits after the first grain have reached the aggregate's;
//  - in EPT in an aggregate that uses proxies: the aggregate needs none (else the path
//    is still in its first grain and has its visits to make);
//  - else (explicit grains, or no aggregate yet): its depth has reached the explicit bounces.
bool lowOrdersDone(const Scene& scene, const PathState& path);

}  // namespace granular
