// Aggregate: cell classification, grain instantiation and ray intersection against
// brute-force references (tests mirror core/aggregate.*).
#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <set>
#include <tuple>

#include "core/aggregate.h"
#include "core/material.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;
using granular::testing::smallAggregate;
using granular::testing::pointInMesh;
using granular::testing::rayTriangle;

namespace {

struct Built {
  EmbreeDevice device = makeEmbreeDevice();
  Aggregate agg;
  explicit Built(const AggregateDesc& d) { agg.build(d, device, {0, 0}); }
};

}  // namespace

TEST(Aggregate, CellClassificationAgreesWithPointInMesh) {
  // Grains small enough that the object holds inside, partial and outside cells.
  AggregateDesc d = smallAggregate(0.02f);
  Built b(d);
  const Aggregate& a = b.agg;
  const TriangleMesh& mesh = a.boundary();
  Rng rng(11);
  int inside = 0, outside = 0;
  float L = a.cellSize();
  Vec3 lo = a.bounds().lo;
  int64_t n[3];
  for (int ax = 0; ax < 3; ++ax) n[ax] = int64_t(std::llround((a.bounds().hi[ax] - lo[ax]) / L));
  for (int64_t k = 0; k < n[2]; ++k)
    for (int64_t j = 0; j < n[1]; ++j)
      for (int64_t i = 0; i < n[0]; ++i) {
        CellClass c = a.cellClass(i, j, k);
        if (c == CellClass::Partial) continue;
        for (int s = 0; s < 8; ++s) {
          Vec3 p = lo + Vec3(i + rng.next1D(), j + rng.next1D(), k + rng.next1D()) * L;
          bool in = pointInMesh(mesh, p);
          if (c == CellClass::Inside) { EXPECT_TRUE(in) << "cell " << i << "," << j << "," << k; ++inside; }
          else { EXPECT_FALSE(in) << "cell " << i << "," << j << "," << k; ++outside; }
        }
      }
  EXPECT_GT(inside, 0);
  EXPECT_GT(outside, 0);
  EXPECT_GT(a.stats().partialCells, 0);
}

TEST(Aggregate, GrainsAreExactlyTheSpheresCentredInside) {
  AggregateDesc d = smallAggregate();
  Built b(d);
  const Aggregate& a = b.agg;
  std::set<std::tuple<int64_t, int64_t, int64_t, int>> produced;
  int counts[2] = {0, 0};
  a.forEachGrain(a.bounds(), [&](const GrainInstance& g) {
    produced.insert({g.cell[0], g.cell[1], g.cell[2], g.sphere});
    ++counts[g.prototype];
  });
  // Brute force: every sphere of every tile copy, tested against the mesh itself.
  std::set<std::tuple<int64_t, int64_t, int64_t, int>> expected;
  float L = a.cellSize();
  Vec3 lo = a.bounds().lo;
  int64_t n[3];
  for (int ax = 0; ax < 3; ++ax) n[ax] = int64_t(std::llround((a.bounds().hi[ax] - lo[ax]) / L));
  for (int64_t k = 0; k < n[2]; ++k)
    for (int64_t j = 0; j < n[1]; ++j)
      for (int64_t i = 0; i < n[0]; ++i)
        for (int s = 0; s < a.tile().numSpheres; ++s) {
          Vec3 c = lo + Vec3(float(i), float(j), float(k)) * L + a.tile().centers[s] * L;
          if (pointInMesh(a.boundary(), c)) expected.insert({i, j, k, s});
        }
  EXPECT_EQ(produced, expected);
  ASSERT_GT(expected.size(), 200u);
  // Mixing weights 3:1 — binomial standard error of the fraction.
  double total = counts[0] + counts[1];
  double p = 0.75, se = std::sqrt(p * (1 - p) / total);
  EXPECT_NEAR(counts[0] / total, p, 4 * se);
}

