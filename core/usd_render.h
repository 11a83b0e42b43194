// usd_render.h — UsdRender settings and products on plain records (usd_values.h), for
// both USD front ends: the image size a settings prim asks for and the pixels its render
// product's data window covers.
#pragma once

#include <optional>
#include <utility>

#include "scene_desc.h"
#include "usd_values.h"

namespace granular {

// A RenderSettings prim's `resolution` (int2 in [1, 32768]²), or nothing when unauthored.
std::optional<std::pair<int, int>> resolutionFromUsd(const UsdPrimRecord& settings);

// The pixels of a width × height image that the active settings prim's first render
// product asks for (UsdRender: the product's own dataWindowNDC, else the settings
// prim's; a front end whose host already merged them, Hydra's, hands the product's value
// with `settings` null). `product` null: the settings prim has no product, and a data
// window it authors is ignored with a warning. Nothing when the whole image is rendered.
// InputError on prim.dataWindowNDC when it is not four finite numbers, is empty, or
// covers no pixel; a window reaching outside [0, 1]² is clipped with a warning (no
// overscan).
std::optional<PixelWindow> dataWindowFromUsd(const UsdPrimRecord* settings, const UsdPrimRecord* product, int width,
                                             int height, UsdWarnings& warnings);

}  // namespace granular
