// test_instanced_grains.cpp — explicit grains (instanced_grains.h): the grid's queries
// against brute force over every grain, its memory bound, and the validation's named
// errors (core and the USD meaning in granular_prims.h).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <utility>

#include "core/ept.h"
#include "core/error.h"
#include "core/granular_prims.h"
#include "core/instanced_grains.h"
#include "core/render.h"
#include "core/scene.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;
using granular::testing::ChannelEstimate;
using granular::testing::errorOf;
using granular::testing::randomRotation;
using granular::testing::blocks;
using granular::testing::renderEstimate;
using granular::testing::renderEstimates;

namespace {

// Two prototypes: a unit icosphere and a box off its origin (a non-zero fitCenter).
std::vector<GrainPrototypeDesc> twoPrototypes() {
  GrainPrototypeDesc a, b;
  a.name = "/Sim/Round";
  a.mesh = makeIcosphere(1);
  b.name = "/Sim/Box";
  b.mesh = makeBox(Vec3(0.2f, 0.2f, 0.2f), Vec3(1.0f, 1.4f, 1.0f));
  return {a, b};
}

// Grains on a jittered lattice of spacing 2.3 (bounding radii <= 1: never overlapping),
// `keep` of the sites occupied, random scales in [0.6, 1], rotations and prototypes.
InstancedGrainsDesc latticeGrains(int side, float keep, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  InstancedGrainsDesc d;
  d.name = "/Sim";
  d.prototypes = twoPrototypes();
  for (int z = 0; z < side; ++z)
    for (int y = 0; y < side; ++y)
      for (int x = 0; x < side; ++x) {
        if (u(rng) >= keep) continue;
        Vec3 jitter(u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f);
        int proto = u(rng) < 0.5f ? 0 : 1;
        Quat q = randomRotation(rng);
        float s = 0.6f + 0.4f * u(rng);
        // The box's bounding centre is off its origin: place the grain by its centre.
        d.positions.push_back(Vec3(float(x), float(y), float(z)) * 2.3f + jitter * 0.2f);
        d.orientations.push_back(q);
        d.scales.push_back(s);
        d.protoIndices.push_back(proto);
      }
  return d;
}

// Fixes each box grain's position so its bounding sphere sits where the lattice put it.
void centreBoxes(InstancedGrainsDesc& d, const InstancedGrains& probe) {
  const GrainPrototype& box = probe.prototypes()[1];
  for (size_t i = 0; i < d.size(); ++i)
    if (d.protoIndices[i] == 1) d.positions[i] = d.positions[i] - rotate(d.orientations[i], box.fitCenter) * d.scales[i];
}

InstancedGrainsDesc nonOverlapping(const EmbreeDevice& device, int side, float keep, uint32_t seed) {
  InstancedGrainsDesc d = latticeGrains(side, keep, seed);
  InstancedGrains probe;
  InstancedGrainsDesc one;
  one.name = "/Probe";
  one.prototypes = d.prototypes;
  one.positions = {Vec3(0.0f)};
  one.protoIndices = {0};
  probe.build(one, device);
  centreBoxes(d, probe);
  return d;
}

Vec3 randomDirection(std::mt19937& rng) {
  std::normal_distribution<float> n(0.0f, 1.0f);
  return normalize(Vec3(n(rng), n(rng), n(rng)));
}

void expectSameHits(const InstancedGrains& g, const Bounds3& region, uint32_t seed, int rays, int minHits) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  int hits = 0;
  const Vec3 lo = region.lo - region.extent() * 0.2f, size = region.extent() * 1.4f;
  for (int k = 0; k < rays; ++k) {
    Vec3 o = lo + Vec3(u(rng), u(rng), u(rng)) * size;
    Vec3 d = randomDirection(rng) * (0.5f + u(rng));  // not unit: t is the caller's
    float tmax = k % 3 == 0 ? 5.0f + 20.0f * u(rng) : kInf;
    InstancedGrainHit a, b;
    bool ha = g.intersect(o, d, 0.0f, tmax, a);
    bool hb = g.intersectAll(o, d, 0.0f, tmax, b);
    ASSERT_EQ(ha, hb) << "ray " << k;
    EXPECT_EQ(g.occluded(o, d, 0.0f, tmax), hb) << "ray " << k;
    if (!ha) continue;
    ++hits;
    ASSERT_EQ(a.grain, b.grain) << "ray " << k;
    EXPECT_EQ(a.t, b.t) << "ray " << k;
    EXPECT_EQ(a.prim, b.prim);
    EXPECT_NEAR(length(a.ng), 1.0f, 1e-5f);
  }
  // Enough rays meet grains for the comparison to mean something.
  EXPECT_GT(hits, minHits);
}

}  // namespace

TEST(InstancedGrains, IntersectMatchesBruteForce) {
  EmbreeDevice device = makeEmbreeDevice();
  InstancedGrains g;
  g.build(nonOverlapping(device, 14, 0.7f, 7), device);
  ASSERT_GT(g.stats().grains, 1500);
  expectSameHits(g, g.objectBounds(), 11, 3000, 600);
}

namespace {

// A turn, a uniform scale and a move.
Transform turnedScaledMoved(double scale, const Vec3& move) {
  const Mat3 r = quatToMat3(0.8f, 0.36f, 0.48f, 0.0f);
  Transform xf;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) xf.m[i][j] = scale * r.m[i][j];
  for (int i = 0; i < 3; ++i) xf.m[i][3] = move[i];
  return xf;
}

// The world bounds of grains placed by xf.
Bounds3 worldBounds(const InstancedGrains& g, const Transform& xf) {
  Bounds3 world;
  const Bounds3 b = g.objectBounds();
  for (int k = 0; k < 8; ++k)
    world.extend(xf.point(Vec3(k & 1 ? b.hi.x : b.lo.x, k & 2 ? b.hi.y : b.lo.y, k & 4 ? b.hi.z : b.lo.z)));
  return world;
}

}  // namespace

TEST(InstancedGrains, IntersectMatchesBruteForceTransformed) {
  EmbreeDevice device = makeEmbreeDevice();
  InstancedGrainsDesc d = nonOverlapping(device, 10, 0.5f, 3);
  d.xf = turnedScaledMoved(1.5, Vec3(4.0f, -2.0f, 7.0f));
  InstancedGrains g;
  g.build(d, device);
  expectSameHits(g, worldBounds(g, d.xf), 5, 1500, 75);
}

namespace {

// Proxies (instanced_grains.h: intersectProxy, proxyTransmittance) against every grain's
// bounding sphere in turn, for rays from random points (inside spheres too) and directions,
// skipping a random grain as a path leaving it does.
void expectSameProxies(const InstancedGrains& g, const Transform& xf, const Bounds3& region, uint32_t seed, int rays) {
  Transform inv;
  ASSERT_TRUE(xf.inverse(inv));
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const Vec3 lo = region.lo - region.extent() * 0.1f, size = region.extent() * 1.2f;
  // Per channel, as a grain that sends some of what it meets straight on (ProxyTable::crossing).
  auto shadow = [](const InstancedGrain& grain, float b) {
    const float c = 0.1f + 0.3f * b + 0.02f * float(grain.prototype);
    return ProxyShadow{Vec3(1.0f - c, 1.0f - 0.5f * c, 1.0f - 0.8f * c), 1.0f - c};
  };
  int hits = 0, products = 0;
  for (int k = 0; k < rays; ++k) {
    const Vec3 o = lo + Vec3(u(rng), u(rng), u(rng)) * size;
    const Vec3 d = randomDirection(rng) * (0.5f + u(rng));
    const float tmax = 2.0f + 10.0f * u(rng);
    const int64_t skip = k % 2 ? int64_t(u(rng) * float(g.stats().grains)) : -1;
    const Vec3 ol = inv.point(o), dl = inv.vector(d);
    float best = tmax;
    ProxyShadow product;
    int64_t nearest = -1;
    for (int64_t i = 0; i < g.stats().grains; ++i) {
      if (i == skip) continue;
      const InstancedGrain s = g.grain(i);
      const Vec3 oc = ol - s.center;
      const float a = dot(dl, dl), b = dot(oc, dl), c = dot(oc, oc) - s.radius * s.radius;
      const float disc = b * b - a * c;
      if (disc < 0 || (-b + std::sqrt(disc)) / a <= 0.0f) continue;
      const float t = std::max((-b - std::sqrt(disc)) / a, 0.0f);
      if (t >= tmax) continue;
      if (t < best) {
        best = t;
        nearest = i;
      }
      const float w2 = std::max(0.0f, dot(oc, oc) - b * b / a);
      product *= shadow(s, std::sqrt(std::min(1.0f, w2 / (s.radius * s.radius))));
    }
    InstancedGrain found;
    float t = 0;
    const bool hit = g.intersectProxy(o, d, 0.0f, tmax, skip, found, t);
    ASSERT_EQ(hit, nearest >= 0) << "ray " << k;
    if (hit) {
      ++hits;
      EXPECT_EQ(found.index, nearest) << "ray " << k;
      EXPECT_NEAR(t, best, 1e-4f * (1.0f + best)) << "ray " << k;
    }
    if (maxComponent(product.crossing) < 0.06f) continue;  // below, Russian roulette decides
    ++products;
    const ProxyShadow tr = g.proxyTransmittance(o, d, 0.0f, tmax, skip, shadow, uint64_t(k));
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(tr.crossing[c], product.crossing[c], 1e-4f) << "ray " << k << " channel " << c;
    EXPECT_NEAR(tr.unscattered, product.unscattered, 1e-4f) << "ray " << k;
  }
  EXPECT_GT(hits, rays / 10);
  EXPECT_GT(products, rays / 10);
}

}  // namespace

