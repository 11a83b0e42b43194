// fuzz_usd_attributes — libFuzzer target for the C++ side of the USD front end
// (python/granular/usd_reader.py through python/bindings.cpp): what a stage's attribute
// values reach in core. The input bytes are read as the values a stage can author, in
// this order (little-endian; missing bytes read as 0; fuzz/seed_corpus.py writes seeds):
//   u8 n, n x float3 points; u8 f, f x int8 faceVertexCounts; u16 k, k x int16
//   faceVertexIndices                                  -> triangulate(), validateClosed()
//   16 floats: the aggregate's world matrix (core convention: a transposed GfMatrix4d)
//   float grainRadius, float packingRate, u64 seed, i32 tileSpheres, u8 w, w x float weights
//   a material, then the camera, one light and the image size (fuzz_common.h:
//   readMaterial, readViewAndLight)
// The mesh becomes the aggregate's boundary and its prototype (a box when triangulate
// refuses it, so that the rest is still exercised). validateSceneDesc must refuse every
// bad value with an InputError; anything else escaping, a crash, or a non-finite sample
// of a scene that validated (fuzz_common.h) is a bug.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "fuzz_common.h"
#include "core/mesh.h"
#include "core/shapes.h"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  granular::fuzz::setUpCache();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace granular;
  fuzz::Reader r{data, size};

  std::vector<Vec3> points(r.get<uint8_t>());
  for (Vec3& p : points) p = r.v3();
  std::vector<int> counts(r.get<uint8_t>());
  for (int& c : counts) c = r.get<int8_t>();
  std::vector<int> indices(r.get<uint16_t>() % 2048);
  for (int& i : indices) i = r.get<int16_t>();
  TriangleMesh mesh;
  try {
    mesh = triangulate(points, counts, indices, "/World/Castle");
    validateClosed(mesh, "/World/Castle");
  } catch (const InputError&) {
    mesh = makeBox(Vec3(-1.0f), Vec3(1.0f));
  }

  SceneDesc d;
  AggregateDesc a;
  a.name = "/World/Castle";
  a.boundary = mesh;
  a.xf = r.matrix();
  a.grainRadius = r.f();
  a.packingRate = r.f();
  a.seed = r.get<uint64_t>();
  a.tileSpheres = r.get<int32_t>();
  a.prototypes = {GrainPrototypeDesc{"/World/Castle/Grain", mesh, 0}};
  a.weights.resize(r.get<uint8_t>() % 4);
  for (float& w : a.weights) w = r.f();
  if (a.weights.size() > 1) a.prototypes.resize(a.weights.size(), a.prototypes[0]);
  d.aggregates.push_back(a);

  d.materials.push_back(fuzz::readMaterial(r, "/World/Looks/Sand"));
  fuzz::readViewAndLight(r, d);

  fuzz::buildAndRender(std::move(d));
  return 0;
}
