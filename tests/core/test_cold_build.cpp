// The cold build's cell classification reads its distances a row at a time
// (DistanceField::distances): the values must be distance()'s bit for bit, so that the
// classes, counts and interior depth are the per-cell classification's.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "core/aggregate.h"
#include "core/distance_field.h"
#include "core/rng.h"
#include "core/shapes.h"

using namespace granular;

namespace {

// An L-shaped prism: the L (2 x 2 with a 1 x 1 notch) in x, y, extruded to height h in z.
TriangleMesh makeLPrism(float h) {
  const float xy[6][2] = {{0, 0}, {2, 0}, {2, 1}, {1, 1}, {1, 2}, {0, 2}};  // counter-clockwise
  TriangleMesh m;
  for (float z : {0.0f, h})
    for (const auto& p : xy) m.points.push_back(Vec3(p[0], p[1], z));
  auto tri = [&](uint32_t a, uint32_t b, uint32_t c) { m.indices.insert(m.indices.end(), {a, b, c}); };
  const uint32_t cap[4][3] = {{3, 4, 5}, {3, 5, 0}, {3, 0, 1}, {3, 1, 2}};  // fans from the notch's corner
  for (const auto& t : cap) {
    tri(6 + t[0], 6 + t[1], 6 + t[2]);  // top, facing +z
    tri(t[0], t[2], t[1]);              // bottom, facing -z
  }
  for (uint32_t i = 0; i < 6; ++i) {
    const uint32_t j = (i + 1) % 6;
    tri(i, j, 6 + j);
    tri(i, 6 + j, 6 + i);
  }
  return m;
}

struct Boundary {
  std::string name;
  TriangleMesh mesh;
  float grainRadius;
};

std::vector<Boundary> boundaries() {
  // Cells of 0.03 to 0.09 (64 spheres a tile at 0.55: L = R / 0.127), about 10^4 of them.
  return {{"box", makeBox(Vec3(-0.5f, -0.3f, -0.4f), Vec3(0.5f, 0.3f, 0.4f)), 0.005f},
          {"sphere", makeIcosphere(3), 0.012f},
          {"L-shape", makeLPrism(0.6f), 0.008f},
          // Five cells thick: inside cells, but none deeper than the field's band (3 cells).
          {"thin slab", makeBox(Vec3(-1.0f, -0.16f, -1.0f), Vec3(1.0f, 0.0f, 1.0f)), 0.004f}};
}

AggregateDesc aggregateOf(const Boundary& b) {
  AggregateDesc a;
  a.name = b.name;
  a.boundary = b.mesh;
  a.grainRadius = b.grainRadius;
  a.packingRate = 0.55f;
  a.seed = 3;
  a.tileSpheres = 64;
  a.prototypes = {GrainPrototypeDesc{"rock", makeRock(1, 0.25f, 3), 0}};
  a.weights = {1.0f};
  return a;
}

bool sameBits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }

// The build cache off for a scope: every build computes its products.
struct NoBuildCache {
  std::string saved;
  bool had;
  NoBuildCache() : had(std::getenv("GRANULAR_CACHE_MAX_MB") != nullptr) {
    if (had) saved = std::getenv("GRANULAR_CACHE_MAX_MB");
    setenv("GRANULAR_CACHE_MAX_MB", "0", 1);
  }
  ~NoBuildCache() {
    if (had) setenv("GRANULAR_CACHE_MAX_MB", saved.c_str(), 1);
    else unsetenv("GRANULAR_CACHE_MAX_MB");
  }
};

}  // namespace

