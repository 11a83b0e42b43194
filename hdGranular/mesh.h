// mesh.h — a Hydra mesh: ordinary geometry, an aggregate's boundary or a grain
// prototype alike. Sync reads points, topology (triangulated), transform, instances,
// visibility, display colour, material binding, the constant "granular:" primvars and
// every float2 primvar (texture coordinates, per triangle corner) into the render param; which role the mesh plays is decided by core
// (granular_prims.h) when the scene is assembled.
#ifndef HDGRANULAR_MESH_H
#define HDGRANULAR_MESH_H

#include <vector>

#include "pxr/imaging/hd/mesh.h"
#include "pxr/imaging/hd/meshUtil.h"
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

 private:
  void ReadUvSets(HdSceneDelegate* delegate, HdMeshUtil& util, VtVec3iArray const& triangles,
                  VtIntArray const& primitiveParams, std::vector<size_t> const& kept,
                  HdGranularRenderParam::Mesh& m);
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
