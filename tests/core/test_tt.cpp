// Teleportation transport: the per-grain estimator against closed forms, the phase table,
// deriveMedium's formulas and mixture rules, the disk cache, and the TT model's mean free
// path against explicit tracing through a large aggregate (tests mirror core/tt.*).
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <cfloat>
#include <cstdio>
#include <fstream>

#include "core/aggregate.h"
#include "core/cache.h"
#include "core/embree_util.h"
#include "core/error.h"
#include "core/medium.h"
#include "core/microfacet.h"
#include "core/sampling.h"
#include "core/shapes.h"
#include "core/tt.h"
#include "core/vpt.h"

#include "test_helpers.h"

using namespace granular;

namespace {

using granular::testing::dielectric;

TTOptions opts(int64_t rays, uint64_t seed = 1) {
  TTOptions o;
  o.rays = rays;
  o.seed = seed;
  o.useCache = false;  // test the estimator itself; the cache has its own test
  return o;
}

TriangleMesh scaled(TriangleMesh m, float s) {
  for (Vec3& p : m.points) p *= s;
  return m;
}

double surfaceArea(const TriangleMesh& m) {
  double a = 0;
  for (size_t t = 0; t < m.numTriangles(); ++t) {
    const Vec3& p = m.points[m.indices[3 * t]];
    const Vec3& q = m.points[m.indices[3 * t + 1]];
    const Vec3& r = m.points[m.indices[3 * t + 2]];
    a += 0.5 * length(cross(q - p, r - p));
  }
  return a;
}

// Smallest distance from the origin to a facet plane: the inscribed sphere of a convex mesh.
double inradius(const TriangleMesh& m) {
  double r = 1e30;
  for (size_t t = 0; t < m.numTriangles(); ++t)
    r = std::min(r, double(dot(triangleNormal(m, unsigned(t)), m.points[m.indices[3 * t]])));
  return r;
}

// Mean chord, in the unit sphere, of rays (uniform over its projected area) that miss a
// centred sphere of radius a: (4/3) sqrt(1 − a²).
double missChord(double a) { return 4.0 / 3.0 * std::sqrt(1.0 - a * a); }

// The unit-sphere prototype of a mesh, as an aggregate uses it.
TriangleMesh prototypeOf(const TriangleMesh& m) {
  EmbreeDevice dev = makeEmbreeDevice();
  return makeGrainPrototype(dev, GrainPrototypeDesc{"p", m, 0}).mesh;
}

void expectSameTransport(const GrainTransport& a, const GrainTransport& b) {
  EXPECT_EQ(a.beta, b.beta);
  EXPECT_EQ(a.betaSE, b.betaSE);
  EXPECT_EQ(a.lambdaDelta, b.lambdaDelta);
  EXPECT_EQ(a.lambdaDeltaSE, b.lambdaDeltaSE);
  EXPECT_EQ(a.rays, b.rays);
  EXPECT_EQ(a.truncated, b.truncated);
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(a.albedo[c], b.albedo[c]);
    EXPECT_EQ(a.albedoSE[c], b.albedoSE[c]);
    EXPECT_EQ(a.lambdaS[c], b.lambdaS[c]);
    EXPECT_EQ(a.lambdaSSE[c], b.lambdaSSE[c]);
    EXPECT_EQ(a.g[c], b.g[c]);
    EXPECT_EQ(a.gSE[c], b.gSE[c]);
    EXPECT_EQ(a.phase[c].density, b.phase[c].density);
    EXPECT_EQ(a.phase[c].cdf, b.phase[c].cdf);
    EXPECT_EQ(a.phase[c].g, b.phase[c].g);
    for (int k = 0; k < ExitMoves::kBins; ++k) {
      const std::vector<Vec3>&ma = a.exits[c].moves[k], &mb = b.exits[c].moves[k];
      ASSERT_EQ(ma.size(), mb.size());
      for (size_t i = 0; i < ma.size(); ++i) EXPECT_TRUE(ma[i].x == mb[i].x && ma[i].y == mb[i].y && ma[i].z == mb[i].z);
    }
  }
}

double tableIntegral(const PhaseTable& p) {
  double s = 0;
  for (float d : p.density) s += d;
  return 2.0 * kPi * s * (2.0 / p.bins());
}

// Chi-square of n samples of p.sample() against the table's own bin masses, over the bins
// whose expected count is at least 5 (the others are lumped together).
double chiSquareOfSampling(const PhaseTable& p, int n, int& dof, uint64_t seed) {
  Rng rng(seed);
  std::vector<int> counts(size_t(p.bins()), 0);
  Vec3 wi = normalize(Vec3(0.3f, -0.5f, 0.8f));
  for (int i = 0; i < n; ++i) {
    float pdf = -1;
    Vec3 wo = p.sample(wi, rng.next1D(), rng.next1D(), &pdf);
    float mu = dot(wi, wo);
    EXPECT_NEAR(length(wo), 1.0f, 1e-5f);
    EXPECT_EQ(pdf, p.eval(mu));  // the stated pdf is the table's value where the sample landed
    int b = std::min(p.bins() - 1, std::max(0, int((mu + 1.0f) * 0.5f * p.bins())));
    ++counts[size_t(b)];
  }
  double chi2 = 0, restExp = 0, restObs = 0;
  dof = -1;
  for (int b = 0; b < p.bins(); ++b) {
    double e = n * p.mass(-1.0 + 2.0 * b / p.bins(), -1.0 + 2.0 * (b + 1) / p.bins());
    if (e >= 5) {
      chi2 += (counts[size_t(b)] - e) * (counts[size_t(b)] - e) / e;
      ++dof;
    } else {
      restExp += e;
      restObs += counts[size_t(b)];
    }
  }
  if (restExp >= 5) {
    chi2 += (restObs - restExp) * (restObs - restExp) / restExp;
    ++dof;
  } else {
    EXPECT_LE(restObs, 20) << "samples in bins of (almost) zero mass";
  }
  return chi2;
}

}  // namespace

// ---------------------------------------------------------------------------------------
TEST(TTPhaseTable, IsotropicAndHistogramTablesAreNormalised) {
  PhaseTable iso = PhaseTable::isotropic(16);
  ASSERT_EQ(iso.bins(), 16);
  EXPECT_NEAR(iso.eval(0.3f), 1.0f / (4.0f * kPi), 1e-7f);
  EXPECT_NEAR(tableIntegral(iso), 1.0, 1e-6);
  EXPECT_NEAR(iso.g, 0.0f, 1e-6f);

  // Mass only in the top bin: a forward delta in the table's resolution.
  std::vector<double> fwd(8, 0.0);
  fwd[7] = 3.0;
  PhaseTable f = PhaseTable::fromHistogram(fwd);
  EXPECT_NEAR(tableIntegral(f), 1.0, 1e-6);
  EXPECT_EQ(f.eval(0.0f), 0.0f);
  EXPECT_NEAR(f.eval(0.99f), 1.0f / (2.0f * kPi * 0.25f), 1e-5f);
  EXPECT_NEAR(f.g, 1.0f - 0.125f, 1e-6f);  // bin centre
  EXPECT_NEAR(f.mass(-1, 1), 1.0, 1e-7);
  EXPECT_NEAR(f.mass(0.75, 0.875), 0.5, 1e-6);

  // Garbage weights are ignored; nothing at all gives the isotropic table.
  PhaseTable z = PhaseTable::fromHistogram({0.0, -1.0, std::nan(""), 0.0});
  EXPECT_NEAR(z.eval(-0.9f), 1.0f / (4.0f * kPi), 1e-7f);
  EXPECT_NEAR(tableIntegral(z), 1.0, 1e-6);
}