namespace {

void checkRaysAgainstBruteForce(const AggregateDesc& d) {
  Built b(d);
  const Aggregate& a = b.agg;
  // Every grain instantiated explicitly, in world space.
  struct WorldGrain { std::vector<Vec3> pts; const TriangleMesh* mesh; int64_t cell[3]; int sphere; float radius; };
  std::vector<WorldGrain> grains;
  a.forEachGrain(a.bounds(), [&](const GrainInstance& g) {
    WorldGrain w;
    w.mesh = &a.prototypes()[g.prototype].mesh;
    for (const Vec3& q : w.mesh->points) w.pts.push_back(g.center + (g.rotation * q) * g.radius);
    std::copy(g.cell, g.cell + 3, w.cell);
    w.sphere = g.sphere;
    w.radius = g.radius;
    grains.push_back(std::move(w));
  });
  ASSERT_GT(grains.size(), 100u);
  Rng rng(5);
  Bounds3 bb = a.bounds();
  int hits = 0, misses = 0;
  for (int r = 0; r < 300; ++r) {
    Vec3 target = bb.lo + Vec3(rng.next1D(), rng.next1D(), rng.next1D()) * bb.extent();
    Vec3 dir = sampleUniformSphere(rng.next1D(), rng.next1D());
    // Half the rays start outside, half inside the aggregate (as scattered paths do).
    Vec3 o = (r % 2) ? target - dir * (2.0f * length(bb.extent())) : target;
    float best = kInf;
    const WorldGrain* bg = nullptr;
    for (const auto& g : grains)
      for (size_t t = 0; t < g.mesh->numTriangles(); ++t) {
        float th = rayTriangle(o, dir, g.pts[g.mesh->indices[3 * t]], g.pts[g.mesh->indices[3 * t + 1]],
                               g.pts[g.mesh->indices[3 * t + 2]]);
        if (th < best) { best = th; bg = &g; }
      }
    GrainHit h;
    bool hit = a.intersect(o, dir, 0.0f, kInf, h);
    ASSERT_EQ(hit, std::isfinite(best)) << "ray " << r;
    if (!hit) { ++misses; continue; }
    ++hits;
    EXPECT_NEAR(h.t, best, 1e-4f * (1.0f + best)) << "ray " << r;
    EXPECT_EQ(h.sphere, bg->sphere) << "ray " << r;
    EXPECT_EQ(h.cell[0], bg->cell[0]);
    EXPECT_EQ(h.cell[1], bg->cell[1]);
    EXPECT_EQ(h.cell[2], bg->cell[2]);
    EXPECT_NEAR(length(h.ng), 1.0f, 1e-4f);
    EXPECT_EQ(h.radius, bg->radius);
  }
  EXPECT_GT(hits, 100);
  EXPECT_GT(misses, 5);
}

}  // namespace

TEST(Aggregate, RayIntersectionMatchesBruteForceOverEveryGrain) { checkRaysAgainstBruteForce(smallAggregate(0.1f, 0.5f)); }

namespace {

AggregateDesc withCoarseField(AggregateDesc d) {
  d.fineFieldBytes = 0;  // no field of a quarter tile fits: half a tile
  return d;
}

}  // namespace

TEST(Aggregate, RayIntersectionMatchesBruteForceWithTheCoarserField) {
  checkRaysAgainstBruteForce(withCoarseField(smallAggregate(0.1f, 0.5f)));
}

TEST(Aggregate, SmallFieldsAreAQuarterTileAndLargeOnesHalf) {
  const AggregateDesc d = smallAggregate(0.02f);
  Built fine(d), coarse(withCoarseField(d));
  const float L = fine.agg.cellSize();
  EXPECT_EQ(fine.agg.stats().fieldVoxel, 0.25f * L);
  EXPECT_EQ(coarse.agg.stats().fieldVoxel, 0.5f * L);
  EXPECT_EQ(fine.agg.distanceField().voxelSize(), 0.25f * L);
  // What the finer field is for: fewer cells near the boundary left partial.
  EXPECT_EQ(fine.agg.stats().cells, coarse.agg.stats().cells);
  EXPECT_GT(fine.agg.stats().insideCells, coarse.agg.stats().insideCells);
  EXPECT_LT(fine.agg.stats().partialCells, coarse.agg.stats().partialCells);
}

