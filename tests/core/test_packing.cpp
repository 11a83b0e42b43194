// Packing: Lubachevsky–Stillinger tiles reach the requested rate, do not overlap, are
// periodic and deterministic, and round-trip through the cache (tests mirror
// core/packing.*).
#include <gtest/gtest.h>

#include <cmath>

#include "core/error.h"
#include "core/packing.h"

using namespace granular;

namespace {

// f = N (4/3) pi r^3 from the tile's own radius, independently of Tile::packingRate.
double rateOf(const Tile& t) { return t.numSpheres * (4.0 / 3.0) * 3.14159265358979323846 * std::pow(t.radius, 3); }

void expectValidTile(const Tile& t, int n, double f) {
  ASSERT_EQ(t.numSpheres, n);
  ASSERT_EQ(int(t.centers.size()), n);
  EXPECT_NEAR(rateOf(t), f, 0.01 * f);
  EXPECT_NEAR(t.packingRate, rateOf(t), 1e-12);
  for (const Vec3& c : t.centers)
    for (int a = 0; a < 3; ++a) {
      EXPECT_GE(c[a], 0.0f);
      EXPECT_LT(c[a], 1.0f);
    }
  // No overlap beyond 1e-6 R, measured with minimum-image (periodic) distances.
  EXPECT_GE(minPeriodicGap(t), -1e-6 * t.radius);
}

}  // namespace

TEST(Packing, DenseTileReachesRandomClosePacking) {
  Tile t = generateTile(256, 0.63, 1);
  expectValidTile(t, 256, 0.63);
}

TEST(Packing, SparseAndMediumRates) {
  for (double f : {0.05, 0.3, 0.55}) {
    SCOPED_TRACE(f);
    expectValidTile(generateTile(128, f, 4), 128, f);
  }
}

TEST(Packing, PeriodicImagesDoNotOverlap) {
  // A brute-force check over all 27 images, independent of minPeriodicGap.
  Tile t = generateTile(64, 0.6, 9);
  double minGap = 1e9;
  for (int i = 0; i < t.numSpheres; ++i)
    for (int j = 0; j < t.numSpheres; ++j)
      for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dx = -1; dx <= 1; ++dx) {
            if (i == j && dx == 0 && dy == 0 && dz == 0) continue;
            double d[3] = {double(t.centers[j].x) + dx - t.centers[i].x, double(t.centers[j].y) + dy - t.centers[i].y,
                           double(t.centers[j].z) + dz - t.centers[i].z};
            minGap = std::min(minGap, std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) - 2 * t.radius);
          }
  EXPECT_GE(minGap, -1e-6 * t.radius);
  EXPECT_NEAR(minGap, minPeriodicGap(t), 1e-7);
  // Jammed-ish: some pair is nearly in contact (the packing is not a loose lattice).
  EXPECT_LT(minGap, 0.05 * t.radius);
}

TEST(Packing, DeterministicForASeedAndDifferentAcrossSeeds) {
  Tile a = generateTile(64, 0.5, 3), b = generateTile(64, 0.5, 3), c = generateTile(64, 0.5, 4);
  ASSERT_EQ(a.centers.size(), b.centers.size());
  for (size_t i = 0; i < a.centers.size(); ++i) EXPECT_EQ(a.centers[i], b.centers[i]);
  int same = 0;
  for (size_t i = 0; i < a.centers.size(); ++i) same += a.centers[i] == c.centers[i];
  EXPECT_LT(same, 2);
}

TEST(Packing, CacheRoundTripGivesTheSameTile) {
  Tile g = generateTile(64, 0.45, 17);
  Tile first = loadOrGenerateTile(64, 0.45, 17);   // generates or reads
  Tile second = loadOrGenerateTile(64, 0.45, 17);  // reads (or regenerates if no cache dir)
  ASSERT_EQ(first.centers.size(), g.centers.size());
  for (size_t i = 0; i < g.centers.size(); ++i) {
    EXPECT_EQ(first.centers[i], g.centers[i]);
    EXPECT_EQ(second.centers[i], g.centers[i]);
  }
  EXPECT_EQ(second.radius, g.radius);
}

