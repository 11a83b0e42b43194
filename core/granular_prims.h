// granular_prims.h — the granular USD schema's meaning on plain data (schemas/README.md),
// shared by every USD front end: the usd-core command line (python/granular) and the
// Hydra delegate (hdGranular/) hand over what they read per prim; this turns it into the
// SceneDesc, so both front ends render the same scene from the same stage.
//
// Contract. A front end lists the mesh prims it sees (ordinary meshes, aggregate
// boundaries, grain prototypes alike) with their granular constant primvars, by name
// without the "primvars:granular:" prefix, as found (type name and values, unchecked).
// assembleGranularScene():
//  - treats a visible Mesh with GranularAggregateAPI as an aggregate: its mesh is the
//    boundary (checked closed), one AggregateDesc per instance transform. Where the
//    front end knows the applied API schemas (MeshPrim::apiSchemas) they decide, as in
//    USD; where it does not (Hydra's scene delegate), a Mesh with any aggregate primvar
//    (grainRadius, packingRate, prototypes, weights, seed, tileSpheres) and no grain
//    primvar is one, unless another such mesh names it as a prototype;
//  - resolves each entry of its `prototypes` (absolute, or relative to the aggregate's
//    path) among the listed prims, else through the front end's lookup; a prototype is
//    never drawn as an ordinary mesh, nor is a mesh with GranularGrainAPI (known) or, when
//    the API schemas are unknown, carrying its primvars (ior, absorption, roughness);
//  - gives a prototype the grain material of its GranularGrainAPI values (when it has the
//    API or any of its primvars), else the material the front end resolved for it
//    (MeshPrim::material), else clear glass (-1);
//  - applies the schema's fallbacks to unauthored values (Hydra delivers authored
//    primvars only) and checks every value, with core's own validation;
//  - turns a visible surface with a light (MeshLightAPI) into a mesh light per instance;
//  - appends everything else that is visible as an ordinary MeshDesc, one per instance.
// Every error is an InputError naming the prim path (where the value was authored, for
// an inherited primvar) and the attribute "primvars:granular:<name>", e.g.
//   /World/Castle.primvars:granular:packingRate: 0.9 is outside (0, 0.64]
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "instanced_grains.h"
#include "scene_desc.h"
#include "usd_values.h"

