// usd_values.cpp — typed reads of the records USD front ends hand core (usd_values.h).
#include "usd_values.h"

#include <cmath>
#include <sys/stat.h>

#include "error.h"

namespace granular {

namespace {

const UsdValue* find(const UsdPrimRecord& r, const std::string& name) {
  auto it = r.attributes.find(name);
  return it == r.attributes.end() ? nullptr : &it->second;
}

const std::string& where(const UsdPrimRecord& r, const UsdValue& v) { return v.source.empty() ? r.path : v.source; }

[[noreturn]] void wrongType(const UsdPrimRecord& r, const std::string& name, const UsdValue& v, const char* expected) {
  std::string text = describeUsdValueShort(v);
  if (v.numbers.empty() && v.strings.empty()) text = "of type " + v.typeName;
  throw InputError(where(r, v), name, str("has value ", text, ", expected ", expected));
}

bool numeric(const UsdValue& v) { return !v.isString && v.strings.empty() && v.typeName != "bool"; }

}  // namespace

std::string describeUsdValueShort(const UsdValue& v, size_t limit) {
  std::string text = describeUsdValue(v);
  if (text.size() <= limit) return text;
  size_t cut = limit > 3 ? limit - 3 : 0;
  while (cut > 0 && (static_cast<unsigned char>(text[cut]) & 0xC0) == 0x80) --cut;  // a continuation byte
  return text.substr(0, cut) + "...";
}

std::string describeUsdValue(const UsdValue& v) {
  std::string s;
  if (v.isString) {
    for (size_t i = 0; i < v.strings.size(); ++i) s += (i ? ", '" : "'") + v.strings[i] + "'";
  } else {
    for (size_t i = 0; i < v.numbers.size(); ++i) s += (i ? ", " : "") + str(v.numbers[i]);
  }
  if (v.isArray) return "[" + s + "]";
  if (!v.isString && v.numbers.size() == 1) return s;
  if (v.isString && v.strings.size() == 1) return s;
  return "(" + s + ")";
}

float usdFloat(const UsdPrimRecord& r, const std::string& name, float fallback) {
  const UsdValue* v = find(r, name);
  if (!v) return fallback;
  if (!numeric(*v) || v->isArray || v->numbers.size() != 1) wrongType(r, name, *v, "a number");
  return float(v->numbers[0]);
}

bool usdBool(const UsdPrimRecord& r, const std::string& name, bool fallback) {
  const UsdValue* v = find(r, name);
  if (!v) return fallback;
  if (v->typeName != "bool" || v->isArray || v->numbers.size() != 1) wrongType(r, name, *v, "a bool");
  return v->numbers[0] != 0;
}

std::string usdToken(const UsdPrimRecord& r, const std::string& name, const std::string& fallback) {
  const UsdValue* v = find(r, name);
  if (!v) return fallback;
  if (!v->isString || v->isArray || v->strings.size() != 1 || v->typeName == "asset") wrongType(r, name, *v, "a token");
  return v->strings[0];
}

std::vector<float> usdFloats(const UsdPrimRecord& r, const std::string& name, std::vector<float> fallback) {
  const UsdValue* v = find(r, name);
  if (!v) return fallback;
  if (!numeric(*v) || v->isArray || v->numbers.size() != fallback.size())
    wrongType(r, name, *v, str(fallback.size(), " numbers").c_str());
  std::vector<float> out;
  for (double x : v->numbers) out.push_back(float(x));
  return out;
}

Vec3 usdColor(const UsdPrimRecord& r, const std::string& name, Vec3 fallback) {
  const std::vector<float> c = usdFloats(r, name, {fallback.x, fallback.y, fallback.z});
  return Vec3(c[0], c[1], c[2]);
}

std::pair<std::string, std::string> usdAsset(const UsdPrimRecord& r, const std::string& name) {
  const UsdValue* v = find(r, name);
  if (!v) return {};
  if (!v->isString || v->isArray || v->strings.size() != 1) wrongType(r, name, *v, "an asset path");
  return {v->strings[0], v->resolvedPath};
}

std::string usdFile(const UsdPrimRecord& r, const std::string& name) {
  const auto [authored, resolved] = usdAsset(r, name);
  if (authored.empty()) return "";
  const std::string& file = resolved.empty() ? authored : resolved;
  struct stat st;
  if (stat(file.c_str(), &st) != 0 || !S_ISREG(st.st_mode))
    throw InputError(r.path, name, str("\"", authored, "\" cannot be found"));
  return file;
}

}  // namespace granular
