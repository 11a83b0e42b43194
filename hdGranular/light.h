// light.h — UsdLux lights as Hydra sprims: their attributes handed to core as plain
// records (core/usd_lights.h decides what each means, shared with the usd-core front end);
// Sync stores the LightDesc, a warning or the error in the render param.
#ifndef HDGRANULAR_LIGHT_H
#define HDGRANULAR_LIGHT_H

#include <string>

#include "core/usd_values.h"
#include "pxr/imaging/hd/light.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdSceneDelegate;

// The record core reads a light from (core/usd_lights.h): the attributes it asks for by
// Hydra's names (without "inputs:"), its light-link collections and transform. typeName:
// USD's (a sprim's type capitalised; "Mesh" or an implicit surface's for MeshLightAPI).
granular::UsdPrimRecord HdGranularLightRecord(HdSceneDelegate* delegate, SdfPath const& id,
                                              std::string const& typeName);

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
