// The cold build's cell classification reads its distances a row at a time
// (DistanceField::distances): the values must be distance()'s bit for bit, so that the
// classes, counts and interior depth are the per-cell classification's. Boundaries equal
// but for a translation share one anchored field (DistanceField::buildShared): it must be
// the field each would build alone, so that their cells are the same.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <thread>
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
  // Each boundary with its field of a quarter tile and with the coarser one of half a tile.
  for (const bool fine : {true, false})
  for (const Boundary& b : boundaries()) {
    AggregateDesc desc = aggregateOf(b);
    if (!fine) desc.fineFieldBytes = 0;
    Aggregate a;
    a.build(desc, device, {0});
    ASSERT_FALSE(a.stats().fromCache);
    ASSERT_EQ(a.distanceField().voxelSize(), (fine ? 0.25f : 0.5f) * a.cellSize()) << b.name;
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
    // boundary (not the boxes), and depths beyond the band: everywhere with the finer
    // field's narrower band, but in the thin slab with the coarser one.
    EXPECT_GT(inside, 0) << b.name;
    EXPECT_GT(partial, 0) << b.name;
    if (b.name == "sphere" || b.name == "L-shape") EXPECT_LT(inside + partial, cells) << b.name;
    EXPECT_EQ(clamped.empty(), !fine && b.name == "thin slab") << b.name;
  }
}

// ---- the exact field of a box (DistanceField::buildBox) ---------------------------------

TEST(DistanceFieldBox, OnlyAnAxisAlignedBoxIsOne) {
  Bounds3 box;
  const TriangleMesh cube = makeBox(Vec3(-0.5f, -0.3f, -0.4f), Vec3(0.5f, 0.3f, 0.4f));
  ASSERT_TRUE(DistanceField::isAxisAlignedBox(cube, box));
  EXPECT_EQ(box.lo, Vec3(-0.5f, -0.3f, -0.4f));
  EXPECT_EQ(box.hi, Vec3(0.5f, 0.3f, 0.4f));
  TriangleMesh flipped = cube;
  flipped.flip();
  EXPECT_TRUE(DistanceField::isAxisAlignedBox(flipped, box));
  EXPECT_FALSE(DistanceField::isAxisAlignedBox(makeLPrism(0.6f), box));
  EXPECT_FALSE(DistanceField::isAxisAlignedBox(makeIcosphere(1), box));
  // Turned about z by 30°: the same twelve triangles, no longer along the axes.
  Transform turn;
  turn.m[0][0] = turn.m[1][1] = 0.8660254037844386;
  turn.m[0][1] = -0.5;
  turn.m[1][0] = 0.5;
  EXPECT_FALSE(DistanceField::isAxisAlignedBox(cube.transformed(turn), box));
  // One corner moved off the bounds' corners (a sheared box).
  TriangleMesh sheared = cube;
  sheared.points[0].x += 0.1f;
  EXPECT_FALSE(DistanceField::isAxisAlignedBox(sheared, box));
  // A face's two triangles the same one twice: the face is not covered.
  TriangleMesh holed = cube;
  for (int k = 0; k < 3; ++k) holed.indices[3 + k] = holed.indices[k];
  EXPECT_FALSE(DistanceField::isAxisAlignedBox(holed, box));
  // Two triangles of a face that leave out adjacent corners: they overlap, and a quarter
  // of the face is open.
  TriangleMesh overlapping = cube;
  const uint32_t other[3] = {overlapping.indices[1], overlapping.indices[2], overlapping.indices[5]};
  for (int k = 0; k < 3; ++k) overlapping.indices[3 + k] = other[k];
  EXPECT_FALSE(DistanceField::isAxisAlignedBox(overlapping, box));
}

