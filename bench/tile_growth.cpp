// tile_growth.cpp — the tiles' growth schedule against others (core/packing.h, TileGrowth):
// packing time and the structure near contact, over seeds. Built and run by
// bench/tile_growth.py; prints one JSON line per schedule.
// Usage: tile_growth N F SEEDS
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "core/packing.h"

using namespace granular;

namespace {

// Neighbours per sphere closer than `factor` diameters (minimum image), for each factor.
void nearContacts(const Tile& t, const double* factors, int count, double* out) {
  for (int f = 0; f < count; ++f) out[f] = 0;
  const double D = 2.0 * t.radius;
  for (int i = 0; i < t.numSpheres; ++i)
    for (int j = i + 1; j < t.numSpheres; ++j) {
      double d2 = 0;
      for (int a = 0; a < 3; ++a) {
        double d = double(t.centers[size_t(j)][a]) - t.centers[size_t(i)][a];
        d -= std::round(d);
        d2 += d * d;
      }
      for (int f = 0; f < count; ++f)
        if (d2 < factors[f] * factors[f] * D * D) out[f] += 2.0 / t.numSpheres;
    }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: tile_growth N F SEEDS\n");
    return 2;
  }
  const int n = std::atoi(argv[1]), seeds = std::atoi(argv[3]);
  const double f = std::atof(argv[2]);
  struct Schedule {
    const char* name;
    TileGrowth growth;
  };
  const Schedule schedules[] = {{"tiles (1.0 to min(0.5, f - 0.1), then 0.1)", TileGrowth()},
                                {"0.1 throughout (before)", TileGrowth::uniform(0.1)},
                                {"0.05 throughout", TileGrowth::uniform(0.05)},
                                {"0.2 throughout", TileGrowth::uniform(0.2)},
                                {"0.6 throughout", TileGrowth::uniform(0.6)},
                                {"1.0 throughout", TileGrowth::uniform(1.0)}};
  const double factors[] = {1.01, 1.02, 1.05};
  for (const Schedule& s : schedules) {
    double seconds = 0, z[3] = {0, 0, 0}, z2[3] = {0, 0, 0};
    for (int seed = 1; seed <= seeds; ++seed) {
      const auto t0 = std::chrono::steady_clock::now();
      const Tile t = generateTile(n, f, uint64_t(seed), TileSizes(), s.growth);
      seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      double c[3];
      nearContacts(t, factors, 3, c);
      for (int k = 0; k < 3; ++k) z[k] += c[k], z2[k] += c[k] * c[k];
    }
    std::printf("{\"schedule\": \"%s\", \"n\": %d, \"f\": %g, \"seeds\": %d, \"seconds\": %.4f", s.name, n, f, seeds,
                seconds / seeds);
    for (int k = 0; k < 3; ++k) {
      const double mean = z[k] / seeds, se = std::sqrt(std::max(0.0, z2[k] / seeds - mean * mean) / (seeds - 1));
      std::printf(", \"z%d\": %.4f, \"z%d_se\": %.4f", int(std::lround((factors[k] - 1) * 100)), mean,
                  int(std::lround((factors[k] - 1) * 100)), se);
    }
    std::printf("}\n");
    std::fflush(stdout);
  }
  return 0;
}