TEST(InstancedGrains, ProxiesMatchBruteForce) {
  EmbreeDevice device = makeEmbreeDevice();
  InstancedGrains g;
  g.build(nonOverlapping(device, 10, 0.7f, 9), device);
  expectSameProxies(g, Transform(), g.objectBounds(), 13, 1500);
  // Scaled, turned and moved: the spheres in world space are the object-space ones mapped.
  InstancedGrainsDesc d = nonOverlapping(device, 8, 0.6f, 4);
  d.xf = turnedScaledMoved(0.5, Vec3(-3.0f, 2.0f, 0.0f));
  InstancedGrains moved;
  moved.build(d, device);
  expectSameProxies(moved, d.xf, worldBounds(moved, d.xf), 17, 1000);
}

TEST(InstancedGrains, ProxyTransmittanceRouletteIsUnbiased) {
  // A long ray through many spheres: the mean of the roulette's answers over seeds is the
  // product (each answer 0 or the last factor's product rescaled: a Bernoulli mean).
  EmbreeDevice device = makeEmbreeDevice();
  InstancedGrains g;
  g.build(nonOverlapping(device, 12, 1.0f, 2), device);
  const Vec3 o(-2.0f, 2.35f, 2.25f), d = normalize(Vec3(1.0f, 0.01f, 0.005f));  // along a row of the lattice
  auto chance = [](const InstancedGrain&, float b) { return 0.4f * (1.0f - b * b); };
  auto shadow = [&](const InstancedGrain& s, float b) { return ProxyShadow{Vec3(1.0f - chance(s, b)), 1.0f - chance(s, b)}; };
  // The exact product, with roulette out of reach (a chance function scaled to stay above it
  // cannot give it: count the factors once by brute force instead).
  double product = 1;
  for (int64_t i = 0; i < g.stats().grains; ++i) {
    const InstancedGrain s = g.grain(i);
    const Vec3 oc = o - s.center;
    const float b = dot(oc, d), w2 = std::max(0.0f, dot(oc, oc) - b * b);
    if (w2 >= s.radius * s.radius || -b + std::sqrt(s.radius * s.radius - w2) <= 0) continue;
    product *= 1.0 - chance(s, std::sqrt(w2) / s.radius);
  }
  ASSERT_LT(product, 0.02);  // roulette is at work
  constexpr int kSeeds = 20000;
  double sum = 0, sum2 = 0;
  for (int k = 0; k < kSeeds; ++k) {
    const double tr = g.proxyTransmittance(o, d, 0.0f, kInf, -1, shadow, uint64_t(k)).crossing.x;
    sum += tr;
    sum2 += tr * tr;
  }
  const double mean = sum / kSeeds, se = std::sqrt((sum2 / kSeeds - mean * mean) / (kSeeds - 1));
  std::printf("transmittance %.5f, roulette's mean %.5f ± %.5f\n", product, mean, se);
  EXPECT_NEAR(mean, product, 4 * se + 1e-6);
}

TEST(InstancedGrains, ForEachGrainMatchesBruteForce) {
  EmbreeDevice device = makeEmbreeDevice();
  InstancedGrains g;
  g.build(nonOverlapping(device, 12, 0.6f, 9), device);
  std::mt19937 rng(4);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const Bounds3 all = g.objectBounds();
  for (int k = 0; k < 40; ++k) {
    Bounds3 box;
    Vec3 a = all.lo + Vec3(u(rng), u(rng), u(rng)) * all.extent();
    Vec3 e = Vec3(u(rng), u(rng), u(rng)) * (k < 35 ? 6.0f : 100.0f);
    box.extend(a);
    box.extend(a + e);
    std::vector<int64_t> want, got;
    for (int64_t i = 0; i < g.stats().grains; ++i) {
      InstancedGrain s = g.grain(i);
      Vec3 c = vmin(vmax(s.center, box.lo), box.hi);
      if (length2(c - s.center) <= s.radius * s.radius) want.push_back(i);
    }
    g.forEachGrain(box, [&](const InstancedGrain& s) { got.push_back(s.index); });
    EXPECT_EQ(got, want) << "box " << k;
  }
}

TEST(InstancedGrains, MemoryPerGrainWithinBound) {
  EmbreeDevice device = makeEmbreeDevice();
  InstancedGrains g;
  g.build(nonOverlapping(device, 47, 1.0f, 1), device);
  const InstancedGrainsStats& s = g.stats();
  EXPECT_EQ(s.grains, 47 * 47 * 47);
  // At most 8 entries per grain (cell edge 3 × the largest bounding radius).
  EXPECT_LE(s.entries, 8 * s.grains);
  // The stated bound: 32 bytes per grain beyond the input arrays, for packed grains.
  EXPECT_LE(s.bytesPerGrain(), 32.0);
  EXPECT_GT(s.bytesPerGrain(), 4.0);  // at least one uint32 entry each
}

TEST(InstancedGrains, BuildIsDeterministic) {
  EmbreeDevice device = makeEmbreeDevice();
  InstancedGrains a, b;
  a.build(nonOverlapping(device, 9, 0.8f, 2), device);
  b.build(nonOverlapping(device, 9, 0.8f, 2), device);
  std::mt19937 rng(1);
  const Bounds3 all = a.objectBounds();
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int k = 0; k < 200; ++k) {
    Vec3 o = all.lo + Vec3(u(rng), u(rng), u(rng)) * all.extent();
    Vec3 d = randomDirection(rng);
    InstancedGrainHit ha, hb;
    ASSERT_EQ(a.intersect(o, d, 0, kInf, ha), b.intersect(o, d, 0, kInf, hb));
    EXPECT_EQ(ha.grain, hb.grain);
    EXPECT_EQ(ha.t, hb.t);
  }
  EXPECT_EQ(a.stats().entries, b.stats().entries);
}

TEST(InstancedGrains, EmptyAndMissingRays) {
  EmbreeDevice device = makeEmbreeDevice();
  InstancedGrainsDesc d;
  d.name = "/Sim";
  d.prototypes = twoPrototypes();
  InstancedGrains g;
  g.build(d, device);
  InstancedGrainHit h;
  EXPECT_FALSE(g.intersect(Vec3(0.0f), Vec3(1, 0, 0), 0, kInf, h));
  EXPECT_FALSE(g.occluded(Vec3(0.0f), Vec3(1, 0, 0), 0, kInf));
  InstancedGrains one;
  d.positions = {Vec3(0.0f)};
  d.protoIndices = {0};
  one.build(d, device);
  EXPECT_TRUE(one.intersect(Vec3(-5, 0, 0), Vec3(1, 0, 0), 0, kInf, h));
  EXPECT_NEAR(h.t, 4.0f, 0.1f);  // the icosphere's surface near radius 1
  EXPECT_FALSE(one.intersect(Vec3(-5, 0, 0), Vec3(1, 0, 0), 0, 3.0f, h));
  EXPECT_FALSE(one.intersect(Vec3(NAN, 0, 0), Vec3(1, 0, 0), 0, kInf, h));  // no crash, no hit
}

