// packing.h — periodic tiles of equal hard spheres, the "tiled sphere packing" of the paper.
//
// Contract: generateTile(n, f, seed) returns n equal, non-overlapping spheres in the periodic
// unit cube [0,1)^3 at packing rate f = n*(4/3)*pi*r^3 (equal to the request up to rounding),
// grown by Lubachevsky–Stillinger event-driven molecular dynamics of growing hard spheres
// (Skoge, Donev, Stillinger, Torquato 2006, Phys. Rev. E 74, 041127). The tile is repeated
// through space, so every distance is a minimum-image one, and the centres are stored as
// float yet still do not overlap (the growth runs a hair past the target to leave room for
// the rounding). The result is a pure function of (n, f, seed).
#pragma once

#include <cstdint>
#include <vector>

#include "math.h"

namespace granular {

struct Tile {
  int numSpheres = 0;
  double radius = 0;       // sphere radius for unit tile edge
  double packingRate = 0;  // achieved f = N*(4/3)*pi*r^3
  uint64_t seed = 0;
  std::vector<Vec3> centers;  // in [0,1)^3
};

// Grows n spheres by LS dynamics until the packing rate reaches targetF; deterministic given
// seed. Throws InputError("tile", "packingRate", ...) if targetF is outside (0, 0.64] or the
// spheres jam before reaching it (also after slower retries), InputError("tile", "numSpheres",
// ...) if n < 1 or n > 100000 or n is too small for targetF (a sphere wider than the tile),
// and std::runtime_error if the event budget runs out (a bug guard, never expected).
Tile generateTile(int n, double targetF, uint64_t seed);

// Same, cached on disk (cache.h) under a name keyed by (n, targetF, seed, format version);
// an absent, corrupted or short cache entry is ignored and regenerated.
Tile loadOrGenerateTile(int n, double targetF, uint64_t seed);

// Smallest periodic gap between sphere surfaces: min over pairs of the minimum-image centre
// distance minus 2r, and over each sphere and its own images (1 - 2r). O(N^2), for tests;
// +infinity for an empty tile.
double minPeriodicGap(const Tile& t);

}  // namespace granular