TEST(Aggregate, TheFieldsVoxelChangesNoGrain) {
  // The same grains, and every ray meets the same one at the same t, bit for bit (its
  // sphere traced from the same cell), whichever field decides the cells and the walk's
  // jumps.
  const AggregateDesc d = smallAggregate(0.02f);
  Built fine(d), coarse(withCoarseField(d));
  std::vector<std::tuple<int64_t, int64_t, int64_t, int, int>> grains[2];
  int k = 0;
  for (const Aggregate* a : {&fine.agg, &coarse.agg}) {
    a->forEachGrain(a->bounds(), [&](const GrainInstance& g) {
      grains[k].emplace_back(g.cell[0], g.cell[1], g.cell[2], g.sphere, g.prototype);
    });
    std::sort(grains[k].begin(), grains[k].end());
    ++k;
  }
  EXPECT_EQ(grains[0], grains[1]);
  ASSERT_GT(grains[0].size(), 10000u);
  Rng rng(23);
  const Bounds3 bb = fine.agg.bounds();
  int hits = 0;
  for (int r = 0; r < 4000; ++r) {
    const Vec3 target = bb.lo + Vec3(rng.next1D(), rng.next1D(), rng.next1D()) * bb.extent();
    const Vec3 dir = sampleUniformSphere(rng.next1D(), rng.next1D());
    const Vec3 o = (r % 2) ? target - dir * (2.0f * length(bb.extent())) : target;
    GrainHit a, b;
    const bool ha = fine.agg.intersect(o, dir, 0.0f, kInf, a), hb = coarse.agg.intersect(o, dir, 0.0f, kInf, b);
    ASSERT_EQ(ha, hb) << "ray " << r;
    EXPECT_EQ(fine.agg.occluded(o, dir, 0.0f, kInf), ha) << "ray " << r;
    EXPECT_EQ(coarse.agg.occluded(o, dir, 0.0f, kInf), hb) << "ray " << r;
    if (!ha) continue;
    ++hits;
    EXPECT_EQ(a.sphere, b.sphere) << "ray " << r;
    EXPECT_EQ(a.prim, b.prim) << "ray " << r;
    for (int ax = 0; ax < 3; ++ax) EXPECT_EQ(a.cell[ax], b.cell[ax]) << "ray " << r;
    EXPECT_EQ(a.t, b.t) << "ray " << r;
  }
  EXPECT_GT(hits, 1000);
}

TEST(Aggregate, JumpsOverEmptySubCellsMissNoGrain) {
  // Smaller grains: the band of partial cells is many sub-cells deep, and rays from
  // outside jump through it by the distance field (sphere tracing) before the surface.
  checkRaysAgainstBruteForce(smallAggregate(0.035f, 0.5f));
}

TEST(Aggregate, GrainsOfManySizesIntersectAsTheirOwnSpheres) {
  // Rocks 1.3 and boxes 0.6 of grainRadius, every grain spread by ±20%: each size class
  // holds one prototype, so a grain's radius says which it is.
  AggregateDesc d = smallAggregate(0.08f, 0.5f);
  d.sizes = {1.3f, 0.6f};
  d.sizeSpread = 0.2f;
  {
    Built b(d);
    int rocks = 0, boxes = 0;
    float largest = 0;
    b.agg.forEachGrain(b.agg.bounds(), [&](const GrainInstance& g) {
      largest = std::max(largest, g.radius);
      const float s = g.radius / d.grainRadius;
      if (g.prototype == 0) {
        ++rocks;
        EXPECT_GE(s, 1.3f * 0.8f - 1e-5f);
        EXPECT_LE(s, 1.3f * 1.2f + 1e-5f);
      } else {
        ++boxes;
        EXPECT_GE(s, 0.6f * 0.8f - 1e-5f);
        EXPECT_LE(s, 0.6f * 1.2f + 1e-5f);
      }
    });
    EXPECT_GT(rocks, 50);
    EXPECT_GT(boxes, 10);
    // The largest radius bounds every grain (the traversal's margins rely on it) and is
    // no larger than the largest size the spread allows.
    EXPECT_GE(b.agg.maxGrainRadius(), largest);
    EXPECT_LE(b.agg.maxGrainRadius(), d.grainRadius * 1.3f * 1.2f * (1.0f + 1e-6f));
  }
  checkRaysAgainstBruteForce(d);
}

