// ept.h — explicit path tracing (EPT) of surfaces and individual grains (Meng et al. 2015), and
// the surface shading that every transport shares (path_state.h: what a path carries).
//
// Contract: eptStep() advances a path by one interaction with the explicit scene:
// unidirectional path tracing with next-event estimation and MIS (power heuristic) at
// non-delta surfaces, delta scattering at grain interfaces (the Fresnel choice guided
// toward suns: a branch that leaves for a sun's disk is taken half the time, weighted),
// Beer–Lambert absorption inside grains and Russian roulette on the throughput after
// rrDepth bounces. Radiance
// is added to PathState::L[technique that produced it], so the EPT, VPT, DA and PPT parts
// of an image are separate AOVs that sum to the beauty. All randomness comes from the
// path's Rng, so a path is a pure function of its seed. The EPT-only reference is the
// hybrid integrator with technique Ept: eptStep() until the path ends.
#pragma once

#include "path_state.h"
#include "scene.h"

namespace granular {

// Relative cost of one ray cast through aggregates (cells, sphere tests, grain BVHs)
// against one cast through plain meshes; measured by bench/ept_throughput.py.
constexpr double kGrainCastCost = 4.0;

// spread: the ray cone's spread angle (Camera::pixelSpreadAngle for camera rays).
PathState startPath(const Ray& ray, uint64_t rngSeed, float spread = 0, float width = 0);

// Spread angle of a ray cone after a non-delta bounce: a diffuse lobe blurs the
// footprint at once (a conservative stand-in for the lobe's width).
constexpr float kDiffuseConeSpread = 0.35f;

// One bounce with explicit grains. Sets alive = false when the path ends.
// Level of detail (RenderSettings::lod): at a path's first grain, if the grain radius is
// under lod × the cone footprint there, that grain is met as a proxy where the aggregate
// has proxy tables (Scene::lodProxies; ppt.h: its scattering averaged over orientations
// and entry points, with next-event estimation), else traced explicitly (its Fresnel
// reflection and refraction, which the medium's boundary does not model); the path goes on
// to the medium after its low orders (ppt.h: lowOrdersDone), with the hybrid's roulette
// (hybrid.h). Entering at the boundary instead measured 3.5% brighter on sub-pixel sand
// (tests/core/test_lod).
void eptStep(const Scene& scene, PathState& path);

// Shared by EPT, PPT and VPT: emission, next-event estimation and BSDF sampling at a
// surface hit. Shadow rays see what the path's mode sees: the media (transmittance) in
// media mode, else proxies (kPpt) or grains.
void shadeSurface(const Scene& scene, PathState& path, const Hit& hit, bool mediaMode);

// The first visible hit's AOVs (depth, normal, kind, primId), once per path.
void recordPrimary(const Scene& scene, PathState& path, const Hit& hit);
// The albedo AOV of a camera ray's first hit, the guide a denoiser takes for reflectance:
// a Lambert surface's albedo (textured), 1 on a dielectric surface and on lights; on an
// aggregate (a grain or its boundary), the total diffuse reflectance of its equivalent
// medium (DiffusionProfile::diffuseReflectance), per channel, so
// that a denoiser sees the colour the aggregate has from afar (an instancer's grain: its
// heterogeneous medium's bulk); 1 when the scene has no media (EPT alone: the grains are
// clear dielectrics).
Vec3 primaryAlbedo(const Scene& scene, const Hit& hit);

// Emission of an area light that the path's last sampled direction reached, MIS-weighted.
void addAreaLightHit(const Scene& scene, PathState& path, const Hit& hit);

// Radiance of the infinite lights along an escaping direction, MIS-weighted against
// light sampling when the last bounce could have sampled them.
Vec3 escapedRadiance(const Scene& scene, const PathState& path, const Vec3& dir);

// Shadow linking: light a scattering's sampled direction would bring past objects that cast
// no shadow from it (Scene::crossesNonCaster). Called after the scattering (path.last* are
// its, path.linkObject its object) with beta, the throughput along its sampled direction
// dir, whose ray starts at origin: for each shadow-linked light that direction meets past
// the bounds of such an object, the light's radiance there times beta and the scattering's
// MIS weight (1 after a delta bounce, which samples no light), handed to add(c, dist,
// casters) to cast the shadow ray (its own transport's: grains, proxies or media) from
// origin over dist and add c times what passes. The emitter the path meets later is not
// counted again (addAreaLightHit, escapedRadiance). So at every scattering, the light that
// arrives straight from a light passes what casts no shadow from it. Does nothing in a
// scene without shadow links.
template <class Add>
void addDirectPastNonCasters(const Scene& scene, PathState& path, const Vec3& beta, const Vec3& origin,
                             const Vec3& dir, Add&& add);

// A ray's end at no hit (the infinite lights' radiance) or at an area light (its
// emission): adds it, ends the path and returns true; else false (the path goes on).
bool endsAtLight(const Scene& scene, PathState& path, bool found, const Hit& hit);

// Throughput Russian roulette after rrDepth events; false: the path ends.
bool russianRoulette(const Scene& scene, PathState& path);

template <class Add>
void addDirectPastNonCasters(const Scene& scene, PathState& path, const Vec3& beta, const Vec3& origin,
                             const Vec3& dir, Add&& add) {
  if (!scene.anyShadowLinked()) return;
  const Vec3& x = path.lastP;
  const bool delta = path.lastDelta;
  for (int li = 0; li < int(scene.lights().size()); ++li) {
    // The whole line first: a direction that crosses no such bounds is the usual case.
    if (!scene.crossesNonCaster(li, path.linkObject, x, dir, kInf) || !scene.lightReaches(li, path.linkObject))
      continue;
    const Light& light = scene.lights()[li];
    // As the emitter met later would be weighed (distances from the scattering's point).
    float reach = kInf, lightPdf = 0, t = kInf;
    Vec3 Le;
    if (light.isInfinite()) {
      // As escapedRadiance sees it (a smooth chain: the sun widened as the chain sees it).
      Le = light.escapedLeSeen(dir, delta ? path.sunHalfAngle : path.lastSunHalfAngle, delta ? nullptr : &lightPdf,
                               path.lastAbove);
    } else {
      if (!light.intersect(Ray{origin, dir, 0.0f, kInf, path.ray.time}, t)) continue;
      const Vec3 q = origin + dir * t;
      reach = length(q - x);
      Le = light.areaLe(q, dir);
      lightPdf = light.pdfLi(x, dir, reach);
    }
    if (isBlack(Le) || (std::isfinite(reach) && !scene.crossesNonCaster(li, path.linkObject, x, dir, reach))) continue;
    const float w =
        delta ? 1.0f : powerHeuristic(path.lastPdf, lightPdf * scene.lightPick(li, path.linkObject) * path.lastNeeChance);
    add(beta * Le * w, std::isfinite(t) ? t * (1.0f - 1e-4f) : kInf, ShadowCasters{li, path.linkObject});
  }
}

}  // namespace granular
