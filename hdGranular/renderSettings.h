// renderSettings.h — the stage's UsdRenderSettings as Hydra bprims, so that the delegate
// sees the render products of the active settings prim (the host's choice, else the stage's
// renderSettingsPrimPath); of them it uses the first product's dataWindowNDC, which the
// product inherits from its settings prim unless it authors its own — the crop, as
// `granular render` reads it.
#ifndef HDGRANULAR_RENDER_SETTINGS_H
#define HDGRANULAR_RENDER_SETTINGS_H

#include "pxr/imaging/hd/renderSettings.h"
#include "pxr/pxr.h"
#include "core/scene_desc.h"
#include "core/usd_render.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdRenderIndex;

class HdGranularRenderSettings final : public HdRenderSettings {
 public:
  explicit HdGranularRenderSettings(SdfPath const& id) : HdRenderSettings(id) {}
};

// The pixels of a width × height image that the active render settings prim's first render
// product asks for (its dataWindowNDC, through granular::dataWindowFromUsd); the whole
// image when there is no active prim or no product. granular::InputError, naming the
// product, for a data window core refuses (empty, not finite, covering no pixel).
granular::PixelWindow HdGranularDataWindow(HdRenderIndex* index, int width, int height,
                                           granular::UsdWarnings& warnings);

PXR_NAMESPACE_CLOSE_SCOPE

#endif