TEST(DistanceFieldBox, VoxelsHoldTheExactDistanceAndTheBandIsBuilds) {
  const Vec3 lo(-0.5f, -0.3f, -0.4f), hi(0.5f, 0.3f, 0.4f);
  const float voxel = 0.013f, minBand = 3.3f * voxel;
  DistanceField exact, meshed;
  exact.buildBox(Bounds3{lo, hi}, voxel, minBand);
  meshed.build(makeBox(lo, hi), voxel, minBand);
  ASSERT_EQ(exact.bandWidth(), meshed.bandWidth());
  const float band = exact.bandWidth();
  // At voxel centres (index space, corners rounded as build() rounds a mesh's points),
  // the distance to the box in double, rounded once, clamped to ±band.
  const double inv = 1.0 / double(voxel);
  double blo[3], bhi[3];
  for (int a = 0; a < 3; ++a) {
    blo[a] = double(float(lo[a] * inv));
    bhi[a] = double(float(hi[a] * inv));
  }
  Rng rng(11);
  int64_t checked = 0, inBand = 0;
  for (int s = 0; s < 200000; ++s) {
    int ijk[3];
    double outside2 = 0, depth = 1e30;
    for (int a = 0; a < 3; ++a) {
      ijk[a] = int(std::floor(blo[a] - 7.0 + rng.next1D() * (bhi[a] - blo[a] + 14.0)));
      const double e = std::max({blo[a] - ijk[a], 0.0, ijk[a] - bhi[a]});
      outside2 += e * e;
      depth = std::min({depth, ijk[a] - blo[a], bhi[a] - ijk[a]});
    }
    const double d = outside2 > 0 ? std::sqrt(outside2) : -depth;
    const float want = float(std::clamp(d, -double(band / voxel), double(band / voxel))) * voxel;
    const Vec3 p(float(ijk[0] * double(voxel)), float(ijk[1] * double(voxel)), float(ijk[2] * double(voxel)));
    // The point's index coordinates are ijk up to float rounding: the trilinear weights of
    // the other corners are ~1e-7, so distance() is the voxel's value to a few ulps.
    ASSERT_NEAR(exact.distance(p), want, 1e-5f * voxel) << ijk[0] << "," << ijk[1] << "," << ijk[2];
    ++checked;
    inBand += std::fabs(d) < band / voxel;
  }
  EXPECT_GT(inBand, checked / 10);
  // Beyond the band, inside and out, the field holds ±band as build()'s does (the
  // signed flood fill of the tiles).
  for (const Vec3& p : {Vec3(0.0f), Vec3(0.0f, 0.0f, 0.05f), Vec3(2.0f, 0.0f, 0.0f), Vec3(-0.9f, 0.8f, 0.7f)}) {
    EXPECT_EQ(exact.distance(p), meshed.distance(p)) << p.x << "," << p.y << "," << p.z;
    EXPECT_EQ(std::fabs(exact.distance(p)), band);
  }
}

TEST(DistanceFieldBox, ClassesAreMeshToLevelSetsButAtAFewCellsOnTheMargin) {
  // The cold build classifies a box's cells on the exact field: against OpenVDB's field of
  // the box's mesh (which renormalises and offsets its values, and near edges and corners
  // is off by up to ~0.2 voxel), a class may differ only where the value lies within that
  // of ±margin, a thin shell along the edges: here, under 1 cell in 10^3.
  for (const Boundary& b : boundaries()) {
    Bounds3 box;
    if (!DistanceField::isAxisAlignedBox(b.mesh, box)) continue;
    const float L = 0.031f, voxel = 0.5f * L, margin = 0.8661f * L + b.grainRadius + 1.5f * voxel;
    DistanceField exact, meshed;
    exact.buildBox(box, voxel, margin + voxel);
    meshed.build(b.mesh, voxel, margin + voxel);
    int64_t cells = 0, differ = 0, partial = 0;
    for (float z = box.lo.z - 2 * L; z < box.hi.z + 2 * L; z += L)
      for (float y = box.lo.y - 2 * L; y < box.hi.y + 2 * L; y += L)
        for (float x = box.lo.x - 2 * L; x < box.hi.x + 2 * L; x += L) {
          const Vec3 c(x + 0.5f * L, y + 0.5f * L, z + 0.5f * L);
          auto classOf = [margin](float d) { return d > margin ? 0 : (d < -margin ? 2 : 1); };
          const int e = classOf(exact.distance(c)), m = classOf(meshed.distance(c));
          ++cells;
          differ += e != m;
          partial += e == 1;
        }
    EXPECT_GT(partial, cells / 10) << b.name;
    EXPECT_LT(differ * 1000, cells) << b.name << ": " << differ << " of " << cells;
  }
}

