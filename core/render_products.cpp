// render_products.cpp — UsdRender products and vars (render_products.h).
#include "render_products.h"

#include "cryptomatte.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <set>
#include <stdexcept>

#include "error.h"
#include "film.h"
#include "usd_render.h"

namespace granular {

namespace {

std::vector<RenderSource> makeSources() {
  // The film's AOVs (film.h: filmAovs, Cryptomatte layers included), each under its own
  // name and the names pipelines use for it.
  static const std::map<std::string, std::vector<std::string>> kAliases = {
      {"color", {"Ci", "C", "beauty", "rgba"}}, {"cameraDepth", {"depth", "z", "Z"}}, {"normal", {"N", "Nn"}}};
  std::vector<RenderSource> s;
  for (const FilmAov& aov : filmAovs(true)) {
    // Ids and Cryptomatte ranks (hashes as floats) must never be rounded to half.
    const bool ids = aov.value == AovValue::Int || aov.name.rfind("Crypto", 0) == 0;
    const bool optionalAlpha = aov.name == "color";
    s.push_back({aov.name, aov.channels, aov.name, ids, optionalAlpha});
    auto alias = kAliases.find(aov.name);
    if (alias != kAliases.end())
      for (const std::string& name : alias->second) s.push_back({name, aov.channels, aov.name, ids, optionalAlpha});
  }
  // Coverage alone: a channel of the beauty.
  for (const char* name : {"a", "alpha", "A"}) s.push_back({name, {"A"}, "", false, false});
  return s;
}

// LPEs that are one of our outputs: only the whole beauty (every path from the camera).
bool isBeautyLpe(const std::string& lpe) { return lpe == "C.*" || lpe == "C.*L" || lpe == "C.*[LO]"; }

struct DataType {
  const char* name;
  int count;
  ExrPixelType type;
  bool integer;
};

const DataType kDataTypes[] = {
    {"float", 1, ExrPixelType::Float, false},    {"half", 1, ExrPixelType::Half, false},
    {"int", 1, ExrPixelType::UInt, true},        {"uint", 1, ExrPixelType::UInt, true},
    {"float2", 2, ExrPixelType::Float, false},   {"half2", 2, ExrPixelType::Half, false},
    {"int2", 2, ExrPixelType::UInt, true},       {"float3", 3, ExrPixelType::Float, false},
    {"half3", 3, ExrPixelType::Half, false},     {"color3f", 3, ExrPixelType::Float, false},
    {"color3h", 3, ExrPixelType::Half, false},   {"normal3f", 3, ExrPixelType::Float, false},
    {"normal3h", 3, ExrPixelType::Half, false},  {"vector3f", 3, ExrPixelType::Float, false},
    {"vector3h", 3, ExrPixelType::Half, false},  {"point3f", 3, ExrPixelType::Float, false},
    {"point3h", 3, ExrPixelType::Half, false},   {"int3", 3, ExrPixelType::UInt, true},
    {"float4", 4, ExrPixelType::Float, false},   {"half4", 4, ExrPixelType::Half, false},
    {"color4f", 4, ExrPixelType::Float, false},  {"color4h", 4, ExrPixelType::Half, false},
    {"int4", 4, ExrPixelType::UInt, true},
};

const DataType* findDataType(const std::string& name) {
  for (const DataType& d : kDataTypes)
    if (name == d.name) return &d;
  return nullptr;
}

std::string knownSourceNames() {
  std::string out;
  std::set<std::string> seen;
  for (const RenderSource& s : renderSources())
    if (seen.insert(s.name).second) out += (out.empty() ? "" : ", ") + s.name;
  return out;
}

// A string-valued attribute (token or string), or fallback.
std::string usdString(const UsdPrimRecord& r, const std::string& name, const std::string& fallback) {
  auto it = r.attributes.find(name);
  if (it == r.attributes.end()) return fallback;
  if (!it->second.isString || it->second.strings.size() != 1 || it->second.isArray)
    throw InputError(r.path, name, str("has value ", describeUsdValue(it->second), ", expected a string or token"));
  return it->second.strings[0];
}

// The record (product first, then settings) that authors `name`, or null.
const UsdPrimRecord* authoring(const UsdPrimRecord* settings, const UsdPrimRecord& product, const std::string& name) {
  if (product.attributes.count(name)) return &product;
  if (settings && settings->attributes.count(name)) return settings;
  return nullptr;
}

std::string frameText(double frame, int digits) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.6f", std::fabs(frame));
  std::string text = buf;
  text.erase(text.find_last_not_of('0') + 1);
  if (!text.empty() && text.back() == '.') text.pop_back();
  const size_t dot = text.find('.');
  std::string whole = text.substr(0, dot), fraction = dot == std::string::npos ? "" : text.substr(dot);
  if (int(whole.size()) < digits) whole.insert(0, size_t(digits) - whole.size(), '0');
  const bool negative = frame < 0 && text != "0";
  return (negative ? "-" : "") + whole + fraction;
}

}  // namespace

