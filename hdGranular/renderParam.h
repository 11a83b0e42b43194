// renderParam.h — what the Hydra prims of one render delegate share: the scene as plain
// data (meshes with their granular primvars, point instancers, lights, materials) and a
// version that every edit bumps, so the render pass knows when to rebuild the core scene.
//
// Contract: the Sync methods of rprims and sprims write here (Hydra may run them in
// parallel, hence the mutex); the render pass reads Assemble() between renders. The
// meaning of the granular primvars is core/granular_prims.h's, shared with the usd-core
// command line.
#ifndef HDGRANULAR_RENDER_PARAM_H
#define HDGRANULAR_RENDER_PARAM_H

#include <atomic>
#include <cmath>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/granular_prims.h"
#include "core/usd_mesh.h"
#include "pxr/base/gf/matrix4d.h"
#include "pxr/base/gf/vec3f.h"
#include "pxr/imaging/hd/renderDelegate.h"
#include "pxr/pxr.h"
#include "pxr/usd/sdf/path.h"
#include "core/scene_desc.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularRenderer;

// USD's row-vector matrix as core's column-form Transform; the rounding an inverse leaves
// in the projective row of an affine matrix is cleared.
inline granular::Transform HdGranularToCore(GfMatrix4d const& m) {
  granular::Transform t;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) t.m[i][j] = m[j][i];
  if (std::fabs(t.m[3][0]) + std::fabs(t.m[3][1]) + std::fabs(t.m[3][2]) + std::fabs(t.m[3][3] - 1) < 1e-9) {
    t.m[3][0] = t.m[3][1] = t.m[3][2] = 0;
    t.m[3][3] = 1;
  }
  return t;
}

class HdGranularRenderParam final : public HdRenderParam {
 public:
  struct Mesh {
    granular::MeshPrim prim;
    SdfPath materialId;
    granular::UsdMeshRecord topology;  // as Hydra holds it, for expanding primvars
    // Texture coordinates: each float2 primvar as found, by name; the bound material's
    // textures pick theirs, expanded to prim.mesh's corners by core.
    std::map<std::string, granular::UsdValue> uvSets;
    // Instanced: the instancer, and the mesh's transform relative to it (a PointInstancer
    // prototype's, its root's own transform included), which explicit grains need alone.
    SdfPath instancerId;
    granular::Transform local;
    // MeshLightAPI: the light's record as last read (prim.light is core's reading of it).
    std::optional<granular::UsdPrimRecord> lightRecord;
  };
  // An instancer as its scene delegate hands it, for explicit grains (Assemble): the
  // per-instance arrays whole, as authored (USD's masks are in the prototypes' instance
  // indices instead).
  struct Instancer {
    SdfPath parentId;                 // a nested instancer's outer one
    granular::Transform xf;           // the instancer's object-to-world
    std::vector<float> positions;     // hydra:instanceTranslations, 3 each
    std::vector<float> orientations;  // hydra:instanceRotations as (w, x, y, z)
    std::vector<float> scales;        // hydra:instanceScales, 3 each
    std::vector<float> velocities, angularVelocities;
    bool transforms = false;          // has hydra:instanceTransforms: not a PointInstancer's
    // protoIndices as authored where the scene delegate hands the attribute over (OpenUSD's
    // UsdImagingDelegate does; a scene index does not): empty when not.
    std::vector<int64_t> protoIndices;
    std::vector<std::string> categories;  // light-link categories (as explicit grains: core/usd_lights.h)
  };

  void SetMesh(SdfPath const& id, Mesh mesh);
  void SetInstancer(SdfPath const& id, Instancer instancer);
  void SetLight(SdfPath const& id, granular::LightDesc light);
  // st: the primvar the material's textures read ("" when it has none). No material: the
  // bound material has no supported surface, and its meshes use the default material.
  void SetMaterial(SdfPath const& id, std::optional<granular::MaterialDesc> material, std::string st = "");
  void Remove(SdfPath const& id);  // any kind
  // A prim whose values core refused: Assemble throws the error (of the first such prim
  // by path) until the prim is set again or removed, so the image is refused as
  // `granular render` refuses the stage.
  void SetError(SdfPath const& id, granular::InputError const& error);
  // Core's warnings about what a prim means: each message once per delegate (TF_WARN),
  // and listed by Warnings() (render stat granular:warnings) in the order given.
  void Warn(granular::UsdWarnings const& warnings);
  std::vector<std::string> Warnings() const;
  // The error that refused the last scene ("" when it was built): render stat granular:error.
  void SetRenderError(std::string error);
  std::string RenderError() const;

  // A mesh light's inputs read again from its scene delegate, before each render: UsdImaging
  // marks a mesh dirty for no change of its light's inputs (OpenUSD 24.08's gprim adapters
  // ignore them), so an edit of one is found by comparing what it reads now. A change is
  // read by core again as an edit (Version()); a value core refuses is the prim's error
  // until it changes again.
  void RefreshMeshLights(HdRenderIndex& index);

  // The scene as the core sees it; throws granular::InputError on bad data. A PointInstancer
  // of explicit grains (core's isExplicitGrainInstancer on its prototype meshes: each carries
  // a grain primvar), neither nested nor holding an instancer, becomes an InstancedGrainsDesc
  // through core's instancedGrainsFromPrototypeInstances, as granular render reads it; its
  // prototypes are then not handed over as meshes. Other instancers' prototypes are meshes
  // with one instance transform each.
  granular::SceneDesc Assemble() const;
  // Bumped by every edit above.
  int Version() const { return _version.load(); }

  // Render buffers call this before Hydra reallocates or frees them: the render loop
  // must not be writing into them then (renderer.h: StopForEdit).
  void SetRenderer(HdGranularRenderer* renderer) { _renderer = renderer; }
  void StopRenderForEdit();

 private:
  // Assemble's PointInstancers of explicit grains, each with its prototype meshes (indices
  // into prims: _meshes' records in _meshes' order, materials resolved); and one's grains,
  // read by core. With _mutex held.
  std::map<SdfPath, std::vector<size_t>> _GrainInstancers(std::vector<granular::MeshPrim> const& prims) const;
  granular::InstancedGrainsDesc _ReadGrains(SdfPath const& id, std::vector<size_t> const& prototypes,
                                            std::vector<granular::MeshPrim> const& prims,
                                            granular::SceneDesc& desc) const;

  mutable std::mutex _mutex;
  std::map<SdfPath, Mesh> _meshes;
  std::map<SdfPath, Instancer> _instancers;
  std::map<SdfPath, granular::LightDesc> _lights;
  std::map<SdfPath, std::optional<granular::MaterialDesc>> _materials;
  std::map<SdfPath, granular::InputError> _errors;
  mutable std::set<std::string> _warned;  // warnings given (Warn, Assemble)
  mutable std::vector<std::string> _warnings;  // the same, in the order given
  std::string _renderError;
  std::map<SdfPath, std::string> _materialSt;
  std::atomic<int> _version{0};
  HdGranularRenderer* _renderer = nullptr;
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