// ---- validation ---------------------------------------------------------------------------

namespace {

InstancedGrainsDesc twoApart() {
  InstancedGrainsDesc d;
  d.name = "/Sim";
  d.prototypes = twoPrototypes();
  d.prototypes.resize(1);
  d.positions = {Vec3(0.0f), Vec3(3.0f, 0.0f, 0.0f)};
  d.protoIndices = {0, 0};
  return d;
}

}  // namespace

TEST(InstancedGrains, ValidationNamesPrimAndAttribute) {
  EmbreeDevice device = makeEmbreeDevice();
  auto build = [&](InstancedGrainsDesc d) {
    return errorOf([&] {
      InstancedGrains g;
      g.build(std::move(d), device);
    });
  };
  EXPECT_EQ(build(twoApart()), "(no error)");
  InstancedGrainsDesc d = twoApart();
  d.positions.pop_back();
  EXPECT_EQ(build(d), "/Sim.positions: has 1 values but protoIndices has 2 (one per instance)");
  d = twoApart();
  d.scales = {1.0f};
  EXPECT_EQ(build(d), "/Sim.scales: has 1 values but protoIndices has 2 (one per instance)");
  d = twoApart();
  d.velocities = {Vec3(0.0f)};
  EXPECT_EQ(build(d), "/Sim.velocities: has 1 values but protoIndices has 2 (one per instance)");
  d = twoApart();
  d.positions[1].y = NAN;
  EXPECT_EQ(build(d).rfind("/Sim.positions: instance 1 is at (3, nan", 0), 0u) << build(d);
  d = twoApart();
  d.protoIndices[1] = 1;
  EXPECT_EQ(build(d), "/Sim.protoIndices: instance 1 has 1, not the index of one of its 1 prototypes");
  d = twoApart();
  d.scales = {1.0f, 0.0f};
  EXPECT_EQ(build(d), "/Sim.scales: instance 1 has scale 0 (must be > 0 and finite)");
  d = twoApart();
  d.orientations = {Quat{}, Quat{0, 0, 0, 0}};
  EXPECT_EQ(build(d), "/Sim.orientations: instance 1 has (0, 0, 0, 0), not a unit quaternion");
  d = twoApart();
  d.angularVelocities = {Vec3(0.0f), Vec3(INFINITY, 0, 0)};
  EXPECT_EQ(build(d), "/Sim.angularVelocities: instance 1 has (inf, 0, 0) (not finite)");
  d = twoApart();
  d.prototypes.clear();
  EXPECT_EQ(build(d), "/Sim.prototypes: is empty (at least one grain prototype mesh is needed)");
  // Overlaps: bounding radii 1 (an icosphere's circumsphere): 5% of 1 is the limit.
  d = twoApart();
  d.positions[1] = Vec3(1.96f, 0, 0);  // 4% deep: allowed
  EXPECT_EQ(build(d), "(no error)");
  d.positions.push_back(Vec3(-1.5f, 0, 0));
  d.protoIndices.push_back(0);
  EXPECT_EQ(build(d).rfind("/Sim.positions: instances 0 and 2 overlap: their bounding spheres (radii 1", 0), 0u)
      << build(d);
}

TEST(InstancedGrains, ValidationTrustsOnlyUnwrittenArrays) {
  // validateInstancedGrains remembers the arrays it found valid; any write, in place or to a
  // copy, and a change of prototypes are checked again.
  InstancedGrainsDesc d = twoApart();
  EXPECT_EQ(errorOf([&] { validateInstancedGrains(d); }), "(no error)");
  const uint64_t stamp = std::as_const(d).positions.stamp();
  EXPECT_NE(stamp, 0u);
  InstancedGrainsDesc copy = d;
  EXPECT_EQ(std::as_const(copy).positions.stamp(), stamp);  // copies share what was checked
  d.positions[1].y = NAN;                                   // the only owner: written in place
  EXPECT_NE(std::as_const(d).positions.stamp(), stamp);
  EXPECT_EQ(errorOf([&] { validateInstancedGrains(d); }).rfind("/Sim.positions: instance 1 is at (3, nan", 0), 0u);
  EXPECT_EQ(errorOf([&] { validateInstancedGrains(copy); }), "(no error)");
  InstancedGrainsDesc other = copy;
  other.scales = {1.0f, -1.0f};
  EXPECT_EQ(errorOf([&] { validateInstancedGrains(other); }), "/Sim.scales: instance 1 has scale -1 (must be > 0 and finite)");
  other = copy;
  other.protoIndices[1] = 0;  // written (the same value): checked again, still valid
  EXPECT_EQ(errorOf([&] { validateInstancedGrains(other); }), "(no error)");
  other.prototypes.push_back(other.prototypes[0]);
  other.protoIndices[1] = 1;
  EXPECT_EQ(errorOf([&] { validateInstancedGrains(other); }), "(no error)");
  other.prototypes.pop_back();  // the same arrays, fewer prototypes: index 1 is out of range again
  EXPECT_EQ(errorOf([&] { validateInstancedGrains(other); }),
            "/Sim.protoIndices: instance 1 has 1, not the index of one of its 1 prototypes");
  InstancedGrainsDesc moved = std::move(copy);
  EXPECT_EQ(std::as_const(moved).positions.stamp(), stamp);
  EXPECT_EQ(std::as_const(copy).positions.stamp(), 0u);  // emptied by the move
}

TEST(InstancedGrains, OverlapCheckFindsEveryPairThroughTheGrid) {
  // A large random set with one planted overlap far from the first grains.
  EmbreeDevice device = makeEmbreeDevice();
  InstancedGrainsDesc d = nonOverlapping(device, 20, 0.9f, 5);
  const size_t last = d.size() - 1;
  d.positions[last] = d.positions[last - 1] + Vec3(0.5f, 0, 0);
  std::string e = errorOf([&] {
    InstancedGrains g;
    g.build(d, device);
  });
  EXPECT_EQ(e.rfind(str("/Sim.positions: instances ", last - 1, " and ", last, " overlap"), 0), 0u) << e;
}

TEST(InstancedGrains, OverlapCheckNamesTheFirstPairAsEveryPairWouldBeCompared) {
  // Overlaps of every kind, planted at random: deep and shallow, across cell and block
  // faces, a grain on top of another (coincident centres). The pair named is the first
  // (smallest i, then j) of a comparison of every pair.
  EmbreeDevice device = makeEmbreeDevice();
  for (uint32_t seed = 1; seed <= 6; ++seed) {
    InstancedGrainsDesc d = nonOverlapping(device, 12, 0.9f, seed);
    std::mt19937 rng(seed);
    std::uniform_int_distribution<size_t> pick(0, d.size() - 1);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (int k = 0; k < 4; ++k) {
      const size_t a = pick(rng), b = pick(rng);
      if (a == b) continue;
      const float sep = k == 0 ? 0.0f : 2.0f * u(rng);  // 0: the same centre
      d.positions[b] = d.positions[a] + randomDirection(rng) * sep;
    }
    InstancedGrains probe;  // the spheres as the grid sees them (no overlap check)
    probe.build(d, device, false);
    int64_t fi = -1, fj = -1;
    for (int64_t i = 0; i < int64_t(d.size()) && fi < 0; ++i)
      for (int64_t j = i + 1; j < int64_t(d.size()); ++j) {
        const InstancedGrain g = probe.grain(i), h = probe.grain(j);
        const float depth = g.radius + h.radius - length(g.center - h.center);
        if (depth > InstancedGrains::kOverlapTolerance * std::min(g.radius, h.radius)) {
          fi = i, fj = j;
          break;
        }
      }
    const std::string e = errorOf([&] {
      InstancedGrains g;
      g.build(d, device);
    });
    if (fi < 0) {
      EXPECT_EQ(e, "") << "seed " << seed;
      continue;
    }
    EXPECT_EQ(e.rfind(str("/Sim.positions: instances ", fi, " and ", fj, " overlap"), 0), 0u) << "seed " << seed << ": " << e;
  }
}

