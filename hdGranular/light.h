// light.h — UsdLux lights as Hydra sprims: distant (with angle), dome (constant or a
// lat-long texture), rect and sphere; intensity, exposure, color, color temperature and
// normalize. Sync turns them into core LightDescs in the render param.
#ifndef HDGRANULAR_LIGHT_H
#define HDGRANULAR_LIGHT_H

#include "pxr/imaging/hd/light.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularLight final : public HdLight {
 public:
  HdGranularLight(SdfPath const& id, TfToken const& type);
  HdDirtyBits GetInitialDirtyBitsMask() const override { return AllDirty; }
  void Sync(HdSceneDelegate* delegate, HdRenderParam* param, HdDirtyBits* dirtyBits) override;
  void Finalize(HdRenderParam* param) override;

 private:
  TfToken _type;
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
