// packing.h — periodic tiles of equal hard spheres, the "tiled sphere packing" of the paper.
//
// Contract: generateTile(n, f, seed) returns n equal, non-overlapping spheres in the periodic
// unit cube [0,1)^3 at packing rate f = n*(4/3)*pi*r^3 (equal to the request up to rounding),
// grown by Lubachevsky–Stillinger event-driven molecular dynamics of growing hard spheres
// (Skoge, Donev, Stillinger, Torquato 2006, Phys. Rev. E 74, 041127). The tile is repeated
// through space, so every distance is a minimum-image one, and the centres are stored as
// float yet still do not overlap (the growth runs a hair past the target to leave room for
// the rounding). The result is a pure function of (n, f, seed, sizes).
// Polydisperse tiles (TileSizes): sphere k has radius r·s_k, s_k its class's size times a
// factor uniform in [1 − spread, 1 + spread]; the classes get their share of the n spheres
// by number. All radii grow in proportion (LS dynamics of polydisperse spheres: a pair
// touches at the sum of its radii), and f = Σ (4/3)π (r s_k)³ counts every size.
#pragma once

#include <cstdint>
#include <vector>

#include "math.h"

namespace granular {

struct Tile {
  int numSpheres = 0;
  double radius = 0;       // sphere radius for unit tile edge (of size 1 in a polydisperse tile)
  double packingRate = 0;  // achieved f = Σ (4/3)π (r s_k)³
  uint64_t seed = 0;
  std::vector<Vec3> centers;  // in [0,1)^3
  // Polydisperse tiles only (empty: every sphere has size 1, class 0): per sphere its size
  // s_k (radius = radius · s_k) and size class.
  std::vector<float> sizes;
  std::vector<uint8_t> classes;
  float size(int k) const { return sizes.empty() ? 1.0f : sizes[size_t(k)]; }
  int sizeClass(int k) const { return classes.empty() ? 0 : int(classes[size_t(k)]); }
  float maxSize() const;
  // Σ s_k³ / Σ s_k² (1 for equal spheres): the Sauter mean size, whose radius R s_32 sets
  // the mean free flight between the spheres (tt.h).
  double sauterSize() const;
};

// Size classes of a polydisperse tile: each class's size (radius relative to the tile's
// reference radius) and number fraction, and the spread within a class. Empty (or one
// class of size 1 without spread): equal spheres.
struct TileSizes {
  std::vector<double> classSize;    // > 0
  std::vector<double> classWeight;  // >= 0, not all 0 (normalised here)
  double spread = 0;                // in [0, 0.5]
  bool monodisperse() const;
  static constexpr int kMaxClasses = 255;
};

// The growth schedule, in Skoge et al. 2006's dimensionless compression rate γ (the diameter
// grows by γ final diameters per unit time at thermal speed 1): fastRate while the packing
// rate is below min(fastLimit, target − fastMargin), then rate up to the target. The slow
// final stage sets the structure; the fast one only brings a fluid of f ≤ 0.5 (below the
// hard-sphere freezing density, 0.494) up to it, and the slow stage's hundreds of
// collisions per sphere rearrange what it left (contact numbers and g(r) at contact as
// those of growth at `rate` throughout, within their scatter over seeds; bench/README.md).
struct TileGrowth {
  double rate = 0.1;
  double fastRate = 1.0;
  double fastMargin = 0.1;
  double fastLimit = 0.5;
  static TileGrowth uniform(double rate);  // no fast stage
  // The packing rate the fast stage stops at (0: none).
  double fastUntil(double targetF) const;
};

// Grows n spheres by LS dynamics until the packing rate reaches targetF; deterministic given
// seed (and growth: tiles are made with the default, tests pin others). Throws InputError("tile", "packingRate", ...) if targetF is outside (0, 0.64] or the
// spheres jam before reaching it (also after retries with every rate slower),
// InputError("tile", "growth", ...) for rates <= 0, InputError("tile", "numSpheres",
// ...) if n < 1 or n > 100000 or n is too small for targetF (a sphere wider than the tile),
// and std::runtime_error if the event budget runs out (a bug guard, never expected).
// A class with a weight > 0 gets at least one sphere; InputError("tile", "sizes", ...) for
// sizes or weights out of range, more classes than spheres or than kMaxClasses.
Tile generateTile(int n, double targetF, uint64_t seed, const TileSizes& sizes = TileSizes(),
                  const TileGrowth& growth = TileGrowth());

// Same, cached on disk (cache.h) under a name keyed by (n, targetF, seed, sizes, format
// version); an absent, corrupted or short cache entry is ignored and regenerated.
Tile loadOrGenerateTile(int n, double targetF, uint64_t seed, const TileSizes& sizes = TileSizes());

// Smallest periodic gap between sphere surfaces: min over pairs of the minimum-image centre
// distance minus the two radii, and over each sphere and its own images (1 - 2 r s_k).
// O(N^2), for tests; +infinity for an empty tile.
double minPeriodicGap(const Tile& t);

}  // namespace granular