// ---- the memory a field will take, before it is built (DistanceField::estimateBytes) ----

TEST(DistanceFieldMemory, TheEstimateIsNearWhatTheBuiltFieldTakes) {
  // Meshes of one surface and of many faces, edges and corners, at voxels from a tenth to
  // an eightieth of their size (the tree's upper nodes weigh most in the coarsest, the
  // leaves in the finest): the aggregate picks its field by this estimate, within a third.
  struct Case { const char* name; TriangleMesh mesh; };
  const Case cases[] = {{"sphere", makeIcosphere(4)}, {"L prism", makeLPrism(0.6f)},
                        {"rock", makeRock(3, 0.25f, 5)}};
  for (const Case& c : cases)
    for (float voxel : {0.1f, 0.05f, 0.025f, 0.0125f}) {
      const float minBand = 3.7f * voxel;
      DistanceField f;
      f.build(c.mesh, voxel, minBand);
      const double built = double(f.memoryBytes()), estimate = DistanceField::estimateBytes(c.mesh.area(), voxel, minBand);
      EXPECT_GT(estimate, 0.75 * built) << c.name << " voxel " << voxel;
      EXPECT_LT(estimate, 1.33 * built) << c.name << " voxel " << voxel;
    }
}

// ---- congruent boundaries share one field (DistanceField::buildShared) ------------------

TEST(DistanceFieldShared, TranslatedCopiesShareTheGridTheyWouldBuildAlone) {
  const TriangleMesh local = makeLPrism(0.6f);
  const float voxel = 0.013f, minBand = 3.3f * voxel;
  // Translations in whole units: q + t is exact in float for the points q below, so that
  // the copies are read at the same local points.
  const Vec3d ta{2, -1, 0.5}, tb{-3, 0.25, 4};
  DistanceField alone;
  alone.buildAnchored(local, tb, voxel, minBand);
  auto a = std::make_unique<DistanceField>();
  DistanceField b;
  a->buildShared(local, ta, voxel, minBand);
  b.buildShared(local, tb, voxel, minBand);
  ASSERT_NE(a->grid(), nullptr);
  EXPECT_EQ(a->grid(), b.grid());
  EXPECT_NE(alone.grid(), b.grid());
  EXPECT_EQ(a->anchor(), ta);
  EXPECT_EQ(b.anchor(), tb);
  EXPECT_EQ(b.bandWidth(), alone.bandWidth());
  // Values on a lattice of local points finer than the voxels (x a row at a time, as the
  // classification reads them), across the band and beyond it: the shared field's are
  // those of the field built alone, and the copies' agree at the translated points.
  const auto at = [](float q, double t) { return float(double(q) + t); };
  int64_t checked = 0, inBand = 0;
  std::vector<Vec3> row;
  std::vector<float> da, db, dalone;
  for (float z = -0.25f; z < 0.85f; z += 1.0f / 32)
    for (float y = -0.25f; y < 2.25f; y += 1.0f / 16) {
      row.clear();
      for (float x = -0.25f; x < 2.25f; x += 1.0f / 128) row.push_back(Vec3(x, y, z));
      std::vector<Vec3> pa(row.size()), pb(row.size());
      for (size_t i = 0; i < row.size(); ++i) {
        pa[i] = Vec3(at(row[i].x, ta.x), at(row[i].y, ta.y), at(row[i].z, ta.z));
        pb[i] = Vec3(at(row[i].x, tb.x), at(row[i].y, tb.y), at(row[i].z, tb.z));
      }
      da.resize(row.size());
      db.resize(row.size());
      dalone.resize(row.size());
      a->distances(pa.data(), pa.size(), da.data());
      b.distances(pb.data(), pb.size(), db.data());
      alone.distances(pb.data(), pb.size(), dalone.data());
      DistanceField::NearestProbe na(*a), nb(b), nalone(alone);
      for (size_t i = 0; i < row.size(); ++i) {
        ASSERT_TRUE(sameBits(db[i], dalone[i])) << row[i].x << "," << row[i].y << "," << row[i].z;
        ASSERT_TRUE(sameBits(da[i], db[i])) << row[i].x << "," << row[i].y << "," << row[i].z;
        ASSERT_TRUE(sameBits(db[i], b.distance(pb[i])));
        ASSERT_TRUE(sameBits(nb(pb[i]), nalone(pb[i])));
        ASSERT_TRUE(sameBits(na(pa[i]), nb(pb[i])));
        inBand += std::fabs(db[i]) < b.bandWidth();
        ++checked;
      }
    }
  EXPECT_GT(inBand, checked / 10);
  EXPECT_LT(inBand, checked);
  // The grid outlives the field that built it.
  const float before = b.distance(Vec3(at(1.0f, tb.x), at(0.5f, tb.y), at(0.3f, tb.z)));
  a.reset();
  EXPECT_TRUE(sameBits(b.distance(Vec3(at(1.0f, tb.x), at(0.5f, tb.y), at(0.3f, tb.z))), before));
  DistanceField c;
  c.buildShared(local, Vec3d{}, voxel, minBand);
  EXPECT_EQ(c.grid(), b.grid());
}