const std::vector<RenderSource>& renderSources() {
  static const std::vector<RenderSource> sources = makeSources();
  return sources;
}

const RenderSource* findRenderSource(const std::string& sourceName, const std::string& sourceType) {
  std::string name = sourceName;
  if (sourceType == "primvar") return nullptr;  // the film holds no primvars
  if (sourceType == "lpe") {
    if (!isBeautyLpe(sourceName)) return nullptr;
    name = "color";
  }
  for (const RenderSource& s : renderSources())
    if (s.name == name) return &s;
  return nullptr;
}

std::vector<std::string> RenderProductDesc::channels() const {
  std::vector<std::string> out;
  for (const RenderVarDesc& v : vars) out.insert(out.end(), v.channels.begin(), v.channels.end());
  return out;
}

bool RenderProductDesc::needsCryptomatte() const {
  CryptomatteType type;
  for (const std::string& c : channels()) {
    const size_t dot = c.rfind('.');
    if (cryptomatteTypeOfLayer(c.substr(0, dot), type)) return true;
  }
  return false;
}

const std::vector<std::string>& usdRenderProductAttributeNames() {
  static const std::vector<std::string> names = {"productName", "productType", "resolution", "dataWindowNDC",
                                                 "pixelAspectRatio", "camera"};
  return names;
}

const std::vector<std::string>& usdRenderVarAttributeNames() {
  static const std::vector<std::string> names = {"sourceName", "sourceType", "dataType"};
  return names;
}

std::optional<RenderVarDesc> renderVarFromUsd(const UsdPrimRecord& r, UsdWarnings& warnings) {
  RenderVarDesc v;
  v.path = r.path;
  v.sourceName = usdString(r, "sourceName", "");
  v.sourceType = usdString(r, "sourceType", "raw");
  v.dataType = usdString(r, "dataType", "color3f");
  static const std::set<std::string> kTypes = {"raw", "primvar", "lpe", "intrinsic"};
  if (!kTypes.count(v.sourceType))
    throw InputError(r.path, "sourceType", str("\"", v.sourceType, "\" is not raw, primvar, lpe or intrinsic"));
  const RenderSource* source = findRenderSource(v.sourceName, v.sourceType);
  if (!source) {
    std::string why = v.sourceType == "primvar" ? "primvars are not among this renderer's outputs"
                      : v.sourceType == "lpe"   ? "the only light path expression rendered is the beauty, C.*"
                                                : "this renderer's outputs are " + knownSourceNames();
    warnings.push_back(str(r.path, ".sourceName: \"", v.sourceName, "\" (", v.sourceType,
                           ") is not an output of this renderer (", why, "); its product is written without it"));
    return std::nullopt;
  }
  const DataType* type = findDataType(v.dataType);
  if (!type) throw InputError(r.path, "dataType", str("\"", v.dataType, "\" is not a data type a render var can have"));
  const int n = int(source->channels.size());
  const bool countFits = type->count == n || (source->optionalAlpha && type->count == n - 1);
  if (!countFits)
    throw InputError(r.path, "dataType",
                     str(v.dataType, " has ", type->count, " channel", type->count == 1 ? "" : "s", ", but ",
                         v.sourceName, " has ", n, source->optionalAlpha ? str(" (or ", n - 1, ")") : "",
                         " (e.g. ", n == 1 ? "float" : n == 3 ? "color3f" : "color4f", ")"));
  if (type->integer && !source->ids)
    throw InputError(r.path, "dataType", str(v.dataType, " holds integers, but ", v.sourceName,
                                             " holds real values (use a float or half type)"));
  if (source->name.rfind("Crypto", 0) == 0 && type->type != ExrPixelType::Float)
    throw InputError(r.path, "dataType", str(v.dataType, ": Cryptomatte ranks are ids and coverages as 32-bit floats "
                                                       "(use color4f or float4)"));
  if (source->ids && type->type == ExrPixelType::Half)
    throw InputError(r.path, "dataType",
                     str(v.dataType, " would round the ids of ", v.sourceName, " (use int, uint or float)"));
  v.channels.assign(source->channels.begin(), source->channels.begin() + type->count);
  v.format = type->type;
  return v;
}