TEST(Packing, BadRequestsAreInputErrors) {
  EXPECT_THROW(generateTile(64, 0.0, 1), InputError);
  EXPECT_THROW(generateTile(64, 0.7, 1), InputError);
  EXPECT_THROW(generateTile(64, std::nan(""), 1), InputError);
  EXPECT_THROW(generateTile(0, 0.5, 1), InputError);
  EXPECT_THROW(generateTile(1000000, 0.5, 1), InputError);
  EXPECT_THROW(generateTile(64, 0.5, 1, TileSizes(), TileGrowth::uniform(0.0)), InputError);
  TileGrowth g;
  g.fastRate = std::nan("");
  EXPECT_THROW(generateTile(64, 0.5, 1, TileSizes(), g), InputError);
}

// ---- the growth schedule ---------------------------------------------------------------

namespace {

// Squared minimum-image distance between the centres of spheres i and j of a periodic tile.
double minImageDistance2(const Tile& t, int i, int j) {
  double d2 = 0;
  for (int a = 0; a < 3; ++a) {
    double d = double(t.centers[size_t(j)][a]) - t.centers[size_t(i)][a];
    d -= std::round(d);
    d2 += d * d;
  }
  return d2;
}

// Neighbours per sphere whose centres are closer than `factor` diameters: the pair
// correlation near contact, which the growth rate changes (faster growth leaves more
// near-contacts; Skoge et al. 2006).
double nearContacts(const Tile& t, double factor) {
  const double reach = factor * 2.0 * t.radius;
  int pairs = 0;
  for (int i = 0; i < t.numSpheres; ++i)
    for (int j = i + 1; j < t.numSpheres; ++j) pairs += minImageDistance2(t, i, j) < reach * reach;
  return 2.0 * pairs / t.numSpheres;
}

struct MeanSE {
  double mean, se;
};

// Near-contacts within 2% of a diameter, over seeds: their mean and standard error.
MeanSE nearContactsOverSeeds(int n, double f, const TileGrowth& growth) {
  const int seeds = 8;
  double sum = 0, sum2 = 0;
  for (int s = 1; s <= seeds; ++s) {
    const double z = nearContacts(generateTile(n, f, uint64_t(s), TileSizes(), growth), 1.02);
    sum += z;
    sum2 += z * z;
  }
  const double mean = sum / seeds;
  return {mean, std::sqrt(std::max(0.0, sum2 / seeds - mean * mean) / (seeds - 1))};
}

}  // namespace

TEST(Packing, FastStageStopsWellBelowTheTarget) {
  const TileGrowth g;
  EXPECT_DOUBLE_EQ(g.fastUntil(0.6), 0.5);
  EXPECT_DOUBLE_EQ(g.fastUntil(0.63), 0.5);
  EXPECT_DOUBLE_EQ(g.fastUntil(0.3), 0.2);
  EXPECT_EQ(g.fastUntil(0.05), 0.0);
  EXPECT_EQ(TileGrowth::uniform(0.1).fastUntil(0.6), 0.0);
}

TEST(Packing, FastStageKeepsTheStructureOfSlowGrowth) {
  // The tiles' schedule (fast up to f = 0.5) against slow growth throughout: the same
  // near-contact number within the scatter over seeds (3 standard errors of the
  // difference). Fast growth throughout differs by far more (about 5.5 against 3.8
  // neighbours within 2% of a diameter): the statistic tells the rates apart.
  const int n = 256;
  const double f = 0.6;
  const MeanSE tiles = nearContactsOverSeeds(n, f, TileGrowth());
  const MeanSE slow = nearContactsOverSeeds(n, f, TileGrowth::uniform(0.1));
  const MeanSE fast = nearContactsOverSeeds(n, f, TileGrowth::uniform(1.0));
  const double se = std::hypot(tiles.se, slow.se);
  EXPECT_NEAR(tiles.mean, slow.mean, 3 * se) << "slow " << slow.mean << ", fast " << fast.mean;
  EXPECT_GT(fast.mean - slow.mean, 3 * std::hypot(fast.se, slow.se));
}

