// fuzz_ies — libFuzzer target for IES LM-63 profiles (core/ies.h): parseIes on arbitrary
// text. Contract under test: every problem is an InputError whose message is valid UTF-8
// (the Python front end decodes it), nothing else escapes, nothing crashes; a profile that
// parses gives finite candela ≥ 0 in every direction and a finite mean ≥ 0 (what a light's
// radiance is multiplied and divided by).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "core/error.h"
#include "core/ies.h"
#include "core/math.h"

namespace {

// Whether s is well-formed UTF-8 (no stray continuation byte, no truncated sequence).
bool validUtf8(const std::string& s) {
  for (size_t i = 0; i < s.size();) {
    const unsigned char c = static_cast<unsigned char>(s[i]);
    const size_t n = c < 0x80 ? 1 : (c >> 5) == 0x6 ? 2 : (c >> 4) == 0xE ? 3 : (c >> 3) == 0x1E ? 4 : 0;
    if (n == 0 || i + n > s.size()) return false;
    for (size_t k = 1; k < n; ++k)
      if ((static_cast<unsigned char>(s[i + k]) & 0xC0) != 0x80) return false;
    i += n;
  }
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace granular;
  const std::string text(reinterpret_cast<const char*>(data), size);
  IesProfile p;
  try {
    p = parseIes(text);
  } catch (const InputError& e) {
    if (!validUtf8(e.what())) std::abort();
    return 0;
  }
  if (!(std::isfinite(p.meanIntensity()) && p.meanIntensity() >= 0)) std::abort();
  for (int i = -1; i <= 37; ++i)
    for (int k = -1; k <= 25; ++k) {
      const float c = p.intensity(kPi * i / 36, 2 * kPi * k / 24 + 0.01f);
      if (!(std::isfinite(c) && c >= 0)) std::abort();
    }
  return 0;
}
