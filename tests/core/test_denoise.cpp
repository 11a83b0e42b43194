// The denoiser (denoise.h): on a synthetic noisy image its error to the clean image drops,
// a constant image stays constant, bad input is an InputError. Skipped, saying why, in a
// build without Intel Open Image Denoise.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <stdexcept>
#include <vector>

#include "core/denoise.h"
#include "core/error.h"

using namespace granular;

namespace {

constexpr int W = 64, H = 48;

std::vector<float> constantImage(float r, float g, float b) {
  std::vector<float> v(size_t(W) * H * 3);
  for (size_t i = 0; i < v.size(); i += 3) v[i] = r, v[i + 1] = g, v[i + 2] = b;
  return v;
}

// A smooth HDR image: a horizontal ramp from 0.2 to 2 times a colour.
std::vector<float> cleanImage() {
  std::vector<float> v(size_t(W) * H * 3);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const float k = 0.2f + 1.8f * float(x) / (W - 1);
      float* p = &v[(size_t(y) * W + x) * 3];
      p[0] = 0.8f * k, p[1] = 0.6f * k, p[2] = 0.4f * k;
    }
  return v;
}

double mse(const std::vector<float>& a, const std::vector<float>& b) {
  double s = 0;
  for (size_t i = 0; i < a.size(); ++i) s += double(a[i] - b[i]) * (a[i] - b[i]);
  return s / double(a.size());
}

}  // namespace

TEST(Denoise, ANoisyImagesErrorDrops) {
  if (!denoiserAvailable()) GTEST_SKIP() << denoiserUnavailableReason();
  const std::vector<float> clean = cleanImage();
  // Monte Carlo-like noise: each pixel the mean of 4 exponential samples of its value
  // (non-negative, relative standard deviation 0.5), the same draw in every channel.
  std::mt19937 rng(7);
  std::exponential_distribution<float> e(1.0f);
  std::vector<float> noisy = clean;
  for (size_t i = 0; i < noisy.size(); i += 3) {
    const float m = 0.25f * (e(rng) + e(rng) + e(rng) + e(rng));
    for (int c = 0; c < 3; ++c) noisy[i + c] *= m;
  }
  const std::vector<float> albedo = constantImage(0.8f, 0.6f, 0.4f), normal = constantImage(0, 0, 1);
  const std::vector<float> out = denoise(noisy, albedo, normal, W, H);
  ASSERT_EQ(out.size(), clean.size());
  for (float v : out) ASSERT_TRUE(std::isfinite(v));
  const double before = mse(noisy, clean), after = mse(out, clean);
  std::printf("denoise: mean squared error %.4g before, %.4g after\n", before, after);
  EXPECT_LT(after, 0.1 * before);
}

TEST(Denoise, AConstantImageStaysConstant) {
  // A Lambert surface of albedo (0.8, 0.6, 0.4) under irradiance 0.5, without noise. OIDN
  // pads the image at its edges, where a flat input comes back off by up to about half
  // its value in the corners: the image's mean, and every pixel 4 or more from an edge,
  // must keep the value.
  if (!denoiserAvailable()) GTEST_SKIP() << denoiserUnavailableReason();
  const float value[3] = {0.4f, 0.3f, 0.2f};
  const std::vector<float> color = constantImage(value[0], value[1], value[2]);
  const std::vector<float> out = denoise(color, constantImage(0.8f, 0.6f, 0.4f), constantImage(0, 0, 1), W, H);
  double sum[3] = {0, 0, 0};
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      for (int c = 0; c < 3; ++c) {
        const float v = out[(size_t(y) * W + x) * 3 + c];
        ASSERT_TRUE(std::isfinite(v));
        sum[c] += v;
        if (x >= 4 && x < W - 4 && y >= 4 && y < H - 4) EXPECT_NEAR(v, value[c], 0.02 * value[c]) << x << "," << y;
      }
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(sum[c] / (W * H), value[c], 0.01 * value[c]) << "channel " << c;
}

TEST(Denoise, BadInputIsAnInputErrorAndWithoutTheLibraryItSaysWhy) {
  std::vector<float> color = constantImage(1, 1, 1), guide = constantImage(0.5f, 0.5f, 0.5f);
  EXPECT_THROW(denoise(color, guide, std::vector<float>(5), W, H), InputError);
  EXPECT_THROW(denoise(color, guide, guide, 0, H), InputError);
  color[7] = NAN;
  EXPECT_THROW(denoise(color, guide, guide, W, H), InputError);
  if (denoiserAvailable()) {
    EXPECT_EQ(denoiserUnavailableReason(), "");
  } else {
    EXPECT_NE(denoiserUnavailableReason(), "");
    EXPECT_THROW(denoise(constantImage(1, 1, 1), guide, guide, W, H), std::runtime_error);
  }
}
