// The film's compositing AOVs (core/film.h): sample counts, the variance of each pixel's
// mean against a direct two-pass computation, the first hit's instance and aggregate ids,
// Cryptomatte's ranked coverage on synthetic samples; and on a render of an aggregate over
// a floor, coverage that sums to alpha, masks where primId and aggregateId put each object,
// and the manifests through an EXR and back.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "core/film.h"
#include "core/image_io.h"
#include "core/render.h"
#include "core/scene.h"
#include "test_helpers.h"

using namespace granular;

namespace {

using granular::testing::bitsOf;

float channel(const Image& img, int x, int y, const std::string& name) {
  const int c = img.channelIndex(name);
  EXPECT_GE(c, 0) << name;
  return c < 0 ? NAN : img.at(x, y)[c];
}

PixelSample sample(Vec3 L, bool hit = false) {
  PixelSample s;
  s.L = L;
  s.byTechnique[0] = L;
  s.hit = hit;
  return s;
}

}  // namespace

TEST(Film, SampleCountAndVarianceOfTheMeanMatchADirectComputation) {
  Film film(2, 1);
  // A deterministic sequence with an offset (the sums of squares must not cancel badly).
  std::vector<Vec3> xs;
  for (int i = 0; i < 37; ++i)
    xs.push_back(Vec3(5.0f + 0.37f * float(i % 7) - 0.11f * float(i % 3), 0.25f * float(i % 5), i % 2 ? 1.5f : 0.0f));
  for (const Vec3& x : xs) film.add(0, 0, sample(x));
  film.add(1, 0, sample(Vec3(2.0f)));
  const Image img = film.toImage();
  const double n = double(xs.size());
  const char* names[3] = {"variance.R", "variance.G", "variance.B"};
  for (int c = 0; c < 3; ++c) {
    double mean = 0, ss = 0;
    for (const Vec3& x : xs) mean += x[c];
    mean /= n;
    for (const Vec3& x : xs) ss += (x[c] - mean) * (x[c] - mean);
    const double expected = ss / (n - 1) / n;  // the unbiased variance, of the mean
    EXPECT_NEAR(channel(img, 0, 0, names[c]), expected, 1e-6 * expected + 1e-12) << names[c];
  }
  EXPECT_EQ(channel(img, 0, 0, "sampleCount"), 37.0f);
  // One sample: no estimate (0), and the count says why.
  EXPECT_EQ(channel(img, 1, 0, "sampleCount"), 1.0f);
  for (const char* v : names) EXPECT_EQ(channel(img, 1, 0, v), 0.0f);
  // A constant pixel has none.
  Film flat(1, 1);
  for (int i = 0; i < 16; ++i) flat.add(0, 0, sample(Vec3(0.3f, 0.7f, 2.0f)));
  const Image f = flat.toImage();
  for (const char* v : names) {
    EXPECT_GE(channel(f, 0, 0, v), 0.0f);
    EXPECT_LT(channel(f, 0, 0, v), 1e-12f);
  }
}

TEST(Film, IdsAreTheFirstHitsAndMinusOneWhereNothingWasHit) {
  Film film(2, 1);
  PixelSample miss = sample(Vec3(1.0f));
  miss.instanceId = 9;  // a miss's ids are never recorded
  miss.aggregateId = 9;
  film.add(0, 0, miss);
  PixelSample a = sample(Vec3(0.5f), true);
  a.primId = 4, a.instanceId = 2, a.aggregateId = 4;
  PixelSample b = sample(Vec3(0.5f), true);
  b.primId = 6, b.instanceId = -1, b.aggregateId = -1;
  film.add(0, 0, a);
  film.add(0, 0, b);
  film.add(1, 0, miss);
  const Image img = film.toImage();
  EXPECT_EQ(channel(img, 0, 0, "primId"), 4.0f);
  EXPECT_EQ(channel(img, 0, 0, "instanceId"), 2.0f);
  EXPECT_EQ(channel(img, 0, 0, "aggregateId"), 4.0f);
  EXPECT_EQ(channel(img, 1, 0, "instanceId"), -1.0f);
  EXPECT_EQ(channel(img, 1, 0, "aggregateId"), -1.0f);
  EXPECT_EQ(img.numChannels(), Film::kChannels);  // no Cryptomatte unless asked for
  EXPECT_FALSE(film.hasCryptomatte());
}