TEST(Aggregate, MemoryDoesNotGrowWithGrainsPerTile) {
  // The same object with 8x the grains per tile costs tile-sized memory only.
  AggregateDesc d = smallAggregate(0.08f, 0.55f);
  d.tileSpheres = 64;
  Built small(d);
  d.tileSpheres = 512;
  d.grainRadius = 0.04f;  // 8x the grains in the same tile volume
  Built big(d);
  EXPECT_NEAR(big.agg.stats().cells, small.agg.stats().cells, 0.5 * small.agg.stats().cells);
  EXPECT_GT(big.agg.stats().approxGrains, 6.0 * small.agg.stats().approxGrains);
}

TEST(Aggregate, TinyAndHugeScenesClassifyLikeUnitScene) {
  // The same aggregate scaled to 1e-6 and 1e6 units: the distance field (OpenVDB refuses
  // transforms with voxels below ~1e-5) must work in any unit, and the cells' classes
  // must be those of the unit-scale aggregate.
  AggregateDesc unit = smallAggregate(0.1f);
  unit.xf = Transform();
  Built ref(unit);
  for (float s : {1e-6f, 1e6f}) {
    AggregateDesc d = unit;
    d.xf = Transform::scale(Vec3(s));
    d.grainRadius = unit.grainRadius * s;
    Built b(d);
    ASSERT_EQ(b.agg.stats().cells, ref.agg.stats().cells) << s;
    EXPECT_EQ(b.agg.stats().insideCells, ref.agg.stats().insideCells) << s;
    EXPECT_EQ(b.agg.stats().partialCells, ref.agg.stats().partialCells) << s;
    EXPECT_NEAR(b.agg.boundaryDistance(Vec3(0.0f)) / s, ref.agg.boundaryDistance(Vec3(0.0f)), 1e-3f) << s;
    for (float z : {1.05f, 0.95f})
      EXPECT_NEAR(b.agg.boundaryDistance(Vec3(0.0f, 0.0f, z * s)) / s, ref.agg.boundaryDistance(Vec3(0.0f, 0.0f, z)), 1e-3f)
          << s << " " << z;
  }
  // And the unit-scale field is the boundary's distance (icosphere: within a voxel).
  EXPECT_NEAR(ref.agg.boundaryDistance(Vec3(0.0f, 0.0f, 1.05f)), 0.05f, 0.02f);
  EXPECT_NEAR(ref.agg.boundaryDistance(Vec3(0.0f, 0.0f, 0.95f)), -0.05f, 0.02f);
}

TEST(Aggregate, NonFiniteRaysHitNothing) {
  Built b(smallAggregate());
  GrainHit h;
  const float nan = std::nanf("");
  EXPECT_FALSE(b.agg.intersect(Vec3(0, 0, 3), Vec3(nan, 0, -1), 0.0f, kInf, h));
  EXPECT_FALSE(b.agg.intersect(Vec3(nan, 0, 3), Vec3(0, 0, -1), 0.0f, kInf, h));
  EXPECT_FALSE(b.agg.intersect(Vec3(0, 0, 3), Vec3(kInf, 0, -1), 0.0f, kInf, h));
  EXPECT_TRUE(b.agg.intersect(Vec3(0.1f, -0.2f, 3), Vec3(0, 0, -1), 0.0f, kInf, h));  // the same ray, finite
}

namespace {
// Every face on the convex hull: a convex mesh.
bool allHull(const std::vector<uint8_t>& hull) {
  return std::all_of(hull.begin(), hull.end(), [](uint8_t h) { return h != 0; });
}
bool isConvex(const TriangleMesh& mesh) { return allHull(hullFaces(mesh, 1e-5f)); }
}  // namespace

