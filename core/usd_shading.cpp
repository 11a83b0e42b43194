// usd_shading.cpp — the UsdPreviewSurface rule and UsdUVTexture networks (usd_shading.h).
#include "usd_shading.h"

#include <cmath>
#include <set>

#include "error.h"

namespace granular {

namespace {

const char* const kPreviewSurface = "UsdPreviewSurface";
const char* const kUvTexture = "UsdUVTexture";
const char* const kPrimvarReader = "UsdPrimvarReader_float2";
const char* const kTransform2d = "UsdTransform2d";

class Network {
 public:
  Network(const UsdMaterialNetwork& n, UsdWarnings& w) : warnings_(w) {
    for (const UsdShaderRecord& s : n.shaders) byPath_[s.path] = &s;
  }

  const UsdShaderRecord* shader(const std::string& path) const {
    auto it = byPath_.find(path);
    return it == byPath_.end() ? nullptr : it->second;
  }

  // The shader feeding `s`'s input (full name) and the output it comes from; null if none.
  const UsdShaderRecord* upstream(const UsdShaderRecord& s, const std::string& input, std::string* output) const {
    auto it = s.connections.find(input);
    if (it == s.connections.end()) return nullptr;
    *output = it->second.second;
    return shader(it->second.first);
  }

  void warn(std::string message) {
    for (const std::string& w : warnings_)
      if (w == message) return;
    warnings_.push_back(std::move(message));
  }

  // The primvar a texture's st reads, following UsdTransform2d's `in`; "" when none.
  std::string textureSt(const UsdShaderRecord& tex, const std::string& input, std::set<std::string> seen) {
    std::string output;
    const UsdShaderRecord* reader = upstream(tex, input, &output);
    if (!reader) {
      warn(str(tex.path, ".", input, ": not connected to a ", kPrimvarReader, "; the texture reads st (0, 0) everywhere"));
      return "";
    }
    if (reader->typeName == kTransform2d) {
      if (!seen.insert(reader->path).second)
        throw InputError(reader->path, "inputs:in", "is connected in a cycle (to its own output)");
      warn(str(reader->path, ": ", kTransform2d, " is not supported; st is read untransformed"));
      return textureSt(*reader, "inputs:in", seen);
    }
    if (reader->typeName != kPrimvarReader) {
      warn(str(tex.path, ".inputs:st: '", reader->typeName, "' is not supported (only ", kPrimvarReader,
               "); the texture reads st (0, 0) everywhere"));
      return "";
    }
    const std::string name = usdToken(*reader, "inputs:varname", "");
    if (name.empty()) throw InputError(reader->path, "inputs:varname", "names no primvar");
    return name;
  }

  // The UsdUVTexture feeding the surface's input, or a disabled TextureDesc; *st gets the
  // primvar its st reads.
  TextureDesc texture(const UsdShaderRecord& surface, const std::string& input, bool colour, std::string* st) {
    TextureDesc t;
    std::string output;
    const UsdShaderRecord* tex = upstream(surface, input, &output);
    if (!tex) return t;
    if (tex->typeName != kUvTexture) {
      warn(str(surface.path, ".", input, ": connected to '", tex->typeName, "', which is not supported (only ",
               kUvTexture, "); using the input's own value"));
      return t;
    }
    t.source = tex->path;
    const std::string authored = usdAsset(*tex, "inputs:file").first;
    if (authored.empty()) throw InputError(tex->path, "inputs:file", "names no image");
    if (authored.find("<UDIM>") != std::string::npos)
      throw InputError(tex->path, "inputs:file", str("\"", authored, "\": UDIM textures are not supported"));
    t.file = usdFile(*tex, "inputs:file");
    t.wrapS = textureWrapFromName(usdToken(*tex, "inputs:wrapS", "useMetadata"), tex->path, "inputs:wrapS");
    t.wrapT = textureWrapFromName(usdToken(*tex, "inputs:wrapT", "useMetadata"), tex->path, "inputs:wrapT");
    const std::vector<float> scale = usdFloats(*tex, "inputs:scale", {1, 1, 1, 1});
    const std::vector<float> bias = usdFloats(*tex, "inputs:bias", {0, 0, 0, 0});
    for (int c = 0; c < 4; ++c) {
      if (!std::isfinite(scale[c])) throw InputError(tex->path, "inputs:scale", "is not finite");
      if (!std::isfinite(bias[c])) throw InputError(tex->path, "inputs:bias", "is not finite");
      t.scale[c] = scale[c];
      t.bias[c] = bias[c];
    }
    t.colorSpace = textureColorSpaceFromName(usdToken(*tex, "inputs:sourceColorSpace", "auto"), tex->path,
                                             "inputs:sourceColorSpace");
    t.channel = textureChannelFromName(output, tex->path, "outputs:" + output);
    if (!colour && t.channel < 0) {
      warn(str(surface.path, ".", input, ": connected to ", tex->path, ".outputs:rgb; its r channel is used"));
      t.channel = 0;
    }
    const std::string name = textureSt(*tex, "inputs:st", {});
    if (!name.empty()) {
      if (!st->empty() && *st != name)
        warn(str(surface.path, ": textures read different primvars ('", *st, "', '", name, "'); '", *st, "' is used"));
      if (st->empty()) *st = name;
    }
    return t;
  }