TEST(InstancedGrains, FarFlungGrainsAreFoundAsPackedOnes) {
  // Three clusters far apart along every axis: the grid's box holds far more blocks than
  // grains (its occupied blocks are then gathered in a hash set instead of marked on the
  // box), and each cluster's rays still meet what brute force meets.
  EmbreeDevice device = makeEmbreeDevice();
  InstancedGrainsDesc d = nonOverlapping(device, 6, 0.8f, 9);
  const size_t n = d.size();
  for (int c = 1; c < 3; ++c)
    for (size_t i = 0; i < n; ++i) {
      d.positions.push_back(d.positions[i] + Vec3(float(c) * 4.0e4f, float(c) * -3.0e4f, float(c) * 5.0e4f));
      d.orientations.push_back(d.orientations[i]);
      d.scales.push_back(d.scales[i]);
      d.protoIndices.push_back(d.protoIndices[i]);
    }
  InstancedGrains g;
  g.build(d, device);
  EXPECT_EQ(g.stats().grains, int64_t(3 * n));
  Bounds3 cluster;
  for (size_t i = 0; i < n; ++i) cluster.extend(d.positions[i]);
  for (int c = 0; c < 3; ++c) {
    const Vec3 move(float(c) * 4.0e4f, float(c) * -3.0e4f, float(c) * 5.0e4f);
    Bounds3 b;
    b.lo = cluster.lo + move;
    b.hi = cluster.hi + move;
    expectSameHits(g, b, 30 + uint32_t(c), 400, 60);
  }
  // The grid's memory follows the grains, not the space between them (10^11 blocks).
  EXPECT_LT(g.stats().gridBytes, size_t(1) << 20);
}

TEST(InstancedGrains, DescriptionCopiesShareTheArraysUntilOneIsWritten) {
  // 10^8 grains are gigabytes: the scene build, its move into render space and the grid
  // keep the description's arrays, not copies of them.
  EmbreeDevice device = makeEmbreeDevice();
  SceneDesc s;
  s.camera.cameraToWorld = Transform::lookAt(Vec3(1.0e5f, 5.0f, 20.0f), Vec3(1.0e5f, 5.0f, 0.0f), Vec3(0, 1, 0));
  InstancedGrainsDesc g = nonOverlapping(device, 5, 1.0f, 4);
  g.xf = Transform::translate(Vec3(1.0e5f, 0.0f, 0.0f));  // far from the origin: render space moves it
  s.instancedGrains.push_back(g);
  EXPECT_TRUE(s.instancedGrains[0].positions.sharesWith(g.positions));
  auto scene = Scene::build(s);
  ASSERT_FALSE(renderOrigin(s) == Vec3d{});
  const InstancedGrainsDesc& kept = scene->instancedGrains()[0]->desc();
  const InstancedGrainsDesc& original = g;  // read through const: a read does not copy
  EXPECT_TRUE(kept.positions.sharesWith(g.positions));
  EXPECT_TRUE(kept.orientations.sharesWith(g.orientations));
  EXPECT_TRUE(kept.scales.sharesWith(g.scales));
  EXPECT_TRUE(kept.protoIndices.sharesWith(g.protoIndices));
  EXPECT_NE(kept.xf.m[0][3], g.xf.m[0][3]);  // the transform is render space's
  // A write copies the array written, and only for the copy written to.
  const Vec3 first = original.positions[0];
  InstancedGrainsDesc edited = g;
  edited.positions[0] = first + Vec3(0.5f);
  EXPECT_FALSE(edited.positions.sharesWith(original.positions));
  EXPECT_TRUE(edited.scales.sharesWith(original.scales));
  EXPECT_TRUE(kept.positions.sharesWith(original.positions));
  EXPECT_EQ(original.positions[0].x, first.x);
  EXPECT_EQ(kept.positions[0].x, first.x);
  EXPECT_EQ(edited.positions[0].x, first.x + 0.5f);
  EXPECT_FALSE(sameInstancedGrains(edited, original));
  edited.positions[0] = first;
  EXPECT_TRUE(sameInstancedGrains(edited, original));
}

// ---- USD meaning (granular_prims.h) -----------------------------------------------------------

namespace {

InstancerPrim instancer() {
  InstancerPrim p;
  p.path = "/World/Sand";
  p.prototypes = {"/World/Sand/Protos/Round"};
  p.positions = {0, 0, 0, 3, 0, 0};
  p.orientations = {2, 0, 0, 0, 1, 0, 0, 0};  // (2, 0, 0, 0): normalised
  p.scales = {1, 1, 1, 0.5f, 0.5f, 0.5f};
  p.protoIndices = {0, 0};
  return p;
}

PrimLookup roundGrain(bool grainApi, bool closed = true) {
  return [=](const std::string& path, MeshPrim& out) {
    if (path != "/World/Sand/Protos/Round") return false;
    out.path = path;
    out.mesh = makeIcosphere(1);
    if (!closed) out.mesh.indices.resize(out.mesh.indices.size() - 3);
    out.apiSchemas = std::vector<std::string>{};
    if (grainApi) {
      out.apiSchemas->push_back(kGrainApi);
      PrimvarValue ior;
      ior.typeName = "float";
      ior.numbers = {1.31};
      out.granular["ior"] = ior;
    }
    return true;
  };
}

}  // namespace

TEST(InstancedGrains, FromUsdReadsAndNormalises) {
  SceneDesc scene;
  InstancedGrainsDesc d = instancedGrainsFromUsd(instancer(), scene, roundGrain(true));
  ASSERT_EQ(d.size(), 2u);
  EXPECT_EQ(d.name, "/World/Sand");
  EXPECT_EQ(d.orientations[0].w, 1.0f);
  EXPECT_EQ(d.scales[1], 0.5f);
  ASSERT_EQ(d.prototypes.size(), 1u);
  ASSERT_EQ(scene.materials.size(), 1u);  // its GranularGrainAPI values
  EXPECT_EQ(d.prototypes[0].material, 0);
  EXPECT_FLOAT_EQ(scene.materials[0].ior, 1.31f);
  // Without the API or a bound material: clear glass, as an aggregate's prototype.
  SceneDesc plain;
  EXPECT_EQ(instancedGrainsFromUsd(instancer(), plain, roundGrain(false)).prototypes[0].material, -1);
  EXPECT_TRUE(plain.materials.empty());
}

TEST(InstancedGrains, FromUsdErrorsNamePrimAndAttribute) {
  auto read = [](InstancerPrim p, PrimLookup lookup = roundGrain(true)) {
    return errorOf([&] {
      SceneDesc s;
      instancedGrainsFromUsd(p, s, lookup);
    });
  };
  InstancerPrim p = instancer();
  p.scales = {1, 1, 1, 0.5f, 0.6f, 0.5f};
  EXPECT_EQ(read(p), "/World/Sand.scales: instance 1 has non-uniform scale (0.5, 0.6, 0.5): a grain takes one size "
                     "(scale its prototype instead)");
  p = instancer();
  p.scales = {1, 1, 1, -1, -1, -1};
  EXPECT_EQ(read(p), "/World/Sand.scales: instance 1 has scale (-1, -1, -1) (each must be > 0 and finite)");
  p = instancer();
  p.orientations = {1, 0, 0, 0, 0, 0, 0, 0};
  EXPECT_EQ(read(p), "/World/Sand.orientations: instance 1 has (0, 0, 0, 0), not a rotation");
  p = instancer();
  p.protoIndices = {0, 4};
  EXPECT_EQ(read(p), "/World/Sand.protoIndices: instance 1 has 4, not the index of one of its 1 prototypes");
  p = instancer();
  p.positions.pop_back();
  EXPECT_EQ(read(p), "/World/Sand.positions: has 5 numbers, not 3 per instance");
  p = instancer();
  p.positions.resize(3);
  EXPECT_EQ(read(p), "/World/Sand.positions: has 1 values but protoIndices has 2 (one per instance)");
  p = instancer();
  p.prototypes = {"/World/Nowhere"};
  EXPECT_EQ(read(p), "/World/Sand.prototypes: target /World/Nowhere is not a prim of the stage");
  EXPECT_EQ(read(instancer(), roundGrain(true, false)).rfind("/World/Sand/Protos/Round", 0), 0u);
  p = instancer();
  p.typeName = "Mesh";
  EXPECT_EQ(read(p), "/World/Sand: GranularInstancedAggregateAPI applies to a PointInstancer, not a Mesh");
  PrimLookup xform = [](const std::string& path, MeshPrim& out) {
    out.path = path;
    out.typeName = "Xform";
    return true;
  };
  EXPECT_EQ(read(instancer(), xform),
            "/World/Sand.prototypes: target /World/Sand/Protos/Round is a Xform, not a Mesh (a grain prototype is one "
            "closed mesh)");
}

