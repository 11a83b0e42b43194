// Proxies' grain scattering tables: the hit chance and albedo against TT's estimator, a
// white furnace, sampling against evaluation, exit points, and the table's exits against
// grains traced explicitly (tests mirror core/proxy.*).
#include <gtest/gtest.h>

#include <cmath>

#include "core/embree_util.h"
#include "core/error.h"
#include "core/grain.h"
#include "core/proxy.h"
#include "core/rng.h"
#include "core/shapes.h"
#include "core/tt.h"

#include "test_helpers.h"

using namespace granular;

namespace {

using granular::testing::dielectric;

// A grain in its unit bounding sphere, made as a prototype is.
TriangleMesh unitGrain(const TriangleMesh& mesh) {
  EmbreeDevice device = makeEmbreeDevice();
  GrainPrototypeDesc desc;
  desc.name = "grain";
  desc.mesh = mesh;
  return makeGrainPrototype(device, desc).mesh;
}

ProxyOptions proxyOptions(int64_t rays, uint64_t seed = 7) {
  ProxyOptions o;
  o.rays = rays;
  o.seed = seed;
  o.useCache = false;
  return o;
}

}  // namespace

TEST(Proxy, HitChanceAndAlbedoAgreeWithGrainTransport) {
  const TriangleMesh rock = unitGrain(makeRock(3, 0.3f, 5));
  const Material amber = dielectric(1.55f, Vec3(0.05f, 0.3f, 1.2f));
  TTOptions tto;
  tto.rays = 1 << 18;
  tto.useCache = false;
  const GrainTransport tt = estimateGrainTransport(rock, amber, tto);
  const int64_t n = 1 << 18;
  const ProxyTable table = estimateProxyTable(rock, amber, proxyOptions(n));
  // Independent rays (other seeds): the difference of two estimates, each with its SE.
  const double hitSE = std::sqrt(tt.beta * (1 - tt.beta) / double(n));
  EXPECT_NEAR(table.meanHitProbability(), tt.beta, 4.0 * std::sqrt(2.0) * hitSE);
  for (int c = 0; c < 3; ++c)
    EXPECT_NEAR(table.meanAlbedo()[c], tt.albedo[c], 4.0 * std::sqrt(2.0) * tt.albedoSE[c] + 1e-4) << "channel " << c;
  // Grazing rays meet the grain less often than central ones.
  EXPECT_LT(table.hitProbability(table.bBins() - 1), table.hitProbability(0));
}

TEST(Proxy, ClearGrainsReturnAllTheyMeetWhiteFurnace) {
  // Clear grains absorb nothing: every impact parameter's albedo is 1 and every sampled
  // weight is 1 (the table integrates to the grain's albedo).
  const TriangleMesh box = unitGrain(makeBox(Vec3(-0.5f), Vec3(0.5f)));
  const ProxyTable table = estimateProxyTable(box, dielectric(1.5f), proxyOptions(1 << 17));
  Rng rng(3);
  for (int b = 0; b < table.bBins(); ++b) {
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(table.albedo(b)[c], 1.0f, 1e-5f) << "b bin " << b;
    for (int k = 0; k < 2000; ++k) {
      ProxyDirection d;
      ASSERT_TRUE(table.sample(b, rng.next1D(), rng.next1D(), rng.next1D(), rng.next1D(), d));
      const Vec3 weight = d.f / d.pdf;
      for (int c = 0; c < 3; ++c) ASSERT_NEAR(weight[c], 1.0f, 1e-4f);
    }
  }
}

