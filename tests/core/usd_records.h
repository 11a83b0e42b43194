// usd_records.h — building the plain records USD front ends hand core (core/usd_values.h)
// in tests, as usd-core or Hydra would fill them.
#pragma once

#include <string>
#include <vector>

#include "core/error.h"
#include "core/usd_values.h"

namespace granular::test {

inline UsdValue usdNumbers(const std::string& type, std::vector<double> v) {
  UsdValue x;
  x.typeName = type;
  x.numbers = std::move(v);
  x.isArray = type.size() > 2 && type.compare(type.size() - 2, 2, "[]") == 0;
  return x;
}

inline UsdValue usdText(const std::string& type, const std::string& text, const std::string& resolved = "") {
  UsdValue x;
  x.typeName = type;
  x.strings = {text};
  x.isString = true;
  x.resolvedPath = resolved;
  return x;
}

inline UsdPrimRecord usdRecord(const std::string& path, const std::string& type,
                               std::initializer_list<std::pair<const std::string, UsdValue>> attributes = {}) {
  UsdPrimRecord r;
  r.path = path;
  r.typeName = type;
  r.attributes = attributes;
  return r;
}

// The message of the InputError f() throws, or "" when it throws none.
template <typename F>
std::string inputErrorOf(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

}  // namespace granular::test
