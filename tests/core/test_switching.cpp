// Switching from measured error (core/switching.*): a white furnace, the choice from the
// bias curve, determinism and the disk cache, and what the scene does with it.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <thread>

#include <tbb/task_arena.h>

#include "core/cache.h"
#include "core/error.h"
#include "core/scene.h"
#include "core/switching.h"
#include "test_helpers.h"

using namespace granular;

namespace {

// The scene of a ball of grains with its proxy tables and medium, not yet measured.
std::unique_ptr<Scene> unmeasured(SceneDesc d) {
  d.settings.technique = Technique::EptVpt;
  d.settings.proxies = ProxyUse::On;
  d.settings.explicitBounces = 0;  // no measurement by the scene: the tests make theirs
  auto scene = Scene::build(d);
  EXPECT_TRUE(scene->hasMedia());
  EXPECT_EQ(scene->switchMeasure(0), nullptr);
  return scene;
}

// The matrix ball of rocks, of the given index and absorption.
std::unique_ptr<Scene> ballScene(float ior, const Vec3& absorption) {
  SceneDesc d = granular::testing::matrixBall(false, ior);
  d.materials[0].absorption = absorption;
  return unmeasured(d);
}

SwitchMeasure measure(const Scene& s, int64_t paths, uint64_t key = 0) {
  SwitchOptions o;
  o.paths = paths;
  return measureSwitch(*s.aggregates()[0], s.proxyTables(0), s.medium(0), o, key);
}

SwitchMeasure measure(const Scene& s, const SwitchOptions& o) {
  return measureSwitch(*s.aggregates()[0], s.proxyTables(0), s.medium(0), o);
}

// Candidate c's estimate is beyond the tolerance by more than `errors` standard errors.
bool beyondBy(const SwitchMeasure& m, int c, float tolerance, float errors) {
  for (int ch = 0; ch < 3; ++ch)
    if (std::fabs(m.bias[size_t(c)][ch]) - errors * m.biasSE[size_t(c)][ch] > tolerance) return true;
  return false;
}

void print(const SwitchMeasure& m) {
  std::printf("albedo %.4f %.4f %.4f ± %.4f, chosen %d visits (%.2f s)\n", m.albedo.x, m.albedo.y, m.albedo.z,
              m.albedoSE.x, m.visits, m.seconds);
  for (int c = 0; c < kSwitchCandidates; ++c)
    std::printf("  after %2d visits: %+.4f %+.4f %+.4f ± %.4f %.4f %.4f\n", kSwitchVisits[c], m.bias[c].x,
                m.bias[c].y, m.bias[c].z, m.biasSE[c].x, m.biasSE[c].y, m.biasSE[c].z);
}

// A white furnace: every path leaves, both ways, so the measured radiance is 1, every
// candidate's bias 0 within its noise, and no visits are needed.
void expectWhiteFurnace(const SwitchMeasure& m) {
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(m.albedo[c], 1.0f, 1e-3f);
  for (int k = 0; k < kSwitchCandidates; ++k)
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(m.bias[size_t(k)][c], 0.0f, 4.0f * m.biasSE[size_t(k)][c] + 1e-3f);
  EXPECT_EQ(m.visits, 0);
}

}  // namespace

TEST(Switching, ClearGrainsReturnAllLightAndNeedNoVisitsWhiteFurnace) {
  // Clear grains absorb nothing, nor does their medium (α_s = 1): every path leaves, both
  // ways, so A∞ = 1 and every candidate's bias is 0, within the estimator's noise.
  auto scene = ballScene(1.5f, Vec3(0.0f));
  const SwitchMeasure m = measure(*scene, 1 << 13);
  print(m);
  expectWhiteFurnace(m);
}

TEST(Switching, HighIndexGrainsNeedVisitsAndTheBiasFallsWithThem) {
  // The IOR 2.4 ball: its medium right after the first grain is the most biased case of
  // the accuracy matrix (the render reads −5.8% there, bench/README.md); the measurement
  // must see that bias, its fall with visits, and choose the first candidate within the
  // tolerance.
  auto scene = ballScene(2.4f, Vec3(0.05f));
  const SwitchMeasure m = measure(*scene, 1 << 15);
  print(m);
  EXPECT_LT(m.bias[0].x + 2.0f * m.biasSE[0].x, 0.0f);
  EXPECT_LT(m.bias[0].x, -0.02f);
  EXPECT_GT(m.visits, 0);
  const SwitchOptions o;
  for (int k = 0; kSwitchVisits[k] < m.visits; ++k)
    EXPECT_TRUE(std::fabs(m.bias[size_t(k)].x) > o.tolerance || m.biasSE[size_t(k)].x > o.precision * o.tolerance)
        << k;
  // After 16 visits nothing measurable is left to gain.
  EXPECT_LT(std::fabs(m.bias[5].x), 4.0f * m.biasSE[5].x + 1e-3f);
  EXPECT_EQ(kSwitchVisits[5], 16);
}

TEST(Switching, TheExitsModelTakesOverAtAGrainAndKeepsTheWayBackOut) {
  // The amber and flint ball: TT's medium, whose first flight is its own, closes the gap
  // the path came in by, and light the first grain sends back along it stays in: right
  // after the first grain it reads −3.8 / −7.4 / −10.4% (R / G / B, ± 0.7). The exits model
  // takes the path over at a grain (vpt.h: enterMedia): the packing's first flight keeps
  // that gap, −1.6 / −2.3 / −2.1%. Over the channels' mean, beyond the noise of both.
  SceneDesc d = granular::testing::matrixBall(true);
  auto tt = unmeasured(d);
  d.settings.mediumModel = MediumModel::Exits;
  auto exits = unmeasured(d);
  ASSERT_FALSE(tt->takesOverAtGrains(0));
  ASSERT_TRUE(exits->takesOverAtGrains(0));
  SwitchOptions o;
  o.paths = 1 << 16;
  o.stopEarly = false;  // every candidate over every path
  const SwitchMeasure own = measure(*tt, o), atGrain = measure(*exits, o);
  print(own);
  print(atGrain);
  // The channels' mean and a bound on its standard error (that of the noisiest channel).
  auto mean = [](const Vec3& v) { return (v.x + v.y + v.z) / 3.0f; };
  const float t = mean(own.bias[0]), e = mean(atGrain.bias[0]);
  const float seT = maxComponent(own.biasSE[0]), seE = maxComponent(atGrain.biasSE[0]);
  EXPECT_LT(t + 3 * seT, -0.03f);
  EXPECT_GT(e - t, 3 * std::hypot(seT, seE));
}

