// instancer.h — Hydra instancers (UsdGeomPointInstancer, native instancing): the
// world transforms of a prototype's instances, nested instancers included; and, for
// explicit grains, the instancer's per-instance arrays as found, handed to the render
// param on every Sync (renderParam.h: Instancer), removed on Finalize.
#ifndef HDGRANULAR_INSTANCER_H
#define HDGRANULAR_INSTANCER_H

#include <map>
#include <mutex>

#include "pxr/base/vt/array.h"
#include "pxr/base/vt/value.h"
#include "pxr/imaging/hd/instancer.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularInstancer final : public HdInstancer {
 public:
  HdGranularInstancer(HdSceneDelegate* delegate, SdfPath const& id);
  void Sync(HdSceneDelegate* delegate, HdRenderParam* param, HdDirtyBits* dirtyBits) override;
  void Finalize(HdRenderParam* param) override;
  // Row-vector matrices (USD's): instance transform, then scale, rotate, translate,
  // then the instancer's own transform, then the parent instancer's instances.
  VtMatrix4dArray ComputeInstanceTransforms(SdfPath const& prototypeId);
  // For each of those transforms, the index of its instance in this instancer (the
  // innermost one: a nested instancer's instances repeat it), for the instanceId AOV.
  VtIntArray ComputeInstanceIndices(SdfPath const& prototypeId);
  // For each of those transforms, the light-link categories of its instance and of the
  // outer instances it is in (the scene delegate's instance categories); empty when the
  // delegate gives none at any level.
  std::vector<std::vector<std::string>> ComputeInstanceCategories(SdfPath const& prototypeId);

 private:
  HdGranularInstancer* _Parent();  // the outer instancer of a nested one, else null
  std::mutex _mutex;
  std::map<TfToken, VtValue> _primvars;  // per-instance primvars by name
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
