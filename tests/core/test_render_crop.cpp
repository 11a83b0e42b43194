// Crops (RenderSettings::crop*): a tiling of an image, rendered crop by crop and merged
// (mergeTiles), is the full render bit for bit, for every technique; bad windows are
// refused by name.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/image_io.h"
#include "core/render.h"
#include "core/scene.h"
#include "test_helpers.h"

using namespace granular;
using granular::testing::sameImage;

namespace {

Image renderWith(const SceneDesc& d, float noiseThreshold = 0) {
  auto scene = Scene::build(d);
  Renderer r(*scene);
  r.setNoiseThreshold(noiseThreshold);
  EXPECT_TRUE(r.render(4));
  return r.film().toImage();
}

// A small view of the sand ball (media, so the hybrid's bundles and its roulette
// pre-render take part), odd sizes so that the tiles are uneven.
SceneDesc ballScene(Technique t) {
  SceneDesc d = granular::testing::sandBallScene(Vec3(0, 0.5f, 4), 24, 0.02f, 7);
  d.settings.width = 37;
  d.settings.height = 29;
  d.settings.spp = 8;
  d.settings.bundleSize = 4;
  d.settings.technique = t;
  return d;
}

class CropTiling : public ::testing::TestWithParam<Technique> {};

// Four uneven tiles of d's 37 × 29 image, one a single pixel wide, rendered alone and
// merged: the full render bit for bit. The full image.
Image expectTilesMergeIntoTheFullRender(SceneDesc d, float noiseThreshold) {
  const Image full = renderWith(d, noiseThreshold);
  EXPECT_EQ(full.x, 0);
  EXPECT_EQ(full.fullWidth, 0);  // a full image says so
  const std::vector<PixelWindow> windows = {{0, 20, 0, 13}, {20, 37, 0, 13}, {0, 1, 13, 29}, {1, 37, 13, 29}};
  std::vector<Image> tiles;
  for (const PixelWindow& w : windows) {
    d.settings.cropX0 = w.x0, d.settings.cropX1 = w.x1, d.settings.cropY0 = w.y0, d.settings.cropY1 = w.y1;
    tiles.push_back(renderWith(d, noiseThreshold));
    const Image& t = tiles.back();
    EXPECT_EQ(t.width, w.width());
    EXPECT_EQ(t.height, w.height());
    EXPECT_EQ(t.x, w.x0);
    EXPECT_EQ(t.y, w.y0);
    EXPECT_EQ(t.displayWidth(), 37);
    EXPECT_EQ(t.displayHeight(), 29);
  }
  EXPECT_TRUE(sameImage(mergeTiles(tiles), full));
  // The scene must have something in view for this to mean anything.
  double sum = 0;
  for (int y = 0; y < full.height; ++y)
    for (int x = 0; x < full.width; ++x) sum += full.at(x, y)[full.channelIndex("A")];
  EXPECT_GT(sum, 0.2 * full.width * full.height);
  return full;
}

}  // namespace

TEST_P(CropTiling, TilesMergeIntoTheFullRenderBitForBit) { expectTilesMergeIntoTheFullRender(ballScene(GetParam()), 0); }

TEST_P(CropTiling, UnderAdaptiveSamplingTooWhereNeighboursVouchAcrossTheTiles) {
  // A pixel stops by its neighbours too (render.h); a crop traces the ring of them around
  // it, so its pixels stop where the full film's do.
  SceneDesc d = ballScene(GetParam());
  d.settings.spp = 64;
  const Image full = expectTilesMergeIntoTheFullRender(d, 0.05f);
  const int n = full.channelIndex("sampleCount");
  float least = 1e9f, most = 0;
  for (int y = 0; y < full.height; ++y)
    for (int x = 0; x < full.width; ++x) least = std::min(least, full.at(x, y)[n]), most = std::max(most, full.at(x, y)[n]);
  EXPECT_LT(least, most);  // pixels stopped at different counts
}

INSTANTIATE_TEST_SUITE_P(Techniques, CropTiling, ::testing::Values(Technique::Ept, Technique::EptVpt, Technique::Hybrid),
                         [](const auto& info) { return std::string(info.param == Technique::Ept      ? "Ept"
                                                                   : info.param == Technique::EptVpt ? "EptVpt"
                                                                                                      : "Hybrid"); });