// A measurement of every candidate without bias or noise, for the choices to be made from.
SwitchMeasure unbiasedMeasure() {
  SwitchMeasure m;
  m.bias.assign(kSwitchCandidates, Vec3(0.0f));
  m.biasSE.assign(kSwitchCandidates, Vec3(0.0f));
  return m;
}

TEST(Switching, TheChoiceIsTheLeastVisitsWithinToleranceInEveryChannel) {
  SwitchMeasure m = unbiasedMeasure();
  SwitchOptions o;
  o.tolerance = 0.01f;
  o.precision = 0.5f;
  EXPECT_EQ(chooseSwitchVisits(m, o), 0);
  m.bias[0] = Vec3(0.0f, -0.02f, 0.0f);  // one channel off
  EXPECT_EQ(chooseSwitchVisits(m, o), kSwitchVisits[1]);
  m.bias[1] = Vec3(0.0f, 0.004f, 0.0f);
  m.biasSE[1] = Vec3(0.0f, 0.006f, 0.0f);  // within the tolerance, not measured well enough to tell
  EXPECT_EQ(chooseSwitchVisits(m, o), kSwitchVisits[2]);
  // A margin of one standard error: within the tolerance by its standard error.
  m.bias[1] = Vec3(0.0f, 0.007f, 0.0f);
  m.biasSE[1] = Vec3(0.0f, 0.004f, 0.0f);
  EXPECT_EQ(chooseSwitchVisits(m, o), kSwitchVisits[1]);
  o.margin = 1.0f;
  EXPECT_EQ(chooseSwitchVisits(m, o), kSwitchVisits[2]) << "0.7% + 0.4% is beyond 1%";
  m.biasSE[1] = Vec3(0.0f, 0.005f, 0.0f);
  o.margin = 0.0f;
  for (Vec3& b : m.bias) b = Vec3(0.05f);
  EXPECT_EQ(chooseSwitchVisits(m, o), kSwitchVisits[kSwitchCandidates - 1]) << "none within: the largest";
}

TEST(Switching, WhatAMeasurementShowsNeededErrsTowardFewerVisits) {
  // Candidates beyond the tolerance by more than three standard errors in some channel are
  // shown biased, whatever the margin; the one after the last shown is taken. A noisy
  // estimate is not shown biased, where the choice proper (within the tolerance, measured
  // to its precision) passes it over.
  SwitchMeasure m = unbiasedMeasure();
  SwitchOptions o;
  o.tolerance = 0.005f;
  o.margin = 1.0f;
  EXPECT_EQ(switchVisitsShownNeeded(m, o), 0);
  auto set = [&](int c, float bias, float se) {  // in one channel of candidate c
    m.bias[size_t(c)][c % 3] = bias;
    m.biasSE[size_t(c)][c % 3] = se;
  };
  set(0, -0.05f, 0.01f);  // 5% ± 1%: shown
  set(1, 0.03f, 0.03f);   // 3% ± 3%: beyond the tolerance by 2.5%, less than its error
  EXPECT_EQ(switchVisitsShownNeeded(m, o), kSwitchVisits[1]);
  EXPECT_EQ(chooseSwitchVisits(m, o), kSwitchVisits[2]) << "the choice proper wants it measured within";
  set(1, 0.03f, 0.01f);  // 3% ± 1%: beyond by 2.5 errors, which chance shows among many
  EXPECT_EQ(switchVisitsShownNeeded(m, o), kSwitchVisits[1]);
  set(1, 0.04f, 0.01f);  // 4% ± 1%: beyond by 3.5, shown
  EXPECT_EQ(switchVisitsShownNeeded(m, o), kSwitchVisits[2]);
  // A noisy estimate before one shown biased does not end the search there (a sun's
  // measurement: −4.6 ± 12.5% after 0 visits, +19.6 ± 4.9% after 2).
  set(0, -0.046f, 0.125f);
  set(1, 0.0f, 0.0f);
  set(2, 0.196f, 0.049f);
  EXPECT_EQ(switchVisitsShownNeeded(m, o), kSwitchVisits[3]);
  // Later candidates beyond the tolerance by one or two standard errors of their own, as
  // noisy estimates of radiance toward one direction read by chance, do not add their
  // visits (each would have at one standard error).
  set(3, 0.02f, 0.01f);
  set(4, -0.012f, 0.005f);
  set(5, 0.09f, 0.05f);
  EXPECT_EQ(switchVisitsShownNeeded(m, o), kSwitchVisits[3]);
  for (Vec3& b : m.bias) b = Vec3(0.05f);
  for (Vec3& e : m.biasSE) e = Vec3(0.001f);
  EXPECT_EQ(switchVisitsShownNeeded(m, o), kSwitchVisits[kSwitchCandidates - 1]) << "every one shown: the largest";
}

