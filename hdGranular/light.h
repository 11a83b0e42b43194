// light.h — UsdLux lights as Hydra sprims: their attributes handed to core as plain
// records (core/usd_lights.h decides what each means, shared with the usd-core front end);
// Sync stores the LightDesc, a warning or the error in the render param.
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
