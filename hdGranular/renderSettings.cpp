#include "renderSettings.h"

#include "pxr/imaging/hd/renderIndex.h"
#include "pxr/imaging/hd/sceneIndex.h"
#include "pxr/imaging/hd/tokens.h"
#include "pxr/imaging/hd/utils.h"

PXR_NAMESPACE_OPEN_SCOPE

granular::PixelWindow HdGranularDataWindow(HdRenderIndex* index, int width, int height,
                                           granular::UsdWarnings& warnings) {
  const granular::PixelWindow whole{0, width, 0, height};
  SdfPath active;  // the scene globals' choice: the host's, else the stage's renderSettingsPrimPath
  if (!index->IsBprimTypeSupported(HdPrimTypeTokens->renderSettings) ||
      !HdUtils::HasActiveRenderSettingsPrim(index->GetTerminalSceneIndex(), &active))
    return whole;
  auto* rs = dynamic_cast<HdRenderSettings*>(index->GetBprim(HdPrimTypeTokens->renderSettings, active));
  if (!rs || rs->GetRenderProducts().empty()) return whole;
  // Hydra hands the product's value, merged with the settings prim's (UsdRender); core
  // checks it and decides (core/usd_render.h), as for granular render.
  const HdRenderSettings::RenderProduct& product = rs->GetRenderProducts().front();
  const GfRange2f& ndc = product.dataWindowNDC;
  granular::UsdPrimRecord record;
  record.path = product.productPath.GetString();
  record.typeName = "RenderProduct";
  granular::UsdValue v;
  v.typeName = "float4";
  v.numbers = {ndc.GetMin()[0], ndc.GetMin()[1], ndc.GetMax()[0], ndc.GetMax()[1]};
  record.attributes["dataWindowNDC"] = v;
  return granular::dataWindowFromUsd(nullptr, &record, width, height, warnings).value_or(whole);
}

PXR_NAMESPACE_CLOSE_SCOPE
