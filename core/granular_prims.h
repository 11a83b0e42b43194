// granular_prims.h — the granular USD schema's meaning on plain data (schemas/README.md),
// shared by every USD front end: the usd-core command line (python/granular) and the
// Hydra delegate (hdGranular/) hand over what they read per prim; this turns it into the
// SceneDesc, so both front ends render the same scene from the same stage.
//
// Contract. A front end lists the mesh prims it sees (ordinary meshes, aggregate
// boundaries, grain prototypes alike) with their granular constant primvars, by name
// without the "primvars:granular:" prefix, as found (type name and values, unchecked).
// assembleGranularScene():
//  - treats a mesh with any GranularAggregateAPI primvar (grainRadius, packingRate,
//    prototypes, weights, seed, tileSpheres) as an aggregate: its mesh is the boundary
//    (checked closed), one AggregateDesc per instance transform;
//  - resolves each entry of its `prototypes` (absolute, or relative to the aggregate's
//    path) among the listed prims; a prototype is never drawn as an ordinary mesh, nor is
//    a mesh carrying GranularGrainAPI primvars (ior, absorption, roughness);
//  - gives a prototype the grain material of its GranularGrainAPI values, else the
//    material the front end resolved for it (MeshPrim::material), else clear glass;
//  - applies the schema's fallbacks to unauthored values (Hydra delivers authored
//    primvars only) and checks every value;
//  - appends everything else that is visible as an ordinary MeshDesc.
// Every error is an InputError naming the prim path and the attribute
// "primvars:granular:<name>", e.g.
//   /World/Castle.primvars:granular:packingRate: 0.9 is outside (0, 0.64]
#pragma once

#include <map>
#include <string>
#include <vector>

#include "scene_desc.h"

namespace granular {

// A constant primvar as a front end found it. Scalars and arrays of numbers (float,
// double, half, int, color3f, ...) fill `numbers` (a color3f gives 3); string and token
// arrays fill `strings`. `typeName` is the USD type name (e.g. "float[]"), for messages.
struct PrimvarValue {
  std::string typeName;
  std::vector<double> numbers;
  std::vector<std::string> strings;
  bool isArray = false;
  bool isString = false;
};

struct MeshPrim {
  std::string path;                  // SdfPath as text, e.g. "/World/Castle"
  TriangleMesh mesh;                 // object space, triangulated
  std::vector<Transform> instances;  // object-to-world, one per instance; empty: one identity
  bool visible = true;
  int material = -1;                 // index into desc.materials resolved by the front end, or -1
  std::map<std::string, PrimvarValue> granular;  // "grainRadius" -> value
  int id = -1;                       // front end's id for the primId AOV (Hydra's prim id)
};

// Names of the schema's properties (without the "primvars:granular:" prefix).
bool isAggregatePrimvar(const std::string& name);
bool isGrainPrimvar(const std::string& name);

// A prototype path as written in `prototypes`, made absolute against the aggregate's path
// ("../Grains/Round" on /World/Castle is /World/Grains/Round).
std::string resolvePrototypePath(const std::string& aggregatePath, const std::string& text);

// Appends the prims' meshes, aggregates and grain materials to desc (see above).
void assembleGranularScene(const std::vector<MeshPrim>& prims, SceneDesc& desc);

}  // namespace granular