// ---- polydisperse tiles ----------------------------------------------------------------

namespace {

double polyRateOf(const Tile& t) {
  double sum = 0;
  for (int k = 0; k < t.numSpheres; ++k) sum += std::pow(t.radius * t.size(k), 3);
  return (4.0 / 3.0) * 3.14159265358979323846 * sum;
}

// Brute-force gap of two spheres' surfaces, radii from the tile, minimum image.
double brutePolyGap(const Tile& t) {
  double best = 1e9;
  for (int i = 0; i < t.numSpheres; ++i) {
    best = std::min(best, 1.0 - 2.0 * t.radius * t.size(i));
    for (int j = i + 1; j < t.numSpheres; ++j)
      best = std::min(best, std::sqrt(minImageDistance2(t, i, j)) - t.radius * (double(t.size(i)) + t.size(j)));
  }
  return best;
}

}  // namespace

TEST(Packing, PolydisperseTilesPackEverySizeWithoutOverlap) {
  // Half the spheres of size 1, half of size 0.5, each spread by ±20%; f counts both.
  TileSizes z;
  z.classSize = {1.0, 0.5};
  z.classWeight = {1.0, 1.0};
  z.spread = 0.2;
  Tile t = generateTile(256, 0.6, 5, z);
  ASSERT_EQ(t.sizes.size(), 256u);
  EXPECT_NEAR(polyRateOf(t), 0.6, 1e-6);
  EXPECT_NEAR(t.packingRate, polyRateOf(t), 1e-12);
  EXPECT_GE(brutePolyGap(t), -1e-6 * t.radius);
  EXPECT_NEAR(minPeriodicGap(t), brutePolyGap(t), 1e-12);
  int small = 0;
  for (int k = 0; k < 256; ++k) {
    const double base = t.sizeClass(k) == 0 ? 1.0 : 0.5;
    small += t.sizeClass(k) == 1;
    EXPECT_GE(t.size(k), base * 0.8 - 1e-6);
    EXPECT_LE(t.size(k), base * 1.2 + 1e-6);
  }
  EXPECT_EQ(small, 128);  // classes by number
  // A real jammed-ish packing: the closest pair nearly touches.
  EXPECT_LT(brutePolyGap(t), 0.05 * t.radius);
  EXPECT_NEAR(t.maxSize(), 1.2, 0.01);
  // Deterministic, and the cache keeps sizes and classes.
  Tile again = generateTile(256, 0.6, 5, z);
  EXPECT_EQ(again.centers, t.centers);
  EXPECT_EQ(again.sizes, t.sizes);
  Tile cached = loadOrGenerateTile(256, 0.6, 5, z), reread = loadOrGenerateTile(256, 0.6, 5, z);
  EXPECT_EQ(cached.sizes, t.sizes);
  EXPECT_EQ(reread.classes, t.classes);
  EXPECT_EQ(reread.centers, t.centers);
  // Another size mix is another tile (another cache entry).
  z.spread = 0.1;
  EXPECT_NE(loadOrGenerateTile(256, 0.6, 5, z).sizes, t.sizes);
}

TEST(Packing, EqualSizesAreTheMonodisperseTile) {
  // One class of size 1 without spread is the ordinary tile, bit for bit.
  TileSizes z;
  z.classSize = {1.0};
  z.classWeight = {3.0};
  Tile a = generateTile(64, 0.5, 3, z), b = generateTile(64, 0.5, 3);
  EXPECT_EQ(a.centers, b.centers);
  EXPECT_EQ(a.radius, b.radius);
  EXPECT_TRUE(a.sizes.empty());
}

