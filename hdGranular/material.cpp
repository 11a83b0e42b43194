#include "material.h"

#include "pxr/base/gf/vec3f.h"
#include "pxr/imaging/hd/sceneDelegate.h"
#include "renderParam.h"

PXR_NAMESPACE_OPEN_SCOPE

namespace {

template <typename T>
T input(HdMaterialNode const& node, const char* name, T fallback) {
  auto it = node.parameters.find(TfToken(name));
  if (it == node.parameters.end()) return fallback;
  if (it->second.IsHolding<T>()) return it->second.UncheckedGet<T>();
  if (it->second.CanCast<T>()) return VtValue::Cast<T>(it->second).template UncheckedGet<T>();
  return fallback;
}

}  // namespace

void HdGranularMaterial::Sync(HdSceneDelegate* delegate, HdRenderParam* renderParam, HdDirtyBits* dirtyBits) {
  auto* store = static_cast<HdGranularRenderParam*>(renderParam);
  const SdfPath& id = GetId();
  *dirtyBits = Clean;
  if (id.IsEmpty()) return;
  VtValue resource = delegate->GetMaterialResource(id);
  if (!resource.IsHolding<HdMaterialNetworkMap>()) {
    store->Remove(id);
    return;
  }
  for (auto const& [terminal, network] : resource.UncheckedGet<HdMaterialNetworkMap>().map) {
    for (HdMaterialNode const& node : network.nodes) {
      if (node.identifier != TfToken("UsdPreviewSurface")) continue;
      granular::MaterialDesc m;
      m.name = id.GetString();
      GfVec3f diffuse = input<GfVec3f>(node, "diffuseColor", GfVec3f(0.18f));
      GfVec3f emissive = input<GfVec3f>(node, "emissiveColor", GfVec3f(0.0f));
      float opacity = input<float>(node, "opacity", 1.0f);
      if (opacity < 1.0f) {
        m.type = granular::MaterialType::Dielectric;
        m.ior = input<float>(node, "ior", 1.5f);
      } else {
        m.albedo = granular::Vec3(diffuse[0], diffuse[1], diffuse[2]);
        m.emission = granular::Vec3(emissive[0], emissive[1], emissive[2]);  // Lambert only, as usd_reader.py
      }
      store->SetMaterial(id, std::move(m));
      return;
    }
  }
  store->Remove(id);  // no UsdPreviewSurface: meshes fall back to their display colour
}

void HdGranularMaterial::Finalize(HdRenderParam* renderParam) {
  static_cast<HdGranularRenderParam*>(renderParam)->Remove(GetId());
}

PXR_NAMESPACE_CLOSE_SCOPE
