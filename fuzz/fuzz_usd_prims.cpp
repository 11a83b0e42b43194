// fuzz_usd_prims — libFuzzer target for the USD front ends' shared C++ entry point,
// assembleGranularScene (core/granular_prims.h): the prims a stage (usd-core reader) or a
// Hydra scene delegate hands over, with their granular constant primvars as found
// (type names, values, arrays, strings, interpolation, inheritance source), applied API
// schemas, prototype paths in SdfPath syntax, instance transforms, materials and display
// colours, and the lookup of prims that are not listed. The result then goes through
// validateSceneDesc and, when it validates, Scene::build and a tiny render
// (fuzz_common.h). Contract under test (granular_prims.h): every problem is an
// InputError naming a prim path and attribute; nothing else escapes, nothing crashes,
// no sample is NaN or Inf.
//
// Input layout (fuzz_common.h's Reader; fuzz/seed_corpus.py writes seeds). A "string" is
// Reader::pick: a plausible path or name from a list, or raw bytes.
//   u8 materials (0-3), each as fuzz_common.h's readMaterial
//   u8 prims (1-4) listed, then u8 prims (0-2) for the lookup, each prim:
//     path, typeName, u8 flags (1 active, 2 visible, 4 apiSchemas known, 8 displayColor),
//     [u8 k, k x apiSchema name], [float3 displayColor], i8 material,
//     u8 n points (< 64), n x float3, u8 f, f x i8 faceVertexCounts, u8 k, k x i8 indices
//     (triangulated; a box when that fails), u8 instances (0-2) x 12 floats (the top
//     three rows of a matrix), u8 primvars (0-6), each: name, typeName, u8 flags
//     (1 isArray, 2 isString, 4 inherited), interpolation, [source path], u8 numbers
//     (< 8) x float, u8 strings (< 4) x path
//   then the camera, one light and the image size (fuzz_common.h's readViewAndLight).
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "fuzz_common.h"
#include "core/granular_prims.h"
#include "core/mesh.h"
#include "core/shapes.h"

namespace {

using namespace granular;

const char* const kPaths[] = {"/World/Castle", "/World/Grains/Round", "/World/Grains/Flat", "/World/Floor",
                              "../Grains/Round", "Grains/Round", "/World/Grains", "/World", "/", "",
                              "/World/Castle.primvars:x", "/World/../..", "/World/Grains/Round{v=a}",
                              "/World/Grains/Round/", "//World", "/World/Castle/Sub", "<bad path>", "/World/Grains/./Round"};
const char* const kNames[] = {"grainRadius", "packingRate", "prototypes", "weights", "seed", "tileSpheres",
                              "ior", "absorption", "roughness", "unknownName", "Mesh", "Cube", "Sphere", "Xform",
                              "GranularAggregateAPI", "GranularGrainAPI", "MaterialBindingAPI"};
const char* const kTypes[] = {"float", "double", "half", "int", "int64", "uint", "uchar", "float[]", "double[]",
                              "half[]", "string[]", "token[]", "color3f", "float3", "vector3f", "string", "token",
                              "bool", "int[]", "matrix4d"};
const char* const kInterpolations[] = {"constant", "uniform", "vertex", "faceVarying", ""};

using fuzz::Reader;

MeshPrim readPrim(Reader& r) {
  MeshPrim prim;
  prim.path = r.pick(kPaths);
  prim.typeName = r.pick(kNames);
  uint8_t flags = r.get<uint8_t>();
  prim.active = flags & 1;
  prim.visible = flags & 2;
  if (flags & 4) {
    std::vector<std::string> apis(r.get<uint8_t>() % 4);
    for (std::string& a : apis) a = r.pick(kNames);
    prim.apiSchemas = apis;
  }
  if (flags & 8) prim.displayColor = r.v3();
  prim.material = r.get<int8_t>();
  std::vector<Vec3> points(r.get<uint8_t>() % 64);
  for (Vec3& q : points) q = r.v3();
  std::vector<int> counts(r.get<uint8_t>() % 32);
  for (int& c : counts) c = r.get<int8_t>();
  std::vector<int> indices(r.get<uint8_t>());
  for (int& i : indices) i = r.get<int8_t>();
  try {
    prim.mesh = triangulate(points, counts, indices, prim.path);
  } catch (const InputError&) {
    prim.mesh = makeBox(Vec3(-1.0f), Vec3(1.0f));
  }
  prim.instances.resize(r.get<uint8_t>() % 3);
  for (Transform& t : prim.instances) t = r.matrix(3);
  int primvars = r.get<uint8_t>() % 7;
  for (int k = 0; k < primvars; ++k) {
    std::string name = r.pick(kNames);
    PrimvarValue v;
    v.typeName = r.pick(kTypes);
    uint8_t vf = r.get<uint8_t>();
    v.isArray = vf & 1;
    v.isString = vf & 2;
    v.interpolation = r.pick(kInterpolations);
    if (vf & 4) v.source = r.pick(kPaths);
    v.numbers.resize(r.get<uint8_t>() % 8);
    for (double& x : v.numbers) x = r.f();
    v.strings.resize(r.get<uint8_t>() % 4);
    for (std::string& s : v.strings) s = r.pick(kPaths);
    prim.granular[name] = v;
  }
  return prim;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  granular::fuzz::setUpCache();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace granular;
  Reader r{data, size};
  SceneDesc d;
  d.materials.resize(r.get<uint8_t>() % 4);
  for (size_t i = 0; i < d.materials.size(); ++i) d.materials[i] = fuzz::readMaterial(r, "/World/Looks/M" + std::to_string(i));
  std::vector<MeshPrim> prims(1 + r.get<uint8_t>() % 4);
  for (MeshPrim& p : prims) p = readPrim(r);
  std::vector<MeshPrim> hidden(r.get<uint8_t>() % 3);
  for (MeshPrim& p : hidden) p = readPrim(r);
  PrimLookup lookup = [&hidden](const std::string& path, MeshPrim& prim) {
    for (const MeshPrim& h : hidden)
      if (h.path == path) {
        prim = h;
        return true;
      }
    return false;
  };

  fuzz::readViewAndLight(r, d);

  try {
    assembleGranularScene(prims, d, lookup);
  } catch (const InputError& e) {
    fuzz::note("refused", e.what());
    return 0;
  }
  fuzz::buildAndRender(std::move(d));
  return 0;
}
