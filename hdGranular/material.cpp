#include "material.h"

#include "core/error.h"
#include "pxr/base/gf/vec3f.h"
#include "pxr/base/gf/vec4f.h"
#include "pxr/imaging/hd/sceneDelegate.h"
#include "pxr/usd/sdf/assetPath.h"
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

// A token or string parameter as text.
std::string text(HdMaterialNode const& node, const char* name, std::string const& fallback) {
  auto it = node.parameters.find(TfToken(name));
  if (it == node.parameters.end()) return fallback;
  if (it->second.IsHolding<TfToken>()) return it->second.UncheckedGet<TfToken>().GetString();
  if (it->second.IsHolding<std::string>()) return it->second.UncheckedGet<std::string>();
  return fallback;
}

// The node that feeds `node`'s input `name`, and the name of its output; nullptr if none.
HdMaterialNode const* upstream(HdMaterialNetwork const& net, HdMaterialNode const& node, const char* name,
                               TfToken* output) {
  for (HdMaterialRelationship const& r : net.relationships)
    if (r.outputId == node.path && r.outputName == TfToken(name))
      for (HdMaterialNode const& n : net.nodes)
        if (n.path == r.inputId) {
          *output = r.inputName;
          return &n;
        }
  return nullptr;
}

// A UsdUVTexture token in core's terms (granular::texture*FromName, as every front end
// reads it); an unknown one is warned about and the fallback used.
template <typename T, typename Parse>
T token(HdMaterialNode const& node, const char* name, const char* fallback, T fallbackValue, Parse parse) {
  try {
    return parse(text(node, name, fallback), node.path.GetString(), std::string("inputs:") + name);
  } catch (const granular::InputError& e) {
    TF_WARN("%s; %s is used", e.what(), fallback);
    return fallbackValue;
  }
}

// The UsdUVTexture feeding preview's input `name` as a TextureDesc (and the primvar its st
// reads into *st), or a disabled one when none feeds it.
granular::TextureDesc texture(HdMaterialNetwork const& net, HdMaterialNode const& preview, const char* name,
                              bool colour, std::string* st) {
  granular::TextureDesc t;
  TfToken output;
  HdMaterialNode const* tex = upstream(net, preview, name, &output);
  if (!tex) return t;
  if (tex->identifier != TfToken("UsdUVTexture")) {
    TF_WARN("%s.inputs:%s: connected to %s, which is not supported (only UsdUVTexture)", preview.path.GetText(), name,
            tex->identifier.GetText());
    return t;
  }
  t.source = tex->path.GetString();
  auto file = tex->parameters.find(TfToken("file"));
  if (file != tex->parameters.end() && file->second.IsHolding<SdfAssetPath>()) {
    SdfAssetPath const& a = file->second.UncheckedGet<SdfAssetPath>();
    t.file = a.GetResolvedPath().empty() ? a.GetAssetPath() : a.GetResolvedPath();  // unresolved: core names it
  } else if (file != tex->parameters.end() && file->second.IsHolding<std::string>()) {
    t.file = file->second.UncheckedGet<std::string>();
  }
  if (t.file.empty()) t.file = "(no file)";  // core refuses it, naming the shader's inputs:file
  t.wrapS = token(*tex, "wrapS", "useMetadata", granular::TextureWrap::UseMetadata, granular::textureWrapFromName);
  t.wrapT = token(*tex, "wrapT", "useMetadata", granular::TextureWrap::UseMetadata, granular::textureWrapFromName);
  GfVec4f scale = input<GfVec4f>(*tex, "scale", GfVec4f(1.0f)), bias = input<GfVec4f>(*tex, "bias", GfVec4f(0.0f));
  for (int c = 0; c < 4; ++c) t.scale[c] = scale[c], t.bias[c] = bias[c];
  t.colorSpace =
      token(*tex, "sourceColorSpace", "auto", granular::TextureColorSpace::Auto, granular::textureColorSpaceFromName);
  try {
    t.channel = granular::textureChannelFromName(output.GetString(), t.source, "outputs:" + output.GetString());
  } catch (const granular::InputError& e) {
    TF_WARN("%s; rgb is used", e.what());
    t.channel = -1;
  }
  if (!colour && t.channel < 0) t.channel = 0;  // a float input reads r, as usd_reader.py
  TfToken readerOutput;
  HdMaterialNode const* reader = upstream(net, *tex, "st", &readerOutput);
  if (reader && reader->identifier == TfToken("UsdTransform2d")) {
    TF_WARN("%s: UsdTransform2d is not supported; st is read untransformed", reader->path.GetText());
    reader = upstream(net, *reader, "in", &readerOutput);
  }
  if (reader && reader->identifier == TfToken("UsdPrimvarReader_float2") && st->empty())
    *st = text(*reader, "varname", "");
  return t;
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
      float threshold = input<float>(node, "opacityThreshold", 0.0f);
      std::string st;
      granular::TextureDesc albedoTex = texture(network, node, "diffuseColor", true, &st);
      granular::TextureDesc emissionTex = texture(network, node, "emissiveColor", true, &st);
      granular::TextureDesc opacityTex = texture(network, node, "opacity", false, &st);
      if (opacity < 1.0f && threshold == 0.0f && !opacityTex.enabled()) {
        // An untextured opacity without a threshold is glass.
        m.type = granular::MaterialType::Dielectric;
        m.ior = input<float>(node, "ior", 1.5f);
        st.clear();
      } else {
        // Lambert; a textured opacity or a threshold makes a cut-out.
        m.albedo = granular::Vec3(diffuse[0], diffuse[1], diffuse[2]);
        m.emission = granular::Vec3(emissive[0], emissive[1], emissive[2]);
        m.opacity = opacity;
        m.opacityThreshold = threshold;
        m.albedoTexture = albedoTex;
        m.emissionTexture = emissionTex;
        m.opacityTexture = opacityTex;
      }
      store->SetMaterial(id, std::move(m), st);
      return;
    }
  }
  store->Remove(id);  // no UsdPreviewSurface: meshes fall back to their display colour
}

void HdGranularMaterial::Finalize(HdRenderParam* renderParam) {
  static_cast<HdGranularRenderParam*>(renderParam)->Remove(GetId());
}

PXR_NAMESPACE_CLOSE_SCOPE
