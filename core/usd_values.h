// usd_values.h — what a USD front end hands core: plain records of what a stage holds
// (prim path, type, attribute name, value as found), and typed reads of them that apply
// the schema's fallback where nothing is authored and name `prim.attribute` on a value of
// the wrong type. The meaning of those values lives in core (granular_prims.h for the
// granular schema, usd_lights.h, usd_camera.h, usd_shading.h, usd_render.h); the front
// ends (python/granular/usd_reader.py through usd-core, hdGranular/ through the Hydra
// scene delegate) only read and convert, so the two cannot disagree.
//
// A layer may author any type for any attribute (USD does not enforce the schema's type
// when a file is read), so every read checks the type and the shape.
#pragma once

#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "error.h"
#include "math.h"

namespace granular {

// One attribute's (or primvar's, or shader input's) value as a front end found it.
// Scalars, vectors and arrays of numbers (float, double, half, int, bool, color3f, ...)
// fill `numbers` (a color3f gives 3); strings, tokens and asset paths fill `strings`.
// `typeName` is USD's name of the authored type (e.g. "float[]", "color3f", "asset"); a
// front end that cannot see it (Hydra's VtValue) names the held type the same way.
struct UsdValue {
  std::string typeName;
  std::vector<double> numbers;
  std::vector<std::string> strings;
  bool isArray = false;
  bool isString = false;
  std::string interpolation = "constant";  // primvars; attributes are constant
  std::string source;        // prim it was authored on when inherited from an ancestor; empty: this prim
  std::string resolvedPath;  // an asset path as the front end's resolver found it; empty: unresolved
};

inline bool operator==(const UsdValue& a, const UsdValue& b) {
  return a.typeName == b.typeName && a.numbers == b.numbers && a.strings == b.strings && a.isArray == b.isArray &&
         a.isString == b.isString && a.interpolation == b.interpolation && a.source == b.source &&
         a.resolvedPath == b.resolvedPath;
}
inline bool operator!=(const UsdValue& a, const UsdValue& b) { return !(a == b); }

// A prim as a front end read it at one time: its type as USD names it ("DistantLight",
// "Camera", "RenderProduct"), the attributes core asked for that hold a value (authored or
// the schema's fallback; a missing one means "use core's fallback"), and where it is.
struct UsdPrimRecord {
  std::string path;
  std::string typeName;
  std::map<std::string, UsdValue> attributes;  // by full name, e.g. "inputs:intensity"
  Transform xf;                                // local-to-world
};

// What a front end shows a user: one line each (stderr, or TF_WARN and a render stat).
using UsdWarnings = std::vector<std::string>;

// Typed reads of record.attributes[name]: the value, or `fallback` when it holds none.
// InputError(record.path, name, "has value ..., expected a float") on a wrong type.
float usdFloat(const UsdPrimRecord& record, const std::string& name, float fallback);
bool usdBool(const UsdPrimRecord& record, const std::string& name, bool fallback);
std::string usdToken(const UsdPrimRecord& record, const std::string& name, const std::string& fallback);
// n numbers (a color3f, float2, float4, ...).
std::vector<float> usdFloats(const UsdPrimRecord& record, const std::string& name, std::vector<float> fallback);
Vec3 usdColor(const UsdPrimRecord& record, const std::string& name, Vec3 fallback);
// An asset path: (as authored, as resolved); both empty when unauthored.
std::pair<std::string, std::string> usdAsset(const UsdPrimRecord& record, const std::string& name);

// An asset that names a file to read: its resolved path (the authored one when the front
// end resolved none); "" when unauthored or empty. InputError "\"x\" cannot be found" when
// it names no regular file.
std::string usdFile(const UsdPrimRecord& record, const std::string& name);

// Core's checks of a description made from a record (check() names prim and the
// description's fields), rethrown in USD's names: rename(field) is the attribute that field
// came from. An error on another object (a texture the description refers to) passes as is.
template <typename Check, typename Rename>
void checkInUsdNames(const std::string& prim, Check&& check, Rename&& rename) {
  try {
    check();
  } catch (const InputError& e) {
    if (e.object() != prim) throw;
    throw InputError(prim, rename(e.attribute()), e.detail());
  }
}

// The value as a user would write it ("0.5", "(1, 0, 0)", "['a', 'b']"), for messages.
std::string describeUsdValue(const UsdValue& v);
// The same, at most `limit` bytes: cut with "..." at a character's start, so that a string
// value's multi-byte UTF-8 characters are never split (a front end decodes the message).
std::string describeUsdValueShort(const UsdValue& v, size_t limit = 60);

}  // namespace granular