TEST(Aggregate, ConvexityOfPrototypes) {
  EXPECT_TRUE(isConvex(makeBox(Vec3(-0.5f, -0.3f, -0.4f), Vec3(0.5f, 0.3f, 0.4f))));
  EXPECT_TRUE(isConvex(makeIcosphere(2)));
  TriangleMesh dented = makeIcosphere(2);
  dented.points[0] = dented.points[0] * 0.5f;  // one vertex pushed halfway in
  EXPECT_FALSE(isConvex(dented));
  // The faces around the dent are not on the hull; every other face is (the dent lies
  // behind them).
  const std::vector<uint8_t> hull = hullFaces(dented, 1e-5f);
  int aroundDent = 0;
  for (size_t t = 0; t < dented.numTriangles(); ++t) {
    const bool touches = dented.indices[3 * t] == 0 || dented.indices[3 * t + 1] == 0 || dented.indices[3 * t + 2] == 0;
    EXPECT_EQ(hull[t] != 0, !touches) << "triangle " << t;
    aroundDent += touches;
  }
  EXPECT_EQ(aroundDent, 5);  // an icosahedron's vertex
  AggregateDesc d = smallAggregate();
  d.prototypes[0].mesh = dented;
  Built b(d);
  EXPECT_FALSE(allHull(b.agg.prototypes()[0].hullFace));
  EXPECT_TRUE(allHull(b.agg.prototypes()[1].hullFace));
}

TEST(Aggregate, RaysFromTheirGrainHitWhatTheWalkHits) {
  // Paths through clear glass grains (IOR 1.5), as EPT casts them: each ray with the grain
  // it starts at (inside it: traced alone; leaving it through a face of its hull, every
  // face of a box and most of a dimpled sphere's: skipped) must hit what the full walk
  // hits without the hint, at the same t.
  AggregateDesc desc = smallAggregate(0.05f, 0.55f);
  TriangleMesh dimpled = makeIcosphere(2);  // prototype 0: a sphere with a dimple at every 7th vertex
  for (size_t v = 0; v < dimpled.points.size(); v += 7) dimpled.points[v] = dimpled.points[v] * 0.85f;
  desc.prototypes[0].mesh = dimpled;
  Built b(desc);
  const Aggregate& a = b.agg;
  ASSERT_FALSE(allHull(a.prototypes()[0].hullFace));
  Material glass;
  glass.type = MaterialType::Dielectric;
  glass.ior = 1.5f;
  Rng rng(3);
  const Bounds3 bb = a.bounds();
  int inside = 0, leavingBox = 0, leavingRockHull = 0, leavingRockDent = 0, rays = 0, hits = 0, sameT = 0;
  while (rays < 6000) {
    Vec3 target = bb.center() + (Vec3(rng.next1D(), rng.next1D(), rng.next1D()) - Vec3(0.5f)) * bb.extent() * 0.5f;
    Vec3 dir = sampleUniformSphere(rng.next1D(), rng.next1D());
    Vec3 o = target - dir * (2.0f * length(bb.extent())), d = dir;
    GrainHit from;
    bool hasFrom = false, in = false;
    for (int bounce = 0; bounce < 64; ++bounce, ++rays) {
      GrainHit h, plain;
      const bool found = a.intersect(o, d, 0.0f, kInf, h, hasFrom ? &from : nullptr, in);
      ASSERT_EQ(found, a.intersect(o, d, 0.0f, kInf, plain)) << "ray " << rays;
      inside += hasFrom && in;
      leavingBox += hasFrom && !in && from.prototype == 1;
      if (hasFrom && !in && from.prototype == 0)
        (a.prototypes()[0].hullFace[from.prim] ? leavingRockHull : leavingRockDent)++;
      if (!found) break;
      ASSERT_EQ(h.sphere, plain.sphere) << "ray " << rays;
      for (int ax = 0; ax < 3; ++ax) ASSERT_EQ(h.cell[ax], plain.cell[ax]) << "ray " << rays;
      EXPECT_NEAR(h.t, plain.t, 1e-5f * plain.t) << "ray " << rays;
      ++hits;
      sameT += h.t == plain.t;
      Frame frame(h.ng);
      BsdfSample bs;
      if (!glass.sample(frame.toLocal(-d), rng.next1D(), rng.next1D(), rng.next1D(), bs)) break;
      const Vec3 wi = frame.toWorld(bs.wi);
      in = dot(wi, h.ng) < 0;
      o = offsetRayOrigin(o + d * h.t, h.ng, wi, kGrainEps * h.radius);
      d = wi;
      from = h;
      hasFrom = true;
    }
  }
  EXPECT_GT(inside, rays / 3);
  EXPECT_GT(leavingBox, 100);
  EXPECT_GT(leavingRockHull, 100);  // skipped
  EXPECT_GT(leavingRockDent, 20);   // traced again: a dent can catch the ray
  // The grain is traced as from the walk's first cell: the same t to the bit (all 6026
  // here) but for an origin that rounds into another cell.
  EXPECT_GE(sameT, 0.99 * hits);
}

