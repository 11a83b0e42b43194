#include "light.h"

#include "pxr/base/gf/vec3f.h"
#include "pxr/imaging/hd/sceneDelegate.h"
#include "pxr/imaging/hd/tokens.h"
#include "pxr/usd/sdf/assetPath.h"
#include "pxr/usd/usdLux/blackbody.h"
#include "renderParam.h"

PXR_NAMESPACE_OPEN_SCOPE

namespace {

template <typename T>
T param(HdSceneDelegate* d, SdfPath const& id, TfToken const& name, T fallback) {
  VtValue v = d->GetLightParamValue(id, name);
  if (v.IsHolding<T>()) return v.UncheckedGet<T>();
  if (v.CanCast<T>()) return v.Cast<T>().template UncheckedGet<T>();
  return fallback;
}

}  // namespace

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
  granular::LightDesc l;
  l.name = id.GetString();
  if (_type == HdPrimTypeTokens->distantLight) {
    l.type = granular::LightType::Distant;
    l.angle = param<float>(delegate, id, HdLightTokens->angle, 0.53f);
  } else if (_type == HdPrimTypeTokens->domeLight) {
    l.type = granular::LightType::Dome;
    SdfAssetPath tex = param<SdfAssetPath>(delegate, id, HdLightTokens->textureFile, SdfAssetPath());
    l.textureFile = tex.GetResolvedPath().empty() ? tex.GetAssetPath() : tex.GetResolvedPath();
  } else if (_type == HdPrimTypeTokens->rectLight) {
    l.type = granular::LightType::Rect;
    l.width = param<float>(delegate, id, HdLightTokens->width, 1.0f);
    l.height = param<float>(delegate, id, HdLightTokens->height, 1.0f);
  } else if (_type == HdPrimTypeTokens->sphereLight) {
    l.type = granular::LightType::Sphere;
    l.radius = param<float>(delegate, id, HdLightTokens->radius, 0.5f);
  } else {
    TF_WARN("hdGranular: %s: %s lights are not supported; skipped", id.GetText(), _type.GetText());
    return;
  }
  l.intensity = param<float>(delegate, id, HdLightTokens->intensity, 1.0f);
  l.exposure = param<float>(delegate, id, HdLightTokens->exposure, 0.0f);
  GfVec3f c = param<GfVec3f>(delegate, id, HdLightTokens->color, GfVec3f(1.0f));
  if (param<bool>(delegate, id, HdLightTokens->enableColorTemperature, false))
    c = GfCompMult(c, UsdLuxBlackbodyTemperatureAsRgb(param<float>(delegate, id, HdLightTokens->colorTemperature, 6500.0f)));
  l.color = granular::Vec3(c[0], c[1], c[2]);
  l.normalize = param<bool>(delegate, id, HdLightTokens->normalize, false);
  l.xf = HdGranularToCore(delegate->GetTransform(id));
  store->SetLight(id, std::move(l));
}

void HdGranularLight::Finalize(HdRenderParam* renderParam) {
  static_cast<HdGranularRenderParam*>(renderParam)->Remove(GetId());
}

PXR_NAMESPACE_CLOSE_SCOPE
