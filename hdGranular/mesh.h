// mesh.h — a Hydra mesh: ordinary geometry, an aggregate's boundary or a grain
// prototype alike. Sync reads points and topology (triangulated by core/usd_mesh.h, as
// for granular render), transform, instances, visibility, display colour, material
// binding, the constant "granular:" primvars and every float2 primvar (texture
// coordinates, expanded by core when the bound material names one) into the render
// param; which role the mesh plays is decided by core (granular_prims.h) when the scene
// is assembled.
#ifndef HDGRANULAR_MESH_H
#define HDGRANULAR_MESH_H

#include <vector>

#include "pxr/imaging/hd/mesh.h"
#include "pxr/pxr.h"
#include "renderParam.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularMesh final : public HdMesh {
 public:
  explicit HdGranularMesh(SdfPath const& id);
  HdDirtyBits GetInitialDirtyBitsMask() const override;
  void Sync(HdSceneDelegate* delegate, HdRenderParam* param, HdDirtyBits* dirtyBits, TfToken const& repr) override;
  void Finalize(HdRenderParam* param) override;
  TfTokenVector const& GetBuiltinPrimvarNames() const override;

 protected:
  HdDirtyBits _PropagateDirtyBits(HdDirtyBits bits) const override { return bits; }
  void _InitRepr(TfToken const&, HdDirtyBits*) override {}
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