std::optional<RenderProductDesc> renderProductFromUsd(const UsdPrimRecord* settings, const UsdPrimRecord& product,
                                                      const std::vector<UsdPrimRecord>& vars,
                                                      UsdWarnings& warnings) {
  RenderProductDesc p;
  p.path = product.path;
  const std::string type = usdString(product, "productType", "raster");
  if (type != "raster") {
    warnings.push_back(str(product.path, ".productType: \"", type,
                           "\" products are not written (only raster images); skipped"));
    return std::nullopt;
  }
  // Its vars first: a product with nothing to write is skipped whatever else it says.
  std::set<std::string> channels;
  for (const UsdPrimRecord& r : vars) {
    std::optional<RenderVarDesc> v = renderVarFromUsd(r, warnings);
    if (!v) continue;
    bool clash = false;
    for (const std::string& c : v->channels) clash |= channels.count(c) > 0;
    if (clash) {
      warnings.push_back(str(r.path, ".sourceName: \"", v->sourceName, "\" writes channels that an earlier var of ",
                             product.path, " writes; skipped"));
      continue;
    }
    channels.insert(v->channels.begin(), v->channels.end());
    p.vars.push_back(*v);
  }
  if (p.vars.empty()) {
    warnings.push_back(str(product.path, ".orderedVars: ", vars.empty() ? "none" : "no var this renderer writes",
                           "; the product is skipped"));
    return std::nullopt;
  }
  p.productName = usdString(product, "productName", "");
  if (p.productName.empty())
    throw InputError(product.path, "productName", "is empty: name the EXR file to write (e.g. beauty.####.exr)");
  if (const UsdPrimRecord* where = authoring(settings, product, "resolution")) {
    auto res = resolutionFromUsd(*where);
    p.width = res->first;
    p.height = res->second;
  }
  if (const UsdPrimRecord* where = authoring(settings, product, "camera")) p.camera = usdString(*where, "camera", "");
  if (const UsdPrimRecord* where = authoring(settings, product, "pixelAspectRatio")) {
    p.pixelAspectRatio = usdFloat(*where, "pixelAspectRatio", 1.0f);
    if (!(std::isfinite(p.pixelAspectRatio) && p.pixelAspectRatio > 0 && p.pixelAspectRatio <= 1e4f))
      throw InputError(where->path, "pixelAspectRatio", str(p.pixelAspectRatio, " is outside (0, 10000]"));
  }
  if (const UsdPrimRecord* where = authoring(settings, product, "dataWindowNDC")) {
    std::vector<float> ndc = usdFloats(*where, "dataWindowNDC", {0, 0, 1, 1});
    std::copy(ndc.begin(), ndc.end(), p.dataWindowNDC);
  }
  // The data window through usd_render.h's checks and names (the product's, else the settings prim's).
  p.window = dataWindowFromUsd(settings, &product, p.width, p.height, warnings)
                 .value_or(PixelWindow{0, p.width, 0, p.height});
  return p;
}

std::string expandFrameTokens(const std::string& name, double frame, const std::string& object,
                              const std::string& attribute) {
  std::string out;
  for (size_t i = 0; i < name.size();) {
    int digits = -1;
    size_t len = 0;
    if (name.compare(i, 2, "$F") == 0) {
      const bool padded = i + 2 < name.size() && name[i + 2] >= '1' && name[i + 2] <= '9';
      digits = padded ? name[i + 2] - '0' : 0;
      len = padded ? 3 : 2;
    } else if (name[i] == '#') {
      len = name.find_first_not_of('#', i);
      len = (len == std::string::npos ? name.size() : len) - i;
      digits = int(len);
    }
    if (digits < 0) {
      out += name[i++];
      continue;
    }
    if (!std::isfinite(frame))
      throw InputError(object, attribute,
                       str("\"", name, "\" has a frame token but the render has no frame number (render frames: "
                                       "granular render --frames, usdrecord --frames)"));
    out += frameText(frame, digits);
    i += len;
  }
  return out;
}

