// fuzz_common.h — what the USD fuzz targets share: reading the input bytes as values
// (Reader; the material, camera, light and image layout both use), and what every target
// does with a scene description that validated: bound its cost (the fuzzer must stay
// fast, and some costs are legitimately large: a 2^28-cell grid, a 100000-sphere tile),
// then build it and render a few pixels with EPT, treating anything but an InputError,
// and any non-finite sample, as a bug (abort()).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <string>

#include "core/error.h"
#include "core/render.h"
#include "core/scene.h"

namespace granular::fuzz {

inline void setUpCache() {
  // Tiles are cached on disk; keep the fuzzer's apart (the Makefile sets its own).
  setenv("GRANULAR_CACHE_DIR", "/tmp/granular-fuzz-cache", /*overwrite=*/0);
  // Every input is a new aggregate: storing its build would only fill the disk.
  setenv("GRANULAR_CACHE_MAX_MB", "0", /*overwrite=*/0);
}

// FUZZ_VERBOSE=1: say what became of an input (replaying seeds or a corpus by hand).
inline void note(const char* what, const char* detail = "") {
  static const bool verbose = std::getenv("FUZZ_VERBOSE") != nullptr;
  if (verbose) std::fprintf(stderr, "fuzz: %s%s%s\n", what, *detail ? ": " : "", detail);
}

// The input bytes as values (little-endian; missing bytes read as 0).
struct Reader {
  const uint8_t* p;
  size_t n;
  template <typename T>
  T get() {
    T v{};
    size_t k = std::min(sizeof(T), n);
    std::memcpy(&v, p, k);
    p += k;
    n -= k;
    return v;
  }
  float f() { return get<float>(); }
  Vec3 v3() {
    float x = f(), y = f(), z = f();
    return {x, y, z};
  }
  // rows x 4 floats, row-major (core convention: a transposed GfMatrix4d); rows 3: an
  // affine matrix without its projective row.
  Transform matrix(int rows = 4) {
    Transform t;
    for (int i = 0; i < 4 * rows; ++i) t.m[i / 4][i % 4] = f();
    return t;
  }
  // A u8 selector: below 0xF0 an entry of list (modulo its size), else a u8 length and
  // that many bytes.
  template <size_t N>
  std::string pick(const char* const (&list)[N]) {
    uint8_t sel = get<uint8_t>();
    if (sel < 0xF0) return list[sel % N];
    std::string s(get<uint8_t>() % 48, '\0');
    for (char& c : s) c = char(get<uint8_t>());
    return s;
  }
};

// u8 type (odd: dielectric, else Lambert), float3 albedo, float ior, float3 absorption,
// float3 emission.
inline MaterialDesc readMaterial(Reader& r, const std::string& name) {
  MaterialDesc m;
  m.name = name;
  m.type = r.get<uint8_t>() % 2 ? MaterialType::Dielectric : MaterialType::Lambert;
  m.albedo = r.v3();
  m.ior = r.f();
  m.absorption = r.v3();
  m.emission = r.v3();
  return m;
}

// 16 floats camera matrix; floats focalLength, horizontal/verticalAperture, their
// offsets, clipping near/far; u8 light type (distant, sphere, rect, dome, disk,
// cylinder), 16 floats matrix, float3 color, floats intensity, exposure, angle, radius,
// width, height, u8 normalize, float length, u8 shaping (odd: on), floats cone angle, cone
// softness, focus, float3 focus tint; u8 light link (bit 0: linked, to every object with
// bit 1 too, to none without: buildAndRender); u8 width, u8 height (1 + value % 8).
// A light linked to every object of the scene (readViewAndLight, buildAndRender).
inline const char* const kLinkEverything = "fuzz:everything";

inline void readViewAndLight(Reader& r, SceneDesc& d) {
  d.camera.cameraToWorld = r.matrix();
  d.camera.focalLength = r.f();
  d.camera.horizontalAperture = r.f();
  d.camera.verticalAperture = r.f();
  d.camera.horizontalApertureOffset = r.f();
  d.camera.verticalApertureOffset = r.f();
  d.camera.clipNear = r.f();
  d.camera.clipFar = r.f();
  LightDesc l;
  l.name = "/World/Light";
  const uint8_t type = r.get<uint8_t>();
  l.type = type == 255 ? LightType::Mesh : LightType(type % 6);  // 255: a mesh light (earlier inputs keep their type)
  l.xf = r.matrix();
  l.color = r.v3();
  l.intensity = r.f();
  l.exposure = r.f();
  l.angle = r.f();
  l.radius = r.f();
  l.width = r.f();
  l.height = r.f();
  l.normalize = r.get<uint8_t>() & 1;
  l.length = r.f();
  if (l.type == LightType::Mesh) {  // a quad of width × height facing its −Z, as a rect
    const float w = 0.5f * l.width, h = 0.5f * l.height;
    l.mesh.points = {Vec3(-w, -h, 0), Vec3(-w, h, 0), Vec3(w, h, 0), Vec3(w, -h, 0)};
    l.mesh.indices = {0, 1, 2, 0, 2, 3};
  }
  l.shaping.enabled = r.get<uint8_t>() & 1;
  l.shaping.coneAngle = r.f();
  l.shaping.coneSoftness = r.f();
  l.shaping.focus = r.f();
  l.shaping.focusTint = r.v3();
  const uint8_t link = r.get<uint8_t>();
  if (link & 1) l.lightLink = link & 2 ? kLinkEverything : "fuzz:nothing";
  d.lights.push_back(l);
  d.settings.width = 1 + r.get<uint8_t>() % 8;
  d.settings.height = 1 + r.get<uint8_t>() % 8;
}

[[noreturn]] inline void bug(const char* what) {
  std::fprintf(stderr, "fuzz: %s\n", what);
  std::abort();
}

// Cheap upper bound of the aggregate's cell count, as Aggregate::build computes it.
inline double estimatedCells(const AggregateDesc& a) {
  double rTile = std::cbrt(3.0 * a.packingRate / (4.0 * kPiD * a.tileSpheres));
  double L = a.grainRadius / rTile;
  Bounds3 b = a.boundary.transformed(a.xf).bounds();
  double cells = 1;
  for (int k = 0; k < 3; ++k) cells *= std::ceil((double(b.hi[k]) - b.lo[k] + 2.0 * a.grainRadius) / L);
  return cells;
}

// Clamps the costly knobs of a validated description (after validation, so that the
// validation saw the raw input); false: too big to build within a fuzzing budget.
inline bool boundCost(SceneDesc& d) {
  RenderSettings& s = d.settings;
  s.width = std::min(s.width, 6);
  s.height = std::min(s.height, 6);
  s.spp = 1;
  s.maxDepth = std::min(s.maxDepth, 64);
  s.threads = 1;
  s.technique = Technique::Ept;  // TT estimation traces 2^18 rays per prototype
  size_t triangles = 0;
  for (const MeshDesc& m : d.meshes) triangles += m.mesh.numTriangles();
  for (const LightDesc& l : d.lights)
    if (!l.textureFile.empty()) return false;  // image decoding is OpenImageIO's, not ours
  for (AggregateDesc& a : d.aggregates) {
    triangles += a.boundary.numTriangles();
    for (const GrainPrototypeDesc& p : a.prototypes) triangles += p.mesh.numTriangles();
    // Few distinct tiles (each new one is a packing simulation, cached on disk).
    a.tileSpheres = a.tileSpheres <= 8 ? 8 : a.tileSpheres <= 16 ? 16 : 32;
    a.packingRate = std::min(0.6f, std::max(0.05f, std::round(a.packingRate * 20.0f) / 20.0f));
    a.seed %= 4;
    double cells = estimatedCells(a);
    if (!(cells <= 4096)) return false;
  }
  return triangles <= 20000;
}

// validateSceneDesc must refuse a bad description with an InputError; one that validates
// is built and rendered.
inline void buildAndRender(SceneDesc d) {
  for (const LightDesc& l : d.lights)
    if (l.lightLink == kLinkEverything) {
      for (MeshDesc& m : d.meshes) m.linkCategories.push_back(l.lightLink);
      for (AggregateDesc& a : d.aggregates) a.linkCategories.push_back(l.lightLink);
      for (InstancedGrainsDesc& g : d.instancedGrains) g.linkCategories.push_back(l.lightLink);
    }
  try {
    validateSceneDesc(d);
  } catch (const InputError& e) {
    note("refused", e.what());
    return;
  }
  if (!boundCost(d)) {
    note("valid, too costly to build here");
    return;
  }
  try {
    auto scene = Scene::build(d);
    Renderer r(*scene);
    r.render(1);
    if (r.nonFiniteSamples() != 0) bug("non-finite sample");
    for (int y = 0; y < d.settings.height; ++y)
      for (int x = 0; x < d.settings.width; ++x)
        if (!isFinite(r.film().mean(x, y))) bug("non-finite pixel");
    note("built and rendered");
  } catch (const InputError& e) {
    note("refused by Scene::build", e.what());
    // A clear refusal (e.g. a tile that jams at this packing rate): fine.
  }
}

}  // namespace granular::fuzz
