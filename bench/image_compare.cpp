// granular-compare — error of an image against a reference (a tool, not a test).
//
//   granular-compare TEST.exr REFERENCE.exr [REFERENCE2.exr]
// Prints one JSON line: the relative difference of the image means (bias), the mean
// relative squared error relMSE = mean((t − r)² / (r² + 0.01)) over pixels and channels
// (the metric of bench/hybrid_speedup.py), and the pixel count.
//
// With two references (the same estimator, independent seeds, half the samples each) the
// reference is their mean r = (a + b) / 2, and "floor" is the part of relMSE that is the
// reference's own noise: E[(a − b)² / 4] = Var(r), so mean(((a − b) / 2)² / (r² + 0.01))
// estimates it without bias. relMSE − floor is then the test image's own error (its
// variance and squared bias), which a noisy reference would otherwise inflate equally for
// every technique, most for the one that converges fastest.
#include <cmath>
#include <cstdio>

#include "core/image_io.h"

using namespace granular;

int main(int argc, char** argv) {
  if (argc != 3 && argc != 4) {
    std::fprintf(stderr, "usage: granular-compare TEST.exr REFERENCE.exr [REFERENCE2.exr]\n");
    return 2;
  }
  try {
    Image t = readImageRGB(argv[1]), r = readImageRGB(argv[2]);
    const bool split = argc == 4;
    Image r2 = split ? readImageRGB(argv[3]) : Image();
    for (const Image* o : {&r, split ? &r2 : &r})
      if (t.width != o->width || t.height != o->height) {
        std::fprintf(stderr, "error: sizes differ (%dx%d vs %dx%d)\n", t.width, t.height, o->width, o->height);
        return 2;
      }
    double st = 0, sr = 0, mse = 0, floor = 0;
    size_t n = size_t(t.width) * t.height * 3;
    for (size_t i = 0; i < n; ++i) {
      double a = t.pixels[i], b = r.pixels[i];
      double half = 0;
      if (split) {
        half = 0.5 * (double(r.pixels[i]) - double(r2.pixels[i]));
        b = 0.5 * (double(r.pixels[i]) + double(r2.pixels[i]));
      }
      const double w = 1.0 / (b * b + 0.01);
      st += a;
      sr += b;
      mse += (a - b) * (a - b) * w;
      floor += half * half * w;
    }
    std::printf("{\"bias\": %.6g, \"relmse\": %.6g, \"floor\": %.6g, \"mean_test\": %.6g, \"mean_ref\": %.6g, "
                "\"pixels\": %zu}\n",
                sr > 0 ? (st - sr) / sr : 0.0, mse / double(n), floor / double(n), st / double(n), sr / double(n),
                n / 3);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 2;
  }
}