TEST(DistanceFieldShared, OnlyTheSameMeshVoxelAndBandShare) {
  const TriangleMesh local = makeLPrism(0.6f);
  const float voxel = 0.017f, minBand = 3.3f * voxel;
  DistanceField f;
  f.buildShared(local, Vec3d{1, 2, 3}, voxel, minBand);
  TriangleMesh moved = local;  // one point off by an ulp
  moved.points[4].x = std::nextafter(moved.points[4].x, 2.0f);
  TriangleMesh rewound = local;  // one triangle wound the other way
  std::swap(rewound.indices[1], rewound.indices[2]);
  DistanceField g, h, i, j;
  g.buildShared(moved, Vec3d{1, 2, 3}, voxel, minBand);
  h.buildShared(rewound, Vec3d{1, 2, 3}, voxel, minBand);
  i.buildShared(local, Vec3d{1, 2, 3}, std::nextafter(voxel, 1.0f), minBand);
  j.buildShared(local, Vec3d{1, 2, 3}, voxel, 5.3f * voxel);  // a wider band
  for (const DistanceField* o : {&g, &h, &i, &j}) EXPECT_NE(o->grid(), f.grid());
}

TEST(DistanceFieldShared, BuildsSideBySideWaitForOneGrid) {
  const TriangleMesh local = makeIcosphere(3);
  const float voxel = 0.011f, minBand = 3.3f * voxel;
  std::vector<DistanceField> fields(4);
  std::vector<std::thread> threads;
  for (size_t k = 0; k < fields.size(); ++k)
    threads.emplace_back([&, k] { fields[k].buildShared(local, Vec3d{double(k), 0, 0}, voxel, minBand); });
  for (auto& t : threads) t.join();
  for (const DistanceField& f : fields) {
    EXPECT_EQ(f.grid(), fields[0].grid());
    EXPECT_FALSE(f.empty());
  }
  EXPECT_TRUE(sameBits(fields[3].distance(Vec3(3.0f, 0.0f, 0.0f)), fields[0].distance(Vec3(0.0f))));
  EXPECT_LT(fields[0].distance(Vec3(0.0f)), 0.0f);
}