TEST(Crop, TheRoulettePreRenderCoversTheWholeImage) {
  SceneDesc d = ballScene(Technique::Hybrid);
  auto fullScene = Scene::build(d);
  Renderer full(*fullScene);
  ASSERT_TRUE(full.renderPass(4));
  d.settings.cropX0 = 30, d.settings.cropX1 = 37, d.settings.cropY0 = 0, d.settings.cropY1 = 3;  // a corner
  auto cropScene = Scene::build(d);
  Renderer crop(*cropScene);
  ASSERT_TRUE(crop.renderPass(4));
  EXPECT_EQ(crop.roulette().pixels, full.roulette().pixels);
  EXPECT_EQ(crop.roulette().VL, full.roulette().VL);
  EXPECT_EQ(crop.roulette().tH, full.roulette().tH);
  EXPECT_EQ(crop.roulette().pa, full.roulette().pa);
}

TEST(Crop, PreviewCoversTheCropOnly) {
  // Preview pixel (i, j) is the first sample of crop pixel (min(4i + 2, 8), min(4j + 2, 3)):
  // the full image's pixel (5 + that, 2 + that), as one sample of the whole image has it.
  SceneDesc d = ballScene(Technique::Ept);
  d.settings.spp = 1;
  auto fullScene = Scene::build(d);
  Renderer full(*fullScene);
  ASSERT_TRUE(full.renderPass(1));
  d.settings.cropX0 = 5, d.settings.cropX1 = 14, d.settings.cropY0 = 2, d.settings.cropY1 = 6;
  auto scene = Scene::build(d);
  Renderer r(*scene);
  Film preview;
  ASSERT_TRUE(r.renderPreview(4, preview));
  ASSERT_EQ(preview.width(), 3);  // ceil(9 / 4)
  ASSERT_EQ(preview.height(), 1);
  int lit = 0;
  for (int i = 0; i < 3; ++i) {
    const Vec3 p = preview.mean(i, 0), f = full.film().mean(5 + std::min(4 * i + 2, 8), 2 + 2);
    EXPECT_EQ(p.x, f.x) << i;
    EXPECT_EQ(p.y, f.y) << i;
    EXPECT_EQ(p.z, f.z) << i;
    lit += f.x > 0;
  }
  EXPECT_GT(lit, 0);
}

TEST(Crop, BadWindowsNameTheRenderCrop) {
  const std::vector<PixelWindow> bad = {{-1, 5, 0, 5}, {0, 38, 0, 5}, {5, 5, 0, 5}, {0, 5, 3, 2}, {0, 5, 0, 30}};
  for (const PixelWindow& w : bad) {
    SceneDesc d = ballScene(Technique::Ept);
    d.settings.cropX0 = w.x0, d.settings.cropX1 = w.x1, d.settings.cropY0 = w.y0, d.settings.cropY1 = w.y1;
    try {
      validateSceneDesc(d);
      ADD_FAILURE() << "accepted [" << w.x0 << ", " << w.x1 << ") x [" << w.y0 << ", " << w.y1 << ")";
    } catch (const InputError& e) {
      EXPECT_EQ(e.object(), "render");
      EXPECT_EQ(e.attribute(), "crop");
    }
  }
}

TEST(Crop, ExrKeepsTheTilesPlaceAndMergesFromFiles) {
  SceneDesc d = ballScene(Technique::Ept);
  d.settings.spp = 2;
  const Image full = renderWith(d);
  std::vector<Image> read;
  const std::vector<PixelWindow> windows = {{0, 37, 0, 10}, {0, 37, 10, 29}};
  for (size_t k = 0; k < windows.size(); ++k) {
    const PixelWindow& w = windows[k];
    d.settings.cropX0 = w.x0, d.settings.cropX1 = w.x1, d.settings.cropY0 = w.y0, d.settings.cropY1 = w.y1;
    const std::string path = ::testing::TempDir() + "crop_tile_" + std::to_string(k) + ".exr";
    writeExr(path, renderWith(d));
    read.push_back(readExr(path));
    std::remove(path.c_str());
    EXPECT_EQ(read.back().y, w.y0);
    EXPECT_EQ(read.back().displayHeight(), 29);
  }
  // OpenEXR stores channels by name, not in the film's order: compare by name.
  const Image merged = mergeTiles(read);
  ASSERT_EQ(merged.width, full.width);
  ASSERT_EQ(merged.height, full.height);
  ASSERT_EQ(merged.numChannels(), full.numChannels());
  for (int c = 0; c < full.numChannels(); ++c) {
    const int m = merged.channelIndex(full.channels[c]);
    ASSERT_GE(m, 0) << full.channels[c];
    for (int y = 0; y < full.height; ++y)
      for (int x = 0; x < full.width; ++x) ASSERT_EQ(merged.at(x, y)[m], full.at(x, y)[c]) << full.channels[c];
  }
}
