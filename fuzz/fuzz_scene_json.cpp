// fuzz_scene_json — libFuzzer target for the JSON scene front end: parseSceneJson (the
// nlohmann parser with comments and the duplicate-key callback, every checked converter,
// shapes, transforms) and validateSceneDesc; a scene that validates is built and a few
// pixels rendered (fuzz_common.h). Contract under test (scene_io.h): every problem is an
// InputError, nothing else escapes, nothing crashes, no sample is NaN or Inf.
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_common.h"
#include "core/scene_io.h"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  granular::fuzz::setUpCache();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace granular;
  std::string text(reinterpret_cast<const char*>(data), size);
  SceneDesc desc;
  try {
    // The folder of the source name resolves "obj" and "texture_file" paths: the
    // current directory, where the fuzzer runs (nothing there to find by accident).
    desc = parseSceneJson(text, "fuzz.json");
  } catch (const InputError& e) {
    fuzz::note("refused", e.what());
    return 0;
  }
  fuzz::buildAndRender(std::move(desc));
  return 0;
}