TEST(AggregateColdBuild, TranslatedCopiesShareTheFieldAndGetTheSameCells) {
  NoBuildCache off;
  const EmbreeDevice device = makeEmbreeDevice();
  // Both copies within [64, 128) on every axis, moved by whole units: every coordinate the
  // build computes (bounds, cell centres, closest points) rounds alike in both, so the
  // copies' cells are the same bit for bit.
  AggregateDesc da = aggregateOf({"L-shape", makeLPrism(0.6f), 0.008f}), db = da;
  da.xf = Transform::translate(70.0, 80.0, 90.0);
  db.xf = Transform::translate(100.0, 72.0, 96.0);
  db.name = "L-shape copy";
  const auto cellsOf = [](const Aggregate& a) {
    std::vector<CellClass> c;
    int64_t n[3];
    for (int ax = 0; ax < 3; ++ax) n[ax] = int64_t(std::llround((a.bounds().hi[ax] - a.bounds().lo[ax]) / a.cellSize()));
    for (int64_t k = 0; k < n[2]; ++k)
      for (int64_t j = 0; j < n[1]; ++j)
        for (int64_t i = 0; i < n[0]; ++i) c.push_back(a.cellClass(i, j, k));
    return c;
  };
  const auto expectSame = [](const Aggregate& x, const Aggregate& y, const std::vector<CellClass>& cx,
                             const std::vector<CellClass>& cy) {
    EXPECT_EQ(x.stats().cells, y.stats().cells);
    EXPECT_EQ(x.stats().insideCells, y.stats().insideCells);
    EXPECT_EQ(x.stats().partialCells, y.stats().partialCells);
    EXPECT_TRUE(sameBits(float(x.stats().approxGrains), float(y.stats().approxGrains)));
    EXPECT_EQ(x.stats().approxGrains, y.stats().approxGrains);
    EXPECT_TRUE(sameBits(x.stats().maxInteriorDepth, y.stats().maxInteriorDepth))
        << x.stats().maxInteriorDepth << " vs " << y.stats().maxInteriorDepth;
    EXPECT_TRUE(cx == cy);
  };
  // The copy built alone (its own grid: no field of that mesh is alive).
  std::vector<CellClass> aloneCells;
  AggregateStats aloneStats;
  {
    Aggregate alone;
    alone.build(db, device, {0});
    aloneCells = cellsOf(alone);
    aloneStats = alone.stats();
  }
  Aggregate a, b;
  a.build(da, device, {0});
  b.build(db, device, {0});
  ASSERT_FALSE(b.stats().fromCache);
  EXPECT_EQ(a.distanceField().grid(), b.distanceField().grid());
  const std::vector<CellClass> ca = cellsOf(a), cb = cellsOf(b);
  expectSame(a, b, ca, cb);
  EXPECT_EQ(b.stats().insideCells, aloneStats.insideCells);
  EXPECT_EQ(b.stats().partialCells, aloneStats.partialCells);
  EXPECT_EQ(b.stats().approxGrains, aloneStats.approxGrains);
  EXPECT_TRUE(sameBits(b.stats().maxInteriorDepth, aloneStats.maxInteriorDepth));
  EXPECT_TRUE(cb == aloneCells);
  EXPECT_GT(b.stats().insideCells, 0);
  EXPECT_GT(b.stats().partialCells, 0);
  // The field reads the copy where it stands: the L's notch (local (1.5, 1.5)) is outside,
  // its arm (local (0.5, 1.5)) inside, at mid-height.
  EXPECT_GT(b.boundaryDistance(Vec3(101.5f, 73.5f, 96.3f)), 0.0f);
  EXPECT_LT(b.boundaryDistance(Vec3(100.5f, 73.5f, 96.3f)), 0.0f);
}