TEST(Film, CryptomatteRanksCoverageAndMissesCountNowhere) {
  Film film(1, 1, /*cryptomatte=*/true);
  const uint32_t obj[2] = {cryptomatteId("/World/A"), cryptomatteId("/World/B")};
  const uint32_t mat[2] = {cryptomatteId("/Looks/Red"), cryptomatteId("/Looks/Blue")};
  // 6 samples of A (red), 3 of B (blue), 1 miss.
  for (int i = 0; i < 10; ++i) {
    PixelSample s = sample(Vec3(1.0f), i < 9);
    const int k = i < 6 ? 0 : 1;
    s.cryptomatte[0] = obj[k];
    s.cryptomatte[1] = mat[k];
    film.add(0, 0, s);
  }
  const Image img = film.toImage();
  ASSERT_EQ(img.numChannels(), Film::kChannels + 2 * 4 * kCryptomatteLayers);
  for (auto [layer, ids] : {std::pair{std::string("CryptoObject"), obj}, std::pair{std::string("CryptoMaterial"), mat}}) {
    EXPECT_EQ(bitsOf(channel(img, 0, 0, layer + "00.R")), ids[0]) << layer;
    EXPECT_FLOAT_EQ(channel(img, 0, 0, layer + "00.G"), 0.6f);
    EXPECT_EQ(bitsOf(channel(img, 0, 0, layer + "00.B")), ids[1]) << layer;
    EXPECT_FLOAT_EQ(channel(img, 0, 0, layer + "00.A"), 0.3f);
    for (const char* rest : {"01.R", "01.G", "01.B", "01.A", "02.R", "02.G", "02.B", "02.A"})
      EXPECT_EQ(channel(img, 0, 0, layer + rest), 0.0f) << layer << rest;
  }
  EXPECT_FLOAT_EQ(channel(img, 0, 0, "A"), 0.9f);
  // filmAovs names exactly the image's channels, in order.
  std::vector<std::string> listed;
  for (const FilmAov& aov : filmAovs(true)) listed.insert(listed.end(), aov.channels.begin(), aov.channels.end());
  EXPECT_EQ(listed, img.channels);
  film.clear();
  float ranked[4 * kCryptomatteLayers];
  film.cryptomatteChannels(0, 0, CryptomatteType::Object, ranked);
  for (float v : ranked) EXPECT_EQ(v, 0.0f);
}