namespace granular {

// A constant primvar as a front end found it (usd_values.h).
using PrimvarValue = UsdValue;

struct MeshPrim {
  std::string path;                  // SdfPath as text, e.g. "/World/Castle"
  // The prim's type as USD names it; "Mesh" for anything that is a UsdGeomMesh. Other
  // types are drawn (a front end tessellates Cube, Sphere) but are neither aggregates nor
  // prototypes: they are listed or looked up so that an error can name their type.
  std::string typeName = "Mesh";
  bool active = true;                // false: an inactive prim, looked up as a prototype
  TriangleMesh mesh;                 // object space, triangulated
  std::vector<Transform> instances;  // object-to-world, one per instance; empty: one identity
  // The instancer's index of each instance (MeshDesc::instanceId), one per transform; empty:
  // not instanced (-1).
  std::vector<int> instanceIds;
  bool visible = true;               // drawn: visible and of a rendered purpose
  int material = -1;                 // index into desc.materials resolved by the front end, or -1
  // primvars:displayColor (averaged), given only when no material is bound: an ordinary
  // mesh then is Lambert of it; a prototype ignores it.
  std::optional<Vec3> displayColor;
  std::map<std::string, PrimvarValue> granular;  // "grainRadius" -> value
  // The applied API schemas, when the front end can see them (usd-core can); unset: the
  // primvars decide (see above).
  std::optional<std::vector<std::string>> apiSchemas;
  int id = -1;                       // front end's id for the primId AOV (Hydra's prim id)
  // The light-link collections that hold the prim (Hydra's categories; usd-core: each light's
  // collection:lightLink that includes it), by the names the lights' records give them
  // (usd_lights.h): MeshDesc::linkCategories of each of its instances, with those of the
  // instance itself where the front end knows them per instance (Hydra's instance
  // categories: one list per instance, or none).
  std::vector<std::string> linkCategories;
  std::vector<std::vector<std::string>> instanceLinkCategories;
  // UsdLuxMeshLightAPI: the light its record gives (lightFromUsd, type Mesh). A visible
  // prim with one becomes a mesh light per instance, its mesh the light's body, instead of
  // a drawn surface (LightDesc::mesh, tintByMaterial); an aggregate or a prototype ignores it.
  std::optional<LightDesc> light;
  bool doubleSided = false;  // UsdGeomGprim's doubleSided: a mesh light emits from both sides
};

// A prim that is not among the listed ones, by absolute path (a front end may list only
// what it draws and let the aggregates' prototypes be looked up): fills `prim` and returns
// true, or returns false when the stage has no such prim.
using PrimLookup = std::function<bool(const std::string& path, MeshPrim& prim)>;

inline constexpr const char* kAggregateApi = "GranularAggregateAPI";
inline constexpr const char* kGrainApi = "GranularGrainAPI";
inline constexpr const char* kInstancedAggregateApi = "GranularInstancedAggregateAPI";
inline constexpr const char* kGranularNamespace = "primvars:granular:";

// Names of the schema's properties (without the "primvars:granular:" prefix).
bool isAggregatePrimvar(const std::string& name);
bool isGrainPrimvar(const std::string& name);

// A prototype path as written in `prototypes`, made absolute against the aggregate's path
// ("../Grains/Round" on /World/Castle is /World/Grains/Round), with SdfPath's syntax.
// InputError on aggregatePath.primvars:granular:prototypes when it is empty, not a
// valid path, or not a prim path (also when it climbs above the root).
std::string resolvePrototypePath(const std::string& aggregatePath, const std::string& text);

// GranularAggregateAPI values of a prim: its primvars type-checked, the schema's
// fallbacks where absent; ranges are checked by assembleGranularScene.
struct AggregateValues {
  float grainRadius = 0.01f;
  float packingRate = 0.6f;
  std::vector<std::string> prototypes;
  std::vector<float> weights;  // as authored: [] = equal
  int64_t seed = 1;
  int64_t tileSpheres = 512;
  std::vector<float> sizes;  // as authored: [] = all 1
  float sizeSpread = 0;
};
AggregateValues readAggregateValues(const MeshPrim& prim);

// GranularGrainAPI values, the same way.
struct GrainValues {
  float ior = 1.5f;
  Vec3 absorption{0.0f};
  float roughness = 0.0f;
};
GrainValues readGrainValues(const MeshPrim& prim);

// Appends the prims' meshes, aggregates and grain materials to desc (see above); desc's
// materials are those the prims' `material` indices refer to.
void assembleGranularScene(const std::vector<MeshPrim>& prims, SceneDesc& desc, const PrimLookup& lookup = {});

// A PointInstancer with GranularInstancedAggregateAPI as a front end read it, at one time:
// its arrays as authored (flattened), its prototypes' targets and their own transforms.
struct InstancerPrim {
  std::string path;
  std::string typeName = "PointInstancer";
  Transform xf;                            // the instancer's object-to-world
  std::vector<std::string> prototypes;     // targets of `prototypes`, absolute paths
  std::vector<Transform> prototypeXforms;  // each prototype root's local transform; empty: identity
  std::vector<float> positions;            // 3 per instance
  std::vector<float> orientations;         // 4 per instance (w, x, y, z); empty: unauthored
  std::vector<float> scales;               // 3 per instance; empty: unauthored
  std::vector<int64_t> protoIndices;
  std::vector<float> velocities, angularVelocities;  // 3 per instance; empty: unauthored
  int id = -1;
  std::vector<std::string> linkCategories;  // as MeshPrim::linkCategories
};

// The instancer's explicit grains (instanced_grains.h), its prototypes' grain materials
// appended to desc.materials as for an aggregate's prototypes (GranularGrainAPI values, else
// the bound material, else clear glass). Each prototype is a closed Mesh (looked up); an
// orientation is normalised (zero: refused); scales must be uniform (within 1e-3 of their
// largest component, which is kept) and positive. Errors name `<instancer>.<attribute>`
// (positions, orientations, scales, protoIndices, velocities, angularVelocities,
// prototypes), or the prototype's own prim. Overlaps are checked when the grid is built.
InstancedGrainsDesc instancedGrainsFromUsd(const InstancerPrim& prim, SceneDesc& desc, const PrimLookup& lookup);

// The same with the per-instance arrays read in place from a front end's own buffers (a
// USD array's, through numpy: no flattened copy; prim's own arrays are ignored): `count`
// numbers of `type` from `data`. arrays.read(attribute) is asked for positions,
// velocities, angularVelocities, orientations, scales and protoIndices, once each and in
// that order, its view valid until the next call: a front end may read each array when
// asked and let go of it at the next, holding one at a time. Orientations in USD's order
// (i, j, k, real) when orientationsRealLast. Converted in parallel (TBB); the errors are
// the first instance's, as above.
struct NumberView {
  enum class Type { Half, Float, Double, Int32, Int64 };
  const void* data = nullptr;
  size_t count = 0;  // 0: unauthored
  Type type = Type::Float;
};
struct InstancerArrays {
  std::function<NumberView(const char* attribute)> read;
  bool orientationsRealLast = false;
};
InstancedGrainsDesc instancedGrainsFromUsd(const InstancerPrim& prim, const InstancerArrays& arrays, SceneDesc& desc,
                                           const PrimLookup& lookup);

// ---- explicit grains where the front end sees no protoIndices (Hydra) --------------------
//
// Whether a PointInstancer holds a simulation's grains, read by instancedGrainsFromUsd rather
// than drawn as instanced meshes. Where the front end sees applied API schemas (usd-core):
// GranularInstancedAggregateAPI on the instancer, or GranularGrainAPI on every prototype.
// Where it does not (a Hydra scene delegate, instancerApiSchemas unset and the prototypes'
// apiSchemas unset): every prototype carrying a GranularGrainAPI primvar (ior, absorption,
// roughness; authored on it or inherited from the instancer). No prototype: no grains.
bool isExplicitGrainInstancer(const std::optional<std::vector<std::string>>& instancerApiSchemas,
                              const std::vector<MeshPrim>& prototypes);

// The instances whose keep[i] is nonzero, in order, in every per-instance array that is
// authored (one of keep.size() values).
void keepInstances(InstancedGrainsDesc& g, const std::vector<uint8_t>& keep);

// instancedGrainsFromUsd for a front end that sees, instead of protoIndices, the instances
// drawn with each prototype (a Hydra scene delegate's GetInstanceIndices): instancesOf[k]
// lists indices into prim's per-instance arrays drawn with prim.prototypes[k]; prim's arrays
// are whole (all instances) and prim.protoIndices is ignored. An instance in no list is one
// the host does not draw: USD's invisibleIds and inactiveIds, or a protoIndices entry that
// names no prototype. Where the front end also sees the authored protoIndices
// (authoredProtoIndices, one per instance; empty: unseen), such an entry is reported as
// instancedGrainsFromUsd reports it; the other undrawn instances are left out of the grains
// (after every check, so that errors name instances by their authored index; the grains'
// indices, e.g. the instanceId AOV's, then count the drawn ones). An instance in two lists
// is an InputError on protoIndices.
InstancedGrainsDesc instancedGrainsFromPrototypeInstances(InstancerPrim prim,
                                                          const std::vector<std::vector<int64_t>>& instancesOf,
                                                          const std::vector<int64_t>& authoredProtoIndices,
                                                          SceneDesc& desc, const PrimLookup& lookup);

}  // namespace granular
