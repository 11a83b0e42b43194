// fuzz_common.h — what both fuzz targets do with a scene description that validated:
// bound its cost (the fuzzer must stay fast, and some costs are legitimately large: a
// 2^28-cell grid, a 100000-sphere tile), then build it and render a few pixels with EPT,
// treating anything but an InputError, and any non-finite sample, as a bug (abort()).
#pragma once

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>

#include "error.h"
#include "render.h"
#include "scene.h"

namespace granular::fuzz {

inline void setUpCache() {
  // Tiles are cached on disk; keep the fuzzer's apart (the Makefile sets its own).
  setenv("GRANULAR_CACHE_DIR", "/tmp/granular-fuzz-cache", /*overwrite=*/0);
}

// FUZZ_VERBOSE=1: say what became of an input (replaying seeds or a corpus by hand).
inline void note(const char* what, const char* detail = "") {
  static const bool verbose = std::getenv("FUZZ_VERBOSE") != nullptr;
  if (verbose) std::fprintf(stderr, "fuzz: %s%s%s\n", what, *detail ? ": " : "", detail);
}

[[noreturn]] inline void bug(const char* what) {
  std::fprintf(stderr, "fuzz: %s\n", what);
  std::abort();
}

// Cheap upper bound of the aggregate's cell count, as Aggregate::build computes it.
inline double estimatedCells(const AggregateDesc& a) {
  double rTile = std::cbrt(3.0 * a.packingRate / (4.0 * 3.14159265358979 * a.tileSpheres));
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

inline void buildAndRender(SceneDesc d) {
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