// An aggregate (id 1, two grain materials) over a floor (id 7, instance 4), EPT and hybrid:
// every pixel's object and material coverages sum to its alpha, a pixel wholly the ball's or
// the floor's carries that object's id with the primId, aggregateId and instanceId it
// should, and the manifests reach an EXR's header and come back.
TEST(Film, ARenderedAggregateOverAFloorDecodesToItsIdsAndAlpha) {
  for (Technique technique : {Technique::Ept, Technique::Hybrid}) {
    SceneDesc d = granular::testing::matrixBall(true);
    d.settings.spp = 4;
    d.settings.technique = technique;
    d.settings.cryptomatte = true;
    d.meshes[0].id = 7;
    d.meshes[0].instanceId = 4;
    auto scene = Scene::build(d);
    Renderer r(*scene);
    ASSERT_TRUE(r.render(4));
    const Image img = r.image();
    const uint32_t ball = cryptomatteId("ball"), floor = cryptomatteId("floor");
    const std::set<uint32_t> materials = {cryptomatteId("grain"), cryptomatteId("flint"), cryptomatteId("floor")};
    int ballPixels = 0, floorPixels = 0;
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x) {
        EXPECT_EQ(channel(img, x, y, "sampleCount"), 4.0f);
        for (const char* v : {"variance.R", "variance.G", "variance.B"}) EXPECT_GE(channel(img, x, y, v), 0.0f);
        for (std::string type : {"CryptoObject", "CryptoMaterial"}) {
          double sum = 0;
          for (const char* l : {"00", "01", "02"}) {
            sum += channel(img, x, y, type + l + ".G") + channel(img, x, y, type + l + ".A");
            for (const char* c : {".R", ".B"}) {
              const float id = channel(img, x, y, type + l + c);
              if (id == 0.0f) continue;
              if (type == "CryptoObject") EXPECT_TRUE(bitsOf(id) == ball || bitsOf(id) == floor);
              else EXPECT_TRUE(materials.count(bitsOf(id))) << std::hex << bitsOf(id);
            }
          }
          EXPECT_NEAR(sum, channel(img, x, y, "A"), 1e-6) << type << " " << x << "," << y;
        }
        if (channel(img, x, y, "CryptoObject00.G") != 1.0f) continue;
        const uint32_t id = bitsOf(channel(img, x, y, "CryptoObject00.R"));
        if (id == ball) {
          ++ballPixels;
          EXPECT_EQ(channel(img, x, y, "primId"), 1.0f);
          EXPECT_EQ(channel(img, x, y, "aggregateId"), 1.0f);
          EXPECT_EQ(channel(img, x, y, "instanceId"), -1.0f);
        } else {
          ++floorPixels;
          EXPECT_EQ(id, floor);
          EXPECT_EQ(channel(img, x, y, "primId"), 7.0f);
          EXPECT_EQ(channel(img, x, y, "aggregateId"), -1.0f);
          EXPECT_EQ(channel(img, x, y, "instanceId"), 4.0f);
          EXPECT_EQ(bitsOf(channel(img, x, y, "CryptoMaterial00.R")), cryptomatteId("floor"));
        }
      }
    EXPECT_GT(ballPixels, 100);
    EXPECT_GT(floorPixels, 20);

    std::map<std::string, std::string> attrs(img.attributes.begin(), img.attributes.end());
    EXPECT_EQ(attrs["cryptomatte/3ae39a5/name"], "CryptoObject");
    char hb[9], hf[9];
    std::snprintf(hb, sizeof hb, "%08x", ball);
    std::snprintf(hf, sizeof hf, "%08x", floor);
    EXPECT_EQ(attrs["cryptomatte/3ae39a5/manifest"], std::string("{\"ball\":\"") + hb + "\",\"floor\":\"" + hf + "\"}");
    EXPECT_EQ(attrs["cryptomatte/be359d6/name"], "CryptoMaterial");
    EXPECT_EQ(attrs.count("cryptomatte/be359d6/manifest"), 1u);

    const std::string path = (std::filesystem::temp_directory_path() /
                              ("granular_film_" + std::to_string(getpid()) + ".exr")).string();
    writeExr(path, img);
    const Image back = readExr(path);
    std::filesystem::remove(path);
    std::map<std::string, std::string> read(back.attributes.begin(), back.attributes.end());
    for (const auto& [k, v] : attrs) EXPECT_EQ(read[k], v) << k;
    // OpenEXR keeps channels in its own order: compared by name, bit for bit.
    ASSERT_EQ(back.numChannels(), img.numChannels());
    for (const std::string& name : img.channels) {
      const int a = img.channelIndex(name), b = back.channelIndex(name);
      ASSERT_GE(b, 0) << name;
      for (int y = 0; y < img.height; ++y)
        for (int x = 0; x < img.width; ++x) ASSERT_EQ(bitsOf(back.at(x, y)[b]), bitsOf(img.at(x, y)[a])) << name;
    }
  }
}
