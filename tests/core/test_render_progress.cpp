// Renderer::progressSamples: progress within a pass, readable from another thread.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <thread>
#include <vector>

#include "core/render.h"
#include "core/scene.h"
#include "core/shapes.h"

using namespace granular;

TEST(RenderProgress, GrowsWithinPassesAndEndsAtTheSampleCount) {
  SceneDesc d;
  d.settings.width = 64;
  d.settings.height = 48;
  d.settings.spp = 6;
  d.settings.technique = Technique::Ept;
  MeshDesc m;
  m.name = "ball";
  m.mesh = makeIcosphere(2);
  m.xf = Transform::translate(Vec3(0, 0, -4));
  d.meshes.push_back(m);
  LightDesc sun;
  sun.name = "sun";
  d.lights.push_back(sun);
  auto scene = Scene::build(d);
  Renderer r(*scene);
  EXPECT_EQ(r.progressSamples(), 0.0);

  std::atomic<bool> stop{false}, polling{false};
  std::vector<double> seen;
  std::thread poller([&] {
    while (!stop) {
      seen.push_back(r.progressSamples());
      polling = true;
      std::this_thread::yield();
    }
  });
  // On a loaded machine the render could end before the poller first runs.
  while (!polling) std::this_thread::yield();
  std::vector<long> atPass;
  std::vector<double> progressAtPass;
  ASSERT_TRUE(r.render(2, [&](const RenderProgress& p) {
    atPass.push_back(p.samplesDone);
    progressAtPass.push_back(r.progressSamples());
  }));
  stop = true;
  poller.join();
  EXPECT_EQ(atPass, (std::vector<long>{2, 4, 6}));
  EXPECT_EQ(progressAtPass, (std::vector<double>{2, 4, 6}));
  EXPECT_EQ(r.progressSamples(), 6.0);
  ASSERT_FALSE(seen.empty());
  for (size_t i = 0; i < seen.size(); ++i) {
    EXPECT_GE(seen[i], 0.0);
    EXPECT_LE(seen[i], 6.0);
    if (i) EXPECT_GE(seen[i], seen[i - 1]) << "progress went back at " << i;
  }
}

// ---- what an interactive host shows before a pass ends ----------------------------------

#include "test_helpers.h"

namespace {

std::unique_ptr<Scene> smallSandBall(int width, int height, int spp) {
  SceneDesc d = granular::testing::sandBallScene(Vec3(0, 0.5f, 4), 24, 0.02f, 1);
  d.settings.width = width;
  d.settings.height = height;
  d.settings.spp = spp;
  d.settings.roulette = 1;  // no pre-render: the test is about pixels, not P_a
  return Scene::build(d);
}

}  // namespace

TEST(RenderProgress, TilesCoverTheImageOnceAndHoldTheirPixelsWhenReported) {
  auto scene = smallSandBall(37, 21, 4);  // not a multiple of the 8x8 tiles
  Renderer r(*scene);
  std::vector<std::atomic<int>> covered(37 * 21);
  std::atomic<int> unfinished{0};
  ASSERT_TRUE(r.renderPass(4, nullptr, [&](int x0, int x1, int y0, int y1) {
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        covered[y * 37 + x]++;
        if (r.film().samples(x, y) != 4) unfinished++;
      }
  }));
  for (size_t i = 0; i < covered.size(); ++i) EXPECT_EQ(covered[i].load(), 1) << i;
  EXPECT_EQ(unfinished.load(), 0);
}

TEST(RenderProgress, APreviewPixelIsTheFirstBundleOfItsBlocksCentrePixel) {
  // With spp equal to the bundle size the full pass is one bundle per pixel, drawn from
  // the same per-sample streams as the preview's: the values must be equal.
  auto scene = smallSandBall(40, 30, 16);
  Renderer full(*scene);
  ASSERT_TRUE(full.renderPass(16));
  Renderer preview(*scene);
  Film coarse;
  ASSERT_TRUE(preview.renderPreview(4, coarse));
  ASSERT_EQ(coarse.width(), 10);
  ASSERT_EQ(coarse.height(), 8);  // ceil(30 / 4)
  EXPECT_EQ(preview.samplesPerPixel(), 0);  // the renderer's own film is untouched
  int lit = 0;
  for (int j = 0; j < coarse.height(); ++j)
    for (int i = 0; i < coarse.width(); ++i) {
      int x = std::min(i * 4 + 2, 39), y = std::min(j * 4 + 2, 29);
      float a[Film::kChannels], b[Film::kChannels];
      coarse.pixelChannels(i, j, a);
      full.film().pixelChannels(x, y, b);
      for (int c = 0; c < Film::kChannels; ++c) EXPECT_EQ(a[c], b[c]) << i << "," << j << " channel " << c;
      lit += a[0] > 0;
    }
  EXPECT_GT(lit, 0);
}

TEST(RenderProgress, AnUntunedPreviewDoesNotWaitForTheRoulettePreRender) {
  // A host's first image after a new view: no tuning before it (P_a 1), then the pass
  // tunes as always and draws the same image as a renderer that never previewed.
  SceneDesc d = granular::testing::sandBallScene(Vec3(0, 0.5f, 4), 24, 0.02f, 1);
  d.settings.width = 40;
  d.settings.height = 30;
  d.settings.spp = 16;
  d.settings.roulette = -1;  // tuned by the pre-render
  auto scene = Scene::build(d);
  ASSERT_TRUE(scene->hasMedia());
  Renderer r(*scene);
  Film coarse;
  ASSERT_TRUE(r.renderPreview(8, coarse, nullptr, /*tuned=*/false));
  EXPECT_EQ(r.roulette().pixels, 0);  // not tuned
  EXPECT_EQ(r.roulette().pa, 1.0f);
  int lit = 0;
  for (int j = 0; j < coarse.height(); ++j)
    for (int i = 0; i < coarse.width(); ++i) {
      const Vec3 c = coarse.mean(i, j);
      ASSERT_TRUE(std::isfinite(c.x) && std::isfinite(c.y) && std::isfinite(c.z));
      lit += c.x > 0;
    }
  EXPECT_GT(lit, 0);
  ASSERT_TRUE(r.renderPass(16));
  EXPECT_GT(r.roulette().pixels, 0);  // the pass tuned it
  Renderer plain(*scene);
  ASSERT_TRUE(plain.renderPass(16));
  EXPECT_EQ(r.roulette().pa, plain.roulette().pa);
  for (int y = 0; y < 30; ++y)
    for (int x = 0; x < 40; ++x) {
      float a[Film::kChannels], b[Film::kChannels];
      r.film().pixelChannels(x, y, a);
      plain.film().pixelChannels(x, y, b);
      for (int c = 0; c < Film::kChannels; ++c) ASSERT_EQ(a[c], b[c]) << x << "," << y << " channel " << c;
    }
}

TEST(RenderProgress, ACancelledPreviewSaysSo) {
  auto scene = smallSandBall(40, 30, 16);
  Renderer r(*scene);
  std::atomic<bool> cancel{true};
  Film coarse;
  EXPECT_FALSE(r.renderPreview(4, coarse, &cancel));
}
