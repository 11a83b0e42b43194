// Stand-ins (scene.h, SceneDetail::StandIns): a first image from each aggregate's
// boundary and equivalent medium before its cells are built, then the full build, which
// takes the stand-in's medium and renders as a build that never had stand-ins.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "core/render.h"
#include "core/scene.h"
#include "test_helpers.h"

using namespace granular;

namespace {

// The LOD tests' ball of bright sand (radius 1, grain radius R) under a 5° sun and a sky,
// filling about 80% of a 24×24 image.
SceneDesc sandBall(float R, int spp, uint64_t seed) {
  const float distance = 6.0f;
  SceneDesc s = granular::testing::sandBallScene(Vec3(0.2f, 0.3f, distance), 50.0f * 2.5f / distance, R, 1);
  s.settings.width = s.settings.height = 24;
  s.settings.spp = spp;
  s.settings.seed = seed;
  return s;
}

Image render(const Scene& scene) {
  Renderer r(scene);
  EXPECT_TRUE(r.render(scene.settings().spp));
  return r.film().toImage();
}

// Mean luminance of the pixels where the ball is (alpha 1) and its standard error over
// those pixels (independent samples per pixel).
struct Estimate {
  double mean = 0, se = 0;
  int pixels = 0;
};

Estimate ballMean(const Scene& scene) {
  Renderer r(scene);
  EXPECT_TRUE(r.render(scene.settings().spp));
  const Image img = r.film().toImage();
  const Film& film = r.film();
  double sum = 0, var = 0;
  int n = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      if (img.at(x, y)[3] < 1.0f) continue;  // sky, or the ball's rim
      sum += luminance(film.mean(x, y));
      const double se = film.stdError(x, y);
      var += se * se;
      ++n;
    }
  return {sum / n, std::sqrt(var) / n, n};
}

}  // namespace

TEST(StandIn, BuildsTheMediumWithoutCells) {
  const SceneDesc d = sandBall(0.02f, 4, 0);
  auto standIn = Scene::build(d, nullptr, SceneDetail::StandIns);
  auto full = Scene::build(d);
  ASSERT_TRUE(standIn->standIns());
  EXPECT_FALSE(full->standIns());
  const Aggregate& s = *standIn->aggregates()[0];
  const Aggregate& f = *full->aggregates()[0];
  EXPECT_TRUE(s.standIn());
  EXPECT_FALSE(f.standIn());
  // No distance field and no cell classes: what the full build spends its time on.
  EXPECT_EQ(s.distanceField().memoryBytes(), 0u);
  EXPECT_EQ(s.stats().insideCells + s.stats().partialCells, 0);
  EXPECT_EQ(s.cellClass(1, 1, 1), CellClass::Outside);
  // The same medium (the same TT parameters), and estimates near the cells' values: the
  // deepest point within a grid step of the deepest cell centre, the grain count within 10%.
  ASSERT_TRUE(standIn->hasMedia() && full->hasMedia());
  for (int c = 0; c < 3; ++c) {
    EXPECT_EQ(standIn->mediumParams(0).sigmaT[c], full->mediumParams(0).sigmaT[c]);
    EXPECT_EQ(standIn->mediumParams(0).albedo[c], full->mediumParams(0).albedo[c]);
  }
  const float step = std::max(f.cellSize(), maxComponent(f.boundary().bounds().extent()) / 32.0f);
  EXPECT_NEAR(s.stats().maxInteriorDepth, f.stats().maxInteriorDepth, step);
  EXPECT_NEAR(s.stats().approxGrains, f.stats().approxGrains, 0.1 * f.stats().approxGrains);
  // A stand-in has no grains to meet; shadow rays are stopped by its boundary.
  GrainHit hit;
  EXPECT_FALSE(s.intersect(Vec3(0, 0, 5), Vec3(0, 0, -1), 0.0f, kInf, hit));
  EXPECT_TRUE(f.intersect(Vec3(0, 0, 5), Vec3(0, 0, -1), 0.0f, kInf, hit));
  EXPECT_TRUE(s.occluded(Vec3(0, 0, 5), Vec3(0, 0, -1), 0.0f, kInf));
  EXPECT_FALSE(s.occluded(Vec3(0, 5, 5), Vec3(0, 0, -1), 0.0f, kInf));
}