TEST(Aggregate, AWrongInsideHintFallsBackToTheWalk) {
  // A hint names a grain the ray does not start in. Where the ray misses that grain (a far
  // one, a neighbour), the walk answers as without the hint; where it meets it, the
  // grain's hit is returned, never nearer than the true one (a hint is the caller's
  // promise: a path's own last grain).
  Built b(smallAggregate(0.05f, 0.55f));
  const Aggregate& a = b.agg;
  Rng rng(9);
  const Bounds3 bb = a.bounds();
  int checked = 0;
  GrainHit previous;
  bool havePrevious = false;
  for (int r = 0; r < 400; ++r) {
    Vec3 o = bb.lo + Vec3(rng.next1D(), rng.next1D(), rng.next1D()) * bb.extent();
    Vec3 d = sampleUniformSphere(rng.next1D(), rng.next1D());
    GrainHit plain, hinted;
    const bool found = a.intersect(o, d, 0.0f, kInf, plain);
    if (havePrevious && !(found && plain.sphere == previous.sphere && plain.cell[0] == previous.cell[0] &&
                          plain.cell[1] == previous.cell[1] && plain.cell[2] == previous.cell[2])) {
      const bool hintedFound = a.intersect(o, d, 0.0f, kInf, hinted, &previous, true);
      if (hintedFound && hinted.sphere == previous.sphere && hinted.cell[0] == previous.cell[0] &&
          hinted.cell[1] == previous.cell[1] && hinted.cell[2] == previous.cell[2]) {
        ASSERT_TRUE(found);
        EXPECT_GT(hinted.t, plain.t) << "ray " << r;
      } else {
        ASSERT_EQ(hintedFound, found) << "ray " << r;
        if (found) {
          EXPECT_EQ(hinted.sphere, plain.sphere);
          EXPECT_EQ(hinted.t, plain.t);
        }
        ++checked;
      }
    }
    if (found) {
      previous = plain;
      havePrevious = true;
    }
  }
  EXPECT_GT(checked, 300);
}

TEST(Aggregate, OccludedAgreesWithTheNearestHit) {
  // Shadow rays stop at the first grain they meet: the answer must be the nearest hit's,
  // for rays from outside and inside, with segments that end before, at and after grains.
  Built b(smallAggregate(0.05f, 0.55f));
  const Aggregate& a = b.agg;
  Rng rng(21);
  const Bounds3 bb = a.bounds();
  int blocked = 0, clear = 0;
  for (int r = 0; r < 3000; ++r) {
    Vec3 o = bb.lo + Vec3(rng.next1D(), rng.next1D(), rng.next1D()) * bb.extent();
    Vec3 d = sampleUniformSphere(rng.next1D(), rng.next1D());
    if (r % 2) o = o - d * length(bb.extent());
    const float tmax = rng.next1D() * 1.5f * length(bb.extent());
    GrainHit h;
    const bool hit = a.intersect(o, d, 0.0f, tmax, h);
    ASSERT_EQ(a.occluded(o, d, 0.0f, tmax), hit) << "ray " << r;
    (hit ? blocked : clear)++;
  }
  EXPECT_GT(blocked, 500);
  EXPECT_GT(clear, 500);
}

