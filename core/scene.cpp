#include "scene.h"

#include <atomic>
#include <condition_variable>
#include <cstdlib>
#include <mutex>
#include <thread>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <set>


#include "arena.h"
#include "build_cache.h"
#include "cache.h"
#include "error.h"
#include "microfacet.h"
#include "ppt.h"
#include "rng.h"
#include "tt.h"

namespace granular {

namespace {

// A light whose shadows some object may not cast (LightDesc::shadowLink, shadows).
bool mayPassObjects(const LightDesc& l) { return !l.shadowLink.empty() || !l.shadows; }

// The kernel width of an instancer's packing-rate grid, in mean bounding radii.
constexpr double kKernelRadii = 3.0;

uint64_t floatBits(float f) {
  uint32_t u;
  std::memcpy(&u, &f, sizeof u);
  return u;
}

// Where an emitter must not reach for an aggregate to get DA (Scene::findEmittersInside):
// inside its boundary, within its bounds. A moving aggregate (aggregate_motion.h) may pass
// over an emitter or the camera at any time of the shutter: the box it sweeps stands in for
// it, boundary and all. Conservative (no DA if it holds them for part of the shutter only,
// or merely passes near), and the simplest test that misses no time: testing a few times
// of the shutter could step over a fast aggregate's pass.
struct DaRegion {
  const Aggregate* still;  // the aggregate, or null: the box alone
  Bounds3 box;             // its bounds, or its sweep (Scene::aggregateBounds_)

