// fuzz_ies — libFuzzer target for IES LM-63 profiles (core/ies.h): parseIes on arbitrary
// text. Contract under test: every problem is an InputError, nothing else escapes, nothing
// crashes; a profile that parses gives finite candela ≥ 0 in every direction and a finite
// mean ≥ 0 (what a light's radiance is multiplied and divided by).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "core/error.h"
#include "core/ies.h"
#include "core/math.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace granular;
  const std::string text(reinterpret_cast<const char*>(data), size);
  IesProfile p;
  try {
    p = parseIes(text);
  } catch (const InputError&) {
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