TEST(InstancedGrains, FromUsdReadsArraysInPlaceAsTheirCopies) {
  // A front end's own arrays (USD's quath: half floats, real last; int indices; double
  // positions), each asked for once and in order: the same grains as the flattened floats,
  // and the same errors.
  auto half = [](float f) {  // exact for the values below
    uint32_t b;
    std::memcpy(&b, &f, 4);
    if (f == 0) return uint16_t((b >> 16) & 0x8000);
    return uint16_t(((b >> 16) & 0x8000) | ((((b >> 23) & 0xff) - 112) << 10) | ((b >> 13) & 0x3ff));
  };
  InstancerPrim p = instancer();
  const std::vector<double> positions(p.positions.begin(), p.positions.end());
  std::vector<uint16_t> quath;
  for (size_t i = 0; i < p.orientations.size(); i += 4)
    for (int k : {1, 2, 3, 0}) quath.push_back(half(p.orientations[i + size_t(k)]));
  const std::vector<uint16_t> scalesh = {half(1), half(1), half(1), half(0.5f), half(0.5f), half(0.5f)};
  std::vector<int32_t> indices(p.protoIndices.begin(), p.protoIndices.end());
  std::vector<std::string> asked;
  InstancerArrays a;
  a.orientationsRealLast = true;
  a.read = [&](const char* attr) {
    asked.push_back(attr);
    const std::string name = attr;
    using T = NumberView::Type;
    if (name == "positions") return NumberView{positions.data(), positions.size(), T::Double};
    if (name == "orientations") return NumberView{quath.data(), quath.size(), T::Half};
    if (name == "scales") return NumberView{scalesh.data(), scalesh.size(), T::Half};
    if (name == "protoIndices") return NumberView{indices.data(), indices.size(), T::Int32};
    return NumberView{};
  };
  SceneDesc s1, s2;
  const InstancedGrainsDesc flat = instancedGrainsFromUsd(p, s1, roundGrain(true));
  const InstancedGrainsDesc viewed = instancedGrainsFromUsd(p, a, s2, roundGrain(true));
  EXPECT_EQ(asked, (std::vector<std::string>{"positions", "velocities", "angularVelocities", "orientations", "scales",
                                             "protoIndices"}));
  EXPECT_TRUE(sameInstancedGrains(flat, viewed));
  EXPECT_EQ(s1.materials.size(), s2.materials.size());
  auto error = [&](const InstancerArrays& arrays) {
    return errorOf([&] {
      SceneDesc s;
      instancedGrainsFromUsd(p, arrays, s, roundGrain(true));
    });
  };
  quath[4] = quath[5] = quath[6] = quath[7] = half(0.0f);
  EXPECT_EQ(error(a), "/World/Sand.orientations: instance 1 has (0, 0, 0, 0), not a rotation");
  quath[7] = half(1.0f);
  indices[1] = -2;
  EXPECT_EQ(error(a), "/World/Sand.protoIndices: instance 1 has -2, not the index of one of its 1 prototypes");
}

// ---- in the scene: explicit grains traced as the same grains given as meshes -------------

namespace {

// A dozen grains of two prototypes (lattice spacing 2.3 at scale 1, scales in [0.6, 1],
// random rotations) under an instancer transform that scales them by 0.4, on a grey floor
// under a sun and a sky; EPT, 24x24. asMeshes: each grain as a closed Dielectric mesh placed
// as the instancer places it, with its absorption per world unit (fitRadius: each
// prototype's bounding radius at scale 1 in the instancer's space).
SceneDesc instancedScene(bool asMeshes, uint64_t seed, const std::vector<float>& fitRadius = {}) {
  SceneDesc s;
  s.settings.width = s.settings.height = 24;
  s.settings.spp = 96;
  s.settings.seed = seed;
  s.settings.technique = Technique::Ept;
  s.settings.bundleSize = 1;
  s.camera.cameraToWorld = Transform::lookAt(Vec3(2.4f, 3.0f, 4.9f), Vec3(0.9f, 0.6f, 0.9f), Vec3(0, 1, 0));
  s.camera.focalLength = 50;
  s.camera.horizontalAperture = s.camera.verticalAperture = 40;
  MaterialDesc amber, clear;
  amber.name = "amber";
  amber.type = clear.type = MaterialType::Dielectric;
  amber.ior = 1.55f;
  amber.absorption = Vec3(0.3f, 0.8f, 2.0f);  // per bounding radius at scale 1
  clear.name = "clear";
  clear.ior = 1.31f;
  clear.absorption = Vec3(0.1f);
  s.materials = {amber, clear};
  s.lights = granular::testing::sunAndSky();
  MeshDesc floor;
  floor.name = "floor";
  floor.mesh = makeBox(Vec3(-4.0f, -1.0f, -4.0f), Vec3(4.0f, -0.6f, 4.0f));
  s.meshes.push_back(floor);

  InstancedGrainsDesc g = latticeGrains(3, 0.5f, 11);
  g.name = "/World/Sim";
  g.id = 7;
  g.xf = Transform::translate(Vec3(0.0f, -0.1f, 0.0f)) * Transform::scale(Vec3(0.4f));
  g.prototypes[0].material = 0;
  g.prototypes[1].material = 1;
  if (!asMeshes) {
    s.instancedGrains.push_back(g);
    return s;
  }
  for (int k = 0; k < 2; ++k) {
    MaterialDesc m = s.materials[size_t(k)];
    m.name += "_per_world_unit";
    m.absorption = m.absorption * (1.0f / (fitRadius[size_t(k)] * 0.4f));
    s.materials.push_back(m);
  }
  for (size_t i = 0; i < g.size(); ++i) {
    MeshDesc m;
    m.name = "grain" + std::to_string(i);
    const int p = g.protoIndices[i];
    m.mesh = g.prototypes[size_t(p)].mesh;
    for (Vec3& v : m.mesh.points) v = g.xf.point(g.positions[i] + rotate(g.orientations[i], v) * g.scales[i]);
    m.material = 2 + p;
    s.meshes.push_back(m);
  }
  return s;
}

}  // namespace

TEST(InstancedGrainsInScene, RenderAsTheSameGrainsGivenAsMeshes) {
  // Two independent seeds: the difference's noise is what the standard errors say.
  auto probe = Scene::build(instancedScene(false, 1));
  ASSERT_EQ(probe->instancedGrains().size(), 1u);
  std::vector<float> fit;
  for (const GrainPrototype& p : probe->instancedGrains()[0]->prototypes()) fit.push_back(p.fitRadius);
  for (auto [x0, x1, y0, y1] : {std::array<int, 4>{0, 24, 0, 24}, {4, 12, 4, 12}, {12, 20, 8, 16}, {8, 16, 12, 20}}) {
    ChannelEstimate inst = renderEstimate(instancedScene(false, 2), x0, x1, y0, y1);
    ChannelEstimate mesh = renderEstimate(instancedScene(true, 3, fit), x0, x1, y0, y1);
    for (int c = 0; c < 3; ++c) {
      const double noise = std::hypot(inst.se[c], mesh.se[c]);
      std::printf("window [%d,%d)x[%d,%d) channel %d: instanced %.4f, meshes %.4f (noise %.4f)\n", x0, x1, y0, y1, c,
                  inst.mean[c], mesh.mean[c], noise);
      EXPECT_GT(inst.mean[c], 0.0);
      EXPECT_LE(std::fabs(inst.mean[c] - mesh.mean[c]), 4 * noise) << "window " << x0 << "," << y0 << " channel " << c;
    }
  }
}