TEST(Aggregate, ProxyQueriesAgreeWithEveryGrainChecked) {
  // Rays leaving a proxy sphere (the neighbour lists answer most of them, the walk the
  // rest): the nearest sphere entered and the proxy transmittance, against a brute force
  // over every grain of the aggregate.
  Built b(smallAggregate(0.05f, 0.55f));
  const Aggregate& a = b.agg;
  a.prepareProxies();
  std::vector<GrainInstance> grains;
  a.forEachGrain(a.bounds(), [&](const GrainInstance& g) { grains.push_back(g); });
  ASSERT_GT(grains.size(), 1000u);
  ProxyOptions po;
  po.rays = 1 << 14;
  po.useCache = false;
  Material glass;
  glass.type = MaterialType::Dielectric;
  glass.ior = 1.5f;
  ProxyTables tables;
  for (size_t i = 0; i < a.prototypes().size(); ++i) tables.add(int(i), 1.0f, estimateProxyTable(a.prototypes()[i].mesh, glass, po));
  Rng rng(33);
  int hits = 0, exact = 0;
  for (int r = 0; r < 3000; ++r) {
    const GrainInstance& g = grains[size_t(rng.next1D() * float(grains.size())) % grains.size()];
    const Vec3 u = sampleUniformSphere(rng.next1D(), rng.next1D());
    Vec3 d = sampleUniformSphere(rng.next1D(), rng.next1D());
    if (dot(d, u) < 0) d = -d;
    const Vec3 o = g.center + u * g.radius;
    GrainHit from;
    for (int k = 0; k < 3; ++k) from.cell[k] = g.cell[k];
    from.sphere = g.sphere;
    // Brute force: the nearest entry, and the product of the chances of crossing.
    float tBest = kInf;
    const GrainInstance* best = nullptr;
    const float tmax = 3.0f * a.grainRadius();
    Vec3 T(1.0f);
    double U = 1;  // the chance of meeting no grain at all
    for (const GrainInstance& h : grains) {
      if (&h == &g) continue;
      const Vec3 oc = o - h.center;
      const float along = dot(oc, d), w2 = length2(oc - d * along), disc = h.radius * h.radius - w2;
      if (disc < 0 || -along + std::sqrt(disc) < 0) continue;
      const float te = std::max(0.0f, -along - std::sqrt(disc));
      if (te < tBest) {
        tBest = te;
        best = &h;
      }
      if (te < tmax) {
        const ProxyTable& t = tables.at(h.prototype, h.radius / a.grainRadius());
        T *= t.crossing(t.bBin(std::sqrt(w2) / h.radius));
        U *= 1.0 - t.hitProbability(t.bBin(std::sqrt(w2) / h.radius));
      }
    }
    GrainHit hit;
    const bool found = a.intersectProxy(o, d, 0.0f, kInf, hit, &from);
    ASSERT_EQ(found, best != nullptr) << "ray " << r;
    if (found) {
      ++hits;
      ASSERT_NEAR(hit.t, tBest, 1e-4f * a.grainRadius()) << "ray " << r;
      if (hit.sphere == best->sphere && hit.cell[0] == best->cell[0] && hit.cell[1] == best->cell[1] &&
          hit.cell[2] == best->cell[2]) {
        ++exact;
        EXPECT_EQ(hit.prototype, best->prototype);
        EXPECT_NEAR(length(hit.center - best->center), 0.0f, 1e-5f);
      }
    }
    const ProxyShadow tr = a.proxyTransmittance(o, d, 0.0f, tmax, tables, &from, uint64_t(r));
    if (maxComponent(T) >= kProxyRoulette * 1.001f) {
      for (int c = 0; c < 3; ++c)
        ASSERT_NEAR(tr.crossing[c], T[c], 1e-4f * T[c] + 1e-6f) << "ray " << r << " channel " << c;
      ASSERT_NEAR(tr.unscattered, U, 1e-4 * U + 1e-6) << "ray " << r;
    } else {
      ASSERT_TRUE(tr.blocked() || std::fabs(maxComponent(tr.crossing) - kProxyRoulette) < 1e-6f) << "ray " << r;
    }
  }
  EXPECT_GT(hits, 1500);
  EXPECT_GE(exact, hits - 3) << "only ties may name another sphere";
}