TEST(Proxy, SamplingAgreesWithEvaluationAndThePdfIntegratesToOne) {
  // A rock, which sends almost nothing straight on, and a box of sucrose's proportions,
  // whose straight lobe (proxy.h) takes its share P out of the density: ∫ pdf dω + P = 1.
  const TriangleMesh rock = unitGrain(makeRock(3, 0.3f, 11));
  const TriangleMesh box = unitGrain(makeBox(Vec3(-1.0f, -0.7f, -0.55f), Vec3(1.0f, 0.7f, 0.55f)));
  const Material tinted = dielectric(1.31f, Vec3(0.2f, 0.5f, 0.9f));
  for (const TriangleMesh* grain : {&rock, &box}) {
    const ProxyTable table = estimateProxyTable(*grain, tinted, proxyOptions(1 << 16));
    Rng rng(5);
    double straightShare = 0;
    for (int b = 0; b < table.bBins(); ++b) {
      const Vec3 a = table.albedo(b), pass = table.pass(b);
      const float P = (pass.x + pass.y + pass.z) / (a.x + a.y + a.z);
      straightShare = std::max(straightShare, double(P));
      for (int k = 0; k < 500; ++k) {
        ProxyDirection s;
        ASSERT_TRUE(table.sample(b, rng.next1D(), rng.next1D(), rng.next1D(), rng.next1D(), s));
        EXPECT_NEAR(length(s.w), 1.0f, 1e-5f);
        if (s.straight) {  // a delta: never evaluated, straight on with its probability
          ASSERT_EQ(s.w.z, 1.0f);
          ASSERT_NEAR(s.pdf, P, 1e-6f);
          for (int c = 0; c < 3; ++c) ASSERT_EQ(s.f[c], pass[c]);
          continue;
        }
        const ProxyDirection e = table.eval(b, s.w);
        ASSERT_EQ(e.bin, s.bin);
        ASSERT_EQ(e.mirrored, s.mirrored);
        ASSERT_NEAR(e.pdf, s.pdf, 1e-5f * s.pdf);
        for (int c = 0; c < 3; ++c) ASSERT_NEAR(e.f[c], s.f[c], 1e-6f * (1 + s.f[c]));
      }
      // ∫ pdf dω over the sphere, on a grid of cells equal in θ and φ, each inside one bin
      // (the bins' edges in θ are among the grid's), each weighed by its solid angle.
      const int nt = 1024, np = 256;
      double integral = 0;
      for (int i = 0; i < nt; ++i) {
        const double t0 = kPiD * i / nt, t1 = kPiD * (i + 1) / nt;
        const float mu = float(std::cos(0.5 * (t0 + t1)));
        const double cellOmega = (std::cos(t0) - std::cos(t1)) * (2.0 * kPiD / np);
        for (int j = 0; j < np; ++j) {
          const float phi = -kPi + 2.0f * kPi * (float(j) + 0.5f) / float(np);
          const float s = std::sqrt(1.0f - mu * mu);
          integral += double(table.eval(b, Vec3(s * std::cos(phi), s * std::sin(phi), mu)).pdf) * cellOmega;
        }
      }
      EXPECT_NEAR(integral + P, 1.0, 1e-3) << "b bin " << b;
    }
    if (grain == &box) EXPECT_GT(straightShare, 0.5) << "the box's straight lobe";
    else EXPECT_LT(straightShare, 0.01) << "the rock's";
  }
}

TEST(Proxy, ExitPointsLieOnTheSphereWhereTheRayLeavesIt) {
  const TriangleMesh rock = unitGrain(makeRock(3, 0.3f, 13));
  const ProxyTable table = estimateProxyTable(rock, dielectric(1.5f), proxyOptions(1 << 16));
  Rng rng(9);
  for (int k = 0; k < 20000; ++k) {
    const int b = int(rng.next1D() * float(table.bBins()));
    ProxyDirection d;
    ASSERT_TRUE(table.sample(b, rng.next1D(), rng.next1D(), rng.next1D(), rng.next1D(), d));
    const Vec3 p = table.exitPoint(b, d, rng.next1D());
    ASSERT_NEAR(length(p), 1.0f, 1e-4f);
    ASSERT_GE(dot(p, d.w), -1e-4f);  // leaving: the direction points out of the sphere there
  }
}

