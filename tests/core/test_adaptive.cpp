// Adaptive sampling (render.h, Renderer::setNoiseThreshold): each pixel stops on its own
// at the noise threshold; the image is the one its per-pixel sample counts draw, whatever
// the threads or passes; its mean is a plain render's within the standard errors.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <vector>

#include "core/error.h"
#include "core/render.h"
#include "core/scene.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;

namespace {

// A grey ball on a grey floor under a sun of 5 degrees and a dim uniform sky, seen from
// above the floor: the sky above the horizon is a flat dark background (every sample
// sees radiance 0.02, no noise), the floor's shadow and the ball's underside are noisy.
SceneDesc ballOnFloor(int spp, uint64_t seed) {
  SceneDesc d;
  d.settings.width = 32;
  d.settings.height = 24;
  d.settings.spp = spp;
  d.settings.seed = seed;
  d.settings.technique = Technique::Ept;
  d.camera.cameraToWorld = Transform::lookAt(Vec3(0, 0.6f, 6), Vec3(0, 0, 0), Vec3(0, 1, 0));
  d.camera.focalLength = 50;
  d.camera.horizontalAperture = 32;
  d.camera.verticalAperture = 24;
  MeshDesc ball;
  ball.name = "ball";
  ball.mesh = makeIcosphere(2);
  d.meshes.push_back(ball);
  MeshDesc floor;
  floor.name = "floor";
  floor.mesh = makeBox(Vec3(-20, -1.1f, -20), Vec3(20, -1, 3));
  d.meshes.push_back(floor);
  LightDesc sun;
  sun.name = "sun";
  sun.type = LightType::Distant;
  sun.angle = 5;
  sun.intensity = 2;
  sun.xf = Transform::lookAt(Vec3(0.0f), Vec3(-0.5f, -1.0f, -0.3f), Vec3(0, 0, 1));
  d.lights.push_back(sun);
  LightDesc sky;
  sky.name = "sky";
  sky.type = LightType::Dome;
  sky.color = Vec3(0.02f);
  d.lights.push_back(sky);
  return d;
}

struct Adaptive {
  std::unique_ptr<Scene> scene;
  std::unique_ptr<Renderer> renderer;
};

Adaptive renderAdaptive(SceneDesc d, float threshold, int passSamples = 1, int threads = 0) {
  d.settings.threads = threads;
  Adaptive a;
  a.scene = Scene::build(d);
  a.renderer = std::make_unique<Renderer>(*a.scene);
  a.renderer->setNoiseThreshold(threshold);
  EXPECT_TRUE(a.renderer->render(passSamples));
  return a;
}

void expectSameFilm(const Film& a, const Film& b) {
  ASSERT_EQ(a.width(), b.width());
  ASSERT_EQ(a.height(), b.height());
  for (int y = 0; y < a.height(); ++y)
    for (int x = 0; x < a.width(); ++x) {
      ASSERT_EQ(a.samples(x, y), b.samples(x, y)) << x << "," << y;
      float pa[Film::kChannels], pb[Film::kChannels];
      a.pixelChannels(x, y, pa);
      b.pixelChannels(x, y, pb);
      for (int c = 0; c < Film::kChannels; ++c) ASSERT_EQ(pa[c], pb[c]) << x << "," << y << " channel " << c;
    }
}

}  // namespace

TEST(Adaptive, AFlatBackgroundStopsAtTheMinimumWhileNoisyPixelsGoOn) {
  auto a = renderAdaptive(ballOnFloor(256, 1), 0.03f);
  const Renderer& r = *a.renderer;
  const Film& f = r.film();
  const long minimum = r.minAdaptiveSamples();
  EXPECT_EQ(minimum, 16);  // two bundles of 1 (EPT), at least 16 samples
  // The top rows see the sky alone.
  for (int x = 0; x < f.width(); ++x) EXPECT_EQ(f.samples(x, 0), minimum) << x;
  const SampleCounts c = r.sampleCounts();
  EXPECT_EQ(c.min, minimum);
  EXPECT_GT(c.max, 4 * minimum);  // the noisy pixels took many more
  EXPECT_LT(c.mean, 0.75 * 256);  // and the image far fewer than spp everywhere
  long atMinimum = 0, beyond = 0;
  for (int y = 0; y < f.height(); ++y)
    for (int x = 0; x < f.width(); ++x) {
      atMinimum += f.samples(x, y) == minimum;
      beyond += f.samples(x, y) >= 2 * minimum;
    }
  EXPECT_GE(atMinimum, f.width());
  EXPECT_GE(beyond, f.width() * f.height() / 16);
  std::printf("adaptive 0.03: samples per pixel mean %.1f, min %ld, max %ld of 256; %ld of %d pixels at the "
              "minimum, %ld at twice it or more\n", c.mean, c.min, c.max, atMinimum, f.width() * f.height(), beyond);
}

