#include "renderSettings.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "pxr/base/tf/diagnostic.h"
#include "pxr/base/tf/getenv.h"
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

bool HdGranularMotionBlurDisabled(HdRenderIndex* index) {
  SdfPath active;
  if (!index->IsBprimTypeSupported(HdPrimTypeTokens->renderSettings) ||
      !HdUtils::HasActiveRenderSettingsPrim(index->GetTerminalSceneIndex(), &active) || active.IsEmpty())
    return false;
  auto* rs = dynamic_cast<HdRenderSettings*>(index->GetBprim(HdPrimTypeTokens->renderSettings, active));
  return rs && !rs->GetRenderProducts().empty() && rs->GetRenderProducts().front().disableMotionBlur;
}

PXR_NAMESPACE_CLOSE_SCOPE