TEST(TTPhaseTable, SamplingMatchesEval) {
  // A lumpy table with empty bins between full ones.
  std::vector<double> w(32);
  for (int i = 0; i < 32; ++i) w[size_t(i)] = (i % 5 == 2) ? 0.0 : 1.0 + i * i * 0.05;
  PhaseTable p = PhaseTable::fromHistogram(w);
  int dof = 0;
  double chi2 = chiSquareOfSampling(p, 40000, dof, 5);
  ASSERT_GT(dof, 10);
  // Chi-square with dof degrees of freedom: mean dof, sd sqrt(2 dof); 5 sd is far beyond chance.
  EXPECT_LT(chi2, dof + 5.0 * std::sqrt(2.0 * dof)) << "dof " << dof;
  // The sample mean cosine is the table's own g.
  Rng rng(9);
  Vec3 wi(0, 0, 1);
  double s = 0;
  const int n = 40000;
  for (int i = 0; i < n; ++i) s += p.sample(wi, rng.next1D(), rng.next1D()).z;
  EXPECT_NEAR(s / n, p.g, 4.0 * std::sqrt(1.0 / n));
}

TEST(TTPhaseTable, TheGuideFindsTheBinTheBinarySearchFinds) {
  // sample() starts from the guide (tt.h) where it has one: the same direction, bit for bit,
  // as the binary search of a table without it — on a table with empty bins, a forward
  // peak, and at u on the guide's steps and the cdf's own values.
  std::vector<double> w(64);
  for (int i = 0; i < 64; ++i) w[size_t(i)] = (i % 7 == 3 || i < 5) ? 0.0 : std::exp(0.15 * i);
  const PhaseTable guided = PhaseTable::fromHistogram(w);
  ASSERT_EQ(guided.guide.size(), size_t(65));  // a starting point per step of u, both ends
  PhaseTable searched = guided;
  searched.guide.clear();
  std::vector<float> us;
  Rng rng(21);
  for (int i = 0; i < 20000; ++i) us.push_back(rng.next1D());
  for (int j = 0; j < 64; ++j) us.push_back(float(j) / 64.0f);
  for (float c : guided.cdf)
    if (c < 1.0f) {
      us.push_back(c);
      us.push_back(std::nextafter(c, 0.0f));
      us.push_back(std::nextafter(c, 1.0f));
    }
  const Vec3 wi = normalize(Vec3(0.3f, -0.2f, 0.9f));
  for (float u : us) {
    float pg = 0, ps = 0;
    const Vec3 a = guided.sample(wi, u, 0.37f, &pg), b = searched.sample(wi, u, 0.37f, &ps);
    ASSERT_EQ(pg, ps) << "u " << u;
    ASSERT_TRUE(a.x == b.x && a.y == b.y && a.z == b.z) << "u " << u;
    EXPECT_GT(pg, 0.0f) << "an empty bin sampled at u " << u;
  }
}

// ---------------------------------------------------------------------------------------
TEST(TTEstimate, CentredSphereHasClosedFormHitProbabilityAndMissChord) {
  // A sphere of radius a in the unit bounding sphere, not normalised into it.
  const double a = 0.6;
  TriangleMesh mesh = scaled(makeIcosphere(5), float(a));
  GrainTransport g = estimateGrainTransport(mesh, dielectric(1.5f), opts(1 << 17, 3));
  // Cauchy: a convex body's mean projected area is a quarter of its surface, so for the
  // facet mesh β = S/(4π) exactly; the true sphere's a² differs by the faceting alone.
  double betaMesh = surfaceArea(mesh) / (4.0 * kPi);
  EXPECT_NEAR(betaMesh, a * a, 2e-4);  // 20480 facets: area deficit ~ 3e-4 relative
  EXPECT_NEAR(g.beta, betaMesh, 4.0 * g.betaSE);
  EXPECT_NEAR(g.beta, a * a, 4.0 * g.betaSE + std::fabs(betaMesh - a * a));
  // The facet mesh's projection lies between the disks of its inradius and of a, so its
  // misses are the rays beyond radius a plus part of the thin annulus (r_in, a): λ_δ lies
  // within about the spread of the closed form over [r_in, a] (~1e-4 here, far below SE).
  double rIn = inradius(mesh), spread = std::fabs(missChord(rIn) - missChord(a));
  EXPECT_LT(spread, 3e-4);
  EXPECT_NEAR(g.lambdaDelta, missChord(a), 4.0 * g.lambdaDeltaSE + 2.0 * spread);
  EXPECT_GT(g.betaSE, 0);
  EXPECT_GT(g.lambdaDeltaSE, 0);
  EXPECT_LT(g.lambdaDeltaSE, 0.01);
}

TEST(TTEstimate, IndexMatchedGrainIsAForwardDelta) {
  // Fills the bounding sphere (vertices on it), IOR 1, no absorption: every ray runs
  // straight through, so x_o − x_i is the chord of the unit sphere, whose mean under
  // uniform-projected-area entry is 4/3 (the volume-to-area formula 4V/S).
  TriangleMesh mesh = makeIcosphere(5);
  GrainTransport g = estimateGrainTransport(mesh, dielectric(1.0f), opts(1 << 16, 4));
  EXPECT_GT(g.beta, 0.999);  // only rays grazing the facets miss
  EXPECT_EQ(g.truncated, 0);
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(g.albedo[c], 1.0);
    // Hits exclude the grazing rays beyond the inradius (chords < 0.04); leaving out that
    // ~4e-4 of the rays raises the mean chord by < 1e-3.
    EXPECT_NEAR(g.lambdaS[c], 4.0 / 3.0, 4.0 * g.lambdaSSE[c] + 1e-3);
    EXPECT_NEAR(g.lambdaSSE[c], std::sqrt(2.0 / 9.0 / double(g.rays)), 2e-4);  // chord sd = sqrt(2/9)
    EXPECT_NEAR(g.g[c], 1.0, 1e-4);
    const PhaseTable& p = g.phase[c];
    ASSERT_EQ(p.bins(), 64);
    EXPECT_EQ(p.cdf[63], 0.0f);  // all the mass in the last bin
    EXPECT_NEAR(tableIntegral(p), 1.0, 1e-5);
    // Where it lets the light out: straight on, moved by the chord along ω_i (mean 4/3).
    const ExitMoves& e = g.exits[c];
    for (int k = 0; k + 1 < ExitMoves::kBins; ++k) EXPECT_TRUE(e.moves[k].empty()) << k;
    const std::vector<Vec3>& fwd = e.moves[ExitMoves::kBins - 1];
    ASSERT_EQ(int(fwd.size()), ExitMoves::kPerBin);
    double along = 0;
    for (const Vec3& m : fwd) {
      EXPECT_LE(m.x, 2.0f + 1e-5f);
      EXPECT_NEAR(m.y, 0.0f, 1e-3f);
      EXPECT_NEAR(m.z, 0.0f, 1e-3f);
      along += m.x;
    }
    along /= double(fwd.size());
    EXPECT_NEAR(along, 4.0 / 3.0, 4.0 * std::sqrt(2.0 / 9.0 / double(fwd.size())));
    // Sampled in a world frame: along ω_i.
    const Vec3 wi = normalize(Vec3(0.2f, -0.3f, 0.9f));
    const Vec3 m = e.sample(wi, wi, 0.5f);
    EXPECT_NEAR(length(cross(m, wi)), 0.0f, 2e-3f);
    EXPECT_GT(dot(m, wi), 0.0f);
  }
}