 private:
  UsdWarnings& warnings_;
  std::map<std::string, const UsdShaderRecord*> byPath_;
};

// A MaterialDesc field's USD input, for core's checks in USD's names.
std::string previewInput(const std::string& field) {
  if (field == "albedo") return "inputs:diffuseColor";
  if (field == "emission") return "inputs:emissiveColor";
  if (field.empty() || field.rfind("inputs:", 0) == 0) return field;
  return "inputs:" + field;
}

}  // namespace

std::optional<UsdMaterial> materialFromUsd(const UsdMaterialNetwork& n, UsdWarnings& warnings) {
  Network net(n, warnings);
  const UsdShaderRecord* s = n.surface.empty() ? nullptr : net.shader(n.surface);
  if (!s) {
    net.warn(str(n.material, ": no surface shader; using the default material"));
    return std::nullopt;
  }
  if (s->typeName != kPreviewSurface) {
    net.warn(str(s->path, ": shader '", s->typeName, "' is not supported (only ", kPreviewSurface,
                 "); using the default material"));
    return std::nullopt;
  }
  static const char* const kTextured[] = {"inputs:diffuseColor", "inputs:emissiveColor", "inputs:opacity"};
  for (const auto& [input, source] : s->connections) {
    bool textured = false;
    for (const char* t : kTextured) textured |= input == t;
    if (!textured)
      net.warn(str(s->path, ".", input, ": connections are not supported; using its own value or the fallback"));
  }
  const Vec3 diffuse = usdColor(*s, "inputs:diffuseColor", Vec3(0.18f));
  const Vec3 emissive = usdColor(*s, "inputs:emissiveColor", Vec3(0.0f));
  const float opacity = usdFloat(*s, "inputs:opacity", 1.0f);
  const float threshold = usdFloat(*s, "inputs:opacityThreshold", 0.0f);
  const float ior = usdFloat(*s, "inputs:ior", 1.5f);
  if (!(opacity >= 0 && opacity <= 1)) throw InputError(s->path, "inputs:opacity", str(opacity, " is outside [0, 1]"));
  if (!(threshold >= 0 && threshold <= 1))
    throw InputError(s->path, "inputs:opacityThreshold", str(threshold, " is outside [0, 1]"));

  UsdMaterial out;
  MaterialDesc& m = out.desc;
  m.name = s->path;
  std::string st;
  const TextureDesc albedoTex = net.texture(*s, "inputs:diffuseColor", true, &st);
  const TextureDesc emissionTex = net.texture(*s, "inputs:emissiveColor", true, &st);
  const TextureDesc opacityTex = net.texture(*s, "inputs:opacity", false, &st);
  if (opacity < 1 && threshold == 0 && !opacityTex.enabled()) {
    m.type = MaterialType::Dielectric;
    m.ior = ior;
    if (albedoTex.enabled())
      net.warn(str(s->path, ".inputs:diffuseColor: a texture on a transparent (glass) material is ignored"));
    if (emissionTex.enabled())
      net.warn(str(s->path, ".inputs:emissiveColor: a texture on a transparent (glass) material is ignored"));
    st.clear();
  } else {
    m.type = MaterialType::Lambert;
    m.albedo = diffuse;
    m.emission = emissive;
    m.opacity = opacity;
    m.opacityThreshold = threshold;
    m.albedoTexture = albedoTex;
    m.emissionTexture = emissionTex;
    m.opacityTexture = opacityTex;
  }
  out.st = st;
  checkInUsdNames(s->path, [&] { validateMaterialDesc(m, s->path); }, previewInput);
  return out;
}

std::optional<Vec3> displayColorFromUsd(const UsdValue& v, const UsdMeshRecord* mesh, const std::string& prim,
                                        UsdWarnings& warnings) {
  const std::string& where = v.source.empty() ? prim : v.source;
  if (v.isString || v.numbers.size() % 3 != 0)
    throw InputError(where, "primvars:displayColor",
                     str("has value ", describeUsdValueShort(v), " of type ", v.typeName, ", expected color3f[]"));
  if (v.numbers.empty()) return std::nullopt;
  if (mesh && v.interpolation != "constant") {
    const size_t expected = usdPrimvarElements(*mesh, v.interpolation), found = v.numbers.size() / 3;
    if (found != expected) {
      warnings.push_back(str(where, ".primvars:displayColor: has ", found, " values; ", v.interpolation,
                             " interpolation needs ", expected, "; ignored"));
      return std::nullopt;
    }
  }
  double sum[3] = {0, 0, 0};
  for (size_t i = 0; i < v.numbers.size(); ++i) sum[i % 3] += v.numbers[i];
  const double n = double(v.numbers.size() / 3);
  const Vec3 c(float(sum[0] / n), float(sum[1] / n), float(sum[2] / n));
  for (float x : {c.x, c.y, c.z})
    if (!(x >= 0 && x <= 1))
      throw InputError(where, "primvars:displayColor", str("(", c.x, ", ", c.y, ", ", c.z, ") is outside [0, 1]"));
  return c;
}

}  // namespace granular
