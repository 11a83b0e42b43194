#include "film.h"

#include <algorithm>
#include <cmath>

namespace granular {

Film::Film(int width, int height, bool cryptomatte) : width_(width), height_(height), px_(size_t(width) * height) {
  if (cryptomatte) crypto_.resize(px_.size() * kCryptomatteTypes * kCryptomatteEntries);
}

Film::Film(const PixelWindow& w, int fullWidth, int fullHeight, bool cryptomatte)
    : Film(w.width(), w.height(), cryptomatte) {
  originX_ = w.x0;
  originY_ = w.y0;
  if (w.x0 != 0 || w.y0 != 0 || w.width() != fullWidth || w.height() != fullHeight) {
    fullWidth_ = fullWidth;
    fullHeight_ = fullHeight;
  }
}

void Film::clear() {
  std::fill(px_.begin(), px_.end(), Pixel());
  std::fill(crypto_.begin(), crypto_.end(), CryptomatteEntry());
}

void Film::add(int x, int y, const PixelSample& s) {
  Pixel& p = px_[idx(x, y)];
  p.sum[0] += s.L.x; p.sum[1] += s.L.y; p.sum[2] += s.L.z;
  for (int c = 0; c < 3; ++c) p.sumSq[c] += double(s.L[c]) * double(s.L[c]);
  double lum = luminance(s.L);
  p.sumLum2 += lum * lum;
  for (int t = 0; t < 4; ++t)
    for (int c = 0; c < 3; ++c) p.part[t][c] += s.byTechnique[t][c];
  ++p.n;
  if (s.hit) {
    if (p.hits == 0) {
      p.primId = s.primId;
      p.instanceId = s.instanceId;
      p.aggregateId = s.aggregateId;
    }
    if (!crypto_.empty())
      for (int t = 0; t < kCryptomatteTypes; ++t)
        cryptomatteCount(&crypto_[(idx(x, y) * kCryptomatteTypes + t) * kCryptomatteEntries], s.cryptomatte[t]);
    ++p.hits;
    p.depth += s.depth;
    p.normal[0] += s.normal.x; p.normal[1] += s.normal.y; p.normal[2] += s.normal.z;
    p.albedo[0] += s.albedo.x; p.albedo[1] += s.albedo.y; p.albedo[2] += s.albedo.z;
  }
}

Vec3 Film::mean(int x, int y) const {
  const Pixel& p = px_[idx(x, y)];
  if (p.n == 0) return Vec3(0.0f);
  return Vec3(float(p.sum[0] / p.n), float(p.sum[1] / p.n), float(p.sum[2] / p.n));
}

float Film::stdError(int x, int y) const {
  const Pixel& p = px_[idx(x, y)];
  if (p.n < 2) return kInf;
  double m = luminance(mean(x, y));
  double var = std::max(0.0, (p.sumLum2 / p.n - m * m)) * p.n / (p.n - 1);
  return float(std::sqrt(var / p.n));
}

float Film::noiseScale(int x, int y) const { return luminance(mean(x, y)) + 0.01f; }

bool Film::pixelBelowNoiseThreshold(int x, int y, float threshold) const {
  return stdError(x, y) <= threshold * noiseScale(x, y);
}

const std::vector<std::string>& Film::channelNames() {
  static const std::vector<std::string> names = {"R",     "G",     "B",     "A",     "Z",     "N.X",
                                                 "N.Y",   "N.Z",   "ept.R", "ept.G", "ept.B", "vpt.R",
                                                 "vpt.G", "vpt.B", "da.R",  "da.G",  "da.B",  "ppt.R",
                                                 "ppt.G", "ppt.B", "primId", "albedo.R", "albedo.G",
                                                 "albedo.B", "sampleCount", "variance.R", "variance.G",
                                                 "variance.B", "instanceId", "aggregateId"};
  return names;
}

void Film::pixelChannels(int x, int y, float* o) const {
  const Pixel& p = px_[idx(x, y)];
  Vec3 c = mean(x, y);
  o[0] = c.x; o[1] = c.y; o[2] = c.z;
  o[3] = p.n ? float(double(p.hits) / p.n) : 0.0f;
  o[4] = p.hits ? float(p.depth / p.hits) : kInf;
  Vec3 n(float(p.normal[0]), float(p.normal[1]), float(p.normal[2]));
  n = p.hits ? normalize(n) : Vec3(0.0f);
  o[5] = n.x; o[6] = n.y; o[7] = n.z;
  for (int t = 0; t < 4; ++t)
    for (int ch = 0; ch < 3; ++ch) o[8 + 3 * t + ch] = p.n ? float(p.part[t][ch] / p.n) : 0.0f;
  o[20] = float(p.primId);
  for (int ch = 0; ch < 3; ++ch) o[21 + ch] = p.hits ? float(p.albedo[ch] / p.hits) : 0.0f;
  o[24] = float(p.n);
  for (int ch = 0; ch < 3; ++ch) {
    // (Σx² − (Σx)²/n) / (n − 1): the unbiased sample variance; / n: that of the mean.
    const double n = double(p.n);
    const double var = p.n >= 2 ? std::max(0.0, p.sumSq[ch] - p.sum[ch] * p.sum[ch] / n) / (n - 1) / n : 0.0;
    o[25 + ch] = float(var);
  }
  o[28] = float(p.instanceId);
  o[29] = float(p.aggregateId);
}

void Film::cryptomatteChannels(int x, int y, CryptomatteType type, float* out) const {
  if (crypto_.empty()) {
    std::fill(out, out + 4 * kCryptomatteLayers, 0.0f);
    return;
  }
  cryptomatteRanked(&crypto_[(idx(x, y) * kCryptomatteTypes + int(type)) * kCryptomatteEntries], px_[idx(x, y)].n,
                    out);
}

std::vector<FilmAov> filmAovs(bool cryptomatte) {
  const std::vector<std::string>& c = Film::channelNames();
  auto range = [&](int first, int count) { return std::vector<std::string>(c.begin() + first, c.begin() + first + count); };
  std::vector<FilmAov> aovs = {
      {"color", range(0, 4), AovValue::Float},      {"cameraDepth", range(4, 1), AovValue::Float},
      {"normal", range(5, 3), AovValue::Float},     {"ept", range(8, 3), AovValue::Float},
      {"vpt", range(11, 3), AovValue::Float},       {"da", range(14, 3), AovValue::Float},
      {"ppt", range(17, 3), AovValue::Float},       {"primId", range(20, 1), AovValue::Int},
      {"albedo", range(21, 3), AovValue::Float},    {"sampleCount", range(24, 1), AovValue::Float},
      {"variance", range(25, 3), AovValue::Float},  {"instanceId", range(28, 1), AovValue::Int},
      {"aggregateId", range(29, 1), AovValue::Int}};
  if (cryptomatte)
    for (CryptomatteType t : {CryptomatteType::Object, CryptomatteType::Material})
      for (int k = 0; k < kCryptomatteLayers; ++k) {
        const std::string layer = cryptomatteLayerName(t, k);
        aovs.push_back({layer, {layer + ".R", layer + ".G", layer + ".B", layer + ".A"}, AovValue::Float});
      }
  return aovs;
}

Image Film::toImage() const {
  Image img;
  img.width = width_;
  img.height = height_;
  img.x = originX_;
  img.y = originY_;
  img.fullWidth = fullWidth_;
  img.fullHeight = fullHeight_;
  img.channels = channelNames();
  if (hasCryptomatte())
    for (const FilmAov& aov : filmAovs(true))
      if (aov.name.rfind("Crypto", 0) == 0) img.channels.insert(img.channels.end(), aov.channels.begin(), aov.channels.end());
  const size_t nch = img.channels.size();
  img.pixels.assign(size_t(width_) * height_ * nch, 0.0f);
  for (int y = 0; y < height_; ++y)
    for (int x = 0; x < width_; ++x) {
      float* o = &img.pixels[idx(x, y) * nch];
      pixelChannels(x, y, o);
      if (!hasCryptomatte()) continue;
      cryptomatteChannels(x, y, CryptomatteType::Object, o + kChannels);
      cryptomatteChannels(x, y, CryptomatteType::Material, o + kChannels + 4 * kCryptomatteLayers);
    }
  return img;
}

}  // namespace granular