TEST(InstancedGrainsInScene, HitsNameTheGrainAndTheInstancer) {
  SceneDesc d = instancedScene(false, 1);
  auto scene = Scene::build(d);
  const InstancedGrains& grains = *scene->instancedGrains()[0];
  // A ray at each grain's centre from above finds that grain or one nearer; whatever it
  // finds is a grain of the instancer with its prototype's material and the instance index.
  int checked = 0;
  for (int64_t i = 0; i < int64_t(grains.desc().size()); ++i) {
    const Vec3 c = d.instancedGrains[0].xf.point(grains.grain(i).center);
    Ray ray;
    ray.o = c + Vec3(0.0f, 5.0f, 0.0f);
    ray.d = Vec3(0.0f, -1.0f, 0.0f);
    Hit hit;
    ASSERT_TRUE(scene->intersect(ray, hit));
    if (hit.kind != Hit::Grain) continue;  // the floor, around a thin box
    EXPECT_EQ(hit.aggregate, -1);
    EXPECT_EQ(hit.instancer, 0);
    ASSERT_GE(hit.instance, 0);
    const int proto = grains.desc().protoIndices[size_t(hit.instance)];
    EXPECT_EQ(hit.grain.prototype, proto);
    EXPECT_EQ(hit.material, proto);  // the description's material indices 0 and 1
    EXPECT_FLOAT_EQ(hit.lengthScale, grains.prototypes()[size_t(proto)].fitRadius * 0.4f);
    const Scene::HitIdentity who = scene->identify(hit);
    EXPECT_EQ(who.instanceId, int(hit.instance));
    EXPECT_EQ(who.aggregateId, 7);
    EXPECT_EQ(who.cryptomatte[0], cryptomatteId("/World/Sim"));
    EXPECT_EQ(who.cryptomatte[1], cryptomatteId(proto == 0 ? "amber" : "clear"));
    // Shadow rays see it in every mode.
    EXPECT_TRUE(scene->occluded(ray.o, ray.d, 10.0f));
    EXPECT_EQ(maxComponent(scene->transmittance(ray.o, ray.d, 10.0f)), 0.0f);
    Hit medium;
    ASSERT_TRUE(scene->intersectMedium(ray, medium));
    EXPECT_EQ(medium.kind, Hit::Grain);
    EXPECT_FLOAT_EQ(medium.t, hit.t);
    ++checked;
  }
  EXPECT_GT(checked, 5);
  const auto& names = scene->cryptomatteNames(CryptomatteType::Object);
  EXPECT_TRUE(std::find(names.begin(), names.end(), "/World/Sim") != names.end());
}

TEST(InstancedGrainsInScene, AnUnchangedInstancerIsLentAndAMovedGrainRebuildsIt) {
  SceneDesc d = instancedScene(false, 1);
  auto first = Scene::build(d);
  EXPECT_EQ(first->instancedGrainsBuilt(), 1);
  d.camera.cameraToWorld = Transform::lookAt(Vec3(2.0f, 3.0f, 5.0f), Vec3(0.9f, 0.6f, 0.9f), Vec3(0, 1, 0));
  d.lights[0].intensity = 2;
  auto second = Scene::build(d, first.get());
  EXPECT_EQ(second->instancedGrainsBuilt(), 0);
  EXPECT_EQ(second->instancedGrains()[0].get(), first->instancedGrains()[0].get());
  SceneDesc moved = d;
  moved.instancedGrains[0].positions[3].x += 0.01f;
  const SceneChanges c = compareScenes(d, moved);
  EXPECT_TRUE(c.instancedGrains);
  EXPECT_EQ(c.level(), SceneChange::Aggregates);
  auto third = Scene::build(moved, second.get());
  EXPECT_EQ(third->instancedGrainsBuilt(), 1);
  EXPECT_NE(third->instancedGrains()[0].get(), second->instancedGrains()[0].get());
  // A grain material's change rebuilds it too (its materials are compared by value).
  SceneDesc amberer = d;
  amberer.materials[0].absorption = Vec3(1.0f);
  auto fourth = Scene::build(amberer, second.get());
  EXPECT_EQ(fourth->instancedGrainsBuilt(), 1);
}

TEST(InstancedGrainsInScene, BadDataIsNamedBySceneValidation) {
  SceneDesc d = instancedScene(false, 1);
  d.instancedGrains[0].positions[2] = Vec3(kInf, 0.0f, 0.0f);
  try {
    Scene::build(d);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.object(), "/World/Sim");
    EXPECT_EQ(e.attribute(), "positions");
  }
  d = instancedScene(false, 1);
  d.instancedGrains[0].prototypes[1].material = 9;
  EXPECT_THROW(Scene::build(d), InputError);
}

// ---- motion blur -----------------------------------------------------------------------

TEST(InstancedGrains, MovingGrainsAreFoundAtEveryTimeOfTheShutter) {
  // The grid lists each moving grain by its sweep: at any time within the span, the walk
  // finds what brute force over the grains placed at that time finds.
  InstancedGrainsDesc d = latticeGrains(6, 0.6f, 5);
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (size_t i = 0; i < d.size(); ++i) {
    d.velocities.push_back(Vec3(u(rng), u(rng), u(rng)) * 40.0f);         // up to ~1.4 spacings in 1/24 s
    d.angularVelocities.push_back(Vec3(u(rng), u(rng), u(rng)) * 2000.0f);  // degrees per second
  }
  InstancedGrains g;
  const float span = 1.0f / 24.0f;
  g.build(d, makeEmbreeDevice(), false, span);
  EXPECT_FLOAT_EQ(g.motionSpan(), span);
  std::uniform_real_distribution<float> ur(0.0f, 1.0f);
  int hits = 0;
  for (int k = 0; k < 3000; ++k) {
    const float time = span * (2.0f * ur(rng) - 1.0f);
    const Vec3 o(-3.0f, 14.0f * ur(rng) - 1.0f, 14.0f * ur(rng) - 1.0f);
    const Vec3 dir = normalize(Vec3(1.0f, 0.3f * u(rng), 0.3f * u(rng)));
    InstancedGrainHit a, b;
    const bool fa = g.intersect(o, dir, 0.0f, kInf, a, time), fb = g.intersectAll(o, dir, 0.0f, kInf, b, time);
    ASSERT_EQ(fa, fb) << k;
    if (!fa) continue;
    ++hits;
    EXPECT_EQ(a.grain, b.grain);
    EXPECT_FLOAT_EQ(a.t, b.t);
    EXPECT_EQ(g.occluded(o, dir, 0.0f, kInf, time), true);
  }
  EXPECT_GT(hits, 500);
  // A grain placed at a time is the still grain moved by velocity and turned by its spin
  // after its orientation (USD's order).
  const InstancedGrain at = g.grain(3, span);
  InstancedGrainsDesc still = d;
  still.positions[3] += still.velocities[3] * span;
  const Vec3 w = still.angularVelocities[3];
  const float angle = length(w) * span * kPi / 180.0f;
  const Vec3 axis = normalize(w);
  const Quat spin{std::cos(0.5f * angle), axis.x * std::sin(0.5f * angle), axis.y * std::sin(0.5f * angle),
                  axis.z * std::sin(0.5f * angle)};
  const Vec3 probe(0.3f, -0.2f, 0.9f);
  EXPECT_NEAR(length(rotate(at.orientation, probe) - rotate(spin, rotate(still.orientations[3], probe))), 0.0f, 1e-5f);
  InstancedGrains moved;
  still.velocities.clear();
  still.angularVelocities.clear();
  still.orientations[3] = at.orientation;
  moved.build(still, makeEmbreeDevice(), false);
  EXPECT_NEAR(length(moved.grain(3).center - at.center), 0.0f, 1e-5f);
}

