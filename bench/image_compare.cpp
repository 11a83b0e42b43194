// granular-compare — error of an image against a reference (a tool, not a test).
//
//   granular-compare TEST.exr REFERENCE.exr
// Prints one JSON line: the relative difference of the image means (bias), the mean
// relative squared error relMSE = mean((t − r)² / (r² + 0.01)) over pixels and channels
// (the metric of bench/hybrid_speedup.py), and the pixel count.
#include <cmath>
#include <cstdio>

#include "core/image_io.h"

using namespace granular;

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: granular-compare TEST.exr REFERENCE.exr\n");
    return 2;
  }
  try {
    Image t = readImageRGB(argv[1]), r = readImageRGB(argv[2]);
    if (t.width != r.width || t.height != r.height) {
      std::fprintf(stderr, "error: sizes differ (%dx%d vs %dx%d)\n", t.width, t.height, r.width, r.height);
      return 2;
    }
    double st = 0, sr = 0, mse = 0;
    size_t n = size_t(t.width) * t.height * 3;
    for (size_t i = 0; i < n; ++i) {
      double a = t.pixels[i], b = r.pixels[i];
      st += a;
      sr += b;
      mse += (a - b) * (a - b) / (b * b + 0.01);
    }
    std::printf("{\"bias\": %.6g, \"relmse\": %.6g, \"mean_test\": %.6g, \"mean_ref\": %.6g, \"pixels\": %zu}\n",
                sr > 0 ? (st - sr) / sr : 0.0, mse / double(n), st / double(n), sr / double(n), n / 3);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 2;
  }
}
