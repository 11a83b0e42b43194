// image_io.h — writing renders (EXR, PNG) and reading environment maps.
//
// Contract: Image is a float image with named, interleaved channels, row-major, top
// row first. writeExr stores every channel as float32 (ZIP); writePngSrgb stores the
// first three channels (linear Rec.709) as 8-bit sRGB through an OpenColorIO
// processor built in code, with exposure, clamping and NaN/Inf -> 0. Both writers go
// through "<path>.tmp" + rename, so a failure never leaves a partial file at <path>;
// they throw std::runtime_error naming the path. readImageRGB returns finite,
// non-negative linear RGB or throws InputError. No OIIO/OCIO types leak out of here.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "output_file.h"

namespace granular {

struct Image {
  int width = 0, height = 0;
  std::vector<std::string> channels;  // e.g. {"R","G","B","A","Z","N.X","N.Y","N.Z"}
  std::vector<float> pixels;          // width*height*channels.size(), interleaved
  // Where these pixels lie in the full image (a crop, a tile): the position of the first
  // pixel, and the full image's size (0: this image is the full image). EXR keeps them as
  // its data and display windows; a PNG holds the pixels alone.
  int x = 0, y = 0, fullWidth = 0, fullHeight = 0;
  // String metadata (name, value) for an EXR header, such as the Cryptomatte manifests
  // (cryptomatte.h); the EXR writers store them, readExr returns them, a PNG has none.
  std::vector<std::pair<std::string, std::string>> attributes;
  int displayWidth() const { return fullWidth > 0 ? fullWidth : width; }
  int displayHeight() const { return fullHeight > 0 ? fullHeight : height; }

  Image() = default;
  Image(int w, int h, std::vector<std::string> names)
      : width(w), height(h), channels(std::move(names)),
        pixels(static_cast<size_t>(w) * h * channels.size(), 0.0f) {}

  int numChannels() const { return static_cast<int>(channels.size()); }
  // Index of a named channel, or -1.
  int channelIndex(const std::string& name) const {
    for (size_t i = 0; i < channels.size(); ++i)
      if (channels[i] == name) return static_cast<int>(i);
    return -1;
  }
  float* at(int x, int y) { return pixels.data() + (static_cast<size_t>(y) * width + x) * channels.size(); }
  const float* at(int x, int y) const {
    return pixels.data() + (static_cast<size_t>(y) * width + x) * channels.size();
  }
};

// Writing: every writer below writes through an OutputFile (output_file.h): the output is
// the old file or the complete new one, whatever else writes there. Each returns true when
// the output was claimed (claimOutput) and another process has replaced it since: this
// one's image is the one that stays, and the caller says so.

// OpenEXR, float32 for every channel, ZIP compression; a crop's data window inside the
// full image's display window; the header marks it as ours (readTileExr).
bool writeExr(const std::string& path, const Image& img);

// The same with a pixel type per channel (types[i] for img.channels[i]: EXR half, float or
// uint; a UInt channel's values are int32 stored as their two's-complement bits, so -1 is
// 4294967295) and the pixel aspect ratio in the header; for render products
// (render_products.h).
enum class ExrPixelType { Half, Float, UInt };
bool writeExrTyped(const std::string& path, const Image& img, const std::vector<ExrPixelType>& types,
                   float pixelAspectRatio);

// An OpenEXR file as written by writeExr (any channels, data and display windows kept,
// string header attributes in `attributes` but OIIO's and OpenEXR's own): float32 of every channel. Throws InputError(path, "", "cannot read image: ...").
Image readExr(const std::string& path);
// The same, for a tile to merge: only an OpenEXR that writeExr wrote (another image, such
// as an 8-bit sRGB PNG, holds no linear radiance), else InputError(path, "", ...).
Image readTileExr(const std::string& path);

// The rectangle of an image tiled by `tiles` (crops of one image: the same display size and
// the same channels) as one image — the full image, or a crop of it when the tiles cover
// less — each pixel copied from the tile that holds it, so the result is bit for bit what
// those pixels were. Throws InputError("tiles", ...) naming the tile when tiles disagree on
// size or channels, lie outside the image, overlap, or leave gaps in their rectangle.
Image mergeTiles(const std::vector<Image>& tiles);

// 8-bit PNG: linear RGB * 2^exposure, sRGB-encoded, clamped to [0,1]; NaN/Inf -> 0.
// With an "A" channel the PNG is RGBA; colour is taken as premultiplied by A (as the
// renderer produces it) and un-premultiplied in linear before encoding, because PNG
// alpha is straight.
bool writePngSrgb(const std::string& path, const Image& img, float exposure = 0.0f);

// .exr -> writeExr, .png -> writePngSrgb (case-insensitive); else InputError.
bool writeImage(const std::string& path, const Image& img);

// Any OIIO-readable image as 3-channel linear RGB (grey expanded, alpha dropped), for
// lat-long environment maps. Images tagged sRGB (8-bit PNG/JPEG) are decoded to
// linear. Non-finite values become 0 (counted in *nonFinite when given: a caller that
// lights a scene with the image refuses it instead) and negatives are clamped to 0.
// Throws InputError(path, "", "cannot read image: ...").
Image readImageRGB(const std::string& path, uint64_t* nonFinite = nullptr);

// The largest image any reader here allocates: kMaxImageSide pixels a side and
// kMaxImagePixels in all (a 16k x 16k texture; 60000 x 30000 would take 21 GB as float RGB).
// A header claiming more is refused before anything is allocated.
constexpr int kMaxImageSide = 65536;
constexpr int64_t kMaxImagePixels = int64_t(1) << 28;
constexpr int kMaxImageChannels = 1024;
// "" for an image size within those limits, else "W x H with C channels, beyond the limit
// of ...", for the reader's own message.
std::string imageSizeBeyondLimits(int64_t width, int64_t height, int channels);

// The PNG's encoding of one linear value (exposure 0), through the same OCIO
// processor, clamped to [0,1] and before 8-bit quantisation.
float srgbEncode(float linear);

}  // namespace granular