std::string productFileName(const RenderProductDesc& p, double frame) {
  return expandFrameTokens(p.productName, frame, p.path, "productName");
}

void checkProductOutput(const RenderProductDesc& p, double frame) {
  const std::string file = productFileName(p, frame);
  std::string ext = std::filesystem::path(file).extension().string();
  for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  if (ext != ".exr") throw InputError(p.path, "productName", str("\"", file, "\" must end in .exr (OpenEXR)"));
  std::error_code ec;
  std::filesystem::path folder = std::filesystem::absolute(file, ec).parent_path();
  if (ec || !std::filesystem::is_directory(folder, ec))
    throw InputError(p.path, "productName", str("folder \"", folder.string(), "\" of \"", file, "\" does not exist"));
  if (std::filesystem::is_directory(file, ec)) throw InputError(p.path, "productName", str("\"", file, "\" is a folder"));
  if (access(folder.c_str(), W_OK) != 0)
    throw InputError(p.path, "productName", str("folder \"", folder.string(), "\" is not writable"));
}

PixelWindow unionWindow(const std::vector<RenderProductDesc>& products) {
  if (products.empty()) return PixelWindow{};
  PixelWindow u = products[0].window;
  for (const RenderProductDesc& p : products) {
    u.x0 = std::min(u.x0, p.window.x0), u.x1 = std::max(u.x1, p.window.x1);
    u.y0 = std::min(u.y0, p.window.y0), u.y1 = std::max(u.y1, p.window.y1);
  }
  return u;
}

bool writeProduct(const RenderProductDesc& p, const Image& image, double frame) {
  checkProductOutput(p, frame);
  const std::string file = productFileName(p, frame);
  auto fail = [&](const std::string& why) {
    throw std::runtime_error(str("cannot write render product ", p.path, " to ", file, ": ", why));
  };
  if (image.displayWidth() != p.width || image.displayHeight() != p.height)
    fail(str("the render is ", image.displayWidth(), "x", image.displayHeight(), ", the product ", p.width, "x",
             p.height));
  const PixelWindow& w = p.window;
  if (w.x0 < image.x || w.y0 < image.y || w.x1 > image.x + image.width || w.y1 > image.y + image.height)
    fail(str("the render holds pixels ", image.x, ":", image.x + image.width, ",", image.y, ":",
             image.y + image.height, ", not all of the data window ", w.x0, ":", w.x1, ",", w.y0, ":", w.y1));
  std::vector<std::string> names;
  std::vector<ExrPixelType> types;
  std::vector<int> from;
  for (const RenderVarDesc& v : p.vars)
    for (const std::string& c : v.channels) {
      const int k = image.channelIndex(c);
      if (k < 0) fail(str("the render has no channel ", c, " (", v.path, ")"));
      names.push_back(c);
      types.push_back(v.format);
      from.push_back(k);
    }
  Image out(w.width(), w.height(), names);
  out.x = w.x0, out.y = w.y0, out.fullWidth = p.width, out.fullHeight = p.height;
  // Header metadata of the layers the product holds (a Cryptomatte layer's name, hash and
  // manifest, cryptomatte.h: "cryptomatte/<key>/name" names the layer); nothing else.
  std::set<std::string> keys;
  for (const auto& [name, value] : image.attributes)
    if (name.rfind("cryptomatte/", 0) == 0 && name.size() > 5 && name.compare(name.size() - 5, 5, "/name") == 0)
      for (const std::string& c : names)
        if (c.rfind(value, 0) == 0) keys.insert(name.substr(0, name.size() - 4));
  for (const auto& kv : image.attributes)
    for (const std::string& key : keys)
      if (kv.first.rfind(key, 0) == 0) out.attributes.push_back(kv);
  for (int y = 0; y < out.height; ++y)
    for (int x = 0; x < out.width; ++x) {
      const float* src = image.at(w.x0 + x - image.x, w.y0 + y - image.y);
      float* dst = out.at(x, y);
      for (size_t c = 0; c < from.size(); ++c) dst[c] = src[from[c]];
    }
  return writeExrTyped(file, out, types, p.pixelAspectRatio);
}

}  // namespace granular
