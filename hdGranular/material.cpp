#include "material.h"

#include "core/error.h"
#include "core/usd_shading.h"
#include "pxr/imaging/hd/material.h"
#include "pxr/imaging/hd/sceneDelegate.h"
#include "renderParam.h"
#include "usdValue.h"

PXR_NAMESPACE_OPEN_SCOPE

namespace {

// The surface network as core reads it (core/usd_shading.h): every node with its
// parameters as "inputs:<name>" and the relationships as connections.
granular::UsdMaterialNetwork toCore(SdfPath const& id, HdMaterialNetworkMap const& map) {
  granular::UsdMaterialNetwork out;
  out.material = id.GetString();
  auto it = map.map.find(HdMaterialTerminalTokens->surface);
  if (it == map.map.end() || it->second.nodes.empty()) return out;
  HdMaterialNetwork const& net = it->second;
  out.surface = net.nodes.back().path.GetString();  // Hydra lists the terminal's node last
  for (SdfPath const& terminal : map.terminals)
    for (HdMaterialNode const& n : net.nodes)
      if (n.path == terminal) out.surface = terminal.GetString();
  for (HdMaterialNode const& n : net.nodes) {
    granular::UsdShaderRecord s;
    s.path = n.path.GetString();
    s.typeName = n.identifier.GetString();
    for (auto const& [name, value] : n.parameters)
      if (auto v = HdGranularUsdValue(value)) s.attributes["inputs:" + name.GetString()] = *v;
    for (HdMaterialRelationship const& r : net.relationships)
      if (r.outputId == n.path)
        s.connections["inputs:" + r.outputName.GetString()] = {r.inputId.GetString(), r.inputName.GetString()};
    out.shaders.push_back(std::move(s));
  }
  return out;
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
  try {
    granular::UsdWarnings warnings;
    std::optional<granular::UsdMaterial> m =
        granular::materialFromUsd(toCore(id, resource.UncheckedGet<HdMaterialNetworkMap>()), warnings);
    store->Warn(warnings);
    if (m) store->SetMaterial(id, std::move(m->desc), m->st);
    else store->SetMaterial(id, std::nullopt);
  } catch (granular::InputError const& e) {
    store->SetError(id, e);
  }
}

void HdGranularMaterial::Finalize(HdRenderParam* renderParam) {
  static_cast<HdGranularRenderParam*>(renderParam)->Remove(GetId());
}

PXR_NAMESPACE_CLOSE_SCOPE
