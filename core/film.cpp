#include "film.h"

#include <cmath>

namespace granular {

Film::Film(int width, int height) : width_(width), height_(height), px_(size_t(width) * height) {}

Film::Film(const PixelWindow& w, int fullWidth, int fullHeight) : Film(w.width(), w.height()) {
  originX_ = w.x0;
  originY_ = w.y0;
  if (w.x0 != 0 || w.y0 != 0 || w.width() != fullWidth || w.height() != fullHeight) {
    fullWidth_ = fullWidth;
    fullHeight_ = fullHeight;
  }
}

void Film::clear() { std::fill(px_.begin(), px_.end(), Pixel()); }

void Film::add(int x, int y, const PixelSample& s) {
  Pixel& p = px_[idx(x, y)];
  p.sum[0] += s.L.x; p.sum[1] += s.L.y; p.sum[2] += s.L.z;
  double lum = luminance(s.L);
  p.sumLum2 += lum * lum;
  for (int t = 0; t < 4; ++t)
    for (int c = 0; c < 3; ++c) p.part[t][c] += s.byTechnique[t][c];
  ++p.n;
  if (s.hit) {
    if (p.hits == 0) p.primId = s.primId;
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

bool Film::belowNoiseThreshold(float threshold) const {
  for (int y = 0; y < height_; ++y)
    for (int x = 0; x < width_; ++x)
      if (!(stdError(x, y) <= threshold * (luminance(mean(x, y)) + 0.01f))) return false;
  return true;
}

const std::vector<std::string>& Film::channelNames() {
  static const std::vector<std::string> names = {"R",     "G",     "B",     "A",     "Z",     "N.X",
                                                 "N.Y",   "N.Z",   "ept.R", "ept.G", "ept.B", "vpt.R",
                                                 "vpt.G", "vpt.B", "da.R",  "da.G",  "da.B",  "ppt.R",
                                                 "ppt.G", "ppt.B", "primId", "albedo.R", "albedo.G",
                                                 "albedo.B"};
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
  img.pixels.assign(size_t(width_) * height_ * kChannels, 0.0f);
  for (int y = 0; y < height_; ++y)
    for (int x = 0; x < width_; ++x) pixelChannels(x, y, &img.pixels[idx(x, y) * kChannels]);
  return img;
}

}  // namespace granular
