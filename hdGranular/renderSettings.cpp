#include "renderSettings.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>

#include "pxr/base/tf/diagnostic.h"
#include "pxr/base/tf/getenv.h"
#include "pxr/imaging/hd/dataSource.h"
#include "pxr/imaging/hd/dataSourceTypeDefs.h"
#include "pxr/imaging/hd/renderIndex.h"
#include "pxr/imaging/hd/sceneDelegate.h"
#include "pxr/imaging/hd/sceneIndex.h"
#include "pxr/imaging/hd/tokens.h"
#include "pxr/imaging/hd/utils.h"
#include "renderParam.h"
#include "renderProducts.h"

PXR_NAMESPACE_OPEN_SCOPE

HdGranularRenderSettings::~HdGranularRenderSettings() {
  if (_renderer) HdGranularClearRenderProducts(_renderer, GetId());
}

void HdGranularRenderSettings::_Sync(HdSceneDelegate*, HdRenderParam* renderParam, const HdDirtyBits*) {
  if (TfGetenvBool("GRANULAR_HD_DEBUG", false))
    fprintf(stderr, "hdGranular: render settings %s: active %d, %zu products\n", GetId().GetText(), int(IsActive()),
            GetRenderProducts().size());
  if (!_renderer) return;
  std::vector<granular::RenderProductDesc> products;
  granular::UsdWarnings warnings;
  std::string error;
  try {
    for (RenderProduct const& p : GetRenderProducts())
      if (auto desc = HdGranularProductDesc(p, warnings)) products.push_back(std::move(*desc));
  } catch (granular::InputError const& e) {
    // Said when this prim is the active one (a render of it is then refused).
    error = e.what();
    products.clear();
  }
  if (auto* param = dynamic_cast<HdGranularRenderParam*>(renderParam)) param->Warn(warnings);
  HdGranularSetRenderProducts(_renderer, GetId(), std::move(products), error);
}

granular::PixelWindow HdGranularDataWindow(HdRenderIndex* index, int width, int height,
                                           granular::UsdWarnings& warnings) {
  const granular::PixelWindow whole{0, width, 0, height};
  SdfPath active;  // the scene globals' choice: the host's, else the stage's renderSettingsPrimPath
  if (!index->IsBprimTypeSupported(HdPrimTypeTokens->renderSettings)) return whole;
  if (!HdUtils::HasActiveRenderSettingsPrim(index->GetTerminalSceneIndex(), &active)) active = SdfPath();
  // Which products the render loop writes when it converges, and for which frame (the
  // fallback prim knows the loop; the default time, a huge negative number, is no frame).
  if (auto* fallback = dynamic_cast<HdGranularRenderSettings*>(index->GetFallbackBprim(HdPrimTypeTokens->renderSettings))) {
    double frame = NAN;
    if (!HdUtils::GetCurrentFrame(index->GetTerminalSceneIndex(), &frame) || !(std::fabs(frame) < 1e15)) frame = NAN;
    if (fallback->_renderer) HdGranularActivateRenderProducts(fallback->_renderer, active, frame);
  }
  if (active.IsEmpty()) return whole;
  auto* rs = dynamic_cast<HdRenderSettings*>(index->GetBprim(HdPrimTypeTokens->renderSettings, active));
  if (!rs || rs->GetRenderProducts().empty()) return whole;
  // Hydra hands each product's value, merged with the settings prim's (UsdRender); core
  // checks it and decides (core/usd_render.h), as for granular render.
  std::optional<granular::PixelWindow> all;
  for (HdRenderSettings::RenderProduct const& product : rs->GetRenderProducts()) {
    const GfRange2f& ndc = product.dataWindowNDC;
    granular::PixelWindow w = whole;
    if (ndc != GfRange2f()) {  // GfRange2f() (min > max): nothing authored or flattened
      granular::UsdPrimRecord record;
      record.path = product.productPath.GetString();
      record.typeName = "RenderProduct";
      granular::UsdValue v;
      v.typeName = "float4";
      v.numbers = {ndc.GetMin()[0], ndc.GetMin()[1], ndc.GetMax()[0], ndc.GetMax()[1]};
      record.attributes["dataWindowNDC"] = v;
      w = granular::dataWindowFromUsd(nullptr, &record, width, height, warnings).value_or(whole);
    }
    if (!all) all = w;
    else
      all = granular::PixelWindow{std::min(all->x0, w.x0), std::max(all->x1, w.x1), std::min(all->y0, w.y0),
                                  std::max(all->y1, w.y1)};
  }
  return all.value_or(whole);
}

namespace {

// The scene-index UsdImaging keeps, beside what it flattens for Hydra, each settings prim's
// and product's own UsdRender attributes (a product's only where authored; UsdImaging's
// dataSourceRenderPrims.cpp): disableMotionBlur and instantaneousShutter, which
// HdRenderSettings drops, resolved there as granular render resolves them
// (usd_reader._motion_blur_disabled, after UsdRenderComputeSpec). Nothing (the legacy
// UsdImagingDelegate, another host): no such data.
std::optional<bool> usdImagingMotionBlurDisabled(HdSceneIndexBaseRefPtr const& si, SdfPath const& settings) {
  static const TfToken settingsKey("__usdRenderSettings"), productKey("__usdRenderProduct"),
      products("products"), disableMotionBlur("disableMotionBlur"), instantaneousShutter("instantaneousShutter");
  auto attributes = [&](SdfPath const& path, TfToken const& key) -> HdContainerDataSourceHandle {
    HdSceneIndexPrim prim = si->GetPrim(path);
    return prim.dataSource ? HdContainerDataSource::Cast(prim.dataSource->Get(key)) : nullptr;
  };
  auto flag = [](HdContainerDataSourceHandle const& c, TfToken const& name) -> std::optional<bool> {
    if (HdBoolDataSourceHandle b = HdBoolDataSource::Cast(c->Get(name))) return b->GetTypedValue(0);
    return std::nullopt;
  };
  HdContainerDataSourceHandle own = attributes(settings, settingsKey);
  if (!own) return std::nullopt;
  bool disabled = flag(own, disableMotionBlur).value_or(false) || flag(own, instantaneousShutter).value_or(false);
  if (HdPathArrayDataSourceHandle targets = HdPathArrayDataSource::Cast(own->Get(products)))
    for (SdfPath const& target : targets->GetTypedValue(0))
      if (HdContainerDataSourceHandle product = attributes(target, productKey)) {  // the first product
        disabled = flag(product, disableMotionBlur).value_or(disabled) ||
                   flag(product, instantaneousShutter).value_or(false);
        break;
      }
  return disabled;
}

}  // namespace

bool HdGranularMotionBlurDisabled(HdRenderIndex* index) {
  SdfPath active;
  if (!index->IsBprimTypeSupported(HdPrimTypeTokens->renderSettings) ||
      !HdUtils::HasActiveRenderSettingsPrim(index->GetTerminalSceneIndex(), &active) || active.IsEmpty())
    return false;
  if (std::optional<bool> d = usdImagingMotionBlurDisabled(index->GetTerminalSceneIndex(), active)) return *d;
  auto* rs = dynamic_cast<HdRenderSettings*>(index->GetBprim(HdPrimTypeTokens->renderSettings, active));
  return rs && !rs->GetRenderProducts().empty() && rs->GetRenderProducts().front().disableMotionBlur;
}

PXR_NAMESPACE_CLOSE_SCOPE
