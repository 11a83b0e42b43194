// texture.h — image textures on ordinary surfaces (UsdUVTexture), through OpenImageIO.
//
// Contract: a Textures looks textures up through the process's shared OIIO TextureSystem
// (its tile cache, MIP maps and filtering) for a scene; a file rewritten since an earlier
// scene opened it is read anew. add() opens a TextureDesc's file, or throws InputError naming
// desc.source and "inputs:file". Filtering must average linear values (an sRGB image
// filtered first and decoded after darkens every edge between texels), so an sRGB image is
// decoded once into a tiled, MIP-mapped linear texture in the cache directory (what maketx
// --colorconvert does), keyed by the file's path, size and time; raw images are read in
// place and MIP-mapped in memory. Without a writable cache an sRGB image is decoded after
// filtering (a warning says so). lookup() is thread-safe: bilinear within a MIP level,
// trilinear across levels, over a square footprint `width` wide in uv units (0: the finest
// level). uv follows USD's st: (0, 0) is the image's lower-left corner.
#pragma once

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "scene_desc.h"

namespace granular {

class Textures {
 public:
  Textures();
  ~Textures();
  Textures(const Textures&) = delete;
  Textures& operator=(const Textures&) = delete;

  // Prepares desc's file (above); returns the index lookup() takes. A float image with a
  // NaN or infinite texel is an InputError too.
  int add(const TextureDesc& desc);
  // rgba: texel × scale + bias. An image of one channel gives (v, v, v, 1), of two (v, v,
  // v, a), of three (r, g, b, 1).
  void lookup(int texture, float u, float v, float width, float rgba[4]) const;
  // The output the TextureDesc names: its channel, or the mean of rgb for channel -1.
  float lookupChannel(int texture, float u, float v, float width) const;
  Vec3 lookupRgb(int texture, float u, float v, float width) const;
  size_t size() const { return entries_.size(); }
  // Warnings for the front ends (e.g. sRGB decoded after filtering); empty when none.
  const std::vector<std::string>& warnings() const { return warnings_; }

 private:
  struct Entry {
    void* handle = nullptr;        // OIIO::TextureSystem::TextureHandle
    int channels = 3;              // of the file
    int wrapS = 0, wrapT = 0;      // OIIO::Tex::Wrap
    float scale[4], bias[4];
    int channel = -1;
    bool decodeAfter = false;      // sRGB decoded after filtering (no cache)
  };
  struct System;
  std::unique_ptr<System> system_;
  std::vector<Entry> entries_;
  std::vector<std::string> warnings_;
};

// The sRGB transfer function's inverse (IEC 61966-2-1): encoded value -> linear.
inline float srgbToLinear(float c) {
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}

}  // namespace granular