TEST(InstancedGrainsInScene, MotionBlurIsTheAverageOfTheShutter) {
  // Grains moving sideways by about two of their radii over the shutter: the blurred image
  // equals the average of still images at 16 times spread evenly across it (midpoints of
  // 16 equal slices; the motion within a slice, 1/8 radius, is below a pixel here).
  const float open = -0.01f, close = 0.03f;
  auto scene = [&](bool blur, float time, uint64_t seed, int spp) {
    SceneDesc s = instancedScene(false, seed);
    s.settings.spp = spp;
    InstancedGrainsDesc& g = s.instancedGrains[0];
    for (size_t i = 0; i < g.size(); ++i) {
      const Vec3 v(40.0f, 0.0f, 10.0f);  // instancer units per second
      const Vec3 w(0.0f, i % 3 ? 3000.0f : -2000.0f, 0.0f);  // degrees per second
      if (blur) {
        g.velocities.push_back(v);
        g.angularVelocities.push_back(w);
      } else {
        g.positions[i] += v * time;
        const float a = w.y * time * kPi / 180.0f;
        const Quat spin{std::cos(0.5f * a), 0.0f, std::sin(0.5f * a), 0.0f};
        const Quat q = g.orientations[i];
        g.orientations[i] = Quat{spin.w * q.w - spin.y * q.y, spin.w * q.x + spin.y * q.z, spin.w * q.y + spin.y * q.w,
                                 spin.w * q.z - spin.y * q.x};
      }
    }
    if (blur) {
      s.camera.shutterOpen = open;
      s.camera.shutterClose = close;
    }
    return s;
  };
  const auto windows = blocks(24, 4);
  const auto blurred = renderEstimates(scene(true, 0.0f, 21, 256), windows);
  constexpr int kSlices = 16;
  std::vector<ChannelEstimate> average(windows.size());
  for (int k = 0; k < kSlices; ++k) {
    const float t = open + (close - open) * (float(k) + 0.5f) / kSlices;
    const auto e = renderEstimates(scene(false, t, 100 + uint64_t(k), 256 / kSlices), windows);
    for (size_t b = 0; b < windows.size(); ++b)
      for (int c = 0; c < 3; ++c) {
        average[b].mean[c] += e[b].mean[c] / kSlices;
        average[b].se[c] += e[b].se[c] * e[b].se[c] / (kSlices * kSlices);
      }
  }
  const auto still = renderEstimates(scene(false, 0.0f, 7, 256), windows);
  double worst = 0, stillWorst = 0;
  for (size_t b = 0; b < windows.size(); ++b)
    for (int c = 0; c < 3; ++c) {
      average[b].se[c] = std::sqrt(average[b].se[c]);
      const double noise = std::hypot(blurred[b].se[c], average[b].se[c]);
      const double z = std::fabs(blurred[b].mean[c] - average[b].mean[c]) / noise;
      worst = std::max(worst, z);
      stillWorst = std::max(stillWorst, std::fabs(blurred[b].mean[c] - still[b].mean[c]) / std::hypot(blurred[b].se[c], still[b].se[c]));
      EXPECT_LE(z, 4.0) << "block " << b << " channel " << c << ": blurred " << blurred[b].mean[c] << ", average "
                        << average[b].mean[c] << " (noise " << noise << ")";
    }
  std::printf("worst block: %.2f standard errors from the shutter's average; the still image at time 0: %.1f\n", worst,
              stillWorst);
  // The test can tell: without the blur, blocks differ far beyond the noise.
  EXPECT_GT(stillWorst, 8.0);
}

// ---- their medium -----------------------------------------------------------------------

namespace {

// A slab of grains placed by random sequential addition (a random packing, as a poured
// material has, not a lattice whose channels let light through), uniform or with a
// gradient in packing rate (candidates kept with a probability rising with height), of
// rock and round prototypes of one amber material, scaled by 0.05; under a sun and a sky,
// seen from above at an angle. EPT or the hybrid's EPT+VPT.
SceneDesc slabScene(Technique technique, uint64_t seed, bool gradient, int explicitBounces = -1) {
  SceneDesc s;
  s.settings.width = s.settings.height = 16;
  s.settings.spp = 128;
  s.settings.seed = seed;
  s.settings.technique = technique;
  s.settings.explicitBounces = explicitBounces;
  s.settings.roulette = 1.0f;
  s.camera.cameraToWorld = Transform::lookAt(Vec3(0.0f, 2.2f, 1.6f), Vec3(0.0f, 0.0f, 0.0f), Vec3(0, 1, 0));
  s.camera.focalLength = 50;
  s.camera.horizontalAperture = s.camera.verticalAperture = 20;
  MaterialDesc sand;
  sand.name = "sand";
  sand.type = MaterialType::Dielectric;
  sand.ior = 1.5f;
  sand.absorption = Vec3(0.05f, 0.1f, 0.3f);
  s.materials = {sand};
  s.lights = granular::testing::sunAndSky();
  std::mt19937 rng(31);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  InstancedGrainsDesc g;
  g.name = "/World/Slab";
  g.id = 3;
  GrainPrototypeDesc round, rock;
  round.name = "/World/Slab/Round";
  round.mesh = makeIcosphere(1);
  rock.name = "/World/Slab/Rock";
  rock.mesh = makeRock(1, 0.2f, 2);
  round.material = rock.material = 0;
  g.prototypes = {round, rock};
  // Bounding radii at most 1.3 (the rock's is about 1.25 at scale 1) times the scale.
  const float X = 40.0f, H = 24.0f, cell = 2.6f;
  const int nc[3] = {int(2 * X / cell) + 1, int(H / cell) + 1, int(2 * X / cell) + 1};
  std::vector<std::vector<int>> grid(size_t(nc[0]) * nc[1] * nc[2]);
  for (int attempt = 0; attempt < 60000; ++attempt) {
    const Vec3 c(X * (2 * u(rng) - 1), -H * u(rng), X * (2 * u(rng) - 1));
    const float scale = 0.8f + 0.1f * u(rng), bound = 1.3f * scale;
    const float keep = gradient ? 0.25f + 0.75f * (1.0f + c.y / H) : 1.0f;
    if (u(rng) >= keep) continue;
    const int ci[3] = {int((c.x + X) / cell), int(-c.y / cell), int((c.z + X) / cell)};
    bool free = true;
    for (int dz = -1; dz <= 1 && free; ++dz)
      for (int dy = -1; dy <= 1 && free; ++dy)
        for (int dx = -1; dx <= 1 && free; ++dx) {
          const int x = ci[0] + dx, y = ci[1] + dy, z = ci[2] + dz;
          if (x < 0 || y < 0 || z < 0 || x >= nc[0] || y >= nc[1] || z >= nc[2]) continue;
          for (int k : grid[(size_t(z) * nc[1] + y) * nc[0] + x])
            if (length(g.positions[size_t(k)] - c) < bound + 1.3f * g.scales[size_t(k)]) free = false;
        }
    if (!free) continue;
    grid[(size_t(ci[2]) * nc[1] + ci[1]) * nc[0] + ci[0]].push_back(int(g.positions.size()));
    g.positions.push_back(c);
    g.orientations.push_back(randomRotation(rng));
    g.scales.push_back(scale);
    g.protoIndices.push_back(u(rng) < 0.5f ? 0 : 1);
  }
  g.xf = Transform::scale(Vec3(0.05f));
  s.instancedGrains.push_back(g);
  return s;
}

}  // namespace

TEST(InstancedGrainsInScene, AThickInstancerHasAMediumThatFollowsItsDensity) {
  auto scene = Scene::build(slabScene(Technique::EptVpt, 1, true));
  ASSERT_TRUE(scene->hasMedia());
  const HeterogeneousMedium* med = scene->instancedMedium(0);
  ASSERT_NE(med, nullptr);
  // Denser higher up the gradient (candidates kept with probability 0.75) than lower (0.5),
  // both a kernel's reach inside the slab; positions in render space.
  const Vec3 origin(float(scene->renderOrigin().x), float(scene->renderOrigin().y), float(scene->renderOrigin().z));
  const float top = med->density(Vec3(0.0f, -0.05f * 8.0f, 0.0f) - origin);
  const float bottom = med->density(Vec3(0.0f, -0.05f * 16.0f, 0.0f) - origin);
  std::printf("packing rate near the top %.3f, near the bottom %.3f; %d explicit bounces\n", top, bottom,
              scene->explicitBounces());
  EXPECT_GT(top, 1.15f * bottom);
  EXPECT_GT(bottom, 0.05f);
  // EPT builds none.
  auto ept = Scene::build(slabScene(Technique::Ept, 1, true));
  EXPECT_EQ(ept->instancedMedium(0), nullptr);
  EXPECT_FALSE(ept->hasMedia());
  // A handful of grains is thinner than its mean free path: none.
  auto thin = Scene::build(instancedScene(false, 1));
  EXPECT_EQ(thin->instancedMedium(0), nullptr);
}