TEST(TTEstimate, ClearDielectricConservesEnergyAndItsPhaseTableSamples) {
  TriangleMesh rock = prototypeOf(makeRock(3, 0.3f, 11));
  GrainTransport g = estimateGrainTransport(rock, dielectric(1.5f), opts(1 << 15, 5));
  EXPECT_GT(g.beta, 0.5);
  EXPECT_LT(g.beta, 1.0);
  EXPECT_GT(g.lambdaDelta, 0.0);
  EXPECT_EQ(g.truncated, 0);
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(g.albedo[c], 1.0, 1e-6);  // weights are exactly 1 without absorption
    EXPECT_GT(g.lambdaS[c], 0.3);
    EXPECT_LT(g.lambdaS[c], 2.0);
    EXPECT_GT(g.gSE[c], 0.0);
    EXPECT_NEAR(tableIntegral(g.phase[c]), 1.0, 1e-5);
    // The table's mean cosine (bin centres) is the exact estimate up to half a bin.
    EXPECT_NEAR(g.phase[c].g, g.g[c], 1.0 / 64 + 4.0 * g.gSE[c]);
  }
  EXPECT_EQ(g.phase[0].density, g.phase[2].density);  // no absorption: channels equal
  int dof = 0;
  double chi2 = chiSquareOfSampling(g.phase[0], 40000, dof, 7);
  ASSERT_GT(dof, 20);
  EXPECT_LT(chi2, dof + 5.0 * std::sqrt(2.0 * dof)) << "dof " << dof;
}

TEST(TTEstimate, AbsorptionLowersTheAlbedo) {
  TriangleMesh rock = prototypeOf(makeRock(2, 0.25f, 4));
  // One channel per absorption level; the channels share their paths, so the ordering is
  // exact sample by sample, and the gaps are far beyond the SE.
  GrainTransport g = estimateGrainTransport(rock, dielectric(1.5f, Vec3(0.05f, 0.5f, 3.0f)), opts(1 << 14, 6));
  EXPECT_LT(g.albedo[0], 1.0);
  EXPECT_GT(g.albedo[0], g.albedo[1] + 4.0 * (g.albedoSE[0] + g.albedoSE[1]));
  EXPECT_GT(g.albedo[1], g.albedo[2] + 4.0 * (g.albedoSE[1] + g.albedoSE[2]));
  EXPECT_GT(g.albedo[2], 0.0);
  for (int c = 0; c < 3; ++c) {
    EXPECT_GT(g.albedoSE[c], 0.0);
    EXPECT_NEAR(tableIntegral(g.phase[c]), 1.0, 1e-5);
  }
  // Strong absorption favours the short paths: external reflection, backward (g smaller).
  EXPECT_LT(g.g[2], g.g[0]);
  // A separate, more absorbing grain: lower again.
  GrainTransport h = estimateGrainTransport(rock, dielectric(1.5f, Vec3(6.0f)), opts(1 << 14, 6));
  EXPECT_LT(h.albedo[0], g.albedo[2]);
  // One generator per ray: every material sees the same entries, hence the same misses.
  GrainTransport clear = estimateGrainTransport(rock, dielectric(1.5f), opts(1 << 14, 6));
  EXPECT_EQ(clear.beta, g.beta);
  EXPECT_EQ(clear.lambdaDelta, g.lambdaDelta);
  EXPECT_EQ(h.lambdaDelta, g.lambdaDelta);
}

TEST(TTEstimate, RoughGrainsAreContinuousAsRoughnessVanishes) {
  // A rough sphere's α_s, g and λ_s approach the smooth sphere's as roughness → 0 (the
  // same random numbers drive both, so differences are far below the standard errors),
  // and roughness does change them.
  TriangleMesh sphere = prototypeOf(makeIcosphere(3));
  Material smooth = dielectric(1.5f, Vec3(0.1f));
  GrainTransport g0 = estimateGrainTransport(sphere, smooth, opts(1 << 14, 6));
  std::vector<double> dAlbedo, dG, dLambda;
  for (float roughness : {0.05f, 0.1f, 0.2f, 0.4f, 0.7f}) {
    MaterialDesc d;  // the renderer's default: energy-compensated
    d.type = MaterialType::Dielectric;
    d.ior = smooth.ior;
    d.absorption = smooth.absorption;
    d.roughness = roughness;
    Material m = Material::fromDesc(d);
    ASSERT_FALSE(m.validTable.empty());
    GrainTransport g = estimateGrainTransport(sphere, m, opts(1 << 14, 6));
    std::printf("roughness %.2f: albedo %.4f (smooth %.4f), g %.4f (%.4f), lambda_s %.4f (%.4f)\n", roughness,
                g.albedo[0], g0.albedo[0], g.g[0], g0.g[0], g.lambdaS[0], g0.lambdaS[0]);
    EXPECT_EQ(g.beta, g0.beta);  // geometry alone
    dAlbedo.push_back(std::fabs(g.albedo[0] - g0.albedo[0]));
    dG.push_back(std::fabs(g.g[0] - g0.g[0]));
    dLambda.push_back(std::fabs(g.lambdaS[0] - g0.lambdaS[0]));
  }
  EXPECT_LT(dAlbedo[0], 0.005);
  EXPECT_LT(dG[0], 0.01);
  EXPECT_LT(dLambda[0], 0.01);
  EXPECT_GT(dG.back(), 10 * dG[0]);
  EXPECT_GT(dG.back(), 4 * g0.gSE[0]);
  for (size_t i = 1; i < dG.size(); ++i) EXPECT_GE(dG[i] + 2 * g0.gSE[0], dG[i - 1]) << i;
}

TEST(TTEstimate, BlackAndNeverHitGrainsStayFinite) {
  Material black;  // Lambert, albedo 0
  black.albedo = Vec3(0.0f);
  GrainTransport b = estimateGrainTransport(makeIcosphere(2), black, opts(4096, 2));
  EXPECT_GT(b.beta, 0.9);
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(b.albedo[c], 0.0);
    EXPECT_EQ(b.lambdaS[c], 0.0);
    EXPECT_EQ(b.g[c], 0.0);
    EXPECT_NEAR(b.phase[c].eval(0.5f), 1.0f / (4.0f * kPi), 1e-7f);  // isotropic stand-in
  }
  MediumParams mb = deriveMedium({b}, {1.0f}, 0.01f, 0.6f);
  EXPECT_TRUE(isFinite(mb.sigmaT) && isFinite(mb.sigmaTr) && isFinite(mb.albedoReduced));
  EXPECT_EQ(mb.albedo, Vec3(0.0f));
  EXPECT_EQ(mb.albedoReduced, Vec3(0.0f));
  EXPECT_NEAR(mb.sigmaT.x, 1.0f / mb.lambdaBeta.x, 1e-3f * mb.sigmaT.x);
  EXPECT_NEAR(mb.sigmaTr.x, std::sqrt(3.0f) * mb.sigmaT.x, 1e-3f * mb.sigmaT.x);

  // A speck (radius 1e-4): 4096 rays never hit it (β ~ 1e-8).
  GrainTransport s = estimateGrainTransport(scaled(makeIcosphere(1), 1e-4f), dielectric(1.5f), opts(4096, 2));
  EXPECT_EQ(s.beta, 0.0);
  EXPECT_EQ(s.betaSE, 0.0);
  EXPECT_NEAR(s.lambdaDelta, 4.0 / 3.0, 4.0 * s.lambdaDeltaSE);
  MediumParams ms = deriveMedium({s}, {1.0f}, 0.01f, 0.6f);
  EXPECT_EQ(ms.sigmaT, Vec3(0.0f));
  EXPECT_EQ(ms.sigmaTr, Vec3(0.0f));
  EXPECT_EQ(ms.lambdaT, Vec3(FLT_MAX));
  EXPECT_EQ(ms.albedo, Vec3(1.0f));
  EXPECT_TRUE(isFinite(ms.albedoReduced) && isFinite(ms.sigmaTReduced));
}

