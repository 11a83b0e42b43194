#include "usdValue.h"

#include "pxr/base/gf/half.h"
#include "pxr/base/gf/vec2d.h"
#include "pxr/base/gf/vec2f.h"
#include "pxr/base/gf/vec2i.h"
#include "pxr/base/gf/vec3d.h"
#include "pxr/base/gf/vec3f.h"
#include "pxr/base/gf/vec3h.h"
#include "pxr/base/gf/vec4d.h"
#include "pxr/base/gf/vec4f.h"
#include "pxr/base/tf/token.h"
#include "pxr/base/vt/array.h"
#include "pxr/base/vt/types.h"
#include "pxr/usd/sdf/assetPath.h"

PXR_NAMESPACE_OPEN_SCOPE

namespace {

template <typename T>
bool scalar(VtValue const& v, const char* name, granular::UsdValue& out) {
  if (!v.IsHolding<T>()) return false;
  out.typeName = name;
  out.numbers = {double(v.UncheckedGet<T>())};
  return true;
}

template <typename V>
bool vector(VtValue const& v, const char* name, granular::UsdValue& out) {
  if (!v.IsHolding<V>()) return false;
  V const& x = v.UncheckedGet<V>();
  out.typeName = name;
  for (size_t i = 0; i < V::dimension; ++i) out.numbers.push_back(double(x[i]));
  return true;
}

template <typename T>
bool array(VtValue const& v, const char* name, granular::UsdValue& out) {
  if (!v.IsHolding<VtArray<T>>()) return false;
  out.typeName = name;
  out.isArray = true;
  for (T const& x : v.UncheckedGet<VtArray<T>>()) out.numbers.push_back(double(x));
  return true;
}

}  // namespace

std::optional<granular::UsdValue> HdGranularUsdValue(VtValue const& v) {
  if (v.IsEmpty()) return std::nullopt;
  granular::UsdValue p;
  if (scalar<float>(v, "float", p) || scalar<double>(v, "double", p) || scalar<GfHalf>(v, "half", p) ||
      scalar<int>(v, "int", p) || scalar<int64_t>(v, "int64", p) || scalar<unsigned int>(v, "uint", p) ||
      scalar<bool>(v, "bool", p) || vector<GfVec2f>(v, "float2", p) || vector<GfVec2d>(v, "double2", p) ||
      vector<GfVec2i>(v, "int2", p) || vector<GfVec3f>(v, "color3f", p) || vector<GfVec3d>(v, "color3d", p) ||
      vector<GfVec3h>(v, "half3", p) || vector<GfVec4f>(v, "float4", p) || vector<GfVec4d>(v, "double4", p) ||
      array<float>(v, "float[]", p) || array<double>(v, "double[]", p) || array<int>(v, "int[]", p))
    return p;
  if (v.IsHolding<VtVec3fArray>() && v.GetArraySize() == 1) {  // a constant colour as an array
    GfVec3f c = v.UncheckedGet<VtVec3fArray>()[0];
    p.typeName = "color3f", p.numbers = {c[0], c[1], c[2]};
  } else if (v.IsHolding<VtVec3fArray>()) {
    p.typeName = "color3f[]", p.isArray = true;
    for (GfVec3f const& c : v.UncheckedGet<VtVec3fArray>()) p.numbers.insert(p.numbers.end(), {c[0], c[1], c[2]});
  } else if (v.IsHolding<VtStringArray>()) {
    p.typeName = "string[]", p.isArray = p.isString = true;
    for (auto const& s : v.UncheckedGet<VtStringArray>()) p.strings.push_back(s);
  } else if (v.IsHolding<VtTokenArray>()) {
    p.typeName = "token[]", p.isArray = p.isString = true;
    for (auto const& s : v.UncheckedGet<VtTokenArray>()) p.strings.push_back(s.GetString());
  } else if (v.IsHolding<std::string>()) {
    p.typeName = "string", p.isString = true, p.strings = {v.UncheckedGet<std::string>()};
  } else if (v.IsHolding<TfToken>()) {
    p.typeName = "token", p.isString = true, p.strings = {v.UncheckedGet<TfToken>().GetString()};
  } else if (v.IsHolding<SdfAssetPath>()) {
    SdfAssetPath const& a = v.UncheckedGet<SdfAssetPath>();
    p.typeName = "asset", p.isString = true, p.strings = {a.GetAssetPath()};
    p.resolvedPath = a.GetResolvedPath();
  } else {
    p.typeName = v.GetTypeName();
  }
  return p;
}

PXR_NAMESPACE_CLOSE_SCOPE
