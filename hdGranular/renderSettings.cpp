#include "renderSettings.h"

#include "pxr/imaging/hd/renderIndex.h"
#include "pxr/imaging/hd/sceneIndex.h"
#include "pxr/imaging/hd/tokens.h"
#include "pxr/imaging/hd/utils.h"

PXR_NAMESPACE_OPEN_SCOPE

granular::PixelWindow HdGranularDataWindow(HdRenderIndex* index, int width, int height) {
  const granular::PixelWindow whole{0, width, 0, height};
  SdfPath active;  // the scene globals' choice: the host's, else the stage's renderSettingsPrimPath
  if (!index->IsBprimTypeSupported(HdPrimTypeTokens->renderSettings) ||
      !HdUtils::HasActiveRenderSettingsPrim(index->GetTerminalSceneIndex(), &active))
    return whole;
  auto* rs = dynamic_cast<HdRenderSettings*>(index->GetBprim(HdPrimTypeTokens->renderSettings, active));
  if (!rs || rs->GetRenderProducts().empty()) return whole;
  // Products carry the settings prim's value unless they author their own (UsdRender).
  const GfRange2f& ndc = rs->GetRenderProducts().front().dataWindowNDC;
  if (ndc.IsEmpty()) return whole;
  const granular::PixelWindow w =
      granular::pixelWindowFromNdc(ndc.GetMin()[0], ndc.GetMin()[1], ndc.GetMax()[0], ndc.GetMax()[1], width, height);
  return w.width() > 0 && w.height() > 0 ? w : whole;
}

PXR_NAMESPACE_CLOSE_SCOPE
