// material.h — a bound material as a Hydra sprim: its surface network handed to core as
// plain records (core/usd_shading.h holds the UsdPreviewSurface and UsdUVTexture rules,
// shared with the usd-core front end).
#ifndef HDGRANULAR_MATERIAL_H
#define HDGRANULAR_MATERIAL_H

#include "pxr/imaging/hd/material.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularMaterial final : public HdMaterial {
 public:
  explicit HdGranularMaterial(SdfPath const& id) : HdMaterial(id) {}
  HdDirtyBits GetInitialDirtyBitsMask() const override { return AllDirty; }
  void Sync(HdSceneDelegate* delegate, HdRenderParam* param, HdDirtyBits* dirtyBits) override;
  void Finalize(HdRenderParam* param) override;
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