TEST(Switching, IsDeterministicCachedAndRecomputesADamagedEntry) {
  auto scene = ballScene(1.55f, Vec3(0.1f));
  const int64_t paths = 1 << 12;
  const SwitchMeasure first = measure(*scene, paths);
  const SwitchMeasure again = measure(*scene, paths);
  EXPECT_FALSE(first.fromCache);
  for (int k = 0; k < kSwitchCandidates; ++k) {
    EXPECT_EQ(first.bias[size_t(k)].x, again.bias[size_t(k)].x);
    EXPECT_EQ(first.biasSE[size_t(k)].z, again.biasSE[size_t(k)].z);
  }
  // With a key: stored, then read back bit for bit.
  const uint64_t key = 0x5eed1234abcdULL;
  const SwitchMeasure stored = measure(*scene, paths, key);
  const SwitchMeasure read = measure(*scene, paths, key);
  EXPECT_TRUE(read.fromCache);
  EXPECT_EQ(read.visits, stored.visits);
  EXPECT_EQ(read.candidatePaths, stored.candidatePaths);
  EXPECT_EQ(read.albedo.y, first.albedo.y);
  for (int k = 0; k < kSwitchCandidates; ++k) EXPECT_EQ(read.bias[size_t(k)].y, first.bias[size_t(k)].y);
  // A damaged entry is never trusted: one byte of this measurement's entry flipped.
  const std::string dir = cacheDirectory();
  ASSERT_FALSE(dir.empty());
  SwitchOptions o;
  o.paths = paths;
  const std::filesystem::path entry = std::filesystem::path(dir) / switchCacheName(key, scene->proxyTables(0), o);
  ASSERT_TRUE(std::filesystem::exists(entry)) << entry;
  {
    std::fstream f(entry, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(20);
    const char c = char(f.get());
    f.seekp(20);
    f.put(char(c ^ 0x5a));
  }
  const SwitchMeasure recomputed = measure(*scene, paths, key);
  EXPECT_FALSE(recomputed.fromCache);
  EXPECT_EQ(recomputed.bias[3].x, first.bias[3].x);
}

namespace {

// A report's options: every candidate forks in every one of `paths` paths.
SwitchOptions everyPath(int64_t paths) {
  SwitchOptions o;
  o.paths = paths;
  o.stopEarly = false;
  return o;
}

// A tolerance of 3% and a precision of a tenth of it: on the IOR 2.4 ball the first
// candidates are decided within a few thousand paths, the others measured on.
SwitchOptions decidingOptions(int64_t paths) {
  SwitchOptions o;
  o.paths = paths;
  o.tolerance = 0.03f;
  o.precision = 0.1f;
  return o;
}

}  // namespace

TEST(Switching, DecidedCandidatesStopForkingAndKeepTheirEstimate) {
  // The IOR 2.4 ball with a tolerance of 3% and a precision of a tenth of it: the medium
  // right after the first grain is about 6% off, decided once its standard error is below
  // 1%, while the candidates after one or two visits (2–3% off) are still measured; it
  // stops forking, they and the reference fork in every path. A candidate that stopped was
  // beyond by 3 standard errors of its own paths (it can never be chosen), and is before
  // the chosen one.
  auto scene = ballScene(2.4f, Vec3(0.05f));
  const SwitchOptions o = decidingOptions(1 << 16);
  const SwitchMeasure m = measure(*scene, o);
  print(m);
  ASSERT_EQ(m.candidatePaths.size(), size_t(kSwitchCandidates));
  EXPECT_EQ(m.candidatePaths.back(), m.paths);
  int stopped = 0;
  for (int c = 0; c < kSwitchCandidates; ++c) {
    EXPECT_LE(m.candidatePaths[size_t(c)], m.paths);
    if (m.candidatePaths[size_t(c)] == m.paths) continue;
    ++stopped;
    EXPECT_TRUE(beyondBy(m, c, o.tolerance, 3.0f)) << c;
    EXPECT_LT(kSwitchVisits[c], m.visits) << c;
  }
  EXPECT_GT(stopped, 0);
  std::printf("%lld paths; per candidate:", (long long)m.paths);
  for (int64_t n : m.candidatePaths) std::printf(" %lld", (long long)n);
  std::printf("\n");
}

TEST(Switching, NothingStopsOrIsDecidedBeforeItsMinimumOfPaths) {
  // The measurement above, which decides candidates after a few thousand paths, asked for
  // a minimum of paths beyond that: every candidate forks in all of them.
  auto scene = ballScene(2.4f, Vec3(0.05f));
  SwitchOptions o = decidingOptions(1 << 15);
  const SwitchMeasure decides = measure(*scene, o);
  const int64_t minPaths = int64_t(1) << 14;
  ASSERT_LT(*std::min_element(decides.candidatePaths.begin(), decides.candidatePaths.end()), minPaths);
  o.minPaths = minPaths;
  SwitchMeasure m = measure(*scene, o);
  for (int64_t n : m.candidatePaths) EXPECT_GE(n, minPaths);
  EXPECT_LT(*std::min_element(m.candidatePaths.begin(), m.candidatePaths.end()), m.paths) << "then it decides";
  // One that would settle after its first batch (EndsEarlyWhenNoCandidateCanReachThePrecision)
  // traces the minimum, and no more; the budget still ends it.
  auto clear = ballScene(1.55f, Vec3(0.1f));
  o = SwitchOptions();
  o.paths = 1 << 15;
  o.precision = 0.02f;
  ASSERT_LT(measure(*clear, o).paths, 1 << 12);
  o.minPaths = 1 << 13;
  m = measure(*clear, o);
  EXPECT_EQ(m.paths, o.minPaths);  // batches of 512, 512, 1024, then 2048 paths end there
  o.eventBudget = m.events / 2;
  EXPECT_LT(measure(*clear, o).paths, o.minPaths) << "the budget still ends it";
}

TEST(Switching, CandidatesBeforeTheFirstAreNotMeasuredAndTheOthersAreTheSame) {
  // From candidate 3 (4 visits) on: the candidates before it fork in no path (0 paths, bias
  // 0, never chosen nor shown), and the others' estimates over the same paths are, bit for
  // bit, those of the measurement of every candidate (a fork draws its own random numbers);
  // cached and read back the same, under a key of its own.
  auto scene = ballScene(2.4f, Vec3(0.05f));
  SwitchOptions o = everyPath(1 << 12);
  const SwitchMeasure all = measure(*scene, o);
  constexpr int kFirst = 3;
  o.firstCandidate = kFirst;
  const SwitchMeasure from = measure(*scene, o);
  ASSERT_EQ(from.paths, all.paths);
  for (int c = 0; c < kSwitchCandidates; ++c) {
    if (c < kFirst) {
      EXPECT_EQ(from.candidatePaths[size_t(c)], 0) << c;
      EXPECT_EQ(from.bias[size_t(c)], Vec3(0.0f)) << c;
      EXPECT_EQ(from.biasSE[size_t(c)], Vec3(0.0f)) << c;
      continue;
    }
    EXPECT_EQ(from.candidatePaths[size_t(c)], all.candidatePaths[size_t(c)]) << c;
    EXPECT_EQ(from.bias[size_t(c)], all.bias[size_t(c)]) << c;
    EXPECT_EQ(from.biasSE[size_t(c)], all.biasSE[size_t(c)]) << c;
  }
  EXPECT_EQ(from.albedo, all.albedo);
  EXPECT_EQ(from.exitReference, all.exitReference);
  EXPECT_LT(from.events, all.events) << "the forks not made";
  EXPECT_GE(from.visits, kSwitchVisits[kFirst]);
  // The medium right after the first grain is about 6% off here (DecidedCandidates...): shown
  // by the measurement of all, not by one that never measured it.
  ASSERT_TRUE(beyondBy(all, 0, o.tolerance, 3.0f));
  EXPECT_GT(switchVisitsShownNeeded(all, o), 0);
  // Nothing measured shown, and a bias where nothing was measured (which a measurement never
  // writes there): still nothing shown.
  SwitchMeasure none = from;
  for (int c = 0; c + 1 < kSwitchCandidates; ++c) none.bias[size_t(c)] = Vec3(c < kFirst ? 0.5f : 0.0f);
  EXPECT_EQ(switchVisitsShownNeeded(none, o), 0);
  // Cached: its own entry, read back as measured.
  const uint64_t key = 0xf125c4ULL;
  const SwitchMeasure stored = measureSwitch(*scene->aggregates()[0], scene->proxyTables(0), scene->medium(0), o, key);
  const SwitchMeasure read = measureSwitch(*scene->aggregates()[0], scene->proxyTables(0), scene->medium(0), o, key);
  EXPECT_TRUE(read.fromCache);
  EXPECT_EQ(read.candidatePaths, from.candidatePaths);
  EXPECT_EQ(read.bias, from.bias);
  SwitchOptions every = o;
  every.firstCandidate = 0;
  EXPECT_NE(switchCacheName(key, scene->proxyTables(0), every), switchCacheName(key, scene->proxyTables(0), o));
}

TEST(Switching, IsTheSameWhateverTheThreads) {
  auto scene = ballScene(2.4f, Vec3(0.05f));
  SwitchOptions o;
  o.paths = 1 << 13;
  o.precision = 0.25f;  // several batches, some candidates stopped
  const SwitchMeasure many = measure(*scene, o);
  tbb::task_arena one(1);
  const SwitchMeasure single = one.execute([&] { return measure(*scene, o); });
  EXPECT_EQ(single.paths, many.paths);
  EXPECT_EQ(single.events, many.events);
  EXPECT_EQ(single.candidatePaths, many.candidatePaths);
  for (int c = 0; c < kSwitchCandidates; ++c) {
    EXPECT_EQ(single.bias[size_t(c)], many.bias[size_t(c)]) << c;
    EXPECT_EQ(single.biasSE[size_t(c)], many.biasSE[size_t(c)]) << c;
  }
  EXPECT_EQ(single.exitBias, many.exitBias);
  EXPECT_EQ(single.exitReference, many.exitReference);
}

TEST(Switching, ExitBinsAreByCosineFromTheNormalAndSide) {
  EXPECT_EQ(switchExitBin(1.0f, true), 0);
  EXPECT_EQ(switchExitBin(0.8f, false), 1);  // an edge belongs to the bin above it
  EXPECT_EQ(switchExitBin(0.79f, true), 2);
  EXPECT_EQ(switchExitBin(0.4f, false), 3);
  EXPECT_EQ(switchExitBin(0.39f, true), 4);
  EXPECT_EQ(switchExitBin(0.0f, false), kSwitchExitBins - 1);
  // Each bin's range (the reports' labels) holds its own lower edge; its upper edge is the
  // bin above's.
  for (int j = 0; j < kSwitchExitBins; ++j) {
    const SwitchExitBinRange r = switchExitBinRange(j);
    EXPECT_EQ(switchExitBin(r.lo, r.back), j);
    EXPECT_EQ(switchExitBin(r.hi, r.back), r.hi < 1.0f ? j - 2 : j);
  }
}

TEST(Switching, ExitBinsSplitTheAlbedoAndItsBias) {
  // What leaves in the bins is what leaves: the bins' reference sums to the albedo, and
  // each candidate's bias, weighted by the bins' share, to its bias in all. Without
  // stopping early every candidate forks in every path and all the paths are traced.
  auto scene = ballScene(2.4f, Vec3(0.05f));
  const SwitchOptions o = everyPath(1 << 12);
  const SwitchMeasure m = measure(*scene, o);
  EXPECT_EQ(m.paths, o.paths);
  for (int64_t n : m.candidatePaths) EXPECT_EQ(n, o.paths);
  ASSERT_EQ(m.exitReference.size(), size_t(kSwitchExitBins));
  ASSERT_EQ(m.exitBias.size(), size_t(kSwitchCandidates * kSwitchExitBins));
  Vec3 sum(0.0f);
  for (const Vec3& e : m.exitReference) {
    EXPECT_GT(minComponent(e), 0.0f);
    sum += e;
  }
  for (int ch = 0; ch < 3; ++ch) EXPECT_NEAR(sum[ch], m.albedo[ch], 1e-5f * m.albedo[ch]);
  for (int c = 0; c < kSwitchCandidates; ++c)
    for (int ch = 0; ch < 3; ++ch) {
      double weighted = 0;
      for (int j = 0; j < kSwitchExitBins; ++j)
        weighted += double(m.exitBias[size_t(c * kSwitchExitBins + j)][ch]) * m.exitReference[size_t(j)][ch];
      EXPECT_NEAR(weighted, double(m.bias[size_t(c)][ch]) * m.albedo[ch], 1e-5 * m.albedo[ch]) << c;
    }
  // The reference against itself: nothing, bin by bin.
  for (int j = 0; j < kSwitchExitBins; ++j)
    EXPECT_EQ(m.exitBias[size_t((kSwitchCandidates - 1) * kSwitchExitBins + j)], Vec3(0.0f));
}

TEST(Switching, EndsEarlyWhenNoCandidateCanReachThePrecision) {
  // A precision no candidate but the reference can reach in options.paths: the measurement
  // ends after its first batch with the reference chosen, instead of tracing every path.
  auto scene = ballScene(1.55f, Vec3(0.1f));
  SwitchOptions o;
  o.paths = 1 << 14;
  o.precision = 0.02f;
  const SwitchMeasure m = measure(*scene, o);
  print(m);
  EXPECT_LT(m.paths, o.paths);
  EXPECT_EQ(m.visits, kSwitchVisits[kSwitchCandidates - 1]);
  // Each candidate before it: decided, or its standard error, scaled as 1/√n to all of
  // options.paths, above the precision asked.
  for (int c = 0; c + 1 < kSwitchCandidates; ++c) {
    bool outOfReach = false;
    const float scale = std::sqrt(float(m.candidatePaths[size_t(c)]) / float(o.paths));
    for (int ch = 0; ch < 3; ++ch)
      outOfReach = outOfReach || m.biasSE[size_t(c)][ch] * scale > o.precision * o.tolerance;
    EXPECT_TRUE(outOfReach || beyondBy(m, c, o.tolerance, 3.0f)) << c;
  }
}

TEST(Switching, OptionsOutOfRangeAreRefused) {
  auto scene = ballScene(1.55f, Vec3(0.1f));
  SwitchOptions o;
  o.paths = 1;
  EXPECT_THROW(measureSwitch(*scene->aggregates()[0], scene->proxyTables(0), scene->medium(0), o), InputError);
  o = SwitchOptions();
  o.tolerance = 0;
  EXPECT_THROW(measureSwitch(*scene->aggregates()[0], scene->proxyTables(0), scene->medium(0), o), InputError);
  o = SwitchOptions();
  o.margin = -1;
  EXPECT_THROW(measureSwitch(*scene->aggregates()[0], scene->proxyTables(0), scene->medium(0), o), InputError);
  o = SwitchOptions();
  o.minPaths = -1;
  EXPECT_THROW(measureSwitch(*scene->aggregates()[0], scene->proxyTables(0), scene->medium(0), o), InputError);
  for (const int first : {-1, kSwitchCandidates}) {
    o = SwitchOptions();
    o.firstCandidate = first;
    EXPECT_THROW(measureSwitch(*scene->aggregates()[0], scene->proxyTables(0), scene->medium(0), o), InputError);
  }
}

TEST(Switching, AMeasurementIsCachedUnderItsTablesToo) {
  // The same key and other tables (estimated from other rays, as a new table format
  // would be): another entry, so the old tables' choice is never lent to new ones.
  auto scene = ballScene(1.55f, Vec3(0.1f));
  const Aggregate& agg = *scene->aggregates()[0];
  SwitchOptions o;
  o.paths = 1 << 10;
  const uint64_t key = 0x7ab1e5c4a11ULL;
  measureSwitch(agg, scene->proxyTables(0), scene->medium(0), o, key);
  EXPECT_TRUE(measureSwitch(agg, scene->proxyTables(0), scene->medium(0), o, key).fromCache);
  ProxyTables other;
  ProxyOptions po;
  po.rays = 1 << 12;
  po.seed = 99;
  po.useCache = false;
  for (size_t p = 0; p < agg.prototypes().size(); ++p) {
    const GrainPrototype& proto = agg.prototypes()[p];
    other.add(int(p), 1.0f, estimateProxyTable(proto.mesh, scene->material(proto.material), po));
  }
  EXPECT_NE(other.key(), scene->proxyTables(0).key());
  EXPECT_NE(switchCacheName(key, other, o), switchCacheName(key, scene->proxyTables(0), o));
}

TEST(Switching, TheSceneMeasuresOncePerAggregateAndLendsIt) {
  // Automatic explicit bounces with media: measured at build, lent to the next build of the
  // same aggregate, and not measured for the explicit reference.
  SceneDesc d = granular::testing::matrixBall(false, 1.55f);
  d.settings.technique = Technique::EptVpt;
  auto first = Scene::build(d);
  ASSERT_NE(first->switchMeasure(0), nullptr);
  auto second = Scene::build(d, first.get());
  EXPECT_EQ(second->switchMeasure(0), first->switchMeasure(0)) << "lent, not measured again";
  d.settings.technique = Technique::Ept;
  EXPECT_EQ(Scene::build(d)->switchMeasure(0), nullptr);
}


namespace {

// The camera's entries into the ball and a measurement of them with `paths` paths.
SwitchMeasure measureView(const Scene& s, const SwitchView& view, int64_t paths, uint64_t key = 0,
                          bool stopEarly = true) {
  SwitchOptions o = viewSwitchOptions();
  o.paths = paths;
  o.stopEarly = stopEarly;
  return measureViewSwitch(*s.aggregates()[0], s.proxyTables(0), s.medium(0), view, o, key);
}

// A distant light of (nearly) a hemisphere about dir (towards the light), radiance 1.
Light hemisphere(const Vec3& dir) {
  LightDesc d;
  d.type = LightType::Distant;
  d.angle = 179.98f;
  d.xf = Transform::lookAt(Vec3(0.0f), -dir, std::fabs(dir.y) > 0.5f ? Vec3(0, 0, 1) : Vec3(0, 1, 0));
  return Light::fromDesc(d);
}

}  // namespace

TEST(Switching, TheViewsEntriesAreWhereTheCameraMeetsTheBoundary) {
  // The ball fills most of the image: most of the grid's rays enter it, from outside, at
  // its boundary (the unit icosphere); the white dome is no distant light: none is lit.
  auto scene = ballScene(1.5f, Vec3(0.0f));
  const SwitchView view = scene->switchViews()[0];
  EXPECT_GT(view.entries.size(), size_t(Scene::kViewGrid * Scene::kViewGrid / 4));
  for (const SwitchView::Entry& e : view.entries) {
    EXPECT_LT(dot(e.d, e.n), 0.0f);
    EXPECT_NEAR(length(e.p), 1.0f, 0.02f);
    EXPECT_EQ(e.lit, 0u);
  }
}

TEST(Switching, TheViewMeasurementOfAWhiteFurnaceSeesTheDome) {
  // Clear grains under the white dome (radiance 1), a medium of albedo 1: every path the
  // camera sends in leaves again and brings the dome's radiance back, whatever the visits.
  auto scene = ballScene(1.5f, Vec3(0.0f));
  const SwitchMeasure m = measureView(*scene, scene->switchViews()[0], 1 << 12);
  print(m);
  expectWhiteFurnace(m);
}

TEST(Switching, TheViewMeasurementsLightSamplesAgreeWithItsDomeWhereTheyMeanTheSame) {
  // Two distant lights of a hemisphere each, radiance 1, light the ball as the white dome
  // does (less a ring 0.01° wide). Next-event estimation gathers theirs at every grain
  // among proxies and every scattering in the medium; the dome's is gathered where paths
  // leave. Absorbing grains of IOR 1.55: the same radiance toward the camera, and the same
  // bias after each visit, within the two estimates' noise.
  auto scene = ballScene(1.55f, Vec3(0.3f));
  const SwitchView domeView = scene->switchViews()[0];
  std::vector<Light> lights = {hemisphere(Vec3(0, 1, 0)), hemisphere(Vec3(0, -1, 0))};
  SwitchView sunView = domeView;
  sunView.lights = &lights;
  for (SwitchView::Entry& e : sunView.entries) e.lit = 3;
  const SwitchMeasure dome = measureView(*scene, domeView, 1 << 14, 0, false);
  const SwitchMeasure suns = measureView(*scene, sunView, 1 << 14, 0, false);
  print(dome);
  print(suns);
  for (int c = 0; c < 3; ++c) {
    EXPECT_LT(dome.albedo[c], 0.9f) << "the grains absorb";
    EXPECT_NEAR(suns.albedo[c], dome.albedo[c], 4.0f * std::hypot(suns.albedoSE[c], dome.albedoSE[c]));
    for (int k : {0, 2}) {
      const float se = std::hypot(suns.biasSE[size_t(k)][c], dome.biasSE[size_t(k)][c]);
      EXPECT_NEAR(suns.bias[size_t(k)][c], dome.bias[size_t(k)][c], 4.0f * se + 1e-3f) << "after " << kSwitchVisits[k];
    }
  }
}

TEST(Switching, TheViewMeasurementIsDeterministicAndCachedUnderItsView) {
  auto scene = ballScene(1.55f, Vec3(0.1f));
  const SwitchView view = scene->switchViews()[0];
  const uint64_t key = 0x71e3a5c0ffeeULL;
  const SwitchMeasure first = measureView(*scene, view, 1 << 10, key);  // stored, or read back
  const SwitchMeasure read = measureView(*scene, view, 1 << 10, key);
  const SwitchMeasure uncached = measureView(*scene, view, 1 << 10);
  EXPECT_TRUE(read.fromCache);
  EXPECT_FALSE(uncached.fromCache);
  for (int k = 0; k < kSwitchCandidates; ++k) {
    EXPECT_EQ(read.bias[size_t(k)].y, uncached.bias[size_t(k)].y);
    EXPECT_EQ(first.bias[size_t(k)].y, uncached.bias[size_t(k)].y);
  }
  // Another view (one entry fewer), or a light more: another entry, never this one's.
  auto differs = [&](const SwitchMeasure& m) {
    for (int k = 0; k < kSwitchCandidates; ++k)
      if (m.bias[size_t(k)] != uncached.bias[size_t(k)]) return true;
    return m.albedo != uncached.albedo;
  };
  SwitchView fewer = view;
  fewer.entries.pop_back();
  EXPECT_TRUE(differs(measureView(*scene, fewer, 1 << 10, key)));
  std::vector<Light> lights = *view.lights;
  lights.push_back(hemisphere(Vec3(0, 1, 0)));
  SwitchView lit = view;
  lit.lights = &lights;
  for (SwitchView::Entry& e : lit.entries) e.lit = 1u << 1;
  EXPECT_TRUE(differs(measureView(*scene, lit, 1 << 10, key)));
  SwitchView none = view;
  none.entries.clear();
  EXPECT_THROW(measureView(*scene, none, 1 << 10), InputError);
}

TEST(Switching, TheSceneMeasuresTheViewWhenAskedAndTakesTheLargerChoice) {
  // switch_for_view is a change of view: the same built scene, the view measured at
  // setView, the visits the larger of the two choices; off again, the dome's alone.
  SceneDesc d = granular::testing::matrixBall(false, 1.55f);
  d.settings.technique = Technique::EptVpt;
  auto scene = Scene::build(d);
  ASSERT_NE(scene->switchMeasure(0), nullptr);
  EXPECT_EQ(scene->viewSwitchMeasure(0), nullptr);
  const int dome = scene->proxyVisits(0);
  RenderSettings s = d.settings;
  s.switchForView = true;
  scene->setView(d.camera, s);
  const SwitchMeasure* view = scene->viewSwitchMeasure(0);
  ASSERT_NE(view, nullptr);
  EXPECT_EQ(scene->proxyVisits(0), std::max(dome, view->visits));
  EXPECT_EQ(scene->switchMeasure(0)->visits, dome);
  EXPECT_NE(scene->lowOrdersText(0).find("for this view"), std::string::npos) << scene->lowOrdersText(0);
  // A camera that sees no aggregate: no view measurement.
  CameraDesc away = d.camera;
  away.cameraToWorld = Transform::lookAt(Vec3(0.3f, 0.7f, 2.6f), Vec3(0.3f, 0.7f, 5.0f), Vec3(0, 1, 0));
  scene->setView(away, s);
  EXPECT_EQ(scene->viewSwitchMeasure(0), nullptr);
  EXPECT_EQ(scene->proxyVisits(0), dome);
  s.switchForView = false;
  scene->setView(d.camera, s);
  EXPECT_EQ(scene->viewSwitchMeasure(0), nullptr);
  EXPECT_EQ(scene->proxyVisits(0), dome);
}

TEST(Switching, TheViewMeasuredApartIsTheSameChoiceAndOnlyForItsView) {
  // A viewport's camera must not wait for the view measurement: setView(..., Apart) leaves
  // it to be made on another thread, the scene rendering the dome's choice meanwhile, and
  // applyViewSwitch then makes the choice setView(..., Now) makes, from the same
  // measurement. Work made for another view, or another scene, is refused; the work holds
  // what it reads, so the scene may take other views while it is measured.
  SceneDesc d = granular::testing::matrixBall(false, 1.55f);
  d.settings.technique = Technique::EptVpt;
  RenderSettings s = d.settings;
  s.switchForView = true;
  auto now = Scene::build(d);
  now->setView(d.camera, s);
  ASSERT_NE(now->viewSwitchMeasure(0), nullptr);
  EXPECT_TRUE(now->pendingViewSwitch().empty());

  auto apart = Scene::build(d);
  const int dome = apart->proxyVisits(0);
  apart->setView(d.camera, s, Scene::ViewSwitchTiming::Apart);
  EXPECT_EQ(apart->viewSwitchMeasure(0), nullptr);
  EXPECT_EQ(apart->proxyVisits(0), dome);
  const Scene::ViewSwitchWork work = apart->pendingViewSwitch();
  ASSERT_EQ(work.items.size(), 1u);
  EXPECT_EQ(work.items[0].index, 0u);
  // Measured on a thread of its own while the scene takes another view and back.
  std::vector<std::shared_ptr<const SwitchMeasure>> measures;
  std::thread measuring([&] { measures = work.measure(); });
  CameraDesc away = d.camera;
  away.cameraToWorld = Transform::lookAt(Vec3(0.3f, 0.7f, 2.6f), Vec3(0.3f, 0.7f, 5.0f), Vec3(0, 1, 0));
  apart->setView(away, s, Scene::ViewSwitchTiming::Apart);
  EXPECT_TRUE(apart->pendingViewSwitch().empty());  // it sees no aggregate
  measuring.join();
  ASSERT_EQ(measures.size(), 1u);
  EXPECT_FALSE(apart->applyViewSwitch(work, measures));  // made for the view before
  EXPECT_EQ(apart->viewSwitchMeasure(0), nullptr);
  EXPECT_EQ(apart->proxyVisits(0), dome);

  apart->setView(d.camera, s, Scene::ViewSwitchTiming::Apart);
  const Scene::ViewSwitchWork again = apart->pendingViewSwitch();
  ASSERT_EQ(again.items.size(), 1u);
  EXPECT_NE(again.view, work.view);
  EXPECT_FALSE(now->applyViewSwitch(again, again.measure()));  // another scene's view
  ASSERT_TRUE(apart->applyViewSwitch(again, again.measure()));
  EXPECT_TRUE(apart->pendingViewSwitch().empty());
  const SwitchMeasure* a = apart->viewSwitchMeasure(0);
  const SwitchMeasure* n = now->viewSwitchMeasure(0);
  ASSERT_NE(a, nullptr);
  // Every candidate but the reference (K, whose bias is 0 by construction), every channel.
  auto expectSame = [&](const SwitchMeasure& m) {
    EXPECT_EQ(m.visits, n->visits);
    EXPECT_EQ(m.paths, n->paths);
    ASSERT_EQ(m.bias.size(), n->bias.size());
    for (size_t c = 0; c + 1 < m.bias.size(); ++c)
      for (int ch = 0; ch < 3; ++ch) {
        EXPECT_EQ(m.bias[c][ch], n->bias[c][ch]) << c;
        EXPECT_EQ(m.biasSE[c][ch], n->biasSE[c][ch]) << c;
      }
  };
  ASSERT_NE(n->bias.front().x, 0.0f);  // the comparison sees a measured bias
  expectSame(*a);
  // The work measured while the scene looked away reads the same: it held its inputs.
  expectSame(*measures[0]);
  EXPECT_EQ(apart->proxyVisits(0), now->proxyVisits(0));
  EXPECT_EQ(apart->proxyVisits(0), std::max(dome, n->visits));
  EXPECT_EQ(apart->lowOrdersText(0), now->lowOrdersText(0));
  // A new view drops the view's choice until its own is applied.
  apart->setView(away, s, Scene::ViewSwitchTiming::Apart);
  EXPECT_EQ(apart->viewSwitchMeasure(0), nullptr);
  EXPECT_EQ(apart->proxyVisits(0), dome);
}

namespace {

// The matrix ball under a sun of the given angle (towards the light: dir) and radiance.
SceneDesc sunlitBall(float angle, const Vec3& dir, float intensity = 1.0f) {
  SceneDesc d = granular::testing::matrixBall(false, 1.55f);
  d.settings.technique = Technique::EptVpt;
  LightDesc sun;
  sun.name = "sun";
  sun.type = LightType::Distant;
  sun.angle = angle;
  sun.intensity = intensity;
  sun.xf = Transform::lookAt(Vec3(0.0f), -dir, Vec3(0, 0, 1));
  d.lights.push_back(sun);
  return d;
}

}  // namespace

TEST(Switching, TheSunsEntriesAreTheBoundaryItLights) {
  // Seen from the sun, the ball's boundary (the unit icosphere) fills π/4 of a grid over
  // its bounds at most; every entry comes in along the sun's light, from outside, and the
  // sun reaches it. A box between the sun and the ball leaves none; so does a sun of zero
  // radiance, which asks for nothing.
  const Vec3 dir = normalize(Vec3(0.3f, 0.8f, 0.5f));
  auto scene = Scene::build(sunlitBall(0.53f, dir));
  const SwitchView view = scene->sunSwitchViews()[0];
  const size_t grid = size_t(Scene::kViewGrid * Scene::kViewGrid);
  EXPECT_GT(view.entries.size(), grid / 8);
  EXPECT_LT(view.entries.size(), grid * 8 / 10);
  const uint32_t sunBit = 1u << 1;  // lights: the sky, then the sun
  for (const SwitchView::Entry& e : view.entries) {
    EXPECT_NEAR(dot(e.d, -dir), 1.0f, 1e-5f);
    EXPECT_LT(dot(e.d, e.n), 0.0f);
    EXPECT_NEAR(length(e.p), 1.0f, 0.02f);
    EXPECT_EQ(e.lit & sunBit, sunBit);
  }
  SceneDesc shaded = sunlitBall(0.53f, dir);
  MeshDesc roof;
  roof.name = "roof";
  roof.mesh = makeBox(Vec3(-3.0f, 2.0f, -3.0f), Vec3(3.0f, 2.2f, 3.0f));
  roof.material = 1;
  shaded.meshes.push_back(roof);
  EXPECT_TRUE(Scene::build(shaded)->sunSwitchViews()[0].entries.empty());
  EXPECT_TRUE(Scene::build(sunlitBall(0.53f, dir, 0.0f))->sunSwitchViews()[0].entries.empty());
  // Nor does a sun linked away from the ball (light linking): it asks the ball for nothing.
  SceneDesc unlinked = sunlitBall(0.53f, dir);
  unlinked.lights[1].lightLink = "other";
  EXPECT_TRUE(Scene::build(unlinked)->sunSwitchViews()[0].entries.empty());
}

TEST(Switching, TheSceneMeasuresTowardANarrowSunAndTakesTheLargerChoice) {
  // Under a narrow sun (smooth grains), each aggregate is also measured as the sun sees it,
  // once per scene whatever the camera; its visits are the larger choice, said on the
  // low-orders line. Under a wide sun there is no such measurement.
  const Vec3 dir = normalize(Vec3(0.3f, 0.8f, 0.5f));
  const SceneDesc d = sunlitBall(0.53f, dir);
  auto scene = Scene::build(d);
  ASSERT_NE(scene->switchMeasure(0), nullptr);
  const SwitchMeasure* sun = scene->sunSwitchMeasure(0);
  ASSERT_NE(sun, nullptr);
  print(*sun);
  // What it shows, not its own choice; from the dome's choice on, whose candidates before
  // it are not measured.
  const SwitchOptions options = scene->sunSwitchOptionsFor(0);
  EXPECT_EQ(kSwitchVisits[options.firstCandidate], scene->switchMeasure(0)->visits);
  for (int c = 0; c < kSwitchCandidates; ++c)
    EXPECT_EQ(sun->candidatePaths[size_t(c)] > 0, c >= options.firstCandidate) << c;
  EXPECT_EQ(sun->visits, std::max(switchVisitsShownNeeded(*sun, options), scene->switchMeasure(0)->visits));
  EXPECT_EQ(scene->proxyVisits(0), std::max(scene->switchMeasure(0)->visits, sun->visits));
  EXPECT_NE(scene->lowOrdersText(0).find("toward the sun"), std::string::npos) << scene->lowOrdersText(0);
  for (int c = 0; c < 3; ++c) EXPECT_GT(sun->albedo[c], 0.0f);  // the radiance sent back toward the sun
  // Another camera: the same measurement, not made again.
  CameraDesc other = d.camera;
  other.cameraToWorld = Transform::lookAt(Vec3(-2.0f, 0.5f, 1.6f), Vec3(0.0f), Vec3(0, 1, 0));
  scene->setView(other, d.settings);
  EXPECT_EQ(scene->sunSwitchMeasure(0), sun);
  auto wide = Scene::build(sunlitBall(20.0f, dir));
  ASSERT_NE(wide->switchMeasure(0), nullptr);
  EXPECT_EQ(wide->sunSwitchMeasure(0), nullptr);
  EXPECT_EQ(wide->lowOrdersText(0).find("toward the sun"), std::string::npos);
}