  bool contains(const Vec3& p) const { return box.contains(p) && (!still || still->insideBoundary(p)); }
  // Does the segment from a along unit d, of length len, cross the region's surface?
  bool crosses(const Vec3& a, const Vec3& d, float len) const {
    float t, t1;
    Vec3 ng;
    if (still) return still->intersectBoundary(a, d, 0.0f, len, t, ng);
    return box.intersect(a, Vec3(1.0f / d.x, 1.0f / d.y, 1.0f / d.z), 0.0f, len, t, t1);
  }
  // The distance from a point outside to the region's surface.
  float distance(const Vec3& p) const {
    Vec3 closest;
    if (still) return still->closestBoundaryPoint(p, closest);
    return length(p - vmin(vmax(p, box.lo), box.hi));
  }
};

// Does the segment a→b cross the region's surface, or does a lie inside it?
bool segmentReachesInto(const DaRegion& region, const Vec3& a, const Vec3& b) {
  if (region.contains(a)) return true;
  Vec3 d = b - a;
  float len = length(d);
  return len > 0 && region.crosses(a, d / len, len);
}

// Does a mesh (world space) reach into the region: a vertex inside, or an edge crossing
// its surface?
bool meshReachesInto(const DaRegion& region, const TriangleMesh& m) {
  Bounds3 b = m.bounds(), ab = region.box;
  for (int k = 0; k < 3; ++k)
    if (b.hi[k] < ab.lo[k] || b.lo[k] > ab.hi[k]) return false;
  for (size_t t = 0; t < m.numTriangles(); ++t)
    for (int e = 0; e < 3; ++e)
      if (segmentReachesInto(region, m.points[m.indices[3 * t + e]], m.points[m.indices[3 * t + (e + 1) % 3]]))
        return true;
  return false;
}

// Does an area light reach into the region (sphere: centre inside or the surface closer
// than its radius; rect: a corner inside or an edge or diagonal crossing; disk: likewise
// its rim as a polygon; cylinder: a point of its axis within its radius; mesh: as an
// emissive mesh)?
bool emitterReachesInto(const DaRegion& region, const LightDesc& l) {
  if (l.type == LightType::Sphere) {
    Vec3 c = l.xf.point(Vec3(0.0f));
    float r = l.radius * length(l.xf.vector(Vec3(1, 0, 0)));
    return region.contains(c) || region.distance(c) < r;
  }
  if (l.type == LightType::Rect) {
    float w = 0.5f * l.width, h = 0.5f * l.height;
    Vec3 p[4] = {l.xf.point(Vec3(-w, -h, 0)), l.xf.point(Vec3(w, -h, 0)), l.xf.point(Vec3(w, h, 0)),
                 l.xf.point(Vec3(-w, h, 0))};
    for (int i = 0; i < 4; ++i)
      if (segmentReachesInto(region, p[i], p[(i + 1) % 4])) return true;
    return segmentReachesInto(region, p[0], p[2]) || segmentReachesInto(region, p[1], p[3]);
  }
  if (l.type == LightType::Disk) {  // its rim, as a polygon of 16 sides, and two diameters
    Vec3 p[16];
    for (int i = 0; i < 16; ++i) {
      const float phi = 2.0f * kPi * float(i) / 16.0f;
      p[i] = l.xf.point(Vec3(l.radius * std::cos(phi), l.radius * std::sin(phi), 0));
    }
    for (int i = 0; i < 16; ++i)
      if (segmentReachesInto(region, p[i], p[(i + 1) % 16])) return true;
    return segmentReachesInto(region, p[0], p[8]) || segmentReachesInto(region, p[4], p[12]);
  }
  if (l.type == LightType::Cylinder) {  // its axis, widened by its radius
    const Vec3 a = l.xf.point(Vec3(-0.5f * l.length, 0, 0)), b = l.xf.point(Vec3(0.5f * l.length, 0, 0));
    const float r = l.radius * length(l.xf.vector(Vec3(0, 1, 0)));
    for (int i = 0; i <= 8; ++i) {
      const Vec3 c = a + (b - a) * (float(i) / 8.0f);
      if (region.contains(c) || region.distance(c) < r + 0.0625f * length(b - a)) return true;
    }
    return false;
  }
  if (l.type == LightType::Mesh) return meshReachesInto(region, l.mesh.transformed(l.xf));
  return false;  // distant and dome lights are outside everything
}

// Exact equality of build inputs (a reused aggregate must be the one build() would make).
// The id is left out: it only names the aggregate in the primId AOV (aggregateId_).
bool sameAggregate(const AggregateDesc& a, const AggregateDesc& b) {
  if (a.name != b.name || !sameMesh(a.boundary, b.boundary) || !sameTransform(a.xf, b.xf) || a.weights != b.weights ||
      a.grainRadius != b.grainRadius || a.packingRate != b.packingRate || a.seed != b.seed ||
      a.tileSpheres != b.tileSpheres || a.sizes != b.sizes || a.sizeSpread != b.sizeSpread ||
      a.fineFieldBytes != b.fineFieldBytes || a.prototypes.size() != b.prototypes.size())
    return false;
  for (size_t i = 0; i < a.prototypes.size(); ++i)
    if (a.prototypes[i].name != b.prototypes[i].name || a.prototypes[i].material != b.prototypes[i].material ||
        !sameMesh(a.prototypes[i].mesh, b.prototypes[i].mesh))
      return false;
  return true;
}

bool isEmitter(const SceneDesc& desc, const MeshDesc& m) {
  return m.visible && m.material >= 0 &&
         (!isBlack(desc.materials[m.material].emission) || desc.materials[m.material].emissionTexture.enabled());
}

bool hasEmissiveSurface(const SceneDesc& desc) {
  for (const auto& m : desc.meshes)
    if (isEmitter(desc, m)) return true;
  return false;
}

// Any grain a smooth dielectric (prototypes without a material are the default glass);
// rough ones connect to delta lights like any non-delta surface.
bool hasSmoothDielectricGrains(const SceneDesc& desc) {
  auto smooth = [&](int material) {
    if (material < 0) return true;
    const MaterialDesc& m = desc.materials[size_t(material)];
    return m.type == MaterialType::Dielectric && alphaFromRoughness(m.roughness) == 0;
  };
  for (const auto& a : desc.aggregates)
    for (const auto& p : a.prototypes)
      if (smooth(p.material)) return true;
  for (const auto& g : desc.instancedGrains)
    for (const auto& p : g.prototypes)
      if (smooth(p.material)) return true;
  return false;
}

// The share of a ray cone's footprint a texture filters over, narrowed as pbrt-v4 narrows
// its ray differentials, by max(1/8, 1/√spp): the pixel's samples already average over its
// area, and a filter a whole footprint wide on top of them would blur twice; the filter
// only has to keep each sample from aliasing.
float textureFilterScale(int spp) { return std::max(0.125f, 1.0f / std::sqrt(float(std::max(1, spp)))); }

// What unassigned surfaces and grains get.
MaterialDesc defaultSurfaceDesc() {
  MaterialDesc grey;
  grey.name = "default_surface";
  return grey;
}

MaterialDesc defaultGrainDesc() {
  MaterialDesc glass;
  glass.name = "default_grain";
  glass.type = MaterialType::Dielectric;
  return glass;
}

}  // namespace

// Embree's filter for cut-out meshes: rejects a candidate hit where the surface is absent.
// The draw hashes the ray (origin, direction) and the triangle: reproducible, and
// independent between rays and between the surfaces one ray crosses.
void Scene::cutoutFilter(const RTCFilterFunctionNArguments* args) {
  const auto* data = static_cast<const CutoutFilterData*>(args->geometryUserPtr);
  for (unsigned i = 0; i < args->N; ++i) {
    if (args->valid[i] != -1) continue;
    const unsigned prim = RTCHitN_primID(args->hit, args->N, i);
    const float p = data->scene->presence(data->geom, prim, RTCHitN_u(args->hit, args->N, i),
                                          RTCHitN_v(args->hit, args->N, i));
    if (p >= 1) continue;
    uint64_t h = hashInts(uint64_t(data->geom), uint64_t(prim));
    for (float x : {RTCRayN_org_x(args->ray, args->N, i), RTCRayN_org_y(args->ray, args->N, i),
                    RTCRayN_org_z(args->ray, args->N, i), RTCRayN_dir_x(args->ray, args->N, i),
                    RTCRayN_dir_y(args->ray, args->N, i), RTCRayN_dir_z(args->ray, args->N, i)}) {
      uint32_t bits;
      std::memcpy(&bits, &x, sizeof bits);
      h = hashCombine(h, bits);
    }
    if (p <= 0 || toUnitFloat(h) >= p) args->valid[i] = 0;
  }
}

void Scene::surfaceUv(int geom, unsigned prim, float bu, float bv, float& u, float& v) const {
  const std::vector<float>& uv = worldMeshes_[size_t(geom)].uvs;
  if (uv.empty()) {  // no texture coordinates: the primvar reader's fallback (0, 0)
    u = v = 0;
    return;
  }
  const size_t c = 6 * size_t(prim);
  const float b0 = 1.0f - bu - bv;
  u = b0 * uv[c] + bu * uv[c + 2] + bv * uv[c + 4];
  v = b0 * uv[c + 1] + bu * uv[c + 3] + bv * uv[c + 5];
}

float Scene::presence(int geom, unsigned prim, float bu, float bv) const {
  const SurfaceMaps& maps = surfaceMaps_[size_t(meshMaterial_[size_t(geom)])];
  if (!maps.cutout) return 1.0f;
  float p = maps.opacityConstant;
  if (maps.opacity >= 0) {
    float u, v;
    surfaceUv(geom, prim, bu, bv, u, v);
    p = textures_->lookupChannel(maps.opacity, u, v, 0.0f);
  }
  if (maps.opacityThreshold > 0) return p >= maps.opacityThreshold ? 1.0f : 0.0f;
  return std::clamp(p, 0.0f, 1.0f);
}

const Material& Scene::shadingMaterial(const Hit& hit, float footprint, std::optional<Material>& storage) const {
  const Material& m = materials_[size_t(hit.material)];
  if (hit.kind != Hit::Surface || hit.geom < 0) return m;
  const SurfaceMaps& maps = surfaceMaps_[size_t(hit.material)];
  if (maps.albedo < 0 && maps.emission < 0) return m;
  float u, v;
  surfaceUv(hit.geom, hit.prim, hit.bu, hit.bv, u, v);
  // The filter width in uv: the (narrowed) footprint times the triangle's uv length per
  // world length.
  float width = 0;
  footprint *= textureFilterScale_;
  const TriangleMesh& mesh = worldMeshes_[size_t(hit.geom)];
  if (footprint > 0 && mesh.hasUvs()) {
    const size_t t = 3 * size_t(hit.prim);
    const Vec3 &a = mesh.points[mesh.indices[t]], &b = mesh.points[mesh.indices[t + 1]], &c = mesh.points[mesh.indices[t + 2]];
    const float* uv = &mesh.uvs[2 * t];
    const float uvArea = std::fabs((uv[2] - uv[0]) * (uv[5] - uv[1]) - (uv[4] - uv[0]) * (uv[3] - uv[1]));
    const float worldArea = length(cross(b - a, c - a));
    if (worldArea > 0) width = footprint * std::sqrt(uvArea / worldArea);
  }
  Material& t = storage.emplace(m);
  if (maps.albedo >= 0) t.albedo = vmin(vmax(textures_->lookupRgb(maps.albedo, u, v, width), Vec3(0.0f)), Vec3(1.0f));
  if (maps.emission >= 0) t.emission = vmax(textures_->lookupRgb(maps.emission, u, v, width), Vec3(0.0f));
  return t;
}

const std::vector<std::string>& Scene::textureWarnings() const {
  static const std::vector<std::string> none;
  return textures_ ? textures_->warnings() : none;
}

const Scene::BuiltAggregate* Scene::findBuilt(const AggregateDesc& desc, const std::vector<int>& materials,
                                              const std::vector<MaterialDesc>& materialDescs, bool fullOnly) const {
  for (const auto& b : built_) {
    if (b.materials != materials || !sameAggregate(b.desc, desc)) continue;
    if (fullOnly && b.aggregate->standIn()) continue;
    bool same = true;
    for (size_t i = 0; i < materialDescs.size() && same; ++i) same = sameMaterial(b.materialDescs[i], materialDescs[i]);
    if (same) return &b;
  }
  return nullptr;
}

namespace {
// Views are named over every scene, so that work made for one scene's view is never taken
// for another's.
std::atomic<uint64_t> gViewIds{0};
}  // namespace

std::unique_ptr<Scene> Scene::build(const SceneDesc& worldDesc, const Scene* previous, SceneDetail detail,
                                    const BuildLog& log) {
  auto t0 = std::chrono::steady_clock::now();
  validateSceneDesc(worldDesc);
  // Everything below is in render space (scene_desc.h: renderOrigin).
  const Vec3d origin = granular::renderOrigin(worldDesc);
  std::optional<SceneDesc> moved;
  const SceneDesc& desc = origin == Vec3d{} ? worldDesc : moved.emplace(toRenderSpace(worldDesc, origin));
  for (const auto& a : desc.aggregates) checkGrainPrecision(a, origin);
  auto s = std::unique_ptr<Scene>(new Scene());
  s->renderOrigin_ = origin;
  s->settings_ = desc.settings;
  s->textureFilterScale_ = textureFilterScale(desc.settings.spp);
  s->camera_ = Camera(desc.camera, desc.settings.width, desc.settings.height);
  const DefaultMaterials defaults = s->buildMaterials(desc);
  s->buildSurfaceMaps(desc);
  Bounds3 all = s->buildMeshes(desc, defaults.surface);
  s->buildAggregates(desc, defaults.grain, previous, all,
                     detail == SceneDetail::StandIns && desc.settings.technique != Technique::Ept, log);
  s->buildInstancedGrains(desc, defaults.grain, previous, all);
  s->sceneScale_ = all.empty() ? 1.0f : std::max(1e-6f, maxComponent(vmax(vabs(all.lo), vabs(all.hi))));
  const std::vector<LightDesc> lights = s->buildLights(desc, all);
  s->buildIdentities(desc, lights);
  s->buildLightLinks(desc, lights);
  s->findEmittersInside(desc, lights);
  s->updateDiffusionDepths();
  s->viewId_ = ++gViewIds;
  s->updateSwitching();
  s->buildSeconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return s;
}

Scene::DefaultMaterials Scene::buildMaterials(const SceneDesc& desc) {
  for (const auto& m : desc.materials) materials_.push_back(Material::fromDesc(m));
  DefaultMaterials defaults;
  defaults.surface = int(materials_.size());
  materials_.push_back(Material::fromDesc(defaultSurfaceDesc()));
  defaults.grain = int(materials_.size());
  materials_.push_back(Material::fromDesc(defaultGrainDesc()));
  MaterialDesc white;
  white.name = "diffusion_exit";
  white.type = MaterialType::DiffusionExit;
  diffusionExitMaterial_ = int(materials_.size());
  materials_.push_back(Material::fromDesc(white));
  return defaults;
}

// Textures and cut-outs of ordinary surfaces: only a scene that has them opens a
// TextureSystem.
void Scene::buildSurfaceMaps(const SceneDesc& desc) {
  surfaceMaps_.resize(materials_.size());
  for (size_t i = 0; i < desc.materials.size(); ++i) {
    const MaterialDesc& m = desc.materials[i];
    SurfaceMaps& maps = surfaceMaps_[i];
    if (m.type != MaterialType::Lambert) continue;
    if (m.hasTextures() && !textures_) textures_.reset(new Textures());
    if (m.albedoTexture.enabled()) maps.albedo = textures_->add(m.albedoTexture);
    if (m.emissionTexture.enabled()) maps.emission = textures_->add(m.emissionTexture);
    if (m.opacityTexture.enabled()) maps.opacity = textures_->add(m.opacityTexture);
    maps.opacityConstant = m.opacity;
    maps.opacityThreshold = m.opacityThreshold;
    maps.cutout = m.hasCutouts();
  }
}

Bounds3 Scene::buildMeshes(const SceneDesc& desc, int defaultSurface) {
  device_ = makeEmbreeDevice();
  surfaces_ = makeEmbreeScene(device_);
  // Shadow linking passes meshes on shadow rays by a filter of the ray's context.
  if (std::any_of(desc.lights.begin(), desc.lights.end(), mayPassObjects))
    rtcSetSceneFlags(surfaces_.get(), rtcGetSceneFlags(surfaces_.get()) | RTC_SCENE_FLAG_CONTEXT_FILTER_FUNCTION);
  cutoutData_.reserve(desc.meshes.size());
  Bounds3 all;
  const CameraDesc& cam = desc.camera;
  shutterOpen_ = cam.shutterOpen;
  shutterClose_ = cam.shutterClose;
  const bool blur = cam.shutterClose > cam.shutterOpen;
  for (const auto& m : desc.meshes) {
    if (!m.visible) continue;
    // A moving mesh: at the shutter's open in slot 0 (what textures and normals start
    // from), at its close in slot 1.
    const bool moves = blur && m.shutterXf;
    TriangleMesh w = m.mesh.transformed(moves ? m.shutterXf->first : m.xf);
    TriangleMesh atClose;
    if (moves) {
      atClose = m.mesh.transformed(m.shutterXf->second);
      all.extend(atClose.bounds());
      movingMeshes_ = true;
    }
    all.extend(w.bounds());
    const int material = m.material >= 0 ? m.material : defaultSurface;
    const TriangleMesh* closeMesh = moves ? &atClose : nullptr;
    if (surfaceMaps_[material].cutout) {
      cutoutData_.push_back({this, int(worldMeshes_.size())});
      attachTriangleMesh(device_.get(), surfaces_.get(), w, cutoutFilter, &cutoutData_.back(), closeMesh);
    } else {
      attachTriangleMesh(device_.get(), surfaces_.get(), w, nullptr, nullptr, closeMesh);
    }
    worldMeshes_.push_back(std::move(w));
    worldMeshesAtClose_.push_back(std::move(atClose));
    meshMaterial_.push_back(material);
    meshId_.push_back(m.id);
  }
  rtcCommitScene(surfaces_.get());
  if (!worldMeshes_.empty()) {
    // Padded a little: the slab test must not cull a hit that Embree finds on the bounds.
    const Vec3 pad = all.extent() * 1e-4f + Vec3(1e-6f * std::max(maxComponent(vabs(all.lo)), maxComponent(vabs(all.hi))));
    surfaceBounds_.lo = all.lo - pad;
    surfaceBounds_.hi = all.hi + pad;
  }
  return all;
}

// Each aggregate lent by the previous scene or built anew, with its medium when the
// technique uses media; the media are kept only if some aggregate needs them.
void Scene::buildAggregates(const SceneDesc& desc, int defaultGrain, const Scene* previous, Bounds3& all,
                            bool standIns, const BuildLog& log) {
  std::vector<BuiltAggregate> entries;
  for (const auto& a : desc.aggregates) entries.push_back(lend(desc, a, defaultGrain, previous, standIns));
  buildConcurrently(desc, entries, standIns, log);
  for (size_t i = 0; i < entries.size(); ++i) {
    const AggregateDesc& a = desc.aggregates[i];
    BuiltAggregate& entry = entries[i];
    const Aggregate& agg = *entry.aggregate;
    standIns_ = standIns_ || agg.standIn();
    aggregateId_.push_back(a.id);
    // Built at its xf; a moving one is posed at each ray's time (aggregate_motion.h).
    const CameraDesc& cam = desc.camera;
    aggregateMotion_.push_back(a.shutterXf && cam.shutterClose > cam.shutterOpen
                                   ? AggregateMotion(a.xf, a.shutterXf->first, a.shutterXf->second, cam.shutterOpen,
                                                     cam.shutterClose)
                                   : AggregateMotion());
    aggregateBounds_.push_back(aggregateMotion_.back().sweep(agg.bounds()));
    all.extend(aggregateBounds_.back());
    maxGrainRadius_ = std::max(maxGrainRadius_, agg.maxGrainRadius());
    if (desc.settings.technique != Technique::Ept) addMedium(a, entry);
    aggregates_.push_back(entry.aggregate);
    built_.push_back(std::move(entry));
  }
  // A stand-in has nothing but its medium: every aggregate keeps one.
  if (standIns_) mediaNeeded_ = true;
  if (!mediaNeeded_) {
    mediumParams_.clear();
    media_.clear();
    diffusionProfiles_.clear();
    daDepthUnit_.clear();
  }
}

Scene::BuiltAggregate Scene::lend(const SceneDesc& desc, const AggregateDesc& a, int defaultGrain,
                                  const Scene* previous, bool standIn) {
  BuiltAggregate entry;
  entry.desc = a;
  for (const auto& p : a.prototypes) {
    entry.materials.push_back(p.material >= 0 ? p.material : defaultGrain);
    entry.materialDescs.push_back(p.material >= 0 ? desc.materials[p.material] : defaultGrainDesc());
  }
  const BuiltAggregate* old = previous ? previous->findBuilt(a, entry.materials, entry.materialDescs, !standIn) : nullptr;
  if (!old && previous && !standIn) {
    // A stand-in of the same inputs lends its medium (the same TT parameters) to the full
    // build when the tile's Sauter size is the one it assumed (below, addMedium).
    if (const BuiltAggregate* s = previous->findBuilt(a, entry.materials, entry.materialDescs); s && s->hasMedium) {
      entry.hasMedium = true;
      entry.medium = s->medium;
      entry.mediumSauterSize = s->mediumSauterSize;
    }
  }
  if (old) {
    entry.aggregate = old->aggregate;
    entry.hasMedium = old->hasMedium;
    entry.medium = old->medium;
    entry.mediumSauterSize = old->mediumSauterSize;
    entry.proxies = old->proxies;
    // Measured with the medium it had: kept where that medium's model is this scene's.
    if (!old->mediumReplaced && previous->settings_.mediumModel == desc.settings.mediumModel)
      entry.switching = old->switching;
    ++aggregatesReused_;
  }
  return entry;
}

namespace {

// GRANULAR_BUILD_MEMORY_MB (default 2048): the estimated memory of the aggregate builds
// that may run at once.
double buildMemoryCapBytes() {
  const char* v = std::getenv("GRANULAR_BUILD_MEMORY_MB");
  char* end = nullptr;
  const double mb = v && *v ? std::strtod(v, &end) : 2048.0;
  return (v && *v && (*end || !(mb > 0) || !std::isfinite(mb)) ? 2048.0 : mb) * 1024.0 * 1024.0;
}

}  // namespace

void Scene::buildConcurrently(const SceneDesc& desc, std::vector<BuiltAggregate>& entries, bool standIns,
                              const BuildLog& log) {
  std::vector<size_t> todo;
  for (size_t i = 0; i < entries.size(); ++i)
    if (!entries[i].aggregate) todo.push_back(i);
  if (todo.empty()) return;
  // The largest first: the others fill the threads around it.
  std::vector<double> estimate(entries.size(), 0.0);
  if (!standIns)
    for (size_t i : todo) estimate[i] = Aggregate::estimateBuildBytes(desc.aggregates[i]);
  std::stable_sort(todo.begin(), todo.end(), [&](size_t a, size_t b) { return estimate[a] > estimate[b]; });
  // Builds run side by side (much of one is serial: the tile's packing, parts of the
  // distance field), on up to as many threads as cores, while the estimated memory of the
  // builds under way stays within the cap; one that alone exceeds it runs alone. Each
  // aggregate is built as it would be alone, so the scene does not depend on the order.
  const double cap = buildMemoryCapBytes();
  const size_t threads = std::min<size_t>(todo.size(), std::max(1u, std::thread::hardware_concurrency()));
  std::mutex mutex;
  std::condition_variable freed;
  double inUse = 0;
  size_t next = 0;
  std::vector<std::exception_ptr> errors(entries.size());
  const BuildLog say = log ? BuildLog([&](const std::string& line) {
    std::lock_guard<std::mutex> lock(mutex);
    log(line);
  }) : BuildLog();
  auto worker = [&] {
    for (;;) {
      size_t i;
      double bytes;
      {
        // The next aggregate in line, once the memory under way leaves room for it.
        std::unique_lock<std::mutex> lock(mutex);
        freed.wait(lock, [&] { return next == todo.size() || inUse == 0 || inUse + estimate[todo[next]] <= cap; });
        if (next == todo.size()) return;
        i = todo[next++];
        bytes = estimate[i];
        inUse += bytes;
      }
      try {
        auto agg = std::make_shared<Aggregate>();
        agg->build(desc.aggregates[i], device_, entries[i].materials, standIns, say);
        entries[i].aggregate = std::move(agg);
      } catch (...) {
        errors[i] = std::current_exception();
      }
      {
        std::lock_guard<std::mutex> lock(mutex);
        inUse -= bytes;
      }
      freed.notify_all();
    }
  };
  std::vector<std::thread> pool;
  for (size_t t = 1; t < threads; ++t) pool.emplace_back(worker);
  worker();
  for (auto& t : pool) t.join();
  for (const auto& e : errors)  // the first aggregate's error, as a sequential build would throw
    if (e) std::rethrow_exception(e);
  (standIns ? standInsBuilt_ : aggregatesBuilt_) += int(todo.size());
}

void Scene::buildInstancedGrains(const SceneDesc& desc, int defaultGrain, const Scene* previous, Bounds3& all) {
  const float span = motionSpan(desc.camera);
  for (const InstancedGrainsDesc& d : desc.instancedGrains) {
    BuiltInstanced entry;
    for (const GrainPrototypeDesc& p : d.prototypes) {
      entry.materials.push_back(p.material >= 0 ? p.material : defaultGrain);
      entry.materialDescs.push_back(p.material >= 0 ? desc.materials[size_t(p.material)] : defaultGrainDesc());
    }
    entry.id = d.id;
    // An unchanged instancer (the same arrays, transform, prototypes and materials) is lent.
    if (previous)
      for (const BuiltInstanced& b : previous->builtInstanced_) {
        const InstancedGrainsDesc& old = b.grains->desc();
        if (old.size() != d.size() || !sameInstancedGrains(old, d) || b.materialDescs.size() != entry.materialDescs.size() ||
            b.grains->motionSpan() != (d.velocities.empty() && d.angularVelocities.empty() ? 0.0f : span))
          continue;
        bool same = true;
        for (size_t k = 0; k < b.materialDescs.size() && same; ++k)
          same = sameMaterial(b.materialDescs[k], entry.materialDescs[k]);
        if (!same) continue;
        entry.grains = b.grains;
        entry.lengthScale = b.lengthScale;
        entry.worldScale = b.worldScale;
        entry.bounds = b.bounds;
        entry.medium = b.medium;  // null when built for EPT: made below if needed
        entry.proxies = b.proxies;  // they depend on the prototypes, materials and scales alone
        entry.diffusion = b.diffusion;  // made from the medium alone
        break;
      }
    if (!entry.grains) {
      auto grains = std::make_shared<InstancedGrains>();
      grains->build(d, device_, true, span);
      entry.worldScale = float(std::cbrt(std::fabs(d.xf.determinant3())));
      for (const GrainPrototype& p : grains->prototypes()) entry.lengthScale.push_back(p.fitRadius * entry.worldScale);
      const Bounds3 box = grains->objectBounds();
      for (int c = 0; c < 8; ++c)
        entry.bounds.extend(d.xf.point(Vec3(c & 1 ? box.hi.x : box.lo.x, c & 2 ? box.hi.y : box.lo.y,
                                            c & 4 ? box.hi.z : box.lo.z)));
      entry.grains = std::move(grains);
      ++instancedBuilt_;
    }
    if (!entry.bounds.empty()) {
      // Padded like the surfaces' bounds: a ray grazing a face still reaches the grid.
      const Vec3 pad = vmax(vabs(entry.bounds.lo), vabs(entry.bounds.hi)) * 1e-5f + Vec3(1e-6f);
      entry.bounds.lo = entry.bounds.lo - pad;
      entry.bounds.hi = entry.bounds.hi + pad;
      all.extend(entry.bounds);
      instancedBounds_.extend(entry.bounds);
    }
    if (desc.settings.technique == Technique::Ept) {
      entry.medium.reset();
    } else if (!entry.medium && entry.grains->stats().grains > 0) {
      const auto m0 = std::chrono::steady_clock::now();
      entry.medium = buildInstancedMedium(*entry.grains, entry.materials, entry.worldScale);
      entry.mediumSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - m0).count();
    }
    if (!entry.medium) entry.diffusion.reset();
    if (entry.medium) {
      ++instancedMedia_;
      // The hybrid's switch measures the spread of a bundle against the largest grain.
      maxGrainRadius_ = std::max(maxGrainRadius_, entry.medium->maxRadius);
    }
    instanced_.push_back(entry.grains);
    builtInstanced_.push_back(std::move(entry));
  }
}

