// renderSettings.h — the stage's UsdRenderSettings as Hydra bprims, so that the delegate
// sees the render products of the active settings prim (the host's choice, else the stage's
// renderSettingsPrimPath). Two uses, both with core's meaning (core/usd_render.h,
// core/render_products.h), as `granular render` reads them:
// - the crop: the pixels the products' dataWindowNDCs cover (each product's own, else the
//   settings prim's; Hydra hands them merged), their union when there are several;
// - the products themselves: each prim hands core's descriptions of them to
//   renderProducts.h on every sync; before each render HdGranularDataWindow says which prim
//   is active and the frame (and refuses the render when its products are bad or cannot be
//   written), and the render loop writes them when it converges.
//   Each var is one of the film's outputs, which the delegate also offers as Hydra AOVs
//   (core's RenderSource::hydraAov names the AOV of the same meaning).
#ifndef HDGRANULAR_RENDER_SETTINGS_H
#define HDGRANULAR_RENDER_SETTINGS_H

#include "pxr/imaging/hd/renderSettings.h"
#include "pxr/pxr.h"
#include "core/scene_desc.h"
#include "core/usd_render.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdRenderIndex;
class HdGranularRenderer;
class HdGranularRenderSettings;
granular::PixelWindow HdGranularDataWindow(HdRenderIndex* index, int width, int height,
                                           granular::UsdWarnings& warnings);

class HdGranularRenderSettings final : public HdRenderSettings {
 public:
  // renderer: the loop that writes this prim's products while it is the active one (null:
  // none are written).
  HdGranularRenderSettings(SdfPath const& id, HdGranularRenderer const* renderer = nullptr)
      : HdRenderSettings(id), _renderer(renderer) {}
  ~HdGranularRenderSettings() override;

 protected:
  void _Sync(HdSceneDelegate* sceneDelegate, HdRenderParam* renderParam, const HdDirtyBits* dirtyBits) override;

 private:
  friend granular::PixelWindow HdGranularDataWindow(HdRenderIndex*, int, int, granular::UsdWarnings&);
  HdGranularRenderer const* _renderer;
};

// The pixels of a width × height image that the active render settings prim's render
// products ask for (the union of their dataWindowNDCs, each through
// granular::dataWindowFromUsd); the whole image when there is no active prim or no product.
// granular::InputError, naming the product, for a data window core refuses (empty, not
// finite, covering no pixel), or for products the delegate could not write (a bad var, a
// productName in a missing folder).
granular::PixelWindow HdGranularDataWindow(HdRenderIndex* index, int width, int height,
                                           granular::UsdWarnings& warnings);

// UsdRenderSettings' disableMotionBlur of the active render settings prim, as granular
// render reads it: its first render product's (Hydra flattens the settings prim's value
// into each product); false when there is no active prim or it has no product. OpenUSD
// 24.08's HdRenderSettings shows nothing else: the settings prim's value without a product
// and instantaneousShutter are read only where the scene-index UsdImaging leaves its copies
// of the prims' attributes in the terminal scene index (README.md).
bool HdGranularMotionBlurDisabled(HdRenderIndex* index);

PXR_NAMESPACE_CLOSE_SCOPE

#endif