TEST(Adaptive, EveryPixelReachesTheSampleCountOrMeetsTheThreshold) {
  const float threshold = 0.03f;
  auto a = renderAdaptive(ballOnFloor(96, 3), threshold);
  const Renderer& r = *a.renderer;
  const Film& f = r.film();
  long stoppedEarly = 0;
  for (int y = 0; y < f.height(); ++y)
    for (int x = 0; x < f.width(); ++x) {
      const long n = f.samples(x, y);
      ASSERT_GE(n, r.minAdaptiveSamples()) << x << "," << y;
      ASSERT_LE(n, 96) << x << "," << y;
      if (n < 96) {
        ++stoppedEarly;
        EXPECT_TRUE(f.pixelBelowNoiseThreshold(x, y, threshold)) << x << "," << y << " stopped at " << n;
      }
    }
  EXPECT_GT(stoppedEarly, 0);
  // Some pixel needed every sample: the render ran to spp and is not "converged".
  EXPECT_EQ(r.samplesPerPixel(), 96);
  EXPECT_EQ(r.converged(), r.activePixels() == 0);
}

TEST(Adaptive, TheImageIsTheRenderOfItsPerPixelSampleCounts) {
  // Each pixel rendered alone (a one-pixel crop) without a threshold, with the samples the
  // adaptive render gave it: the same streams, bit for bit.
  const SceneDesc d = ballOnFloor(64, 5);
  auto a = renderAdaptive(d, 0.05f);
  const Film& f = a.renderer->film();
  auto scene = Scene::build(d);
  for (int y = 0; y < f.height(); ++y)
    for (int x = 0; x < f.width(); ++x) {
      RenderSettings rs = d.settings;
      rs.spp = int(f.samples(x, y));
      rs.cropX0 = x, rs.cropX1 = x + 1, rs.cropY0 = y, rs.cropY1 = y + 1;
      scene->setView(d.camera, rs);
      Renderer plain(*scene);
      ASSERT_TRUE(plain.render(64));
      ASSERT_EQ(plain.film().samples(0, 0), f.samples(x, y));
      float pa[Film::kChannels], pb[Film::kChannels];
      f.pixelChannels(x, y, pa);
      plain.film().pixelChannels(0, 0, pb);
      for (int c = 0; c < Film::kChannels; ++c) ASSERT_EQ(pa[c], pb[c]) << x << "," << y << " channel " << c;
    }
}

TEST(Adaptive, NeitherThreadsNorPassSplitsChangeTheImage) {
  const SceneDesc d = ballOnFloor(64, 7);
  auto one = renderAdaptive(d, 0.05f, /*passSamples=*/1, /*threads=*/1);
  auto many = renderAdaptive(d, 0.05f, /*passSamples=*/5, /*threads=*/0);
  auto whole = renderAdaptive(d, 0.05f, /*passSamples=*/64, /*threads=*/2);
  expectSameFilm(one.renderer->film(), many.renderer->film());
  expectSameFilm(one.renderer->film(), whole.renderer->film());
}

TEST(Adaptive, BundlesStayWholeAndThreadsDoNotMatterInTheHybrid) {
  // Sand with media: bundles of 16; a pixel's count is a whole number of bundles (or spp),
  // two of them at least.
  SceneDesc d = granular::testing::sandBallScene(Vec3(0, 0.5f, 4), 24, 0.02f, 1);
  d.settings.width = 16;
  d.settings.height = 12;
  d.settings.spp = 80;
  d.settings.roulette = 1;
  d.settings.seed = 2;
  auto one = renderAdaptive(d, 0.1f, 16, 1);
  ASSERT_TRUE(one.scene->hasMedia());
  ASSERT_EQ(one.renderer->bundleSize(), 16);
  EXPECT_EQ(one.renderer->minAdaptiveSamples(), 32);
  const Film& f = one.renderer->film();
  long early = 0;
  for (int y = 0; y < f.height(); ++y)
    for (int x = 0; x < f.width(); ++x) {
      const long n = f.samples(x, y);
      EXPECT_GE(n, 32) << x << "," << y;
      EXPECT_TRUE(n % 16 == 0 || n == 80) << x << "," << y << ": " << n;
      early += n < 80;
    }
  EXPECT_GT(early, 0);
  auto many = renderAdaptive(d, 0.1f, 48, 0);
  expectSameFilm(f, many.renderer->film());
}