TEST(StandIn, TheFullBuildTakesTheStandInsMediumAndRendersAsAnEagerBuild) {
  // One grain size: the stand-in's Sauter size (no tile) is the tile's exactly, and its
  // medium is lent. Sizes spread ±30%: the tile's own sizes differ from their expectation,
  // and the full build derives its medium from them, as an eager build does.
  for (float spread : {0.0f, 0.3f}) {
    SceneDesc d = sandBall(0.02f, 4, 3);
    d.aggregates[0].sizeSpread = spread;
    auto standIn = Scene::build(d, nullptr, SceneDetail::StandIns);
    auto full = Scene::build(d, standIn.get());
    EXPECT_FALSE(full->standIns());
    EXPECT_EQ(full->aggregatesBuilt(), 1);  // a stand-in is never lent as the aggregate
    EXPECT_EQ(full->mediaDerived(), spread > 0 ? 1 : 0) << spread;
    auto eager = Scene::build(d);
    EXPECT_TRUE(granular::testing::sameImage(render(*full), render(*eager))) << spread;
  }
  const SceneDesc d = sandBall(0.02f, 4, 3);
  auto full = Scene::build(d);
  // The other way round: a full aggregate is lent to a stand-in build unchanged.
  auto again = Scene::build(d, full.get(), SceneDetail::StandIns);
  EXPECT_EQ(again->aggregatesReused(), 1);
  EXPECT_FALSE(again->aggregates()[0]->standIn());
}

TEST(StandIn, EptIsAlwaysBuiltFull) {
  SceneDesc d = sandBall(0.02f, 4, 0);
  d.settings.technique = Technique::Ept;
  auto scene = Scene::build(d, nullptr, SceneDetail::StandIns);
  EXPECT_FALSE(scene->standIns());
  EXPECT_FALSE(scene->aggregates()[0]->standIn());
}

TEST(StandIn, TheFirstImageAgreesWithTheHybridOnAverage) {
  // What a host shows first is the medium alone from the camera on; the hybrid keeps the
  // first grain explicit. Their means over the ball must agree closely, so that the
  // refinement is no jump in brightness: within 3%, beyond 4 standard errors of the
  // difference (a memoryless medium misses some of the packing's shadowing near the
  // surface: scene.h, explicitBouncesFor).
  for (float R : {0.004f, 0.02f}) {
    const SceneDesc first = sandBall(R, 64, 11), last = sandBall(R, 64, 12);
    Estimate a = ballMean(*Scene::build(first, nullptr, SceneDetail::StandIns));
    Estimate b = ballMean(*Scene::build(last));
    const double rel = (a.mean - b.mean) / b.mean, noise = std::hypot(a.se, b.se) / b.mean;
    std::printf("grain radius %g: stand-ins %.4f, hybrid %.4f over %d pixels (relative %+.4f, noise %.4f)\n", R,
                a.mean, b.mean, b.pixels, rel, noise);
    EXPECT_GT(b.pixels, 200);
    EXPECT_LE(std::fabs(rel), 0.03 + 4 * noise) << "grain radius " << R;
  }
}

// A stand-in has no distance field: the exits model's moves ask whether they stayed inside
// by the boundary itself there (Aggregate::insideBoundaryFast), never by a field it lacks.
TEST(StandIn, TheExitsModelRendersStandIns) {
  SceneDesc d = sandBall(0.02f, 4, 0);
  d.settings.mediumModel = MediumModel::Exits;
  auto standIn = Scene::build(d, nullptr, SceneDetail::StandIns);
  ASSERT_TRUE(standIn->medium(0).movesLight());
  const Image img = render(*standIn);
  double sum = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      for (int c = 0; c < 3; ++c) ASSERT_TRUE(std::isfinite(img.at(x, y)[c]));
      sum += luminance(Vec3(img.at(x, y)[0], img.at(x, y)[1], img.at(x, y)[2]));
    }
  EXPECT_GT(sum, 0.0);
}