std::shared_ptr<const Scene::InstancedMedium> Scene::buildInstancedMedium(const InstancedGrains& grains,
                                                                          const std::vector<int>& materials,
                                                                          float worldScale) const {
  const InstancedGrainsDesc& d = grains.desc();
  auto m = std::make_shared<InstancedMedium>();
  // The grains' sizes (world bounding radii): per prototype their count and sum, and the
  // second and third moments of all, for the mean, the Sauter mean and the largest.
  const size_t np = grains.prototypes().size();
  std::vector<double> count(np, 0.0), sum(np, 0.0);
  double r1 = 0, r2 = 0, r3 = 0;
  const std::vector<GrainPrototype>& protos = grains.prototypes();
  for (size_t i = 0; i < d.size(); ++i) {
    // grain(i)'s radius, without placing the grain.
    const size_t p = size_t(d.protoIndices[i]);
    const double r = double(protos[p].fitRadius * (d.scales.empty() ? 1.0f : d.scales[i])) * worldScale;
    count[p] += 1;
    sum[p] += r;
    r1 += r;
    r2 += r * r;
    r3 += r * r * r;
    m->maxRadius = std::max(m->maxRadius, float(r));
  }
  const float meanR = float(r1 / double(std::max<size_t>(1, d.size())));
  m->meanRadius = meanR;
  // The kernel of 3 mean radii, sampled on voxels as wide as the kernel: its largest voxel
  // (grain_density.h), 8 times fewer than at half of it, for 64 voxels a grain instead of
  // 512 (bench/README.md: at 10^6 grains 0.34 s and 13 MiB instead of 1.1 s and 92 MiB).
  GrainDensityOptions options;
  options.kernelWidth = float(kKernelRadii) * meanR;
  options.voxelSize = options.kernelWidth;
  options.fractions = false;  // the medium reads the packing rate alone
  m->density = buildGrainDensity(d, options);
  const VoxelLeaves& f = m->density.packing;
  // The bulk's packing rate: f averaged over the grains' volume (Σ f² / Σ f over voxels),
  // where the linear σ_t(f) is exact (heterogeneous_medium.h).
  double s1 = 0, s2 = 0, fmax = 0;
  for (float v : f.values)
    if (v > 0) s1 += v, s2 += double(v) * v, fmax = std::max(fmax, double(v));
  if (!(s1 > 0)) return nullptr;
  const double fGrains = s2 / s1;
  // TT's packing rate is the bounding spheres' (Meng et al. 2015: a sphere packing, a grain
  // in each sphere); the density counts the grains' own volume, a fraction φ of their spheres.
  const double sphereVolume = 4.0 / 3.0 * kPiD * r3;
  const double phi = sphereVolume > 0 ? std::clamp(m->density.stats.totalVolume / sphereVolume, 0.05, 1.0) : 1.0;
  const float fRef = float(std::clamp(fGrains / phi, 0.01, 0.64));
  AggregateDesc a;
  a.name = d.name;
  a.grainRadius = meanR;
  a.packingRate = fRef;
  std::vector<const TriangleMesh*> meshes;
  std::vector<Material> mats;
  for (size_t k = 0; k < np; ++k) {
    const GrainPrototype& p = grains.prototypes()[k];
    a.prototypes.push_back(d.prototypes[k]);
    a.weights.push_back(float(count[k]));
    // Sizes in units of R̄ (TT's unit, as absorption per R̄ below), within deriveMedium's range.
    a.sizes.push_back(count[k] > 0 ? float(std::clamp(sum[k] / count[k] / meanR, 0.1, 10.0)) : 1.0f);
    meshes.push_back(&p.mesh);
    Material mat = materials_[size_t(materials[k])];
    mat.absorption = mat.absorption * (meanR / (p.fitRadius * worldScale));
    mats.push_back(mat);
  }
  m->params = aggregateMedium(meshes, mats, a, r3 / std::max(1e-30, r2) / meanR);  // Sauter mean, in R̄
  // Thinner than its mean free path at its densest across its narrowest extent: EPT alone.
  const Vec3 extent = grains.objectBounds().extent() * worldScale;
  const float sigmaMax = maxComponent(m->params.sigmaT) * float(fmax) / fRef;
  if (!(sigmaMax * 0.5f * minComponent(extent) > 1.0f)) return nullptr;
  // σ_t(x) follows the grains' volume fraction, equal to f_ref φ in the bulk.
  MediumParams scaled = m->params;
  scaled.packingRate = float(fGrains);
  // The packing rate moves into the medium (m->density keeps its stats).
  m->medium = HeterogeneousMedium(std::move(m->density.packing), scaled.packingRate, HomogeneousMedium(scaled), d.name);
  m->diffuseReflectance = DiffusionProfile(m->params).diffuseReflectance;
  return m;
}

bool Scene::firstInstancedMedium(const Ray& ray, float tmax, int& index, float& t0, float& t1) const {
  const Vec3 invD(1.0f / ray.d.x, 1.0f / ray.d.y, 1.0f / ray.d.z);
  float best = kInf;
  for (size_t i = 0; i < builtInstanced_.size(); ++i) {
    const BuiltInstanced& b = builtInstanced_[i];
    if (!b.medium) continue;
    float a0, a1;
    // An empty interval (a ray leaving through a face) holds no medium.
    if (!b.medium->medium.bounds().intersect(ray.o, invD, ray.tmin, tmax, a0, a1) || !(a1 > a0) || !(a0 < best))
      continue;
    best = a0;
    index = int(i);
    t0 = a0;
    t1 = a1;
  }
  return std::isfinite(best);
}

void Scene::addMedium(const AggregateDesc& a, BuiltAggregate& entry) {
  const Aggregate& agg = *entry.aggregate;
  if (entry.hasMedium && !agg.standIn() && entry.mediumSauterSize != agg.tile().sauterSize())
    entry.hasMedium = false;  // a stand-in's, for sizes this tile does not hold exactly
  if (!entry.hasMedium) {
    // TT parameters per grain kind (cached on disk), combined per aggregate (Meng et al. 2015;
    // tt.h: aggregateMedium), the flights between spheres by the tile's own sizes.
    std::vector<const TriangleMesh*> meshes;
    std::vector<Material> mats;
    for (size_t i = 0; i < agg.prototypes().size(); ++i) {
      meshes.push_back(&agg.prototypes()[i].mesh);
      mats.push_back(materials_[entry.materials[i]]);
    }
    // A stand-in has no tile: the Sauter size its tile would have (grain.h), which a full
    // build's tile matches exactly when all grains have one size.
    entry.mediumSauterSize = agg.standIn() ? sauterSizeOf(a) : agg.tile().sauterSize();
    entry.medium = aggregateMedium(meshes, mats, a, entry.mediumSauterSize);
    entry.hasMedium = true;
    ++mediaDerived_;
  }
  mediumParams_.push_back(entry.medium);
  media_.emplace_back(mediumParams_.back(), settings_.mediumModel);
  diffusionProfiles_.emplace_back();
  daDepthUnit_.push_back(kInf);
  setDiffusion(media_.size() - 1);
  // VPT pays off only where paths scatter many times: an object thinner than its
  // mean free path is left to EPT alone (no bundles, no pre-render).
  if (2.0f * agg.stats().maxInteriorDepth > maxComponent(mediumParams_.back().lambdaT)) mediaNeeded_ = true;
}