TEST(TTEstimate, DeterministicForASeedWhateverTheThreadCount) {
  TriangleMesh rock = prototypeOf(makeRock(2, 0.25f, 4));
  Material m = dielectric(1.4f, Vec3(0.2f, 0.4f, 0.8f));
  TTOptions o = opts(3 * 4096 + 100, 8);  // a ragged last chunk
  GrainTransport a = estimateGrainTransport(rock, m, o);
  GrainTransport one;
  tbb::task_arena arena(1);
  arena.execute([&] { one = estimateGrainTransport(rock, m, o); });
  expectSameTransport(a, one);
  EXPECT_EQ(a.rays, o.rays);
  GrainTransport other = estimateGrainTransport(rock, m, opts(o.rays, 9));
  EXPECT_NE(a.albedo[0], other.albedo[0]);
}

TEST(TTEstimate, CacheRoundTripAndCorruptEntry) {
  TriangleMesh rock = prototypeOf(makeRock(2, 0.25f, 12));
  Material m = dielectric(1.5f, Vec3(0.3f));
  TTOptions o = opts(4096, 21);
  o.useCache = true;
  std::string dir = cacheDirectory();
  ASSERT_FALSE(dir.empty());
  std::string path = dir + "/" + grainTransportCacheName(rock, m, o);
  std::remove(path.c_str());  // a previous run's entry

  GrainTransport first = estimateGrainTransport(rock, m, o);
  EXPECT_FALSE(first.fromCache);
  ASSERT_TRUE(std::ifstream(path).good());
  GrainTransport second = estimateGrainTransport(rock, m, o);
  EXPECT_TRUE(second.fromCache);
  expectSameTransport(first, second);

  // Any change of the inputs names another entry.
  TTOptions o2 = o;
  o2.phaseBins = 32;
  Material m2 = m;
  m2.ior = 1.51f;
  EXPECT_NE(grainTransportCacheName(rock, m, o2), grainTransportCacheName(rock, m, o));
  EXPECT_NE(grainTransportCacheName(rock, m2, o), grainTransportCacheName(rock, m, o));

  // A corrupted entry (one byte flipped) is ignored, recomputed and rewritten.
  std::vector<char> bytes;
  {
    std::ifstream in(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  ASSERT_GT(bytes.size(), 100u);
  bytes[60] ^= 0x20;
  std::ofstream(path, std::ios::binary).write(bytes.data(), std::streamsize(bytes.size()));
  GrainTransport third = estimateGrainTransport(rock, m, o);
  EXPECT_FALSE(third.fromCache);
  expectSameTransport(first, third);
  // A truncated one too.
  std::ofstream(path, std::ios::binary).write(bytes.data(), 40);
  GrainTransport fourth = estimateGrainTransport(rock, m, o);
  EXPECT_FALSE(fourth.fromCache);
  expectSameTransport(first, fourth);
  EXPECT_TRUE(estimateGrainTransport(rock, m, o).fromCache);
}

TEST(TTEstimate, BadOptionsAreInputErrors) {
  TriangleMesh m = makeIcosphere(1);
  TTOptions o = opts(0);
  EXPECT_THROW(estimateGrainTransport(m, dielectric(1.5f), o), InputError);
  o = opts(100);
  o.phaseBins = 0;
  EXPECT_THROW(estimateGrainTransport(m, dielectric(1.5f), o), InputError);
  o = opts(100);
  o.maxBounces = 0;
  EXPECT_THROW(estimateGrainTransport(m, dielectric(1.5f), o), InputError);
  EXPECT_THROW(estimateGrainTransport(TriangleMesh(), dielectric(1.5f), opts(100)), InputError);
}

// ---------------------------------------------------------------------------------------
namespace {

GrainTransport handMade(double beta, double delta, std::array<double, 3> alpha, std::array<double, 3> ls,
                        std::array<double, 3> g) {
  GrainTransport t;
  t.beta = beta;
  t.lambdaDelta = delta;
  t.albedo = alpha;
  t.lambdaS = ls;
  t.g = g;
  t.rays = 1000;
  for (int c = 0; c < 3; ++c) t.phase[c] = PhaseTable::isotropic(8);
  return t;
}

void expectRel(float got, double want, double rel = 1e-5) {
  EXPECT_NEAR(got, want, rel * std::max(std::fabs(want), 1e-30)) << "want " << want;
}

}  // namespace

TEST(TTMedium, FormulasMatchHandComputation) {
  GrainTransport t = handMade(0.8, 0.5, {1.0, 0.9, 0.5}, {1.2, 1.1, 1.0}, {0.5, 0.4, 0.3});
  MediumParams m = deriveMedium({t}, {1.0f}, 0.01f, 0.6f);
  // By hand (R = 0.01, f = 0.6): σ_b = 3/(4·0.01)·0.6/0.4 = 112.5, λ_b = 0.0088889;
  // λ_β = λ_b + (λ_b + 0.005)·0.25/0.8 … = 0.0123611; λ_t = λ_β + α·0.01·λ_s.
  expectRel(m.sigmaB, 112.5);
  for (int c = 0; c < 3; ++c) expectRel(m.lambdaBeta[c], 0.0123611111);
  const double lt[3] = {0.0243611111, 0.0222611111, 0.0173611111};
  const double st[3] = {41.0490308, 44.9213876, 57.6};
  const double ssr[3] = {20.5245154, 24.2575493, 20.16};
  const double sa[3] = {0.0, 4.49213876, 28.8};
  const double str_[3] = {20.5245154, 28.749688, 48.96};
  const double asr[3] = {1.0, 0.84375, 0.411764706};
  const double tr[3] = {0.0, 19.6835658, 65.0395572};
  for (int c = 0; c < 3; ++c) {
    expectRel(m.lambdaT[c], lt[c]);
    expectRel(m.meanFreePath()[c], lt[c]);
    expectRel(m.sigmaT[c], st[c]);
    expectRel(m.sigmaSReduced[c], ssr[c]);
    EXPECT_NEAR(m.sigmaA[c], sa[c], 1e-4);
    expectRel(m.sigmaTReduced[c], str_[c]);
    expectRel(m.albedoReduced[c], asr[c]);
    EXPECT_NEAR(m.sigmaTr[c], tr[c], 1e-4);
  }
  EXPECT_EQ(m.albedo, Vec3(1.0f, 0.9f, 0.5f));
  EXPECT_EQ(m.g, Vec3(0.5f, 0.4f, 0.3f));
  EXPECT_EQ(m.sigmaTr.x, 0.0f);  // α_s = 1 exactly: no absorption, σ_tr = 0
}

TEST(TTMedium, MixtureOfTwoCopiesEqualsTheSinglePrototype) {
  TriangleMesh rock = prototypeOf(makeRock(2, 0.25f, 4));
  GrainTransport g = estimateGrainTransport(rock, dielectric(1.5f, Vec3(0.1f, 0.5f, 2.0f)), opts(1 << 13, 3));
  MediumParams one = deriveMedium({g}, {1.0f}, 0.02f, 0.55f);
  MediumParams two = deriveMedium({g, g}, {0.3f, 2.0f}, 0.02f, 0.55f);
  for (int c = 0; c < 3; ++c) {
    expectRel(two.sigmaT[c], one.sigmaT[c]);
    expectRel(two.albedo[c], one.albedo[c]);
    expectRel(two.g[c], one.g[c]);
    expectRel(two.sigmaTReduced[c], one.sigmaTReduced[c]);
    expectRel(two.sigmaTr[c], one.sigmaTr[c]);
    expectRel(float(two.combined.lambdaS[c]), one.combined.lambdaS[c]);
    for (int b = 0; b < 64; ++b) EXPECT_NEAR(two.phase[c].density[b], one.phase[c].density[b], 1e-5f);
  }
  expectRel(float(two.combined.lambdaDelta), one.combined.lambdaDelta);
  expectRel(float(two.combined.beta), one.combined.beta);
  EXPECT_EQ(two.combined.rays, 2 * one.combined.rays);
}

TEST(TTMedium, MixtureRules) {
  // Prototype A: small (β 0.5), clear, isotropic. B: big (β 1), half absorbing, all forward.
  GrainTransport a = handMade(0.5, 0.8, {1.0, 1.0, 1.0}, {1.0, 1.0, 1.0}, {0.0, 0.0, 0.0});
  GrainTransport b = handMade(1.0, 0.0, {0.5, 0.5, 0.5}, {2.0, 2.0, 2.0}, {0.9, 0.9, 0.9});
  std::vector<double> fwd(4, 0.0);
  fwd[3] = 1.0;
  for (int c = 0; c < 3; ++c) b.phase[c] = PhaseTable::fromHistogram(fwd);  // coarser table: rebinned
  MediumParams m = deriveMedium({a, b}, {1.0f, 3.0f}, 0.01f, 0.5f);       // w = 1/4, 3/4
  const GrainTransport& x = m.combined;
  EXPECT_NEAR(x.beta, 0.25 * 0.5 + 0.75 * 1.0, 1e-12);                    // Σ w β
  EXPECT_NEAR(x.lambdaDelta, 0.8, 1e-12);                                 // only A misses
  double hitA = 0.25 * 0.5, hitB = 0.75;                                  // w β
  EXPECT_NEAR(x.albedo[0], (hitA * 1.0 + hitB * 0.5) / (hitA + hitB), 1e-12);
  double exA = hitA * 1.0, exB = hitB * 0.5;                              // w β α
  EXPECT_NEAR(x.lambdaS[0], (exA * 1.0 + exB * 2.0) / (exA + exB), 1e-12);
  EXPECT_NEAR(x.g[0], exB * 0.9 / (exA + exB), 1e-12);
  // Phase: A's mass is spread evenly over the 8 bins, B's all in the top quarter (2 bins).
  const PhaseTable& p = m.phase[0];
  ASSERT_EQ(p.bins(), 8);
  double fa = exA / (exA + exB), fb = exB / (exA + exB);
  EXPECT_NEAR(p.mass(-1.0, -0.75), fa / 8, 1e-6);
  EXPECT_NEAR(p.mass(0.75, 1.0), fa / 8 + fb / 2, 1e-6);
  EXPECT_NEAR(tableIntegral(p), 1.0, 1e-5);
  // And the world-space parameters follow from the mixed statistics.
  double lb = 1.0 / (3.0 / (4.0 * 0.01) * 0.5 / 0.5);
  double lbeta = lb + (lb + 0.01 * 0.8) * (1.0 - x.beta) / x.beta;
  expectRel(m.lambdaBeta.x, lbeta);
  expectRel(m.lambdaT.x, lbeta + x.albedo[0] * 0.01 * x.lambdaS[0]);
}

TEST(TTMedium, DegenerateInputsStayFiniteOrAreRejected) {
  GrainTransport clear = handMade(1.0, 0.0, {1.0, 1.0, 1.0}, {4.0 / 3.0, 4.0 / 3.0, 4.0 / 3.0}, {1.0, 1.0, 1.0});
  // Index-matched: α_s = 1, g = 1 → σ'_s = σ_a = 0, σ'_t = 0; α'_s reported as α_s.
  MediumParams m = deriveMedium({clear}, {1.0f}, 0.01f, 0.64f);
  EXPECT_EQ(m.sigmaTReduced, Vec3(0.0f));
  EXPECT_EQ(m.sigmaTr, Vec3(0.0f));
  EXPECT_EQ(m.albedoReduced, Vec3(1.0f));
  EXPECT_GT(m.sigmaT.x, 0.0f);
  // Packing rates at both ends.
  for (float f : {1e-30f, 1e-45f, 1e-3f, 0.64f}) {
    MediumParams e = deriveMedium({clear}, {1.0f}, 0.01f, f);
    EXPECT_TRUE(isFinite(e.sigmaT) && isFinite(e.lambdaT) && isFinite(e.sigmaTr) && isFinite(e.albedoReduced)) << f;
    EXPECT_TRUE(std::isfinite(e.sigmaB)) << f;
    EXPECT_GE(e.sigmaT.x, 0.0f);
  }
  EXPECT_EQ(deriveMedium({clear}, {1.0f}, 0.01f, 1e-45f).lambdaT.x, FLT_MAX);
  EXPECT_THROW(deriveMedium({clear}, {1.0f}, 0.01f, 0.0f), InputError);
  EXPECT_THROW(deriveMedium({clear}, {1.0f}, 0.01f, 0.7f), InputError);
  EXPECT_THROW(deriveMedium({clear}, {1.0f}, 0.0f, 0.5f), InputError);
  EXPECT_THROW(deriveMedium({clear}, {1.0f, 1.0f}, 0.01f, 0.5f), InputError);
  EXPECT_THROW(deriveMedium({clear}, {0.0f}, 0.01f, 0.5f), InputError);
  EXPECT_THROW(deriveMedium({clear}, {-1.0f}, 0.01f, 0.5f), InputError);
  EXPECT_THROW(deriveMedium({}, {}, 0.01f, 0.5f), InputError);
  // A prototype without a phase table counts as isotropic.
  GrainTransport bare = clear;
  for (auto& p : bare.phase) p = PhaseTable();
  MediumParams b = deriveMedium({bare}, {1.0f}, 0.01f, 0.5f);
  EXPECT_NEAR(b.phase[0].eval(0.2f), 1.0f / (4.0f * kPi), 1e-6f);
}

// ---------------------------------------------------------------------------------------
// The key physical check: do TT's λ_β and λ_t = λ_β + α_s λ_s describe EPT in a real
// aggregate? We follow EPT paths through Aggregate::intersect (the renderer's grain
// query; grains scattered exactly as ept.cpp does) and cut each path into TT events. An
// event k starts where the path leaves the bounding sphere of the grain it last
// interacted with (x_o of event k−1), flies straight to the entry point x_i of the
// bounding sphere of the next grain it actually hits (passing through the spheres of
// grains it misses) — the sample of λ_β — and then "teleports": the path bounces in that
// grain until it leaves its bounding sphere at x_o; |x_o − x_i| times the exit energy is
// the sample of α_s λ_s. Their sum is the sample of λ_t. Paths start at a random point
// and direction; the first two events are dropped so that the start points are genuine
// exits (the flight from a random void point is length-biased unless the flights are
// exactly exponential). With non-absorbing grains the exits settle to the uniform,
// cosine-weighted distribution over the sphere surfaces, the one the TT estimator
// assumes for entries. A path stops (decided before a flight, so no flight is censored)
// when its exit point is within 15 predicted λ_β of the aggregate's boundary (a flight
// that long has odds of about e^-15), and the test checks that no path escaped.
namespace {

// Sums over events, and per walk (batch means): successive events of one walk are
// correlated, so the standard errors come from the spread of the walks' own sums (the
// ratio estimator's delta-method SE), not from the events as if independent.
struct WalkStats {
  int64_t events = 0, escaped = 0;
  double sum[3] = {0, 0, 0};  // flight, teleport, total
  std::vector<std::array<double, 4>> walks;  // per walk: events, flight, teleport, total
  double mean(int q) const { return sum[q] / double(events); }
  double se(int q) const {
    double m = mean(q), ss = 0;
    for (const auto& w : walks) ss += (w[1 + q] - m * w[0]) * (w[1 + q] - m * w[0]);
    double nw = double(walks.size()), nbar = double(events) / nw;
    return std::sqrt(ss / (nw * (nw - 1))) / nbar;
  }
};

// Entry (near root) and exit (far root) of a ray against a sphere; false if it misses.
bool sphereSpan(const Vec3& o, const Vec3& d, const Vec3& c, float r, double& t0, double& t1) {
  Vec3 oc = o - c;
  double b = dot(oc, d), cc = double(length2(oc)) - double(r) * r, disc = b * b - cc;
  if (disc < 0) return false;
  double s = std::sqrt(disc);
  t0 = -b - s;
  t1 = -b + s;
  return true;
}

WalkStats walkThroughAggregate(const Aggregate& agg, const Material& m, int walks, int maxEvents, float margin,
                               uint64_t seed) {
  const float R = agg.grainRadius(), L = agg.cellSize();
  const Vec3 origin = agg.bounds().lo;  // the cell grid's origin
  // A grain's centre, computed as the aggregate computes it.
  auto centreOf = [&](const GrainHit& h) {
    return origin + Vec3(float(h.cell[0]), float(h.cell[1]), float(h.cell[2])) * L + agg.tile().centers[h.sphere] * L;
  };
  auto same = [](const GrainHit& a, const GrainHit& b) {
    return a.sphere == b.sphere && a.cell[0] == b.cell[0] && a.cell[1] == b.cell[1] && a.cell[2] == b.cell[2];
  };
  WalkStats st;
  Rng rng(seed);
  // scene.cpp's offset for grain hits: 2e-4 of the grain's radius.
  for (int wk = 0; wk < walks; ++wk) {
    Vec3 o = sampleUniformSphere(rng.next1D(), rng.next1D()) * (0.3f * std::cbrt(rng.next1D()));
    Vec3 d = sampleUniformSphere(rng.next1D(), rng.next1D());
    GrainHit h;
    if (!agg.intersect(o, d, 0.0f, kInf, h)) { ++st.escaped; continue; }
    double tExitPrev = 0;  // where the ray (o, d) left the previous grain's sphere
    std::array<double, 4> batch{0, 0, 0, 0};
    for (int ev = 0; ev < maxEvents; ++ev) {
      GrainHit grain = h;
      Vec3 c = centreOf(grain);
      const float r = grain.radius;  // this grain's bounding radius (polydisperse: its own)
      double t0, t1;
      if (!sphereSpan(o, d, c, r, t0, t1)) t0 = h.t;  // rounding at a grazing hit
      double flight = std::max(0.0, t0 - tExitPrev);
      Vec3 xi = o + d * float(std::max(t0, 0.0));
      // Teleport: EPT's scattering inside this grain's bounding sphere.
      Vec3 w(1.0f);
      bool escaped = false;
      float t = h.t;
      for (int bounce = 0;; ++bounce) {
        Vec3 p = o + d * t;
        if (dot(d, h.ng) > 0) w *= vexp(m.absorption * (-t / R));
        Frame frame(h.ng);
        BsdfSample bs;
        float uLobe = rng.next1D(), u1 = rng.next1D(), u2 = rng.next1D();
        if (bounce > 1000 || !m.sample(frame.toLocal(-d), uLobe, u1, u2, bs)) { w = Vec3(0.0f); break; }
        w *= bs.weight;
        Vec3 ng = h.ng;
        d = normalize(frame.toWorld(bs.wi));
        o = offsetRayOrigin(p, ng, d, kGrainEps * r);
        if (!agg.intersect(o, d, 0.0f, kInf, h)) { escaped = true; break; }
        if (!same(h, grain)) break;  // left this grain's sphere towards another grain
        t = h.t;
      }
      if (escaped || isBlack(w)) { st.escaped += escaped; break; }
      double e0, e1;
      sphereSpan(o, d, c, r, e0, e1);
      double tExit = std::max(0.0, e1);
      Vec3 xo = o + d * float(tExit);
      double tele = w.x * double(length(xo - xi));
      if (ev >= 2) {  // burn-in: see above
        batch[0] += 1;
        batch[1] += flight;
        batch[2] += tele;
        batch[3] += flight + tele;
      }
      if (length(xo) > 1.0f - margin) break;  // near the boundary: stop before the next flight
      tExitPrev = tExit;
    }
    if (batch[0] > 0) {
      st.walks.push_back(batch);
      st.events += int64_t(batch[0]);
      for (int q = 0; q < 3; ++q) st.sum[q] += batch[1 + q];
    }
  }
  return st;
}

struct AggregateCase {
  TriangleMesh grain;
  float f;
  const char* name;
  float R = 0.01f;  // grain radius; the boundary is the unit sphere
  // Polydisperse: a second prototype (the same mesh) of this size with this share by
  // number, and a spread of every grain's size.
  float secondSize = 0, secondWeight = 0, spread = 0;
  double tolerance = 0.05;  // of λ_β and λ_t
};

void checkAgainstTT(const AggregateCase& k, int walks, int events) {
  AggregateDesc desc;
  desc.name = k.name;
  desc.boundary = makeIcosphere(3);  // radius 1
  desc.grainRadius = k.R;            // 0.01: ~0.6 million grains
  desc.packingRate = k.f;
  desc.seed = 3;
  desc.tileSpheres = 64;
  desc.prototypes = {GrainPrototypeDesc{k.name, k.grain, 0}};
  desc.weights = {1.0f};
  if (k.secondSize > 0) {
    desc.prototypes.push_back(GrainPrototypeDesc{k.name, k.grain, 0});
    desc.weights = {1.0f - k.secondWeight, k.secondWeight};
    desc.sizes = {1.0f, k.secondSize};
  }
  desc.sizeSpread = k.spread;
  EmbreeDevice dev = makeEmbreeDevice();
  Aggregate agg;
  agg.build(desc, dev, std::vector<int>(desc.prototypes.size(), 0));
  Material m = dielectric(1.5f);
  // Exactly what EPT traces, and what Scene::build derives (the tile's packing rate).
  std::vector<const TriangleMesh*> meshes;
  for (const auto& p : agg.prototypes()) meshes.push_back(&p.mesh);
  AggregateDesc derived = desc;
  derived.packingRate = float(agg.tile().packingRate);
  MediumParams mp = aggregateMedium(meshes, std::vector<Material>(meshes.size(), m), derived, agg.tile().sauterSize(),
                                    opts(1 << 16, 17));
  const GrainTransport& g = mp.combined;  // in units of R
  float margin = std::min(0.6f, 15.0f * mp.lambdaBeta.x);
  WalkStats st = walkThroughAggregate(agg, m, walks, events, margin, 23);
  ASSERT_GT(st.events, 10000);
  double R = agg.grainRadius();
  double lambdaB = 1.0 / mp.sigmaB;
  double fl = st.mean(0), te = st.mean(1), tot = st.mean(2);
  std::printf(
      "[%s f=%.3f] beta=%.4f lambda_delta=%.4f lambda_s=%.4f g=%.4f | per R: lambda_b(Dixmier)=%.4f "
      "lambda_beta TT=%.4f measured=%.4f+-%.4f | alpha*lambda_s TT=%.4f measured=%.4f+-%.4f | "
      "lambda_t TT=%.4f measured=%.4f+-%.4f (%lld events, %lld escaped)\n",
      k.name, agg.tile().packingRate, g.beta, g.lambdaDelta, g.lambdaS[0], g.g[0], lambdaB / R, mp.lambdaBeta.x / R,
      fl / R, st.se(0) / R, g.albedo[0] * g.lambdaS[0], te / R, st.se(1) / R,
      mp.lambdaT.x / R, tot / R, st.se(2) / R, (long long)st.events, (long long)st.escaped);
  EXPECT_EQ(st.escaped, 0);
  // The teleport part is the estimator's own quantity measured a second way: SE-tight.
  double teSE = st.se(1), ttTe = g.albedo[0] * g.lambdaS[0] * R;
  EXPECT_NEAR(te, ttTe, 4.0 * std::hypot(teSE, g.lambdaSSE[0] * R));
  // The model's claims: λ_β and λ_t = 1/σ_t within the tolerance.
  EXPECT_NEAR(fl, mp.lambdaBeta.x, k.tolerance * mp.lambdaBeta.x);
  EXPECT_NEAR(tot, 1.0 / mp.sigmaT.x, k.tolerance / mp.sigmaT.x);
}

}  // namespace

TEST(TTAggregate, SphereGrainsMatchDixmierAndTT) {
  // Grains that fill their bounding spheres (β ≈ 1): λ_β is Dixmier's λ_b itself.
  checkAgainstTT({makeIcosphere(3), 0.6f, "sphere"}, 300, 150);
}

TEST(TTAggregate, RockGrainsMatchTT) {
  // Rocks miss some rays (β < 1): λ_β adds the chords through missed spheres.
  checkAgainstTT({makeRock(2, 0.35f, 5), 0.6f, "rock"}, 300, 150);
}

TEST(TTAggregate, ElongatedGrainsAtALowerPackingRateMatchTT) {
  // An ellipsoid fills a third of its bounding sphere's projection (β ≈ 0.33), so most of
  // λ_β is chords through missed spheres; f = 0.45 moves Dixmier's λ_b away from 0.6's.
  checkAgainstTT({makeEllipsoid(Vec3(1.0f, 0.5f, 0.3f), 3), 0.45f, "ellipsoid", 0.004f}, 300, 150);
}

// Grains of many sizes (tt.h): a flight meets a sphere by its cross-section, missed
// spheres' chords and teleports scale with each size, and the space between spheres
// follows their surface per volume (the Sauter mean). λ_β and λ_t within 2% of explicit
// walks (the test's bound; the equal-sized rocks above read +0.8%).

TEST(TTAggregate, TwoSizesOfSpheresMatchTheSauterMeanAndTT) {
  // Sizes 1 and 0.5, half of each by number (by volume 8 : 1).
  checkAgainstTT({makeIcosphere(3), 0.6f, "bimodal spheres", 0.01f, 0.5f, 0.5f, 0.0f, 0.02}, 300, 150);
}

TEST(TTAggregate, SpheresOfSpreadSizesMatchTT) {
  // One prototype, every grain's size spread by ±25% (the tile's sizes stratified).
  checkAgainstTT({makeIcosphere(3), 0.55f, "spheres spread", 0.01f, 0.0f, 0.0f, 0.25f, 0.02}, 300, 150);
}

TEST(TTAggregate, RocksOfTwoSizesMatchTT) {
  // Rocks (β < 1) of sizes 1 and 0.6, 40% small by number.
  checkAgainstTT({makeRock(2, 0.35f, 5), 0.55f, "rocks two sizes", 0.01f, 0.6f, 0.4f, 0.0f, 0.02}, 300, 150);
}

TEST(TTAggregate, RocksOfTwoSizesAndASpreadMatchTT) {
  // The same with every grain's size spread by ±25%.
  checkAgainstTT({makeRock(2, 0.35f, 5), 0.55f, "polydisperse rocks", 0.01f, 0.6f, 0.4f, 0.25f, 0.02}, 300, 150);
}

// Where a grain lets light out by the angle it turns it (ExitMoves): each bin's moves are
// drawn in proportion to each channel's exiting energy, so their mean is the energy-weighted
// mean move of the exits in that bin, per channel, as traced here directly with other rays.
TEST(TTExits, MovesAreDrawnByEachChannelsExitingEnergy) {
  TriangleMesh rock = prototypeOf(makeRock(2, 0.2f, 1));
  const Material m = dielectric(1.55f, Vec3(0.02f, 0.5f, 3.0f));
  GrainTransport g = estimateGrainTransport(rock, m, opts(1 << 17, 8));
  EmbreeDevice dev = makeEmbreeDevice();
  EmbreeScene bvh = buildTriangleScene(dev, rock);
  const int kBins = ExitMoves::kBins;
  std::vector<std::array<double, 3>> w(kBins), wx(kBins), wxx(kBins);
  for (int i = 0; i < (1 << 17); ++i) {
    Rng rng(hashInts(99, uint64_t(i)));
    Vec3 xi, wi;
    sampleSphereEntry(rng, xi, wi);
    const GrainPassage p = traceGrainPassage(bvh.get(), rock, m, 4096, xi, wi, rng);
    if (!p.hit) continue;
    const float b = dot(p.o, p.d), tOut = -b + std::sqrt(std::max(0.0f, b * b - (length2(p.o) - 1.0f)));
    const double along = dot(p.o + p.d * tOut - xi, wi);
    const int k = ExitMoves::bin(dot(wi, p.d));
    for (int c = 0; c < 3; ++c) {
      w[k][c] += p.weight[c];
      wx[k][c] += p.weight[c] * along;
      wxx[k][c] += p.weight[c] * along * along;
    }
  }
  double backRed = 0, fwdRed = 0;
  for (int c = 0; c < 3; ++c)
    for (int k : {0, kBins - 1}) {  // straight back, straight on
      const std::vector<Vec3>& moves = g.exits[c].moves[k];
      ASSERT_EQ(int(moves.size()), ExitMoves::kPerBin) << c << " " << k;
      double mean = 0;
      for (const Vec3& x : moves) {
        EXPECT_LE(length(x), 2.0f + 1e-4f);
        mean += x.x;
      }
      mean /= double(moves.size());
      const double want = wx[k][c] / w[k][c];
      const double sd = std::sqrt(std::max(0.0, wxx[k][c] / w[k][c] - want * want));
      EXPECT_NEAR(mean, want, 4.0 * sd / std::sqrt(double(moves.size()))) << "channel " << c << " bin " << k;
      if (c == 0) (k == 0 ? backRed : fwdRed) = mean;
    }
  // Light a grain sends back leaves near where it came in, light it sends on a diameter on.
  EXPECT_LT(backRed, 0.6);
  EXPECT_GT(fwdRed, 1.2);
  // Absorption shifts the draws: blue keeps the short paths through the grain.
  double fwdBlue = 0;
  for (const Vec3& x : g.exits[2].moves[kBins - 1]) fwdBlue += x.x;
  EXPECT_LT(fwdBlue / ExitMoves::kPerBin, fwdRed);
}

// The mixture's moves: per bin, a kind's share of the kPerBin moves is its share of the
// energy exiting into that bin (to a count's rounding), its moves scaled by its size.
TEST(TTExits, AMixturesMovesComeFromEachKindByItsExitingEnergy) {
  GrainTransport a = handMade(0.5, 0.8, {1.0, 1.0, 1.0}, {1.0, 1.0, 1.0}, {0.0, 0.0, 0.0});
  GrainTransport b = handMade(1.0, 0.0, {0.5, 0.5, 0.5}, {2.0, 2.0, 2.0}, {0.9, 0.9, 0.9});
  std::vector<double> fwd(4, 0.0);
  fwd[3] = 1.0;
  for (int c = 0; c < 3; ++c) {
    b.phase[c] = PhaseTable::fromHistogram(fwd);  // all in μ > 0.5
    for (int k = 0; k < ExitMoves::kBins; ++k) {
      a.exits[c].moves[k].assign(7, Vec3(0.1f, 0.0f, 0.0f));
      if (k >= 12) b.exits[c].moves[k].assign(5, Vec3(1.0f, 0.5f, 0.0f));
    }
  }
  // Weights by number 1 : 3, sizes 1 and 2: a flight meets b with w_b = 3·4 / (1 + 3·4).
  MediumParams m = deriveMedium({a, b}, {1.0f, 3.0f}, {1.0f, 2.0f}, 0.01f, 0.5f);
  const double wa = 1.0 / 13.0, wb = 12.0 / 13.0;
  const double exA = wa * 0.5 * 1.0, exB = wb * 1.0 * 0.5;  // w β α
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k < ExitMoves::kBins; ++k) {
      const std::vector<Vec3>& mv = m.combined.exits[c].moves[k];
      ASSERT_EQ(int(mv.size()), ExitMoves::kPerBin);
      int fromB = 0;
      for (const Vec3& x : mv) {
        const bool isB = x.x == 2.0f && x.y == 1.0f && x.z == 0.0f;  // b's move at size 2
        EXPECT_TRUE(isB || (x.x == 0.1f && x.y == 0.0f)) << x.x;
        fromB += isB;
      }
      const double massA = 1.0 / ExitMoves::kBins, massB = k >= 12 ? 0.25 : 0.0;
      const double want = ExitMoves::kPerBin * exB * massB / (exA * massA + exB * massB);
      EXPECT_NEAR(fromB, want, 1.0) << "bin " << k;
    }
}

// The exits model's diffusion (exitsDiffusionMedium): its σ_t makes a standard medium's
// spread per scattering, 2 / (σ_t² (1 − g)), the exits walk's own. Walked here with the
// medium's own sampling (vpt.h: flights, phase, moves) in an unbounded medium of clear
// rocks: the growth of the mean square distance per scattering, between the 100th and the
// 300th, against M = 2 / (σ_t² (1 − g)), and against the formula on the moves as the walk
// samples them (binned by μ), which it must meet within its noise alone: the diffusion's M
// is 1.4% under that here (the traced exits' exact means, against 16 bins of moves).
// Without moves, the flights' own exponential medium: σ_t = 1 / (kExitFlight λ_β).
TEST(TTExits, TheExitsModelsDiffusionSpreadsAsItsWalkDoes) {
  TriangleMesh rock = prototypeOf(makeRock(2, 0.2f, 1));
  GrainTransport g = estimateGrainTransport(rock, dielectric(1.55f), opts(1 << 17, 9));
  const MediumParams p = deriveMedium({g}, {1.0f}, 1.0f, 0.6f);
  const MediumParams da = exitsDiffusionMedium(p);
  const HomogeneousMedium walk(p, MediumModel::Exits);
  ASSERT_TRUE(walk.movesLight());
  const double gt = p.phase[0].g;
  const double M = 2.0 / (double(da.sigmaT.x) * da.sigmaT.x * (1.0 - gt));
  const int walks = 1 << 16, first = 100, last = 300;
  double s1 = 0, s2 = 0;
  for (int i = 0; i < walks; ++i) {
    Rng rng(hashInts(77, uint64_t(i)));
    Vec3 x(0.0f), d = sampleUniformSphere(rng.next1D(), rng.next1D());
    double at100 = 0;
    for (int k = 1; k <= last; ++k) {
      x += d * walk.sampleDistance(rng.next1D(), rng.next1D());
      Vec3 weight;
      float pdf;
      const Vec3 wo = walk.samplePhase(d, rng.next1D(), rng.next1D(), rng.next1D(), weight, pdf);
      x += walk.exitMove(d, wo, rng.next1D(), rng.next1D());
      d = wo;
      if (k == first) at100 = length2(x);
    }
    const double growth = (length2(x) - at100) / double(last - first);
    s1 += growth;
    s2 += growth * growth;
  }
  const double mean = s1 / walks, se = std::sqrt(std::max(0.0, s2 / walks - mean * mean) / (walks - 1));
  std::printf("exits walk: spread per scattering %.3f ± %.3f R², the diffusion's %.3f, TT's %.3f\n", mean, se, M,
              2.0 / (double(p.sigmaT.x) * p.sigmaT.x * (1.0 - gt)));
  EXPECT_NEAR(mean, M, 4.0 * se + 0.005 * M);
  EXPECT_LT(se, 0.01 * M);  // tight enough to tell TT's spread apart where they differ by a few %
  // What the walk samples, exactly: the same formula on the tables' own moments — the moves
  // of μ's bin, μ uniform within each of the phase table's bins (E[sqrt(1 − μ²)] over a bin
  // from its antiderivative (μ sqrt(1 − μ²) + asin μ) / 2). The walk must read it within
  // its noise alone; the diffusion takes the traced exits' exact means, which the 16 bins
  // of moves blur by a little.
  const PhaseTable& phase = p.phase[0];
  const int perBin = phase.bins() / ExitMoves::kBins;
  ASSERT_EQ(perBin * ExitMoves::kBins, phase.bins());
  auto root = [](double mu) { return 0.5 * (mu * std::sqrt(std::max(0.0, 1.0 - mu * mu)) + std::asin(mu)); };
  double in = 0, out = 0, sq = 0;
  for (int b = 0; b < ExitMoves::kBins; ++b) {
    const std::vector<Vec3>& moves = p.combined.exits[0].moves[b];
    double mass = 0, mu = 0, side = 0;
    for (int j = b * perBin; j < (b + 1) * perBin; ++j) {
      const double lo = -1.0 + 2.0 * j / phase.bins(), hi = -1.0 + 2.0 * (j + 1) / phase.bins();
      const double mj = phase.mass(lo, hi);
      mass += mj;
      mu += mj * 0.5 * (lo + hi);
      side += mj * (root(hi) - root(lo)) / (hi - lo);
    }
    if (!(mass > 0)) continue;
    ASSERT_FALSE(moves.empty()) << b;
    Vec3 x(0.0f);
    double x2 = 0;
    for (const Vec3& m : moves) x += m, x2 += length2(m);
    x /= float(moves.size());
    in += mass * x.x;
    out += x.x * mu + x.y * side;
    sq += mass * x2 / double(moves.size());
  }
  const double L = 1.0 / walk.sigmaT().x;
  const double sampled = sq + 2 * L * out + 2 * L * L + 2 * (in + L * gt) * (out + L) / (1.0 - gt);
  std::printf("  the tables' own moments: %.3f R²\n", sampled);
  EXPECT_NEAR(mean, sampled, 4.0 * se);
  EXPECT_NEAR(M, sampled, 0.02 * sampled);
  // Without moves: the flights' own medium.
  MediumParams still = p;
  for (int c = 0; c < 3; ++c) {
    still.combined.moveIn[c] = still.combined.moveOut[c] = still.combined.moveSquared[c] = 0;
    for (std::vector<Vec3>& m : still.combined.exits[c].moves) std::fill(m.begin(), m.end(), Vec3(0.0f));
  }
  const MediumParams flights = exitsDiffusionMedium(still);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(flights.sigmaT[c], 1.0f / (kExitFlight * p.lambdaBeta[c]), 1e-5f * flights.sigmaT[c]);
  // A medium without moves (given directly) keeps its own parameters.
  const MediumParams rte = mediumFromRte(Vec3(2.0f), Vec3(0.9f), PhaseTable::isotropic());
  EXPECT_EQ(exitsDiffusionMedium(rte).sigmaTReduced.x, rte.sigmaTReduced.x);
}