TEST(DistanceFieldRows, RowsGiveDistanceBitForBit) {
  Rng rng(5);
  for (const Boundary& b : boundaries()) {
    for (float voxel : {0.013f, 0.031f}) {
      DistanceField f;
      f.build(b.mesh, voxel, 3.3f * voxel);
      const Bounds3 box = b.mesh.bounds();
      const Vec3 lo = box.lo - Vec3(0.2f), hi = box.hi + Vec3(0.2f);
      size_t checked = 0;
      for (int row = 0; row < 400; ++row) {
        // Rows of evenly spaced points as the classification makes them (spacing finer
        // and coarser than a voxel), and unevenly spaced ones in any order.
        const float y = lo.y + rng.next1D() * (hi.y - lo.y), z = lo.z + rng.next1D() * (hi.z - lo.z);
        const float step = voxel * (0.2f + 2.0f * rng.next1D());
        std::vector<Vec3> p;
        for (float x = lo.x; x < hi.x; x += step) p.push_back(Vec3(x, y, z));
        if (row % 4 == 3) {
          for (Vec3& q : p) q.x = lo.x + rng.next1D() * (hi.x - lo.x);
        }
        std::vector<float> d(p.size());
        f.distances(p.data(), p.size(), d.data());
        for (size_t i = 0; i < p.size(); ++i)
          ASSERT_TRUE(sameBits(d[i], f.distance(p[i])))
              << b.name << " voxel " << voxel << " at " << p[i].x << "," << p[i].y << "," << p[i].z << ": " << d[i]
              << " vs " << f.distance(p[i]);
        checked += p.size();
      }
      // Points off a common row, and a row of a few points far apart, take distance() itself.
      std::vector<Vec3> scattered(257);
      for (Vec3& q : scattered)
        q = lo + Vec3(rng.next1D(), rng.next1D(), rng.next1D()) * (hi - lo);
      std::vector<Vec3> sparse = {Vec3(-50.0f, 0.1f, 0.2f), Vec3(0.3f, 0.1f, 0.2f), Vec3(70.0f, 0.1f, 0.2f)};
      for (const std::vector<Vec3>* pts : {&scattered, &sparse}) {
        std::vector<float> d(pts->size());
        f.distances(pts->data(), pts->size(), d.data());
        for (size_t i = 0; i < pts->size(); ++i) ASSERT_TRUE(sameBits(d[i], f.distance((*pts)[i])));
      }
      EXPECT_GT(checked, 10000u);
    }
  }
}

TEST(AggregateColdBuild, ClassesAndDepthAreThePerCellClassification) {
  NoBuildCache off;
  const EmbreeDevice device = makeEmbreeDevice();
  for (const Boundary& b : boundaries()) {
    Aggregate a;
    a.build(aggregateOf(b), device, {0});
    ASSERT_FALSE(a.stats().fromCache);
    // The classification of build() as it was, cell by cell through distance().
    const DistanceField& f = a.distanceField();
    const float L = a.cellSize(), margin = 0.8661f * L + a.maxGrainRadius() + 1.5f * f.voxelSize();
    const Vec3 origin = a.bounds().lo;
    int64_t n[3];
    for (int ax = 0; ax < 3; ++ax) n[ax] = int64_t(std::llround((a.bounds().hi[ax] - origin[ax]) / L));
    const int64_t cells = n[0] * n[1] * n[2];
    ASSERT_EQ(cells, a.stats().cells) << b.name;
    const int64_t keepStride = std::max<int64_t>(1, cells / 65536);
    int64_t inside = 0, partial = 0, mismatched = 0;
    float deepest = 0;
    std::vector<Vec3> clamped;
    for (int64_t k = 0; k < n[2]; ++k)
      for (int64_t j = 0; j < n[1]; ++j)
        for (int64_t i = 0; i < n[0]; ++i) {
          const Vec3 c = origin + Vec3(float(i) + 0.5f, float(j) + 0.5f, float(k) + 0.5f) * L;
          const float dist = f.distance(c);
          const CellClass cls =
              dist > margin ? CellClass::Outside : (dist < -margin ? CellClass::Inside : CellClass::Partial);
          mismatched += a.cellClass(i, j, k) != cls;
          inside += cls == CellClass::Inside;
          partial += cls == CellClass::Partial;
          deepest = std::max(deepest, -dist);
          if (-dist >= 0.99f * f.bandWidth() && ((k * n[1] + j) * n[0] + i) % keepStride == 0) clamped.push_back(c);
        }
    float depth = deepest;
    const size_t stride = std::max<size_t>(1, clamped.size() / 4096);
    for (size_t s = 0; s < clamped.size(); s += stride) {
      Vec3 closest;
      depth = std::max(depth, a.closestBoundaryPoint(clamped[s], closest));
    }
    EXPECT_EQ(mismatched, 0) << b.name;
    EXPECT_EQ(a.stats().insideCells, inside) << b.name;
    EXPECT_EQ(a.stats().partialCells, partial) << b.name;
    EXPECT_TRUE(sameBits(a.stats().maxInteriorDepth, depth))
        << b.name << ": " << a.stats().maxInteriorDepth << " vs " << depth;
    // Inside and partial cells everywhere, outside ones where the grid does not hug the
    // boundary (not the boxes), and depths beyond the band but in the thin slab.
    EXPECT_GT(inside, 0) << b.name;
    EXPECT_GT(partial, 0) << b.name;
    if (b.name == "sphere" || b.name == "L-shape") EXPECT_LT(inside + partial, cells) << b.name;
    EXPECT_EQ(clamped.empty(), b.name == "thin slab") << b.name;
  }
}