std::vector<LightDesc> Scene::buildLights(const SceneDesc& desc, const Bounds3& all) {
  std::vector<LightDesc> lights = desc.lights;
  if (lights.empty() && desc.settings.defaultLight && !hasEmissiveSurface(desc)) {
    LightDesc dome;  // a uniform white dome of radiance 1 (RenderSettings::defaultLight)
    dome.name = "default_dome";
    dome.type = LightType::Dome;
    lights.push_back(dome);
    defaultLightAdded_ = true;
  }
  const bool smooth = hasSmoothDielectricGrains(desc);
  const bool widen = desc.settings.physicalSun && smooth;
  for (auto& l : lights)
    if (widen && isDeltaSun(l)) {  // widenedSuns()
      l.angle = kSunAngle;
      l.normalize = true;  // a delta light's intensity is its irradiance: keep it
      widenedSuns_.push_back(l.name);
    }
  for (const auto& l : lights) {
    if (smooth && l.type == LightType::Distant && l.angle < Scene::kNarrowSunAngle) narrowSun_ = true;
    if (l.type != LightType::Dome) proxyLightSampling_ = true;
    int idx = int(lights_.size());
    lights_.push_back(Light::fromDesc(l));
    (lights_.back().isInfinite() ? infiniteLights_ : areaLights_).push_back(idx);
  }
  buildAreaLightBvh();
  const Vec3 ref = all.empty() ? Vec3(0.0f) : all.center();
  // Weights relative to the largest (in double: a bright delta sun's would overflow a float).
  std::vector<double> x;
  double largest = 0;
  for (const Light& l : lights_) {
    const double v = l.pickWeight(ref);
    x.push_back(std::isfinite(v) && v > 0 ? v : 0.0);
    largest = std::max(largest, x.back());
  }
  std::vector<float> w;
  for (double v : x) w.push_back(largest > 0 ? float(v / largest) : 1.0f);  // none weighs: all alike
  lightPick_ = Distribution1D(w);
  pickWeights_ = w;
  for (size_t i = 0; i < lights_.size() && lights_.size() > 1; ++i) {
    char chance[32];
    std::snprintf(chance, sizeof chance, " %.1f%%", 100.0 * lightPick(int(i)));
    lightPicksText_ += (i ? ", " : "") + lights[i].name + chance;
  }
  for (size_t i = 0; i < lights.size(); ++i) {
    const IesProfile* p = lights_[i].iesProfile();
    if (!p) continue;
    const LightDesc& d = lights[i];
    char text[160];
    std::snprintf(text, sizeof text, " (%d × %d angles, peak %.4g cd, mean %.4g cd%s)", p->verticalCount(),
                  p->horizontalCount(), double(p->maxIntensity()), p->meanIntensity(),
                  d.shaping.iesNormalize ? ", normalised: divided by the mean" : "");
    iesProfilesText_ += (iesProfilesText_.empty() ? "" : "; ") + d.name + ": " +
                        std::filesystem::path(d.shaping.iesFile).filename().string() + text;
  }
  return lights;
}

// DA stands for light that entered an aggregate through its boundary from outside and
// leaves through it towards the outside (diffusion.h). An aggregate that holds an
// emitter or the camera gets no DA (VPT all the way down): DA cannot see an emitter
// inside (a sphere light inside a ball rendered 15x too dark) and a camera inside would
// see nothing but DA's planar-boundary model of the deep interior (60% too dark), both
// measured by bench/stress.py against EPT.
void Scene::findEmittersInside(const SceneDesc& desc, const std::vector<LightDesc>& lights) {
  // An instancer's medium likewise: a sphere, disk or cylinder light's centre, a rect
  // light's corner or an emissive or mesh light's vertex where its packing rate is > 0 (within the
  // grains' reach).
  instancedEmitterInside_.assign(builtInstanced_.size(), 0);
  for (size_t i = 0; i < builtInstanced_.size(); ++i) {
    if (!builtInstanced_[i].medium) continue;
    const HeterogeneousMedium& med = builtInstanced_[i].medium->medium;
    auto inside = [&](const Vec3& p) { return med.density(p) > 0; };
    bool found = false;
    for (const auto& l : lights) {
      if (l.type == LightType::Sphere) found = found || inside(l.xf.point(Vec3(0.0f)));
      if (l.type == LightType::Rect)
        for (float sx : {-0.5f, 0.5f})
          for (float sy : {-0.5f, 0.5f}) found = found || inside(l.xf.point(Vec3(sx * l.width, sy * l.height, 0)));
      if (l.type == LightType::Disk || l.type == LightType::Cylinder) found = found || inside(l.xf.point(Vec3(0.0f)));
      if (l.type == LightType::Mesh)
        for (const Vec3& v : l.mesh.points) found = found || inside(l.xf.point(v));
    }
    for (const auto& m : desc.meshes)
      if (isEmitter(desc, m))
        for (const Vec3& v : m.mesh.points) found = found || inside(m.xf.point(v));
    instancedEmitterInside_[i] = found;
  }
  if (media_.empty()) return;
  emitterInside_.assign(aggregates_.size(), false);
  for (size_t a = 0; a < aggregates_.size(); ++a) {
    const DaRegion region{aggregateMotion_[a].moving() ? nullptr : aggregates_[a].get(), aggregateBounds_[a]};
    bool inside = false;
    for (const auto& l : lights) inside = inside || emitterReachesInto(region, l);
    for (const auto& m : desc.meshes)
      if (isEmitter(desc, m)) inside = inside || meshReachesInto(region, m.mesh.transformed(m.xf));
    emitterInside_[a] = inside;
  }
}

std::string Scene::widenedSunsWarning() const {
  if (widenedSuns_.empty()) return "";
  std::string names;
  for (const auto& n : widenedSuns_) names += (names.empty() ? "" : ", ") + n;
  return str("the delta sun", widenedSuns_.size() > 1 ? "s " : " ", names, widenedSuns_.size() > 1 ? " are" : " is",
             " rendered as the physical sun, a disk of ", kSunAngle,
             " degrees with the same irradiance: light refracted through the smooth grains could never reach a "
             "delta light (set its angle to choose another size)");
}

bool Scene::intersectSurfaces(const Ray& ray, const Vec3& invD, Hit& hit, float& tmax, bool mediaMode,
                              bool proxyMode) const {
  bool found = intersectMeshes(ray, invD, hit, tmax);
  if (!instanced_.empty()) found |= intersectInstancedGrains(ray, invD, hit, tmax, mediaMode, proxyMode);
  return found;
}

bool Scene::intersectInstancedGrains(const Ray& ray, const Vec3& invD, Hit& hit, float& tmax, bool mediaMode,
                                     bool proxyMode) const {
  float t0, t1;
  if (!instancedBounds_.intersect(ray.o, invD, ray.tmin, tmax, t0, t1)) return false;
  bool found = false;
  for (size_t i = 0; i < instanced_.size(); ++i) {
    const BuiltInstanced& b = builtInstanced_[i];
    if (mediaMode && b.medium) continue;  // the media see its medium instead
    if (proxyMode && instancedProxies_[i]) continue;  // its proxies instead
    if (!b.bounds.intersect(ray.o, invD, ray.tmin, tmax, t0, t1)) continue;
    InstancedGrainHit g;
    if (!b.grains->intersect(ray.o, ray.d, ray.tmin, tmax, g, ray.time) || !(g.t < tmax)) continue;
    found = true;
    tmax = g.t;
    instancedHit(Hit::Grain, int(i), g.grain, g.prototype, g.t, g.radius * b.worldScale, hit);
    hit.ng = hit.grain.ng = g.ng;
    hit.grain.prim = g.prim;
  }
  return found;
}

