// film.h — per-pixel accumulation of radiance and AOVs.
//
// Contract: the film sums samples (double precision) per pixel; each pixel is written
// by one thread at a time, in sample order, so the result does not depend on the
// thread count. toImage() averages into channels R,G,B,A (coverage), Z (depth along the
// view axis, of the covered samples; +inf where nothing was hit), N.X,N.Y,N.Z (mean
// normal of the first hits), and ept.R.. vpt.R.. da.R.. ppt.R.. (the radiance each
// transport gathered: explicit grains, the media, diffusion, proxies; the four add up to
// R,G,B), primId (the front end's id of what the first covering sample hit; -1 where
// nothing or an unnamed object was hit), albedo.R.. (the mean albedo of the first hits,
// the reflectance guide of a denoiser: ept.h, primaryAlbedo), sampleCount (the pixel's
// samples n, dropped non-finite ones included: render.h), variance.R/G/B (the estimated
// variance of the pixel's mean of R, G and B: the unbiased sample variance of its
// samples' values divided by n, i.e. the squared standard error of R, G, B; 0 below two
// samples), instanceId (the front end's instance index of the object the first covering
// sample hit, -1 where it is not instanced: MeshDesc::instanceId) and aggregateId (the
// front end's id of the aggregate whose grain, boundary or medium that sample hit, -1
// for anything else). Ids are integers held exactly in float channels.
//
// Cryptomatte (cryptomatte.h): a film made with cryptomatte keeps per pixel and type
// (object, material) a table of kCryptomatteEntries ids with their sample counts, the ids
// of each sample's first hit (Scene::identify; misses count nowhere, so each type's
// coverages sum to A). toImage() then appends the layers CryptoObject00.. and
// CryptoMaterial00.. (channels <layer>.R/G/B/A) after the fixed channels; the ids a full
// table leaves out are lost to that pixel (its coverages sum to less than A).
#pragma once

#include <string>
#include <vector>

#include "cryptomatte.h"
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
  int instanceId = -1, aggregateId = -1;  // of the first hit (Scene::identify)
  uint32_t cryptomatte[kCryptomatteTypes] = {0, 0};  // its object's and material's ids
};

// An AOV of the film by name, as the front ends offer it: its channels in toImage() and
// the kind of value its channels hold (ids: integers in float channels).
enum class AovValue { Float, Int };
struct FilmAov {
  std::string name;  // color, cameraDepth, normal, ept, vpt, da, ppt, primId, albedo,
                     // sampleCount, variance, instanceId, aggregateId, CryptoObject00, ...
  std::vector<std::string> channels;
  AovValue value = AovValue::Float;
};
// Every AOV of toImage(), in channel order: the fixed ones, then with cryptomatte the
// Cryptomatte layers (RGBA, Float).
std::vector<FilmAov> filmAovs(bool cryptomatte);

class Film {
 public:
  Film() = default;
  // cryptomatte: keep the Cryptomatte tables (see above; off: no memory for them).
  Film(int width, int height, bool cryptomatte = false);
  // A film of the window's pixels of a fullWidth × fullHeight image: toImage() says where
  // they lie (Image::x, y, fullWidth, fullHeight); pixel (0, 0) is the window's first.
  Film(const PixelWindow& window, int fullWidth, int fullHeight, bool cryptomatte = false);
  int width() const { return width_; }
  int height() const { return height_; }
  void add(int x, int y, const PixelSample& s);
  long samples(int x, int y) const { return px_[idx(x, y)].n; }
  Vec3 mean(int x, int y) const;
  // Standard error of the mean of the pixel's luminance.
  float stdError(int x, int y) const;
  // What the noise threshold is relative to: the pixel's luminance + 0.01, the 0.01 keeping
  // black pixels from never settling.
  float noiseScale(int x, int y) const;
  // The pixel's own part of the noise threshold both front ends stop at: its standard error
  // at most threshold × noiseScale (false below two samples); adaptive sampling (render.h)
  // adds its neighbours' part.
  bool pixelBelowNoiseThreshold(int x, int y, float threshold) const;
  Image toImage() const;
  // The channels of toImage() (kChannels of them, named by channelNames()) of one pixel.
  static constexpr int kChannels = 30;
  static const std::vector<std::string>& channelNames();
  void pixelChannels(int x, int y, float* out) const;
  // Cryptomatte: whether the film keeps it, and one pixel's ranked layers of a type
  // (kCryptomatteLayers RGBA values; zeros without it).
  bool hasCryptomatte() const { return !crypto_.empty(); }
  void cryptomatteChannels(int x, int y, CryptomatteType type, float* out) const;
  void clear();

 private:
  struct Pixel {
    double sum[3] = {0, 0, 0};
    double sumSq[3] = {0, 0, 0};  // per channel: variance.R/G/B
    double sumLum2 = 0;
    double depth = 0, normal[3] = {0, 0, 0}, albedo[3] = {0, 0, 0};
    double part[4][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
    long n = 0, hits = 0;
    int primId = -1;     // of the first sample that hit something
    int instanceId = -1, aggregateId = -1;  // likewise
  };
  size_t idx(int x, int y) const { return size_t(y) * width_ + x; }
  int width_ = 0, height_ = 0;
  int originX_ = 0, originY_ = 0, fullWidth_ = 0, fullHeight_ = 0;
  std::vector<Pixel> px_;
  // kCryptomatteTypes tables of kCryptomatteEntries per pixel, or empty.
  std::vector<CryptomatteEntry> crypto_;
};

}  // namespace granular
