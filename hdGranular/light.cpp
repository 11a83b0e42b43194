#include "light.h"

#include <cctype>

#include "core/error.h"
#include "core/usd_lights.h"
#include "pxr/imaging/hd/sceneDelegate.h"
#include "pxr/imaging/hd/tokens.h"
#include "renderParam.h"
#include "usdValue.h"

PXR_NAMESPACE_OPEN_SCOPE

HdGranularLight::HdGranularLight(SdfPath const& id, TfToken const& type) : HdLight(id), _type(type) {}

void HdGranularLight::Sync(HdSceneDelegate* delegate, HdRenderParam* renderParam, HdDirtyBits* dirtyBits) {
  auto* store = static_cast<HdGranularRenderParam*>(renderParam);
  const SdfPath& id = GetId();
  *dirtyBits = Clean;
  if (id.IsEmpty()) return;  // a fallback prim
  // A light described by a GlfSimpleLight ("params") is the host's viewer light (usdview's
  // and usdrecord's camera light), not the scene's: a path tracer renders UsdLux lights only.
  if (!delegate->GetVisible(id) || !delegate->GetLightParamValue(id, HdLightTokens->params).IsEmpty()) {
    store->Remove(id);
    return;
  }
  // The light as core reads it: USD's type name is Hydra's sprim type, capitalised.
  std::string typeName = _type.GetString();
  if (!typeName.empty()) typeName[0] = char(std::toupper(typeName[0]));
  const granular::UsdPrimRecord record = HdGranularLightRecord(delegate, id, typeName);
  try {
    granular::UsdWarnings warnings;
    std::optional<granular::LightDesc> light = granular::lightFromUsd(record, warnings);
    store->Warn(warnings);
    if (light) store->SetLight(id, std::move(*light));
    else store->Remove(id);
  } catch (granular::InputError const& e) {
    store->SetError(id, e);  // the render pass reports it, as granular render does
  }
}

granular::UsdPrimRecord HdGranularLightRecord(HdSceneDelegate* delegate, SdfPath const& id,
                                              std::string const& typeName) {
  granular::UsdPrimRecord record;
  record.path = id.GetString();
  record.typeName = typeName;
  for (std::string const& name : granular::usdLightAttributeNames()) {
    const std::string hydraName = name.rfind("inputs:", 0) == 0 ? name.substr(7) : name;
    if (auto v = HdGranularUsdValue(delegate->GetLightParamValue(id, TfToken(hydraName))))
      record.attributes[name] = *v;
  }
  // Light linking: UsdImaging names a collection that does not hold every prim (its
  // collection cache's id; empty: every prim), as the categories of the prims it includes.
  for (auto const& [hydraName, name] : {std::pair{HdTokens->lightLink, granular::kUsdLightLink},
                                        std::pair{HdTokens->shadowLink, granular::kUsdShadowLink}}) {
    const VtValue link = delegate->GetLightParamValue(id, hydraName);
    if (link.IsHolding<TfToken>() && !link.UncheckedGet<TfToken>().IsEmpty())
      if (auto v = HdGranularUsdValue(link)) record.attributes[name] = *v;
  }
  record.xf = HdGranularToCore(delegate->GetTransform(id));
  return record;
}

void HdGranularLight::Finalize(HdRenderParam* renderParam) {
  static_cast<HdGranularRenderParam*>(renderParam)->Remove(GetId());
}

PXR_NAMESPACE_CLOSE_SCOPE