bool Scene::intersectMeshes(const Ray& ray, const Vec3& invD, Hit& hit, float& tmax) const {
  float t0, t1;
  if (surfaceBounds_.empty() || !surfaceBounds_.intersect(ray.o, invD, ray.tmin, tmax, t0, t1)) return false;
  if (!traceable(ray.o, ray.d, ray.tmin, tmax)) return false;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh = makeRayHit(ray.o, ray.d, ray.tmin, tmax);
  rh.ray.time = shutterFraction(ray.time);
  rtcIntersect1(surfaces_.get(), &ctx, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  tmax = rh.ray.tfar;
  hit.kind = Hit::Surface;
  hit.t = tmax;
  const TriangleMesh& atClose = worldMeshesAtClose_[rh.hit.geomID];
  if (atClose.points.empty()) {
    hit.ng = triangleNormal(worldMeshes_[rh.hit.geomID], rh.hit.primID);
  } else {  // the moving triangle where the ray met it
    const TriangleMesh& atOpen = worldMeshes_[rh.hit.geomID];
    const float u = rh.ray.time;
    Vec3 v[3];
    for (int k = 0; k < 3; ++k) {
      const uint32_t i = atOpen.indices[3 * size_t(rh.hit.primID) + k];
      v[k] = atOpen.points[i] * (1.0f - u) + atClose.points[i] * u;
    }
    hit.ng = normalize(cross(v[1] - v[0], v[2] - v[0]));
  }
  hit.material = meshMaterial_[rh.hit.geomID];
  hit.primId = meshId_[rh.hit.geomID];
  hit.geom = int(rh.hit.geomID);
  hit.prim = rh.hit.primID;
  hit.bu = rh.hit.u;
  hit.bv = rh.hit.v;
  hit.lengthScale = 1.0f;
  hit.eps = 0;
  hit.instancer = -1;
  return true;
}

namespace {

Ray rayOf(RTCRayN* ray, unsigned N, unsigned i) {
  return Ray{Vec3(RTCRayN_org_x(ray, N, i), RTCRayN_org_y(ray, N, i), RTCRayN_org_z(ray, N, i)),
             Vec3(RTCRayN_dir_x(ray, N, i), RTCRayN_dir_y(ray, N, i), RTCRayN_dir_z(ray, N, i)),
             RTCRayN_tnear(ray, N, i), RTCRayN_tfar(ray, N, i)};
}

}  // namespace

void Scene::areaLightBounds(const RTCBoundsFunctionArguments* args) {
  const auto* s = static_cast<const Scene*>(args->geometryUserPtr);
  const Bounds3 b = s->lights_[size_t(s->areaLights_[args->primID])].bounds();
  *args->bounds_o = RTCBounds{b.lo.x, b.lo.y, b.lo.z, 0.0f, b.hi.x, b.hi.y, b.hi.z, 0.0f};
}

void Scene::areaLightIntersect(const RTCIntersectFunctionNArguments* args) {
  const auto* s = static_cast<const Scene*>(args->geometryUserPtr);
  RTCRayN* ray = RTCRayHitN_RayN(args->rayhit, args->N);
  RTCHitN* hit = RTCRayHitN_HitN(args->rayhit, args->N);
  const Light& l = s->lights_[size_t(s->areaLights_[args->primID])];
  for (unsigned i = 0; i < args->N; ++i) {
    if (args->valid[i] != -1) continue;
    float t;
    const Ray r = rayOf(ray, args->N, i);
    if (!l.intersect(r, t) || !(t < r.tmax)) continue;
    RTCRayN_tfar(ray, args->N, i) = t;
    RTCHitN_Ng_x(hit, args->N, i) = RTCHitN_Ng_y(hit, args->N, i) = RTCHitN_Ng_z(hit, args->N, i) = 0.0f;
    RTCHitN_u(hit, args->N, i) = RTCHitN_v(hit, args->N, i) = 0.0f;
    RTCHitN_primID(hit, args->N, i) = args->primID;
    RTCHitN_geomID(hit, args->N, i) = args->geomID;
    RTCHitN_instID(hit, args->N, i, 0) = args->context->instID[0];
  }
}

void Scene::areaLightOccluded(const RTCOccludedFunctionNArguments* args) {
  const auto* s = static_cast<const Scene*>(args->geometryUserPtr);
  const Light& l = s->lights_[size_t(s->areaLights_[args->primID])];
  for (unsigned i = 0; i < args->N; ++i)
    if (args->valid[i] == -1 && l.blocksShadowRay(rayOf(args->ray, args->N, i)))
      RTCRayN_tfar(args->ray, args->N, i) = -kInf;
}

void Scene::buildAreaLightBvh() {
  if (areaLights_.size() < kAreaLightBvhMin) return;
  areaLightBvh_ = makeEmbreeScene(device_);
  RTCGeometry g = rtcNewGeometry(device_.get(), RTC_GEOMETRY_TYPE_USER);
  rtcSetGeometryUserPrimitiveCount(g, unsigned(areaLights_.size()));
  rtcSetGeometryUserData(g, this);
  rtcSetGeometryBoundsFunction(g, &Scene::areaLightBounds, nullptr);
  rtcSetGeometryIntersectFunction(g, &Scene::areaLightIntersect);
  rtcSetGeometryOccludedFunction(g, &Scene::areaLightOccluded);
  rtcCommitGeometry(g);
  rtcAttachGeometry(areaLightBvh_.get(), g);
  rtcReleaseGeometry(g);
  rtcCommitScene(areaLightBvh_.get());
}

bool Scene::intersectAreaLights(const Ray& ray, Hit& hit, float& tmax) const {
  if (areaLightBvh_) {
    if (!traceable(ray.o, ray.d, ray.tmin, tmax)) return false;
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRayHit rh = makeRayHit(ray.o, ray.d, ray.tmin, tmax);
    rtcIntersect1(areaLightBvh_.get(), &ctx, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
    tmax = rh.ray.tfar;
    hit.kind = Hit::AreaLight;
    hit.t = tmax;
    hit.light = areaLights_[rh.hit.primID];
    return true;
  }
  bool found = false;
  for (int li : areaLights_) {
    float t;
    Ray r = ray;
    r.tmax = tmax;
    if (lights_[li].intersect(r, t) && t < tmax) {
      found = true;
      tmax = t;
      hit.kind = Hit::AreaLight;
      hit.t = t;
      hit.light = li;
    }
  }
  return found;
}

bool Scene::areaLightsOccluded(const Vec3& p, const Vec3& dir, float dist) const {
  if (areaLights_.empty()) return false;
  // A shadow ray aimed at an area light ends on it: Light::blocksShadowRay.
  if (areaLightBvh_) {
    if (!traceable(p, dir, 0.0f, dist)) return false;
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRay ray = makeRayHit(p, dir, 0.0f, dist).ray;
    rtcOccluded1(areaLightBvh_.get(), &ctx, &ray);
    return ray.tfar < 0;
  }
  const Ray r{p, dir, 0.0f, dist};
  for (int li : areaLights_)
    if (lights_[li].blocksShadowRay(r)) return true;
  return false;
}

void Scene::buildIdentities(const SceneDesc& desc, const std::vector<LightDesc>& lights) {
  // The scene's materials in buildMaterials' order, the defaults after the description's.
  std::vector<std::string> materialNames;
  for (const auto& m : desc.materials) materialNames.push_back(m.name);
  const int defaultSurface = int(materialNames.size()), defaultGrain = defaultSurface + 1;
  materialNames.push_back(defaultSurfaceDesc().name);
  materialNames.push_back(defaultGrainDesc().name);
  for (const std::string& n : materialNames) materialCryptomatte_.push_back(cryptomatteId(n));
  std::set<std::string> names[kCryptomatteTypes];
  for (const auto& m : desc.meshes) {
    if (!m.visible) continue;  // as buildMeshes: one per geometry id
    const int material = m.material >= 0 ? m.material : defaultSurface;
    HitIdentity id;
    id.instanceId = m.instanceId;
    id.cryptomatte[0] = cryptomatteId(m.name);
    id.cryptomatte[1] = materialCryptomatte_[size_t(material)];
    names[0].insert(m.name);
    names[1].insert(materialNames[size_t(material)]);
    meshIdentity_.push_back(id);
  }
  for (const auto& a : desc.aggregates) {
    HitIdentity id;
    id.instanceId = a.instanceId;
    id.aggregateId = a.id;
    id.cryptomatte[0] = cryptomatteId(a.name);
    names[0].insert(a.name);
    float heaviest = -1;
    for (size_t k = 0; k < a.prototypes.size(); ++k) {
      const int material = a.prototypes[k].material >= 0 ? a.prototypes[k].material : defaultGrain;
      names[1].insert(materialNames[size_t(material)]);
      const float w = k < a.weights.size() ? a.weights[k] : 1.0f;
      if (w > heaviest) {
        heaviest = w;
        id.cryptomatte[1] = materialCryptomatte_[size_t(material)];
      }
    }
    aggregateIdentity_.push_back(id);
  }
  for (const auto& g : desc.instancedGrains) {
    HitIdentity id;
    id.aggregateId = g.id;
    id.cryptomatte[0] = cryptomatteId(g.name);
    names[0].insert(g.name);
    for (const GrainPrototypeDesc& p : g.prototypes) {
      const int material = p.material >= 0 ? p.material : defaultGrain;
      names[1].insert(materialNames[size_t(material)]);
    }
    instancedIdentity_.push_back(id);
  }
  for (const auto& l : lights) {
    HitIdentity id;
    id.cryptomatte[0] = id.cryptomatte[1] = cryptomatteId(l.name);
    if (l.type != LightType::Distant && l.type != LightType::Dome) {  // only area lights are hit
      names[0].insert(l.name);
      names[1].insert(l.name);
    }
    lightIdentity_.push_back(id);
  }
  for (int t = 0; t < kCryptomatteTypes; ++t) cryptomatteNames_[t].assign(names[t].begin(), names[t].end());
}

void Scene::buildLightLinks(const SceneDesc& desc, const std::vector<LightDesc>& lights) {
  std::vector<const std::vector<std::string>*> categories;  // per object, in linkObjectOf's order
  for (const auto& m : desc.meshes)
    if (m.visible) categories.push_back(&m.linkCategories);  // as buildMeshes: one per geometry id
  linkMeshes_ = int(categories.size());
  for (const auto& a : desc.aggregates) categories.push_back(&a.linkCategories);
  for (const auto& g : desc.instancedGrains) categories.push_back(&g.linkCategories);
  linkObjects_ = int(categories.size());
  unlit_.clear();
  lightLinksText_.clear();
  linkPicks_.clear();
  objectPick_.clear();
  buildShadowLinks(categories, lights);
  bool linked = false;
  for (const auto& l : lights) linked = linked || !l.lightLink.empty();
  if (!linked) return;
  unlit_.assign(lights.size() * categories.size(), 0);
  for (size_t i = 0; i < lights.size(); ++i) {
    if (lights[i].lightLink.empty()) continue;
    size_t lit = 0;
    for (size_t o = 0; o < categories.size(); ++o) {
      const auto& c = *categories[o];
      unlit_[i * categories.size() + o] = std::find(c.begin(), c.end(), lights[i].lightLink) == c.end();
      lit += !unlit_[i * categories.size() + o];
    }
    lightLinksText_ += str(lightLinksText_.empty() ? "" : "; ", lights[i].name, " lights ", lit, " of ",
                           categories.size(), " objects");
  }
  // Each object picks among the lights that reach it (an object no light reaches, among
  // all: its estimates are 0 either way). One pick per distinct set of lights.
  std::map<std::vector<float>, int> picks;
  for (size_t o = 0; o < categories.size(); ++o) {
    std::vector<float> w = pickWeights_;
    float sum = 0;
    for (size_t i = 0; i < lights.size(); ++i) {
      if (unlit_[i * categories.size() + o]) w[i] = 0;
      sum += w[i];
    }
    if (!(sum > 0)) w = pickWeights_;
    auto [it, added] = picks.emplace(w, int(linkPicks_.size()));
    if (added) linkPicks_.emplace_back(w);
    objectPick_.push_back(it->second);
  }
}

void Scene::buildShadowLinks(const std::vector<const std::vector<std::string>*>& categories,
                             const std::vector<LightDesc>& lights) {
  unshadowed_.clear();
  shadowLinksText_.clear();
  nonCasters_.clear();
  nonCasterBounds_.clear();
  if (std::none_of(lights.begin(), lights.end(), mayPassObjects) || categories.empty()) return;
  unshadowed_.assign(lights.size() * categories.size(), 0);
  for (size_t i = 0; i < lights.size(); ++i) {
    if (!mayPassObjects(lights[i])) continue;
    size_t casting = 0;
    for (size_t o = 0; o < categories.size(); ++o) {
      const auto& c = *categories[o];
      const bool casts = lights[i].shadows && std::find(c.begin(), c.end(), lights[i].shadowLink) != c.end();
      unshadowed_[i * categories.size() + o] = !casts;
      casting += casts;
    }
    if (casting == categories.size()) continue;  // the collection holds every object
    nonCasters_.resize(lights.size());
    nonCasterBounds_.resize(lights.size());
    for (size_t o = 0; o < categories.size(); ++o)
      if (unshadowed_[i * categories.size() + o]) {
        nonCasters_[i].push_back({int(o), linkObjectBounds(int(o))});
        nonCasterBounds_[i].extend(nonCasters_[i].back().bounds);
      }
    shadowLinksText_ += str(shadowLinksText_.empty() ? "" : "; ", lights[i].name, ": ", casting, " of ",
                            categories.size(), " objects cast shadows");
  }
}

Bounds3 Scene::linkObjectBounds(int object) const {
  Bounds3 b;
  const int a = object - linkMeshes_;
  if (object < linkMeshes_) {
    b = worldMeshes_[size_t(object)].bounds();
    if (worldMeshesAtClose_[size_t(object)].numTriangles() > 0) b.extend(worldMeshesAtClose_[size_t(object)].bounds());
  } else if (a < int(aggregates_.size())) {
    b = aggregateBounds_[size_t(a)];
  } else {
    b = builtInstanced_[size_t(a) - aggregates_.size()].bounds;
  }
  if (b.empty()) return b;
  // Padded a little, as surfaceBounds_: a ray that meets the object must cross them.
  const Vec3 pad = b.extent() * 1e-4f + Vec3(1e-6f * std::max(maxComponent(vabs(b.lo)), maxComponent(vabs(b.hi))));
  b.lo = b.lo - pad;
  b.hi = b.hi + pad;
  return b;
}

bool Scene::crossesNonCaster(int light, int self, const Vec3& x, const Vec3& dir, float dist) const {
  // Cheap for a light without shadow links, which callers ask about too.
  if (!shadowLinked(light)) return false;
  const Vec3 invD(1.0f / dir.x, 1.0f / dir.y, 1.0f / dir.z);
  float t0, t1;
  if (!nonCasterBounds_[size_t(light)].intersect(x, invD, 0.0f, dist, t0, t1)) return false;
  const std::vector<NonCaster>& listed = nonCasters_[size_t(light)];
  if (listed.size() > kListedNonCasters) return true;
  for (const NonCaster& n : listed)
    if (n.object != self && n.bounds.intersect(x, invD, 0.0f, dist, t0, t1)) return true;
  return false;
}

int Scene::linkObjectOf(const Hit& hit) const {
  switch (hit.kind) {
    case Hit::Surface: return hit.geom >= 0 && hit.geom < linkMeshes_ ? hit.geom : -1;
    case Hit::Grain:
    case Hit::Proxy:
    case Hit::Boundary:
      if (hit.aggregate >= 0) return aggregateLinkObject(hit.aggregate);
      return hit.instancer >= 0 ? instancerLinkObject(hit.instancer) : -1;
    case Hit::AreaLight: return -1;
  }
  return -1;
}

Scene::HitIdentity Scene::identify(const Hit& hit) const {
  switch (hit.kind) {
    case Hit::Surface: return meshIdentity_[size_t(hit.geom)];
    case Hit::Grain:
    case Hit::Proxy: {
      HitIdentity id;
      if (hit.instancer >= 0) {
        id = instancedIdentity_[size_t(hit.instancer)];
        id.instanceId = hit.instance <= std::numeric_limits<int>::max() ? int(hit.instance) : -1;
      } else {
        id = aggregateIdentity_[size_t(hit.aggregate)];
      }
      if (hit.material >= 0 && size_t(hit.material) < materialCryptomatte_.size())
        id.cryptomatte[1] = materialCryptomatte_[size_t(hit.material)];
      return id;
    }
    case Hit::Boundary: return aggregateIdentity_[size_t(hit.aggregate)];
    case Hit::AreaLight: return lightIdentity_[size_t(hit.light)];
  }
  return HitIdentity();
}

void Scene::finishHit(const Ray& ray, Hit& hit) const {
  hit.p = ray.o + ray.d * hit.t;
  // Position error grows with the coordinates' magnitude (float) and, for p = o + t d,
  // with the distance t travelled: keep the offset above both. (With |p| alone, a floor
  // at the world origin seen from 2 units away lost ~1 NEE sample in 16 near the origin
  // to shadow rays starting below its surface: test_light.cpp.)
  float coordScale = std::max({maxComponent(vabs(hit.p)), hit.t, 1e-3f * sceneScale_});
  hit.eps = std::max(hit.eps, 4e-7f * coordScale);
  if (hit.kind == Hit::Surface) hit.eps = std::max(hit.eps, surfaceOffset(hit.p, hit.t));
}

float Scene::surfaceOffset(const Vec3& p, float t) const {
  return 1e-5f * std::max({maxComponent(vabs(p)), t, 1e-3f * sceneScale_});
}

void Scene::instancedHit(Hit::Kind kind, int i, int64_t instance, int prototype, float t, float radius,
                         Hit& hit) const {
  const BuiltInstanced& b = builtInstanced_[size_t(i)];
  hit.kind = kind;
  hit.t = t;
  hit.aggregate = -1;
  hit.instancer = i;
  hit.instance = instance;
  hit.material = b.materials[size_t(prototype)];
  hit.lengthScale = b.lengthScale[size_t(prototype)];
  hit.primId = b.id;
  hit.eps = kGrainEps * radius;
  hit.grain = GrainHit();
  hit.grain.t = t;
  hit.grain.prototype = prototype;
  hit.grain.radius = radius;
}

void Scene::grainHit(Hit::Kind kind, int aggregate, const GrainHit& g, Hit& hit) const {
  const Aggregate& agg = *aggregates_[size_t(aggregate)];
  hit.kind = kind;
  hit.t = g.t;
  hit.ng = g.ng;
  hit.aggregate = aggregate;
  hit.instancer = -1;
  hit.material = agg.prototypes()[g.prototype].material;
  hit.lengthScale = agg.grainRadius();  // absorption is per R, whatever the grain's size
  hit.primId = aggregateId_[size_t(aggregate)];
  hit.eps = kGrainEps * g.radius;
  hit.grain = g;
}

bool Scene::intersect(const Ray& ray, Hit& hit, const GrainStart* from) const {
  float tmax = ray.tmax;
  // A ray that starts at a grain mostly meets a grain next: the surfaces are then asked
  // over the segment up to it (and not at all when it misses their bounds). Others ask
  // the surfaces first, whose hit shortens the walk through the aggregates.
  const bool grainsFirst = from && from->aggregate >= 0;
  const Vec3 invD(1.0f / ray.d.x, 1.0f / ray.d.y, 1.0f / ray.d.z);
  bool found = !grainsFirst && intersectSurfaces(ray, invD, hit, tmax);
  for (size_t a = 0; a < aggregates_.size(); ++a) {
    GrainHit g;
    const bool own = from && from->aggregate == int(a);
    float t0, t1;  // scenes of many aggregates: most are missed by their bounds
    if (!own && !aggregateBounds_[a].intersect(ray.o, invD, ray.tmin, tmax, t0, t1)) continue;
    if (aggregateAt(int(a), ray.time)
            .intersect(ray.o, ray.d, ray.tmin, tmax, g, own ? &from->grain : nullptr, own && from->inside) &&
        g.t < tmax) {
      found = true;
      tmax = g.t;
      grainHit(Hit::Grain, int(a), g, hit);
    }
  }
  if (grainsFirst) found |= intersectSurfaces(ray, invD, hit, tmax);
  found |= intersectAreaLights(ray, hit, tmax);
  if (!found) return false;
  finishHit(ray, hit);
  return true;
}

void Scene::setView(const CameraDesc& camera, const RenderSettings& settings, ViewSwitchTiming timing) {
  SceneDesc check;
  check.camera = camera;
  check.settings = settings;
  validateSceneDesc(check);
  if ((settings.technique == Technique::Ept) != (settings_.technique == Technique::Ept) &&
      (!aggregates_.empty() || !instanced_.empty()))
    throw InputError("render", "technique", "a change between ept and the hybrid needs the scene built anew");
  if (settings.mediumModel != settings_.mediumModel && !aggregates_.empty())
    throw InputError("render", "medium_model", "a change of the medium model needs the scene built anew");
  settings_ = settings;
  textureFilterScale_ = textureFilterScale(settings.spp);
  camera_ = Camera(toRenderSpace(camera, renderOrigin_), settings.width, settings.height);
  updateDiffusionDepths();  // the camera may have moved into or out of an aggregate
  viewId_ = ++gViewIds;
  viewMeasured_.clear();
  updateSwitching(timing);
}

std::shared_ptr<const SwitchMeasure> Scene::ViewSwitchWork::Item::measure(int threads,
                                                                         const SwitchOptions& options) const {
  return std::make_shared<const SwitchMeasure>(
      inArena(threads, [&] { return measureViewSwitch(*aggregate, *tables, medium, view, options, cacheKey); }));
}

std::vector<std::shared_ptr<const SwitchMeasure>> Scene::ViewSwitchWork::measure() const {
  std::vector<std::shared_ptr<const SwitchMeasure>> out;
  for (const Item& i : items) out.push_back(i.measure(threads));
  return out;
}

bool Scene::applyViewSwitch(const ViewSwitchWork& work,
                            const std::vector<std::shared_ptr<const SwitchMeasure>>& measures) {
  if (work.empty() || work.view != viewId_ || measures.size() != work.items.size())
    return false;
  viewMeasured_.assign(aggregates_.size(), nullptr);
  for (size_t i = 0; i < measures.size(); ++i) viewMeasured_[work.items[i].index] = measures[i];
  updateSwitching(ViewSwitchTiming::Now);  // takes viewMeasured_ instead of the camera's entries
  return true;
}

void Scene::updateProxyTables() {
  for (BuiltAggregate& entry : built_) {
    entry.aggregate->prepareProxies();
    if (!entry.proxies) {
      // Per prototype (cached on disk), at the prototype's size, or with a spread of sizes
      // at the three Gauss–Legendre nodes aggregateMedium traces: absorption is per R.
      auto tables = std::make_shared<ProxyTables>();
      const Aggregate& agg = *entry.aggregate;
      const float spread = entry.desc.sizeSpread;
      for (size_t i = 0; i < agg.prototypes().size(); ++i)
        for (float node : spread > 0 ? std::vector<float>{-0.7745967f, 0.0f, 0.7745967f} : std::vector<float>{0.0f}) {
          const float size = (entry.desc.sizes.empty() ? 1.0f : entry.desc.sizes[i]) * (1.0f + spread * node);
          Material m = materials_[size_t(entry.materials[i])];
          m.absorption = m.absorption * size;
          tables->add(int(i), size, estimateProxyTable(agg.prototypes()[i].mesh, m));
        }
      entry.proxies = std::move(tables);
    }
    proxyTables_.push_back(entry.proxies);
  }
}

void Scene::measureSwitching(size_t a) {
  BuiltAggregate& entry = built_[a];
  if (entry.switching) return;
  const Aggregate& agg = *entry.aggregate;
  const MediumParams& m = mediumParams_[a];
  // The cache key: what the aggregate's build depends on, its grains, and its medium
  // (setMedium may have replaced the TT-derived one).
  uint64_t key = hashInts(0x47525357 /* "GRSW" */, buildKey(entry.desc, agg.boundary(), agg.tile()));
  for (size_t i = 0; i < agg.prototypes().size(); ++i)
    key = hashGrainInputs(key, agg.prototypes()[i].mesh, materials_[size_t(entry.materials[i])]);
  for (const Vec3* v : {&m.sigmaT, &m.albedo, &m.g}) key = hashBytes(key, v, sizeof(Vec3));
  // The exits model: its flight, and that it takes over at a grain (vpt.h: enterMedia).
  if (media_[a].movesLight())
    key = hashInts(key, 0x45584954 /* "EXIT" */, uint64_t(kExitFlight * 1e6f), 0x47524149 /* "GRAI" */);
  entry.switchKey = key;
  // As many threads as the render may use (the result does not depend on them).
  entry.switching = std::make_shared<const SwitchMeasure>(
      inArena(settings_.threads, [&] { return measureSwitch(agg, *entry.proxies, media_[a], {}, key); }));
}

Scene::ViewSwitchWork::Item Scene::viewSwitchItem(size_t a, const SwitchView& view) const {
  return {a, aggregates_[a], built_[a].proxies, media_[a], view, built_[a].switchKey};
}

std::shared_ptr<const SwitchMeasure> Scene::measureViewSwitching(size_t a, const SwitchView& view,
                                                                 const SwitchOptions& options) const {
  return viewSwitchItem(a, view).measure(settings_.threads, options);
}

void Scene::updateSwitching(ViewSwitchTiming timing) {
  const size_t n = aggregates_.size();
  pendingViewSwitch_ = ViewSwitchWork{};
  pendingViewSwitch_.view = viewId_;
  pendingViewSwitch_.threads = settings_.threads;
  aggregateProxies_.assign(n, 0);
  proxyVisits_.assign(n, 0);
  aggregateBounces_.assign(n, 0);
  switching_.assign(n, nullptr);
  viewSwitching_.assign(n, nullptr);
  const bool canUse = settings_.technique != Technique::Ept && !standIns_ && n > 0;
  const bool measure = canUse && !media_.empty() && settings_.explicitBounces < 0;
  const ProxyUse use = settings_.proxies;
  // The camera's entries, unless applyViewSwitch has given this view's measurements.
  const std::vector<SwitchView> views =
      measure && settings_.switchForView && viewMeasured_.empty() ? switchViews() : std::vector<SwitchView>();
  proxyTables_.clear();
  if (canUse && (measure || use == ProxyUse::On || (use == ProxyUse::Auto && narrowSun_))) updateProxyTables();
  // The sun measurements depend on the aggregates, their media and the lights only: made
  // once per scene (and setMedium), not at each setView.
  const bool measureSuns = measure && narrowSun_ && sunSwitching_.size() != n;
  const std::vector<SwitchView> suns = measureSuns ? sunSwitchViews() : std::vector<SwitchView>();
  if (measureSuns) sunSwitching_.assign(n, nullptr);
  explicitBounces_ = std::max(0, settings_.explicitBounces);
  maxProxyVisits_ = 0;
  useProxies_ = false;
  for (size_t a = 0; a < n; ++a) {
    if (measure) {
      measureSwitching(a);
      switching_[a] = built_[a].switching;
      // Not where the dome's choice is the most visits already: it could add nothing.
      if (!suns.empty() && int(suns[a].entries.size()) >= kMinViewEntries &&
          switching_[a]->visits < kSwitchVisits[kSwitchCandidates - 1]) {
        // It adds to the dome's choice what it shows to be needed: toward the sun, nearly
        // clear grains' radiance is too noisy to resolve within its paths, and erring toward
        // the most visits there would make their renders noisier, not more accurate.
        const SwitchOptions options = sunSwitchOptionsFor(int(a));
        SwitchMeasure sun = *measureViewSwitching(a, suns[a], options);
        sun.visits = std::max(switchVisitsShownNeeded(sun, options), kSwitchVisits[options.firstCandidate]);
        sunSwitching_[a] = std::make_shared<const SwitchMeasure>(std::move(sun));
      }
      if (!viewMeasured_.empty()) {
        viewSwitching_[a] = viewMeasured_[a];
      } else if (!views.empty() && int(views[a].entries.size()) >= kMinViewEntries) {
        if (timing == ViewSwitchTiming::Now)
          viewSwitching_[a] = measureViewSwitching(a, views[a], viewSwitchOptions());
        else
          pendingViewSwitch_.items.push_back(viewSwitchItem(a, views[a]));
      }
    }
    int k = switching_[a] ? switching_[a]->visits : -1;
    if (const SwitchMeasure* sun = sunSwitchMeasure(int(a))) k = std::max(k, sun->visits);
    if (viewSwitching_[a]) k = std::max(k, viewSwitching_[a]->visits);
    const bool proxies = canUse && (use == ProxyUse::On || (use == ProxyUse::Auto && (narrowSun_ || k > 0)));
    aggregateProxies_[a] = proxies;
    useProxies_ = useProxies_ || proxies;
    if (k >= 0) {
      proxyVisits_[a] = k;
      aggregateBounces_[a] = kProxyOrders * k;
    } else {
      aggregateBounces_[a] = std::max(0, settings_.explicitBounces);
      proxyVisits_[a] = (aggregateBounces_[a] + kProxyOrders - 1) / kProxyOrders;
    }
    explicitBounces_ = std::max(explicitBounces_, aggregateBounces_[a]);
    maxProxyVisits_ = std::max(maxProxyVisits_, proxyVisits_[a]);
  }
  // Instancers: the rule on their media (explicitBouncesFor; a dome-albedo measurement
  // like the aggregates' missed what the view sees on a simulated heap: bench/README.md),
  // carried by proxies where they use them (kProxyOrders bounces a visit), else by
  // explicit bounces; the setting's bounces when it sets them.
  const size_t ni = builtInstanced_.size();
  instancedProxies_.assign(ni, 0);
  instancedProxyVisits_.assign(ni, 0);
  instancedBounces_.assign(ni, 0);
  bool instancedTables = false;
  for (size_t i = 0; i < ni; ++i) {
    const BuiltInstanced& b = builtInstanced_[i];
    if (!b.medium || settings_.technique == Technique::Ept || standIns_) continue;
    int bounces = std::max(0, settings_.explicitBounces);
    if (settings_.explicitBounces < 0) {
      // Half its narrowest extent stands for its interior depth.
      const MediumParams& m = b.medium->params;
      const float depth = 0.5f * minComponent(b.bounds.extent());
      bounces = explicitBouncesFor(m.albedo, m.g, depth / std::max(1e-30f, maxComponent(m.lambdaT)));
    }
    const bool proxies = use == ProxyUse::On || (use == ProxyUse::Auto && (narrowSun_ || bounces > 0));
    instancedBounces_[i] = bounces;
    if (proxies) {
      instancedProxies_[i] = 1;
      instancedProxyVisits_[i] = (bounces + kProxyOrders - 1) / kProxyOrders;
      maxProxyVisits_ = std::max(maxProxyVisits_, instancedProxyVisits_[i]);
      useProxies_ = instancedTables = true;
    } else {
      explicitBounces_ = std::max(explicitBounces_, bounces);
    }
  }
  if (instancedTables) {
    updateInstancedProxyTables();
    // A path among proxies meets every aggregate's as proxies (intersectProxies).
    if (proxyTables_.empty() && n > 0 && !standIns_) updateProxyTables();
  }
}

std::vector<SwitchView> Scene::switchViews() const {
  std::vector<SwitchView> views(aggregates_.size());
  for (SwitchView& v : views) v.lights = &lights_;
  bool lit = false;
  for (const Light& light : lights_) lit = lit || light.isInfinite();
  if (!lit || lights_.size() > 32) return views;
  // The centres of a kViewGrid² grid over the image; a ray counts for the aggregate whose
  // boundary is the first thing it meets in the media's view (grains unseen), from outside.
  for (int j = 0; j < kViewGrid; ++j)
    for (int i = 0; i < kViewGrid; ++i) {
      const Ray ray = camera_.generateRay((float(i) + 0.5f) * float(settings_.width) / float(kViewGrid),
                                          (float(j) + 0.5f) * float(settings_.height) / float(kViewGrid));
      Hit hit;
      if (!intersectMedium(ray, hit) || hit.kind != Hit::Boundary || hit.aggregate < 0 ||
          aggregateMotion_[size_t(hit.aggregate)].moving() || !(dot(ray.d, hit.ng) < 0))
        continue;
      views[size_t(hit.aggregate)].entries.push_back({hit.p, hit.ng, ray.d, distantLightsReaching(hit)});
    }
  return views;
}

uint32_t Scene::distantLightsReaching(const Hit& hit) const {
  // A distant light reaches the entry when its central ray (the cone's axis: u1 = 0) leaves
  // there unblocked by surfaces and the media's boundaries (another aggregate's shadow).
  uint32_t lit = 0;
  for (size_t l = 0; l < lights_.size(); ++l) {
    LightSample ls;
    if (lights_[l].type() != LightType::Distant || !lightReaches(int(l), aggregateLinkObject(hit.aggregate)) ||
        !lights_[l].sampleLi(hit.p, 0.0f, 0.0f, ls))
      continue;
    Ray shadow;
    shadow.o = hit.p + hit.ng * (1e-3f * aggregates_[size_t(hit.aggregate)]->grainRadius());
    shadow.d = ls.wi;
    Hit blocker;
    if (!intersectMedium(shadow, blocker)) lit |= 1u << l;
  }
  return lit;
}

SwitchOptions Scene::sunSwitchOptionsFor(int aggregate) const {
  SwitchOptions o = sunSwitchOptions();
  const SwitchMeasure* dome = size_t(aggregate) < switching_.size() ? switching_[size_t(aggregate)].get() : nullptr;
  if (dome)
    while (o.firstCandidate + 1 < kSwitchCandidates && kSwitchVisits[o.firstCandidate] < dome->visits) ++o.firstCandidate;
  return o;
}

std::vector<SwitchView> Scene::sunSwitchViews() const {
  std::vector<SwitchView> views(aggregates_.size());
  for (SwitchView& v : views) v.lights = &lights_;
  if (lights_.size() > 32) return views;
  for (size_t l = 0; l < lights_.size(); ++l) {
    if (lights_[l].type() != LightType::Distant) continue;
    for (size_t a = 0; a < aggregates_.size(); ++a) {
      const Bounds3& b = aggregateBounds_[a];
      LightSample ls;
      if (aggregateMotion_[a].moving() || b.empty() || !lightReaches(int(l), aggregateLinkObject(int(a))) ||
          !lights_[l].sampleLi(b.center(), 0.0f, 0.0f, ls) || !(maxComponent(ls.Li) > 0))
        continue;  // a sun that adds no light (or none to this aggregate: light linking) asks for nothing
      // An orthographic grid across the sun's direction over the aggregate's bounds, its rays
      // starting beyond everything in the scene.
      const Frame f(ls.wi);
      float u0 = kInf, u1 = -kInf, v0 = kInf, v1 = -kInf;
      for (int c = 0; c < 8; ++c) {
        const Vec3 q = f.toLocal(Vec3(c & 1 ? b.hi.x : b.lo.x, c & 2 ? b.hi.y : b.lo.y, c & 4 ? b.hi.z : b.lo.z) -
                                 b.center());
        u0 = std::min(u0, q.x), u1 = std::max(u1, q.x), v0 = std::min(v0, q.y), v1 = std::max(v1, q.y);
      }
      const Vec3 start = b.center() + ls.wi * (4.0f * sceneScale_ + length(b.extent()));
      for (int j = 0; j < kViewGrid; ++j)
        for (int i = 0; i < kViewGrid; ++i) {
          Ray ray;
          ray.o = start + f.s * (u0 + (u1 - u0) * (float(i) + 0.5f) / float(kViewGrid)) +
                  f.t * (v0 + (v1 - v0) * (float(j) + 0.5f) / float(kViewGrid));
          ray.d = -ls.wi;
          Hit hit;
          if (intersectMedium(ray, hit) && hit.kind == Hit::Boundary && hit.aggregate == int(a) &&
              dot(ray.d, hit.ng) < 0)
            views[a].entries.push_back({hit.p, hit.ng, ray.d, distantLightsReaching(hit)});
        }
    }
  }
  return views;
}

void Scene::updateInstancedProxyTables() {
  for (size_t i = 0; i < builtInstanced_.size(); ++i) {
    BuiltInstanced& b = builtInstanced_[i];
    if (!instancedProxies_[i] || b.proxies) continue;
    const auto t0 = std::chrono::steady_clock::now();
    // Per prototype, at three scales spanning its grains' (absorption is per the
    // prototype's radius at scale 1: a grain twice as large absorbs twice as much across).
    const InstancedGrainsDesc& desc = b.grains->desc();
    const size_t np = desc.prototypes.size();
    std::vector<float> lo(np, kInf), hi(np, 0.0f);
    for (size_t k = 0; k < desc.size(); ++k) {
      const size_t p = size_t(desc.protoIndices[k]);
      const float s = desc.scales.empty() ? 1.0f : desc.scales[k];
      lo[p] = std::min(lo[p], s);
      hi[p] = std::max(hi[p], s);
    }
    auto tables = std::make_shared<ProxyTables>();
    for (size_t p = 0; p < np; ++p) {
      if (!(lo[p] <= hi[p])) lo[p] = hi[p] = 1.0f;  // a prototype no grain uses
      const std::vector<float> scales = hi[p] > lo[p] * 1.02f
                                            ? std::vector<float>{lo[p], 0.5f * (lo[p] + hi[p]), hi[p]}
                                            : std::vector<float>{0.5f * (lo[p] + hi[p])};
      for (float scale : scales) {
        // The table's sphere is the prototype's bounding sphere: absorption per its radius.
        Material m = materials_[size_t(b.materials[p])];
        m.absorption = m.absorption * scale;
        tables->add(int(p), scale, estimateProxyTable(b.grains->prototypes()[p].mesh, m));
      }
    }
    b.proxies = std::move(tables);
    b.tablesSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }
}

std::string Scene::lowOrdersText(int a) const {
  std::string text = useProxies(a) ? (switching_[size_t(a)] ? str("proxies for ", proxyVisits(a), " visits")
                                                            : str("proxies to bounce ", explicitBounces(a)))
                     : explicitBounces(a) > 0 ? str("explicit grains to bounce ", explicitBounces(a))
                                              : std::string();
  text += text.empty() ? "the medium" : ", then the medium";
  // The exits model (vpt.h) where it moves the light; TT's medium is the one unnamed.
  if (!media_.empty() && media_[size_t(a)].movesLight()) text += " (exits)";
  auto worst = [](const Vec3& v) {
    int w = 0;
    for (int ch = 1; ch < 3; ++ch) w = std::fabs(v[ch]) > std::fabs(v[w]) ? ch : w;
    return w;
  };
  // The measured bias at the visits taken, in its worst channel.
  auto at = [&](const SwitchMeasure& m, char* buf, size_t size) {
    int c = 0;
    while (c + 1 < kSwitchCandidates && kSwitchVisits[c] < proxyVisits(a)) ++c;
    const int w = worst(m.bias[size_t(c)]);
    std::snprintf(buf, size, "%+.2f%% ± %.2f%%", 100.0 * m.bias[size_t(c)][w], 100.0 * m.biasSE[size_t(c)][w]);
  };
  if (const SwitchMeasure* m = switching_[size_t(a)].get()) {
    char bias[64], buf[200];
    at(*m, bias, sizeof bias);
    // Not whether it came from the disk cache: the words are the same whatever the cache holds.
    std::snprintf(buf, sizeof buf, " (measured: the medium's bias there %s, right after the first grain %+.1f%%",
                  bias, 100.0 * m->bias[0][worst(m->bias[0])]);
    text += buf;
    // The measurements toward one direction are noisy: their first-grain figure with its error.
    auto directional = [&](const char* what, const SwitchMeasure& v) {
      at(v, bias, sizeof bias);
      std::snprintf(buf, sizeof buf, "; %s %s", what, bias);
      text += buf;
      if (!v.measured(0)) return;  // measured from the dome's choice on (sunSwitchOptionsFor)
      const int w = worst(v.bias[0]);
      std::snprintf(buf, sizeof buf, ", right after the first grain %+.1f%% ± %.1f%%", 100.0 * v.bias[0][w],
                    100.0 * v.biasSE[0][w]);
      text += buf;
    };
    if (const SwitchMeasure* v = sunSwitchMeasure(a)) directional("toward the sun", *v);
    if (const SwitchMeasure* v = viewSwitching_[size_t(a)].get()) directional("for this view", *v);
    text += ")";
  }
  return text;
}

std::string Scene::instancedLowOrdersText(int i) const {
  if (!instancedMedium(i)) return "grain by grain (no medium: thinner than its mean free path, or technique ept)";
  const int k = instancedBounces_[size_t(i)];
  const std::string medium = "its heterogeneous medium";
  if (instancedProxies(i))
    return str("proxies for ", instancedProxyVisits(i), " visits, then ", medium, " (the rule for ", k, " bounces)");
  return k > 0 ? str("explicit grains to bounce ", k, ", then ", medium) : medium;
}

std::string Scene::instancedDiffusionText(int i) const {
  if (instancedDiffusion(i))
    return str("DA where the medium is deep and its packing uniform within ±",
               int(std::lround(100 * HeterogeneousDiffusion::kTolerance)), "% over the diffusion's reach");
  if (!instancedMedium(i) || settings_.technique != Technique::Hybrid) return "no DA (technique not hybrid, or no medium)";
  return settings_.daInstanced ? "no DA (the camera or an emitter is inside the medium)" : "no DA (da_instanced off)";
}

int Scene::explicitBouncesFor(const Vec3& albedo, const Vec3& g, float depthMfp) {
  float x = 0;  // the absorption of back-scattered light, (1 − α_s)(1 − g), worst channel
  for (int c = 0; c < 3; ++c) x = std::max(x, (1.0f - albedo[c]) * (1.0f - g[c]));
  const float k16 = std::clamp((x - 0.03f) / 0.01f, 0.0f, 1.0f), k32 = std::clamp((x - 0.05f) / 0.05f, 0.0f, 1.0f);
  int k = int(std::lround(16.0f * k16 + 16.0f * k32));
  const float lowest = std::min({albedo.x, albedo.y, albedo.z});
  if (lowest < kThinAlbedo && depthMfp < 20.0f)
    k = std::max(k, int(std::lround(32.0f * std::clamp((20.0f - depthMfp) / 10.0f, 0.0f, 1.0f))));
  return k;
}

void Scene::updateDiffusionDepths() {
  // Instancers' media: DA where heterogeneous_diffusion.h's rule holds, unless an emitter or
  // the camera is inside (as below).
  instancedDa_.assign(builtInstanced_.size(), 0);
  for (size_t i = 0; i < builtInstanced_.size(); ++i) {
    BuiltInstanced& b = builtInstanced_[i];
    if (!b.medium || settings_.technique != Technique::Hybrid || !settings_.daInstanced || instancedEmitterInside_[i])
      continue;
    if (!b.diffusion)
      b.diffusion = std::make_shared<const HeterogeneousDiffusion>(b.medium->medium, b.medium->params,
                                                                   b.medium->density.kernelWidth);
    instancedDa_[i] = !(b.diffusion->boundary().distance(camera_.position()) < 0);
  }
  diffusionDepth_.assign(media_.size(), kInf);
  for (size_t a = 0; a < media_.size(); ++a) {
    // No DA where the object is too thin for it (its depth criterion is never met), nor
    // where an emitter or the camera is inside (above).
    float depth = settings_.daDepthFactor * daDepthUnit_[a];
    // A moving aggregate: the camera within its sweep (DaRegion, as for emitters).
    const Vec3 eye = camera_.position();
    const bool cameraInside =
        aggregateMotion_[a].moving() ? aggregateBounds_[a].contains(eye) : mediumAt(eye) == int(a);
    bool blocked = emitterInside_[a] || cameraInside;
    if (!blocked && aggregates_[a]->stats().maxInteriorDepth > depth) diffusionDepth_[a] = depth;
  }
}

void Scene::setDiffusion(size_t a) {
  auto set = [&](const MediumParams& da) {
    diffusionProfiles_[a] = DiffusionProfile(da);
    daDepthUnit_[a] = granular::diffusionDepth(da, 1.0f);
  };
  if (media_[a].movesLight())
    set(exitsDiffusionMedium(mediumParams_[a]));
  else
    set(mediumParams_[a]);  // TT's: its own parameters, not a copy
}

void Scene::setMedium(int aggregate, const MediumParams& params) {
  if (media_.empty()) return;  // technique Ept, or no aggregate thick enough: no media
  mediumParams_[aggregate] = params;
  media_[aggregate] = HomogeneousMedium(params, settings_.mediumModel);
  setDiffusion(size_t(aggregate));
  built_[size_t(aggregate)].switching.reset();  // measured with the medium it replaces
  built_[size_t(aggregate)].mediumReplaced = true;
  sunSwitching_.clear();
  viewMeasured_.clear();  // measured with the medium it replaces
  updateDiffusionDepths();
  updateSwitching();
}

Vec3 Scene::beforeSurfaces(const Vec3& from, const Vec3& to, float time) const {
  const Vec3 step = to - from;
  const float len = length(step);
  if (!(len > 0)) return to;
  Ray ray;
  ray.o = from;
  ray.d = step / len;
  ray.tmin = 0;
  ray.tmax = len;
  ray.time = time;
  Hit hit;
  float tmax = len;
  if (!intersectMeshes(ray, Vec3(1.0f / ray.d.x, 1.0f / ray.d.y, 1.0f / ray.d.z), hit, tmax)) return to;
  // Back from the surface by its own ray offset: the path then meets it next.
  return from + ray.d * std::max(0.0f, tmax - 2.0f * surfaceOffset(from + ray.d * tmax, tmax));
}

float Scene::flightReach(const Vec3& o, float t) const {
  // Ten times surfaceOffset at any point of the flight (|p| ≤ |o| + t), in a unit direction.
  return t + 10.0f * surfaceOffset(vabs(o) + Vec3(t), t);
}

bool Scene::intersectMedium(const Ray& ray, Hit& hit) const {
  float tmax = ray.tmax;
  bool found = intersectSurfaces(ray, Vec3(1.0f / ray.d.x, 1.0f / ray.d.y, 1.0f / ray.d.z), hit, tmax, true);
  // A boundary face that a surface covers (an aggregate standing on a ground card at its
  // bottom face): the surface, not the crossing, within the surface's own offset. Else the
  // path would leave the medium there and, offset past the coplanar surface, go on under
  // it (to the sky's lower half).
  const float tie = found ? surfaceOffset(ray.o + ray.d * tmax, tmax) / std::max(length(ray.d), 1e-30f) : 0.0f;
  for (size_t a = 0; a < aggregates_.size(); ++a) {
    float t;
    Vec3 ng;
    if (missesMoving(a, ray.o, ray.d, ray.tmin, tmax)) continue;
    if (aggregateAt(int(a), ray.time).intersectBoundary(ray.o, ray.d, ray.tmin, tmax, t, ng) && t < tmax - tie) {
      found = true;
      tmax = t;
      hit.kind = Hit::Boundary;
      hit.t = t;
      hit.ng = ng;
      hit.aggregate = int(a);
      hit.material = -1;
      hit.primId = aggregateId_[a];
      hit.eps = 0;
    }
  }
  found |= intersectAreaLights(ray, hit, tmax);
  if (!found) return false;
  finishHit(ray, hit);
  return true;
}

bool Scene::intersectInstancedProxies(const Ray& ray, const Vec3& invD, Hit& hit, float& tmax,
                                      const GrainStart* from) const {
  float t0, t1;
  if (!instancedBounds_.intersect(ray.o, invD, ray.tmin, tmax, t0, t1)) return false;
  bool found = false;
  for (size_t i = 0; i < builtInstanced_.size(); ++i) {
    const BuiltInstanced& b = builtInstanced_[i];
    const bool own = from && from->instancer == int(i);
    if (!instancedProxies_[i] || (!own && !b.bounds.intersect(ray.o, invD, ray.tmin, tmax, t0, t1))) continue;
    InstancedGrain g;
    float t;
    if (!b.grains->intersectProxy(ray.o, ray.d, ray.tmin, tmax, own ? from->instance : -1, g, t, ray.time) ||
        !(t < tmax))
      continue;
    found = true;
    tmax = t;
    instancedHit(Hit::Proxy, int(i), g.index, g.prototype, t, g.radius * b.worldScale, hit);
    hit.grain.center = b.grains->desc().xf.point(g.center);
    hit.ng = hit.grain.ng = normalize(ray.o + ray.d * t - hit.grain.center);
  }
  return found;
}

bool Scene::intersectProxies(const Ray& ray, Hit& hit, const GrainStart* from) const {
  float tmax = ray.tmax;
  const Vec3 invD(1.0f / ray.d.x, 1.0f / ray.d.y, 1.0f / ray.d.z);
  // Spheres first (a path among proxies mostly meets one next): the surfaces are then asked
  // only up to it, and not at all when their bounds end before it.
  bool found = !instanced_.empty() && intersectInstancedProxies(ray, invD, hit, tmax, from);
  for (size_t a = 0; a < aggregates_.size(); ++a) {
    const bool own = from && from->aggregate == int(a);
    float t0, t1;
    if (!own && !aggregateBounds_[a].intersect(ray.o, invD, ray.tmin, tmax, t0, t1)) continue;
    const PosedAggregate agg = aggregateAt(int(a), ray.time);
    GrainHit g;
    if (agg.intersectProxy(ray.o, ray.d, ray.tmin, tmax, g, own ? &from->grain : nullptr) && g.t < tmax) {
      found = true;
      tmax = g.t;
      grainHit(Hit::Proxy, int(a), g, hit);
    }
  }
  found |= intersectSurfaces(ray, invD, hit, tmax, false, true);
  found |= intersectAreaLights(ray, hit, tmax);
  if (!found) return false;
  finishHit(ray, hit);
  return true;
}

bool Scene::firstGrainProxy(const Ray& ray, const GrainStart& met, Hit& hit) const {
  if (met.aggregate < 0 || met.grain.sphere < 0) return false;
  GrainHit g = met.grain;
  g.center = aggregateAt(met.aggregate, ray.time).grainCenter(g);
  const Vec3 oc = ray.o - g.center;
  if (!sphereNearSide(oc, ray.d, g.radius, g.t) || !(g.t > ray.tmin) || !(g.t < ray.tmax)) return false;
  g.ng = normalize(oc + ray.d * g.t);
  grainHit(Hit::Proxy, met.aggregate, g, hit);
  finishHit(ray, hit);
  return true;
}

ProxyShadow Scene::proxyTransmittance(const Vec3& p, const Vec3& dir, float dist, const GrainStart* from,
                                      uint64_t seed, float time, ShadowCasters casters) const {
  const ShadowPass passes = shadowPass(casters);
  if (surfacesOccluded(p, dir, dist, time, false, true, passes)) return ProxyShadow{Vec3(0.0f), 0.0f};
  ProxyShadow tr;
  for (size_t i = 0; i < builtInstanced_.size() && !tr.blocked(); ++i) {
    if (!instancedProxies_[i] || passes(instancerLinkObject(int(i)))) continue;
    const BuiltInstanced& b = builtInstanced_[i];
    const ProxyTables& tables = *b.proxies;
    const bool own = from && from->instancer == int(i);
    tr *= b.grains->proxyTransmittance(
        p, dir, 0.0f, dist, own ? from->instance : -1,
        [&](const InstancedGrain& g, float bRel) {
          const ProxyTable& t = tables.at(g.prototype, g.scale);
          return t.shadow(t.bBin(bRel));
        },
        hashInts(seed, 0x1257ULL, i), time);
  }
  for (size_t a = 0; a < aggregates_.size() && !tr.blocked(); ++a) {
    const bool own = from && from->aggregate == int(a);
    if (passes(aggregateLinkObject(int(a))) || missesMoving(a, p, dir, 0.0f, dist)) continue;
    tr *= aggregateAt(int(a), time).proxyTransmittance(p, dir, 0.0f, dist, *proxyTables_[a],
                                                       own ? &from->grain : nullptr, hashInts(seed, a));
  }
  return tr;
}

namespace {

// Embree's context for a shadow ray that passes some meshes (shadow linking): the filter
// rejects a candidate hit on a mesh the ray passes (by geometry id, its link object).
struct ShadowLinkContext {
  RTCIntersectContext context;  // first: Embree hands the filter a pointer to it
  const ShadowPass* passes;
};

void shadowLinkFilter(const RTCFilterFunctionNArguments* args) {
  const auto* c = reinterpret_cast<const ShadowLinkContext*>(args->context);
  for (unsigned i = 0; i < args->N; ++i)
    if (args->valid[i] == -1 && (*c->passes)(int(RTCHitN_geomID(args->hit, args->N, i)))) args->valid[i] = 0;
}

}  // namespace

bool Scene::surfacesOccluded(const Vec3& p, const Vec3& dir, float dist, float time, bool mediaMode,
                             bool proxyMode, ShadowPass passes) const {
  if (!traceable(p, dir, 0.0f, dist)) return false;
  if (areaLightsOccluded(p, dir, dist)) return true;
  if (!instanced_.empty()) {
    const Vec3 invD(1.0f / dir.x, 1.0f / dir.y, 1.0f / dir.z);
    float t0, t1;
    if (instancedBounds_.intersect(p, invD, 0.0f, dist, t0, t1))
      for (size_t i = 0; i < builtInstanced_.size(); ++i) {
        const BuiltInstanced& b = builtInstanced_[i];
        if (!(mediaMode && b.medium) && !(proxyMode && instancedProxies_[i]) &&
            !passes(instancerLinkObject(int(i))) && b.bounds.intersect(p, invD, 0.0f, dist, t0, t1) &&
            b.grains->occluded(p, dir, 0.0f, dist, time))
          return true;
      }
  }
  if (surfaceBounds_.empty()) return false;
  ShadowLinkContext link;
  RTCIntersectContext& ctx = link.context;
  rtcInitIntersectContext(&ctx);
  link.passes = &passes;
  if (passes.row) ctx.filter = shadowLinkFilter;
  RTCRay r;
  r.org_x = p.x; r.org_y = p.y; r.org_z = p.z;
  r.dir_x = dir.x; r.dir_y = dir.y; r.dir_z = dir.z;
  r.tnear = 0; r.tfar = dist; r.time = shutterFraction(time); r.mask = 0xffffffffu; r.id = 0; r.flags = 0;
  rtcOccluded1(surfaces_.get(), &ctx, &r);
  return r.tfar < 0;  // Embree marks a hit by tfar = -inf
}

Vec3 Scene::transmittance(const Vec3& p, const Vec3& dir, float dist, float time, Rng* rng,
                          ShadowCasters casters) const {
  const ShadowPass passes = shadowPass(casters);
  if (surfacesOccluded(p, dir, dist, time, true, false, passes)) return Vec3(0.0f);
  Vec3 tr(1.0f);
  if (instancedMedia_ > 0) {
    std::optional<Rng> own;  // without the path's: from a hash of the ray, reproducible
    if (!rng)
      rng = &own.emplace(hashInts(floatBits(p.x), floatBits(p.y), floatBits(p.z),
                                  floatBits(dir.x) ^ (uint64_t(floatBits(dir.y)) << 32)),
                         floatBits(dir.z));
    Ray ray{p, dir, 0.0f, kInf, time};
    for (size_t i = 0; i < builtInstanced_.size(); ++i)
      if (const BuiltInstanced& b = builtInstanced_[i]; b.medium && !passes(instancerLinkObject(int(i)))) {
        tr *= b.medium->medium.transmittance(ray, dist, *rng);
        if (isBlack(tr)) return tr;
      }
  }
  Vec3 opticalDepth(0.0f);
  for (size_t a = 0; a < aggregates_.size(); ++a) {
    // Walk the boundary crossings; a crossing whose normal faces along the ray leaves
    // the medium, so the segment before it was inside.
    if (passes(aggregateLinkObject(int(a))) || missesMoving(a, p, dir, 0.0f, dist))
      continue;  // casts no shadow from the light, or neither crosses nor holds p
    const PosedAggregate agg = aggregateAt(int(a), time);
    float t0 = 0, t;
    Vec3 ng;
    float inside = 0;
    float eps = 1e-5f * std::max(1.0f, maxComponent(vabs(p)));
    for (int crossings = 0; crossings < 1024; ++crossings) {
      if (!agg.intersectBoundary(p, dir, t0, dist, t, ng)) {
        if (crossings == 0 && aggregateBounds_[a].contains(p) && agg.insideBoundary(p)) inside += dist;  // never leaves
        else if (crossings > 0 && dot(ng, dir) < 0) inside += dist - t0;  // entered, never left
        break;
      }
      if (dot(ng, dir) > 0) inside += t - t0;
      t0 = t + eps;
    }
    if (inside > 0) opticalDepth += media_[a].sigmaT() * inside;
  }
  return tr * vexp(-opticalDepth);
}

Vec3 Scene::movedLight(const Vec3& p, const Vec3& move, float time) const {
  const float len = length(move);
  if (!(len > 0)) return p;
  return surfacesOccluded(p, move / len, len, time, true) ? p : p + move;
}

int Scene::mediumAfterMove(int m, const Vec3& q, float time) const {
  return m >= 0 && aggregateAt(m, time).insideBoundaryFast(q) ? m : mediumAt(q, time);
}

int Scene::mediumAt(const Vec3& p, float time) const {
  for (size_t a = 0; a < aggregates_.size(); ++a)
    if (aggregateBounds_[a].contains(p) && aggregateAt(int(a), time).insideBoundary(p)) return int(a);
  return -1;
}

bool Scene::occluded(const Vec3& p, const Vec3& dir, float dist, float time, ShadowCasters casters) const {
  const ShadowPass passes = shadowPass(casters);
  if (surfacesOccluded(p, dir, dist, time, false, false, passes)) return true;
  for (size_t a = 0; a < aggregates_.size(); ++a)
    if (!passes(aggregateLinkObject(int(a))) && !missesMoving(a, p, dir, 0.0f, dist) &&
        aggregateAt(int(a), time).occluded(p, dir, 0.0f, dist))
      return true;
  return false;
}

}  // namespace granular