TEST(Proxy, TableExitsMatchTheGrainTracedExplicitly) {
  // The same kind of rays traced through the grain explicitly (randomly rotated, which the
  // uniform entries stand for) and drawn from the table, per b bin: the energy-weighted
  // mean exit cosine ⟨ω·z⟩ and the mean exit point's ⟨p·z⟩ (how far through the sphere the
  // light leaves: the back side for transmission, the front for reflection).
  const TriangleMesh rock = unitGrain(makeRock(3, 0.3f, 17));
  const Material m = dielectric(1.5f, Vec3(0.3f));
  const ProxyTable table = estimateProxyTable(rock, m, proxyOptions(1 << 18));
  EmbreeDevice device = makeEmbreeDevice();
  EmbreeScene bvh = buildTriangleScene(device, rock);
  const int nb = table.bBins();
  std::vector<double> w(nb), w2(nb), wmu(nb), wmu2(nb), wz(nb), wz2(nb);
  std::vector<int64_t> n(nb);
  for (int64_t k = 0; k < (1 << 18); ++k) {
    Rng rng(hashInts(99, uint64_t(k)));  // other rays than the table's
    Vec3 xi, wi;
    sampleSphereEntry(rng, xi, wi);
    const ProxyFrame frame(wi, xi);
    const int b = table.bBin(frame.b);
    const GrainPassage g = traceGrainPassage(bvh.get(), rock, m, 4096, xi, wi, rng);
    if (!g.hit) continue;
    ++n[b];
    const double e = g.weight.x;
    const Vec3 d = frame.toLocal(g.d), o = frame.toLocal(g.o);
    const float bo = dot(o, d), c = length2(o) - 1.0f;
    const Vec3 p = o + d * (-bo + std::sqrt(std::max(0.0f, bo * bo - c)));
    w[b] += e; w2[b] += e * e; wmu[b] += e * d.z; wmu2[b] += e * e * d.z * d.z; wz[b] += e * p.z; wz2[b] += e * e * p.z * p.z;
  }
  Rng rng(21);
  for (int b = 0; b < nb; ++b) {
    const double meanE = w[b] / double(n[b]);
    const double mu = wmu[b] / w[b], z = wz[b] / w[b];
    // Standard errors of the ratio estimators (weights near-constant here: the plain SE of
    // the weighted values over the mean weight).
    const double seMu = std::sqrt(std::max(0.0, wmu2[b] / double(n[b]) - std::pow(wmu[b] / double(n[b]), 2)) / double(n[b])) / meanE;
    const double seZ = std::sqrt(std::max(0.0, wz2[b] / double(n[b]) - std::pow(wz[b] / double(n[b]), 2)) / double(n[b])) / meanE;
    double tw = 0, tmu = 0, tz = 0;
    const int draws = 100000;
    for (int k = 0; k < draws; ++k) {
      ProxyDirection d;
      ASSERT_TRUE(table.sample(b, rng.next1D(), rng.next1D(), rng.next1D(), rng.next1D(), d));
      const double e = d.f.x / d.pdf;
      const Vec3 p = table.exitPoint(b, d, rng.next1D());
      tw += e; tmu += e * d.w.z; tz += e * p.z;
    }
    // Table side: its own estimate (SE like the explicit one's), plus the binning: ω is
    // uniform within a μ bin, at most 1 − cos(π/32) ≈ π/32 wide in μ, which moves ⟨μ⟩ by
    // well under half of it.
    const double bin = 0.5 * kPiD / 32.0;
    EXPECT_NEAR(tmu / tw, mu, 4.0 * std::sqrt(2.0) * seMu + 0.1 * bin) << "b bin " << b;
    EXPECT_NEAR(tz / tw, z, 4.0 * std::sqrt(2.0) * seZ + 0.1 * bin) << "b bin " << b;
    // The albedo: the table's rays against these, each a mean over the bin's hits.
    const double seE = std::sqrt(std::max(0.0, w2[b] / double(n[b]) - meanE * meanE) / double(n[b]));
    EXPECT_NEAR(table.albedo(b).x, meanE, 4.0 * std::sqrt(2.0) * seE) << "b bin " << b;
  }
}

