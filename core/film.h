// film.h — per-pixel accumulation of radiance and AOVs.
//
// Contract: the film sums samples (double precision) per pixel; each pixel is written
// by one thread at a time, in sample order, so the result does not depend on the
// thread count. toImage() averages into channels R,G,B,A (coverage), Z (depth along the
// view axis, of the covered samples; +inf where nothing was hit), N.X,N.Y,N.Z (mean
// normal of the first hits), and ept.R.. vpt.R.. da.R.. ppt.R.. (the radiance each
// transport gathered: explicit grains, the media, diffusion, proxies; the four add up to
// R,G,B), primId (the front end's id of what the first covering sample hit; -1 where
// nothing or an unnamed object was hit) and albedo.R.. (the mean albedo of the first hits,
// the reflectance guide of a denoiser: ept.h, primaryAlbedo).
#pragma once

#include <string>
#include <vector>

#include "image_io.h"
#include "math.h"
#include "scene_desc.h"

namespace granular {

struct PixelSample {
  Vec3 L;
  Vec3 byTechnique[4];  // EPT, VPT, DA, PPT parts of L (ept.h: Transport)
  int primId = -1;
  bool hit = false;
  float depth = 0;
  Vec3 normal;
  Vec3 albedo;          // of the first hit (ept.h: primaryAlbedo)
};

class Film {
 public:
  Film() = default;
  Film(int width, int height);
  // A film of the window's pixels of a fullWidth × fullHeight image: toImage() says where
  // they lie (Image::x, y, fullWidth, fullHeight); pixel (0, 0) is the window's first.
  Film(const PixelWindow& window, int fullWidth, int fullHeight);
  int width() const { return width_; }
  int height() const { return height_; }
  void add(int x, int y, const PixelSample& s);
  long samples(int x, int y) const { return px_[idx(x, y)].n; }
  Vec3 mean(int x, int y) const;
  // Standard error of the mean of the pixel's luminance.
  float stdError(int x, int y) const;
  // The noise threshold both front ends stop at: every pixel's standard error at most
  // threshold × (its luminance + 0.01), the 0.01 keeping black pixels from never settling.
  bool belowNoiseThreshold(float threshold) const;
  Image toImage() const;
  // The channels of toImage() (kChannels of them, named by channelNames()) of one pixel.
  static constexpr int kChannels = 24;
  static const std::vector<std::string>& channelNames();
  void pixelChannels(int x, int y, float* out) const;
  void clear();

 private:
  struct Pixel {
    double sum[3] = {0, 0, 0};
    double sumLum2 = 0;
    double depth = 0, normal[3] = {0, 0, 0}, albedo[3] = {0, 0, 0};
    double part[4][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
    long n = 0, hits = 0;
    int primId = -1;     // of the first sample that hit something
  };
  size_t idx(int x, int y) const { return size_t(y) * width_ + x; }
  int width_ = 0, height_ = 0;
  int originX_ = 0, originY_ = 0, fullWidth_ = 0, fullHeight_ = 0;
  std::vector<Pixel> px_;
};

}  // namespace granular