TEST(Adaptive, TheMeanIsAPlainRendersWithinTheStandardErrors) {
  // Independent seeds: an adaptive render against one of 512 samples everywhere. Over the
  // image, the mean difference is within 4 standard errors of the mean. Per pixel, the
  // luminance differs by at most 4.5 combined standard errors (an unbiased pair fails that
  // 7 times in a million) except in at most 1% of the pixels, where the stopping rule
  // misjudges a pixel. The adaptive pixel's standard error is the reference's per-sample
  // variance over its own count: its own estimate reads no noise where its samples agree
  // because an event of a few percent (a bounce onto the ball) has not happened in them,
  // and the sky-lit floor is otherwise exact (a constant dome over a Lambert surface).
  // Pixels without noise (the sky) are equal.
  auto a = renderAdaptive(ballOnFloor(256, 11), 0.03f);
  auto refScene = Scene::build(ballOnFloor(512, 12));
  Renderer ref(*refScene);
  ASSERT_TRUE(ref.render(64));
  const Film& fa = a.renderer->film();
  const Film& fr = ref.film();
  double diff = 0, var = 0;
  int outliers = 0;
  const int pixels = fa.width() * fa.height();
  for (int y = 0; y < fa.height(); ++y)
    for (int x = 0; x < fa.width(); ++x) {
      const double la = luminance(fa.mean(x, y)), lr = luminance(fr.mean(x, y));
      const double sr = fr.stdError(x, y), sa = sr * std::sqrt(512.0 / double(fa.samples(x, y)));
      const double s2 = sa * sa + sr * sr;
      diff += la - lr;
      var += s2;
      if (s2 == 0) {
        EXPECT_NEAR(la, lr, 1e-6) << x << "," << y;
      } else if (std::fabs(la - lr) > 4.5 * std::sqrt(s2)) {
        ++outliers;
      }
    }
  EXPECT_LE(outliers, pixels / 100);
  std::printf("adaptive vs plain: %d of %d pixels beyond 4.5 standard errors\n", outliers, pixels);
  const double meanDiff = diff / pixels, meanSe = std::sqrt(var) / pixels;
  std::printf("adaptive vs plain: image mean difference %.3g, its standard error %.3g\n", meanDiff, meanSe);
  EXPECT_LE(std::fabs(meanDiff), 4 * meanSe);
}

TEST(Adaptive, ABadThresholdIsAnInputErrorAndItCannotChangeMidRender) {
  auto scene = Scene::build(ballOnFloor(16, 1));
  Renderer r(*scene);
  EXPECT_THROW(r.setNoiseThreshold(-0.1f), InputError);
  EXPECT_THROW(r.setNoiseThreshold(std::nanf("")), InputError);
  EXPECT_THROW(r.setNoiseThreshold(INFINITY), InputError);
  r.setNoiseThreshold(0.05f);
  ASSERT_TRUE(r.renderPass(8));
  EXPECT_NO_THROW(r.setNoiseThreshold(0.05f));
  EXPECT_THROW(r.setNoiseThreshold(0.1f), InputError);
}

TEST(Adaptive, NeighboursKeepGoingAPixelWhoseSamplesAgreeByChance) {
  // A floor under a constant dome (exact in every sample) and a small bright emitter beside
  // it that only BSDF sampling finds, in about 2.4% of a floor pixel's samples, each worth
  // 60 times the rest: about 2/3 of the floor pixels see none of it in their 16 first
  // samples, and by their own spread would stop there, less than half as bright as they
  // are (180 of 256 do without the neighbours). Their neighbours, which saw it, keep them
  // going: a pixel stops there only if its 25-pixel box all missed the lamp, 0.68^25 =
  // 6e-5 inside the image; a corner's box is 9 pixels (0.03), an edge's 15: below one
  // such pixel expected in all, so at most 4 (a Poisson count of mean 1 exceeds 4 with
  // chance 0.004).
  SceneDesc d;
  d.settings.width = d.settings.height = 16;
  d.settings.spp = 256;
  d.settings.seed = 4;
  d.settings.technique = Technique::Ept;
  d.camera.cameraToWorld = Transform::lookAt(Vec3(0, 3, 0), Vec3(0.0f), Vec3(0, 0, -1));
  d.camera.horizontalAperture = d.camera.verticalAperture = 10;
  MaterialDesc grey, glow;
  glow.emission = Vec3(60.0f);
  glow.albedo = Vec3(0.0f);
  d.materials = {grey, glow};
  MeshDesc floor;
  floor.name = "floor";
  floor.mesh = makeBox(Vec3(-5, -0.1f, -5), Vec3(5, 0, 5));
  floor.material = 0;
  MeshDesc lamp;
  lamp.name = "lamp";
  lamp.mesh = makeIcosphere(2);
  lamp.xf = Transform::translate(Vec3(1.2f, 1.0f, 0)) * Transform::scale(Vec3(0.3f));  // out of view
  lamp.material = 1;
  d.meshes = {floor, lamp};
  LightDesc sky;
  sky.name = "sky";
  sky.type = LightType::Dome;
  d.lights = {sky};
  auto a = renderAdaptive(d, 0.05f);
  const Film& f = a.renderer->film();
  const long minimum = a.renderer->minAdaptiveSamples();
  int atMinimum = 0, pixels = 0;
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x) {
      ++pixels;
      atMinimum += f.samples(x, y) == minimum;
    }
  std::printf("floor pixels stopped at the minimum: %d of %d\n", atMinimum, pixels);
  EXPECT_LE(atMinimum, 4);
}