TEST(Proxy, AFlatGrainsStraightOnAndStraightBackPeaksStayNarrow) {
  // A flat box (sucrose's 1 : 0.7 : 0.55) sends light straight on through its parallel
  // faces and straight back from faces met head-on: peaks at θ = 0 and π. Straight on, the
  // table's straight lobe holds exactly what leaves within kStraightOnDegrees. Within 3°
  // of each peak, traced explicitly, against the table's samples: the table keeps the
  // rest of what its first bin (5.6°, bins equal in θ) holds uniform over the bin's solid
  // angle, so its share within 3° is at least that bin's share × (1 − cos 3°) /
  // (1 − cos 5.625°). Bins equal in μ (a 20° first bin) put about a tenth of the straight
  // back peak there instead.
  const TriangleMesh box = unitGrain(makeBox(Vec3(-0.5f, -0.35f, -0.275f), Vec3(0.5f, 0.35f, 0.275f)));
  const Material m = dielectric(1.56f);
  const ProxyTable table = estimateProxyTable(box, m, proxyOptions(1 << 18));
  EmbreeDevice device = makeEmbreeDevice();
  EmbreeScene bvh = buildTriangleScene(device, box);
  const double c3 = std::cos(3.0 * kPiD / 180.0), cBin = std::cos(kPiD / 32.0);
  const double withinBin = (1.0 - c3) / (1.0 - cBin);
  int64_t hits = 0;
  double on = 0, on2 = 0, back = 0, back2 = 0, straight = 0, straight2 = 0;
  const double cStraight = std::cos(kStraightOnDegrees * kPiD / 180.0);
  const int64_t n = 1 << 18;
  for (int64_t k = 0; k < n; ++k) {
    Rng rng(hashInts(77, uint64_t(k)));
    Vec3 xi, wi;
    sampleSphereEntry(rng, xi, wi);
    const GrainPassage g = traceGrainPassage(bvh.get(), box, m, 4096, xi, wi, rng);
    if (!g.hit) continue;
    ++hits;
    const double mu = dot(g.d, wi);
    const double e = g.weight.x;
    if (mu > c3) { on += e; on2 += e * e; }
    if (mu > cStraight) { straight += e; straight2 += e * e; }
    if (mu < -c3) { back += e; back2 += e * e; }
  }
  // The table's share, over the b bins (equal shares of entering rays) weighed by hits.
  Rng rng(31);
  double tOn = 0, tBack = 0, tHits = 0;
  for (int b = 0; b < table.bBins(); ++b) {
    const int draws = 200000;
    double sOn = 0, sBack = 0;
    for (int k = 0; k < draws; ++k) {
      ProxyDirection d;
      ASSERT_TRUE(table.sample(b, rng.next1D(), rng.next1D(), rng.next1D(), rng.next1D(), d));
      const double e = d.f.x / d.pdf;
      if (d.w.z > c3) sOn += e;
      if (d.w.z < -c3) sBack += e;
    }
    tOn += table.hitProbability(b) * sOn / draws;
    tBack += table.hitProbability(b) * sBack / draws;
    tHits += table.hitProbability(b);
  }
  tOn /= tHits;
  tBack /= tHits;
  const double h = double(hits);
  const double pOn = on / h, pBack = back / h;
  const double seOn = std::sqrt(std::max(0.0, on2 / h - pOn * pOn) / h);
  const double seBack = std::sqrt(std::max(0.0, back2 / h - pBack * pBack) / h);
  // Straight on within kStraightOnDegrees: the table's straight lobe, per ray met (over
  // the b bins weighed by hits), against the share traced (the box's parallel faces send
  // these rays exactly straight).
  double lobe = 0;
  for (int b = 0; b < table.bBins(); ++b) lobe += table.hitProbability(b) * table.pass(b).x;
  lobe /= tHits;
  const double pStraight = straight / double(hits);
  const double seStraight = std::sqrt(std::max(0.0, straight2 / double(hits) - pStraight * pStraight) / double(hits));
  std::printf("straight on within %.2f°: explicit %.4f ± %.4f, the table's lobe %.4f\n", kStraightOnDegrees,
              pStraight, seStraight, lobe);
  EXPECT_GT(pStraight, 0.2);
  EXPECT_NEAR(lobe, pStraight, 4.0 * std::sqrt(2.0) * seStraight);
  ASSERT_GT(pOn, 0.05);  // the peaks are there to keep
  ASSERT_GT(pBack, 0.01);
  // The explicit share lies between the uniform-in-bin share and the whole bin's; the
  // table's must be at least the uniform share of it, less noise: the explicit estimate's
  // and the table's own, from as many rays (√2 of one), the draws' far below.
  std::printf("within 3°: straight on explicit %.4f ± %.4f, table %.4f; straight back %.4f ± %.4f, table %.4f\n",
              pOn, seOn, tOn, pBack, seBack, tBack);
  EXPECT_GT(tOn, withinBin * pOn - 4.0 * std::sqrt(2.0) * seOn);
  EXPECT_GT(tBack, withinBin * pBack - 4.0 * std::sqrt(2.0) * seBack);
}

TEST(Proxy, TablesAreCachedAndReadBackIdentical) {
  const TriangleMesh box = unitGrain(makeBox(Vec3(-0.5f), Vec3(0.5f, 0.4f, 0.5f)));
  ProxyOptions o = proxyOptions(1 << 14, 1234567);
  o.useCache = true;
  const Material m = dielectric(1.4f, Vec3(0.1f));
  const ProxyTable first = estimateProxyTable(box, m, o);
  const ProxyTable second = estimateProxyTable(box, m, o);
  EXPECT_TRUE(second.fromCache());
  Rng rng(1);
  for (int k = 0; k < 1000; ++k) {
    const int b = k % first.bBins();
    float u[5] = {rng.next1D(), rng.next1D(), rng.next1D(), rng.next1D(), rng.next1D()};
    ProxyDirection a, c;
    ASSERT_EQ(first.sample(b, u[0], u[1], u[2], u[3], a), second.sample(b, u[0], u[1], u[2], u[3], c));
    EXPECT_EQ(a.bin, c.bin);
    EXPECT_EQ(a.straight, c.straight);
    EXPECT_EQ(a.pdf, c.pdf);
    const Vec3 pa = first.exitPoint(b, a, u[4]), pc = second.exitPoint(b, c, u[4]);
    EXPECT_EQ(pa.x, pc.x);
    EXPECT_EQ(pa.z, pc.z);
  }
}

TEST(Proxy, OptionsOutOfRangeAreRefused) {
  const TriangleMesh box = unitGrain(makeBox(Vec3(-0.5f), Vec3(0.5f)));
  ProxyOptions o = proxyOptions(0);
  EXPECT_THROW(estimateProxyTable(box, dielectric(1.5f), o), InputError);
  o = proxyOptions(100);
  o.offsetsPerBin = 0;
  EXPECT_THROW(estimateProxyTable(box, dielectric(1.5f), o), InputError);
  EXPECT_THROW(estimateProxyTable(TriangleMesh(), dielectric(1.5f), proxyOptions(100)), InputError);
}