TEST(InstancedGrainsInScene, TheHybridMatchesExplicitGrainsOnASlab) {
  // Per 8x8 block and channel against EPT on the same grains: with the automatic low orders
  // (the rule's 32 bounces for grains this absorbing, Scene::explicitBouncesFor, carried by
  // proxies as 16 visits) within noise; with
  // none, the medium alone carries everything after the first grain, within the equivalent
  // medium's known low-order error (a few percent dark: bench/README.md) plus noise.
  for (bool gradient : {false, true}) {
    const auto windows = blocks(16, 2);
    const auto ept = renderEstimates(slabScene(Technique::Ept, 5, gradient), windows);
    for (int bounces : {-1, 0}) {
      const auto hyb = renderEstimates(slabScene(Technique::EptVpt, 6, gradient, bounces), windows);
      for (size_t b = 0; b < windows.size(); ++b)
        for (int c = 0; c < 3; ++c) {
          const double noise = std::hypot(ept[b].se[c], hyb[b].se[c]);
          const double diff = hyb[b].mean[c] - ept[b].mean[c];
          std::printf("%s, %d explicit bounces, block %zu channel %d: EPT %.4f, EPT+VPT %.4f (%+.1f%%, noise %.1f%%)\n",
                      gradient ? "gradient" : "uniform", bounces, b, c, ept[b].mean[c], hyb[b].mean[c],
                      100 * diff / ept[b].mean[c], 100 * noise / ept[b].mean[c]);
          const double allowed = 4 * noise + (bounces == 0 ? 0.05 * ept[b].mean[c] : 0.0);
          EXPECT_LE(std::fabs(diff), allowed) << (gradient ? "gradient" : "uniform") << ", " << bounces
                                              << " explicit bounces, block " << b << ", channel " << c;
        }
    }
  }
}

TEST(InstancedGrainsInScene, PathsLeaveTheMediumThroughItsBoundsWhereverTheSlabStands) {
  // The slab of nearly clear grains, and the same slab and camera 20 times larger, lifted
  // by 60 (render space keeps it there: the origin's grid is 128): its medium's bounds' top
  // face lies where a float's step is 3.8e-6, 150 grain radii up, as a simulation's slab in
  // metres of 1 cm grains has it. A path leaving the medium from just below that face must
  // still leave. (One that went on from o + d t_end as its new origin could round onto the
  // face, find the bounds again as the empty interval [0, 0] and never leave: lost, and a
  // slab of ice 26% too dark.) The same image both ways, no path lost.
  std::vector<Image> at;
  for (float size : {1.0f, 20.0f}) {
    SceneDesc d = slabScene(Technique::EptVpt, 8, false, 0);
    d.materials[0].absorption = Vec3(0.002f, 0.004f, 0.008f);  // per bounding radius: alike at both sizes
    d.settings.spp = 32;
    const double lift = size > 1 ? 60.0 : 0.0;
    d.camera.cameraToWorld = Transform::translate(0.0, lift, 0.0) * Transform::scale(Vec3(size)) * d.camera.cameraToWorld *
                             Transform::scale(Vec3(1.0f / size));
    d.instancedGrains[0].xf = Transform::translate(0.0, lift, 0.0) * Transform::scale(Vec3(size)) * d.instancedGrains[0].xf;
    auto scene = Scene::build(d);
    ASSERT_NE(scene->instancedMedium(0), nullptr);
    Renderer r(*scene);
    ASSERT_TRUE(r.render(d.settings.spp));
    EXPECT_EQ(r.lostPaths(), 0) << "size " << size;
    at.push_back(r.film().toImage());
  }
  // The same seeds: the pixel-paired difference's own noise.
  const auto p = granular::testing::pairedDifference(at[1], at[0]);
  for (int c = 0; c < 3; ++c) {
    std::printf("channel %d: 20 times larger and lifted − the slab %+.5f ± %.5f\n", c, p.diff[c], p.se[c]);
    EXPECT_NEAR(p.diff[c], 0.0, 4 * p.se[c]) << "channel " << c;
  }
}

TEST(InstancedGrainsInScene, ProxiesFindANarrowSunThroughSimulatedGrains) {
  // Under the physical sun (0.53°) a path refracted through smooth grains reaches the sun
  // only by hitting its disk. Where grains are below the pixel's footprint (the level of
  // detail's shortcut; lod 2 here), proxies take the path from its first grain on and reach
  // the sun by next-event estimation (ppt.h). The hybrid under that sun against EPT under a
  // 5° sun of the same irradiance (normalised), which EPT can converge: within noise and 2%
  // (the two suns differ by less on these grains: the aggregates' ball, bench/README.md,
  // "Narrow suns"). Before proxies the medium took such paths at their first grain.
  auto withSun = [](SceneDesc s, float angle) {
    s.lights[0].angle = angle;
    s.lights[0].normalize = true;
    s.lights[0].intensity = 1.5f;
    s.settings.lod = 2.0f;
    return s;
  };
  SceneDesc hybrid = withSun(slabScene(Technique::EptVpt, 8, false), 0.53f);
  {
    auto scene = Scene::build(hybrid);
    ASSERT_TRUE(scene->narrowSun());
    ASSERT_TRUE(scene->instancedProxies(0));
    EXPECT_EQ(scene->explicitBounces(), 0) << "the proxies carry the low orders";
    EXPECT_GT(scene->instancedProxyVisits(0), 0);
  }
  // The whole image (EPT's noise under the 5° sun needs its 1024 samples per pixel).
  const auto whole = blocks(16, 1);
  SceneDesc reference = withSun(slabScene(Technique::Ept, 9, false), 5.0f);
  reference.settings.spp = 1024;
  const ChannelEstimate ept = renderEstimates(reference, whole)[0];
  const ChannelEstimate hyb = renderEstimates(hybrid, whole)[0];
  SceneDesc off = hybrid;
  off.settings.proxies = ProxyUse::Off;
  const ChannelEstimate medium = renderEstimates(off, whole)[0];
  double worstMedium = 0;
  for (int c = 0; c < 3; ++c) {
    const double allowed = 4 * std::hypot(ept.se[c], hyb.se[c]) + 0.02 * ept.mean[c];
    std::printf("channel %d: EPT (5° sun) %.4f ± %.4f, hybrid (0.53° sun) %.4f ± %.4f (%+.1f%%), the medium at the "
                "first grain %.4f (%+.1f%%)\n",
                c, ept.mean[c], ept.se[c], hyb.mean[c], hyb.se[c], 100 * (hyb.mean[c] / ept.mean[c] - 1), medium.mean[c],
                100 * (medium.mean[c] / ept.mean[c] - 1));
    EXPECT_LE(std::fabs(hyb.mean[c] - ept.mean[c]), allowed) << "channel " << c;
    worstMedium = std::max(worstMedium, std::fabs(medium.mean[c] - ept.mean[c]) / allowed);
  }
  // The test can tell: what proxies replace is beyond its tolerance.
  EXPECT_GT(worstMedium, 1.0);
}

TEST(InstancedGrainsInScene, TheAlbedoAovOfAGrainWithAMediumIsTheMediumsColour) {
  // As an aggregate's grain (ept.h: primaryAlbedo): the bulk's diffuse reflectance, below 1
  // for absorbing grains and bluish-dark for this amber; 1 without a medium (EPT).
  auto scene = Scene::build(slabScene(Technique::EptVpt, 1, false));
  ASSERT_NE(scene->instancedMedium(0), nullptr);
  Ray ray;
  const Vec3 origin(float(scene->renderOrigin().x), float(scene->renderOrigin().y), float(scene->renderOrigin().z));
  ray.o = Vec3(0.0f, 1.0f, 0.0f) - origin;
  ray.d = Vec3(0.0f, -1.0f, 0.0f);
  Hit hit;
  ASSERT_TRUE(scene->intersect(ray, hit));
  ASSERT_EQ(hit.kind, Hit::Grain);
  const Vec3 a = primaryAlbedo(*scene, hit);
  EXPECT_GT(minComponent(a), 0.0f);
  EXPECT_LT(maxComponent(a), 1.0f);
  EXPECT_GT(a.x, a.z);  // absorbs blue most
  auto ept = Scene::build(slabScene(Technique::Ept, 1, false));
  Hit h2;
  ASSERT_TRUE(ept->intersect(ray, h2));
  EXPECT_EQ(primaryAlbedo(*ept, h2), Vec3(1.0f));
}

TEST(InstancedGrainsInScene, ANewViewCannotSwitchBetweenEptAndTheHybrid) {
  // The medium is built with the scene (or not, for EPT): switching needs a build, as for
  // aggregates.
  SceneDesc d = slabScene(Technique::Ept, 1, false);
  auto scene = Scene::build(d);
  RenderSettings hybrid = d.settings;
  hybrid.technique = Technique::Hybrid;
  EXPECT_THROW(scene->setView(d.camera, hybrid), InputError);
  EXPECT_TRUE(settingsNeedBuild(d.settings, hybrid));
}