TEST(Packing, SmallClassesGetASphereAndBadSizesAreRefused) {
  TileSizes z;
  z.classSize = {1.0, 0.4};
  z.classWeight = {0.999, 0.001};
  Tile t = generateTile(64, 0.4, 2, z);
  int small = 0;
  for (int k = 0; k < 64; ++k) small += t.sizeClass(k) == 1;
  EXPECT_EQ(small, 1);
  z.classWeight = {0, 0};
  EXPECT_THROW(generateTile(64, 0.4, 2, z), InputError);
  z.classWeight = {1, 1};
  z.spread = 0.7;
  EXPECT_THROW(generateTile(64, 0.4, 2, z), InputError);
  z.spread = 0;
  z.classSize = {1.0, -1.0};
  EXPECT_THROW(generateTile(64, 0.4, 2, z), InputError);
}

// ---- the packing, bit for bit ---------------------------------------------------------

namespace {

// FNV-1a over the centres' floats, the radius's double and the sizes' floats.
uint64_t tileChecksum(const Tile& t) {
  uint64_t h = 1469598103934665603ull;
  auto eat = [&h](const void* p, size_t n) {
    for (size_t i = 0; i < n; ++i) h = (h ^ static_cast<const unsigned char*>(p)[i]) * 1099511628211ull;
  };
  eat(t.centers.data(), t.centers.size() * sizeof(Vec3));
  eat(&t.radius, sizeof t.radius);
  eat(t.sizes.data(), t.sizes.size() * sizeof(float));
  return h;
}

}  // namespace

TEST(Packing, TilesAreBitForBitThoseOfTheOneLoopSearch) {
  // The growth is chaotic: one rounding changed anywhere in its 10^5..10^7 events gives
  // another packing. These checksums were taken from tiles packed by the neighbour search
  // as it was before it gathered the neighbours first (one loop over the 27 cells' member
  // lists, each pair tested as it came): the same events in the same order, so cached
  // tiles, build-cache keys and images stay valid. Few spheres (fewer than 3 cells a side:
  // a cell seen as several images), sparse to dense, polydisperse, and one of the demo
  // castle's tiles.
  struct Case {
    int n;
    double f;
    uint64_t seed;
    bool poly;
    uint64_t checksum;
  };
  const Case cases[] = {
      {1, 0.05, 1, false, 0x31f76f8c23e701a9ull},   {5, 0.3, 1, false, 0xae44ec214e6bddd5ull},
      {8, 0.5, 2, true, 0x486c61b7b4cf0335ull},     {13, 0.63, 2, true, 0x53d3cb30bd24a7daull},
      {27, 0.6, 1, false, 0x815d20fa6bbf456dull},   {64, 0.5, 3, false, 0xbd3a8c0307a41f71ull},
      {100, 0.63, 2, false, 0xa2dbfb7fb7ee30d1ull}, {256, 0.6, 5, true, 0x9adf10232c4067f7ull},
      {512, 0.6, 1, false, 0xdf883d82b9890047ull},  {1000, 0.3, 1, false, 0xc14c1fa38d3c79a2ull},
  };
  TileSizes z;  // as in PolydisperseTilesPackEverySizeWithoutOverlap
  z.classSize = {1.0, 0.5};
  z.classWeight = {1.0, 1.0};
  z.spread = 0.2;
  for (const Case& c : cases) {
    // The growth of those tiles: slow throughout (the tiles' schedule now starts faster).
    const Tile t = generateTile(c.n, c.f, c.seed, c.poly ? z : TileSizes(), TileGrowth::uniform(0.1));
    EXPECT_EQ(tileChecksum(t), c.checksum) << c.n << " spheres at f=" << c.f << " seed " << c.seed
                                           << (c.poly ? " (two sizes)" : "");
  }
}
