// material.h — a UsdPreviewSurface subset as a Hydra material: diffuseColor gives a
// Lambert surface; opacity < 1 a smooth dielectric of inputs:ior; emissiveColor
// emission; diffuseColor, emissiveColor and opacity fed by a UsdUVTexture (its st from a
// UsdPrimvarReader_float2) become core textures, and a textured opacity or an
// opacityThreshold > 0 a Lambert cut-out (the usd-core front end's rules, README.md).
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
