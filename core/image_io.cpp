// image_io.cpp — OIIO for files, OCIO (built in code) for the display encoding.
#include "image_io.h"

#include <OpenColorIO/OpenColorIO.h>
#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/half.h>
#include <OpenImageIO/imageio.h>
#include <OpenImageIO/strutil.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <set>
#include <stdexcept>

#include "error.h"
#include "output_file.h"

namespace OCIO = OCIO_NAMESPACE;

namespace granular {
namespace {

// The OpenEXR header attribute that marks our own images.
constexpr const char* kWriterAttribute = "granular:writer";
constexpr const char* kWriterName = "granular";

// sRGB piecewise curve: ExponentWithLinear with gamma 2.4 / offset 0.055 is the
// sRGB EOTF (decode) forward, the encoding inverse. OCIO 2.1 has no built-in
// configs, so the transform is assembled here on a raw config.
OCIO::ExponentWithLinearTransformRcPtr srgbCurve(OCIO::TransformDirection dir) {
  auto curve = OCIO::ExponentWithLinearTransform::Create();
  // Alpha gets the same curve (a 1/0 pair is degenerate); it is never used:
  // only RGB buffers are processed.
  const double gamma[4] = {2.4, 2.4, 2.4, 2.4};
  const double offset[4] = {0.055, 0.055, 0.055, 0.055};
  curve->setGamma(gamma);
  curve->setOffset(offset);
  curve->setDirection(dir);
  return curve;
}

OCIO::ConstCPUProcessorRcPtr cpuProcessor(const OCIO::ConstTransformRcPtr& t) {
  // Lossless only: the default flags may swap pow() for a fast approximation.
  return OCIO::Config::CreateRaw()->getProcessor(t)->getOptimizedCPUProcessor(
      OCIO::BIT_DEPTH_F32, OCIO::BIT_DEPTH_F32, OCIO::OPTIMIZATION_LOSSLESS);
}

// Linear -> scale by 2^exposure -> sRGB encoding.
OCIO::ConstCPUProcessorRcPtr makeEncoder(float exposure) {
  auto group = OCIO::GroupTransform::Create();
  const double s = std::exp2(static_cast<double>(exposure));
  if (s != 1.0) {
    auto scale = OCIO::MatrixTransform::Create();
    const double m[16] = {s, 0, 0, 0, 0, s, 0, 0, 0, 0, s, 0, 0, 0, 0, 1};
    scale->setMatrix(m);
    group->appendTransform(scale);
  }
  group->appendTransform(srgbCurve(OCIO::TRANSFORM_DIR_INVERSE));
  return cpuProcessor(group);
}

const OCIO::CPUProcessor& defaultEncoder() {
  static const OCIO::ConstCPUProcessorRcPtr p = makeEncoder(0.0f);
  return *p;
}

const OCIO::CPUProcessor& srgbDecoder() {
  static const OCIO::ConstCPUProcessorRcPtr p = cpuProcessor(srgbCurve(OCIO::TRANSFORM_DIR_FORWARD));
  return *p;
}

float finiteOrZero(float v) { return std::isfinite(v) ? v : 0.0f; }

// Encodes n interleaved RGB triples in place to display values in [0,1]. Non-finite
// input is zeroed before OCIO (NaN must not reach the curve) and the result is
// checked again, so nothing non-finite can come out.
void encodeRGB(const OCIO::CPUProcessor& proc, float* rgb, size_t n) {
  for (size_t i = 0; i < 3 * n; ++i) rgb[i] = finiteOrZero(rgb[i]);
  if (n > 0) {
    OCIO::PackedImageDesc desc(rgb, static_cast<long>(n), 1, 3);
    proc.apply(desc);
  }
  for (size_t i = 0; i < 3 * n; ++i) rgb[i] = std::clamp(finiteOrZero(rgb[i]), 0.0f, 1.0f);
}

uint8_t toByte(float v01) { return static_cast<uint8_t>(std::lround(v01 * 255.0f)); }

std::string failure(const std::string& path, const std::string& why) {
  return "cannot write image " + path + ": " + (why.empty() ? "unknown error" : why);
}

void checkShape(const std::string& path, const Image& img, int minChannels) {
  if (img.width <= 0 || img.height <= 0)
    throw std::runtime_error(failure(path, str("empty image ", img.width, "x", img.height)));
  if (img.numChannels() < minChannels)
    throw std::runtime_error(failure(path, str("needs at least ", minChannels, " channels, has ", img.numChannels())));
  const size_t expected = static_cast<size_t>(img.width) * img.height * img.channels.size();
  if (img.pixels.size() != expected)
    throw std::runtime_error(
        failure(path, str("pixel buffer holds ", img.pixels.size(), " floats, expected ", expected)));
}

// Writes through an OutputFile (output_file.h): the output is the old file or the complete
// new one, whatever else writes there. The plugin is chosen by format name because the
// temporary name says nothing; it writes through the temporary's own stream where it can,
// else by the temporary's name, which only this process knows. True when another process
// replaced a claimed output meanwhile.
bool writeAtomically(const std::string& path, const char* format, const OIIO::ImageSpec& spec, OIIO::TypeDesc type,
                     const void* data) {
  OutputFile file(path);
  auto out = OIIO::ImageOutput::create(format);
  if (!out) throw std::runtime_error(failure(path, OIIO::geterror()));
  std::unique_ptr<OIIO::Filesystem::IOFile> proxy;
  if (out->supports("ioproxy")) {
    proxy.reset(new OIIO::Filesystem::IOFile(file.stream(), OIIO::Filesystem::IOProxy::Write));
    out->set_ioproxy(proxy.get());
  } else {
    file.close();
  }
  auto fail = [&](const std::string& why) {
    out.reset();  // closes the handle before the temporary goes
    throw std::runtime_error(failure(path, why));
  };
  if (!out->open(file.temporaryPath(), spec)) fail(out->geterror());
  if (!out->write_image(type, data)) fail(out->geterror());
  if (!out->close()) fail(out->geterror());
  out.reset();
  proxy.reset();
  return file.commit();
}

std::string lowerExtension(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  const size_t dot = path.find_last_of('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  std::string ext = path.substr(dot + 1);
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

// An image file open for reading, of a usable flat 2-D shape; InputError naming the path.
OIIO::ImageInput::unique_ptr openFlatImage(const std::string& path) {
  auto in = OIIO::ImageInput::open(path);
  if (!in) {
    std::string why = OIIO::geterror();
    throw InputError(path, "", "cannot read image: " + (why.empty() ? std::string("unknown error") : why));
  }
  const OIIO::ImageSpec& spec = in->spec();
  if (spec.deep) throw InputError(path, "", "cannot read image: deep images are not supported");
  if (spec.width <= 0 || spec.height <= 0 || spec.depth > 1 || spec.nchannels <= 0)
    throw InputError(path, "", str("cannot read image: unusable size ", spec.width, "x", spec.height, "x",
                                   spec.depth, " with ", spec.nchannels, " channels"));
  const std::string tooLarge = imageSizeBeyondLimits(spec.width, spec.height, spec.nchannels);
  if (!tooLarge.empty()) throw InputError(path, "", "cannot read image: its header says " + tooLarge);
  return in;
}

}  // namespace

namespace {

// Image::attributes into an EXR header; the writers' own attributes are not overridden.
void addStringAttributes(const std::string& path, const Image& img, OIIO::ImageSpec& spec) {
  for (const auto& [name, value] : img.attributes) {
    if (name.empty() || name == kWriterAttribute || name == "compression" || name.rfind("oiio:", 0) == 0 ||
        name.rfind("openexr:", 0) == 0)
      throw std::runtime_error(failure(path, str("header attribute '", name, "' is reserved or empty")));
    spec.attribute(name, value);
  }
}

// The string attributes a writer added (addStringAttributes), without OIIO's and OpenEXR's.
std::vector<std::pair<std::string, std::string>> stringAttributes(const OIIO::ImageSpec& spec) {
  std::vector<std::pair<std::string, std::string>> out;
  for (const OIIO::ParamValue& p : spec.extra_attribs) {
    const std::string name = p.name().string();
    if (p.type() != OIIO::TypeDesc::STRING || name == kWriterAttribute || name == "compression" ||
        name.rfind("oiio:", 0) == 0 || name.rfind("openexr:", 0) == 0)
      continue;
    out.emplace_back(name, p.get_string());
  }
  return out;
}

}  // namespace

namespace {

// What an EXR needs of an image beyond its shape: unique, non-empty channel names and a
// data window inside the display window.
void checkExrChannelsAndWindow(const std::string& path, const Image& img) {
  std::set<std::string> seen;
  for (const std::string& name : img.channels)
    if (name.empty() || !seen.insert(name).second)
      throw std::runtime_error(failure(path, "channel names must be unique and non-empty"));
  if (img.x < 0 || img.y < 0 || img.x + img.width > img.displayWidth() || img.y + img.height > img.displayHeight())
    throw std::runtime_error(failure(path, str("pixels at (", img.x, ", ", img.y, ") of size ", img.width, "x", img.height,
                                               " lie outside the ", img.displayWidth(), "x", img.displayHeight(), " image")));
}

}  // namespace

namespace {

// The header every EXR of ours has: channels, data and display windows, alpha and depth,
// compression, our writer mark (what merge checks a tile for) and the string metadata.
OIIO::ImageSpec exrSpec(const std::string& path, const Image& img) {
  checkShape(path, img, 1);
  checkExrChannelsAndWindow(path, img);
  OIIO::ImageSpec spec(img.width, img.height, img.numChannels(), OIIO::TypeDesc::FLOAT);
  spec.channelnames = img.channels;
  spec.x = img.x;
  spec.y = img.y;
  spec.full_x = spec.full_y = 0;
  spec.full_width = img.displayWidth();
  spec.full_height = img.displayHeight();
  // The constructor guesses alpha at index 3; only a channel named A is alpha.
  spec.alpha_channel = img.channelIndex("A");
  spec.z_channel = img.channelIndex("Z");
  spec.attribute("compression", "zip");
  spec.attribute(kWriterAttribute, kWriterName);
  addStringAttributes(path, img, spec);
  return spec;
}

}  // namespace

bool writeExr(const std::string& path, const Image& img) {
  const OIIO::ImageSpec spec = exrSpec(path, img);
  return writeAtomically(path, "openexr", spec, OIIO::TypeDesc::FLOAT, img.pixels.data());
}

bool writeExrTyped(const std::string& path, const Image& img, const std::vector<ExrPixelType>& types,
                   float pixelAspectRatio) {
  OIIO::ImageSpec spec = exrSpec(path, img);
  if (types.size() != img.channels.size())
    throw std::runtime_error(failure(path, str(types.size(), " pixel types for ", img.channels.size(), " channels")));
  if (!(std::isfinite(pixelAspectRatio) && pixelAspectRatio > 0))
    throw std::runtime_error(failure(path, str("pixel aspect ratio ", pixelAspectRatio, " is not finite and > 0")));
  spec.channelformats.clear();
  size_t pixelBytes = 0;
  for (ExrPixelType t : types) {
    const OIIO::TypeDesc d = t == ExrPixelType::Half    ? OIIO::TypeDesc::HALF
                             : t == ExrPixelType::UInt ? OIIO::TypeDesc::UINT
                                                       : OIIO::TypeDesc::FLOAT;
    spec.channelformats.push_back(d);
    pixelBytes += d.size();
  }
  spec.attribute("PixelAspectRatio", pixelAspectRatio);
  // The file's own per-channel layout, converted here: OIIO's conversion would clamp a
  // negative id to 0 on its way to uint.
  const size_t n = size_t(img.width) * img.height, nch = img.channels.size();
  std::vector<unsigned char> native(n * pixelBytes);
  unsigned char* out = native.data();
  for (size_t i = 0; i < n; ++i)
    for (size_t c = 0; c < nch; ++c) {
      const float v = img.pixels[i * nch + c];
      if (types[c] == ExrPixelType::Half) {
        const half h(v);
        std::memcpy(out, &h, sizeof h);
        out += sizeof h;
      } else if (types[c] == ExrPixelType::UInt) {
        // Ids are whole numbers the film wrote; anything else is a bug upstream, not a 0.
        if (!std::isfinite(v) || std::fabs(v) >= 2147483648.0f)
          throw std::runtime_error(failure(path, str("channel ", img.channels[c], " holds ", v, ", not an integer id")));
        const int32_t k = int32_t(std::nearbyint(double(v)));
        uint32_t u;
        std::memcpy(&u, &k, sizeof u);
        std::memcpy(out, &u, sizeof u);
        out += sizeof u;
      } else {
        std::memcpy(out, &v, sizeof v);
        out += sizeof v;
      }
    }
  return writeAtomically(path, "openexr", spec, OIIO::TypeDesc::UNKNOWN, native.data());
}

bool writePngSrgb(const std::string& path, const Image& img, float exposure) {
  checkShape(path, img, 3);
  if (!std::isfinite(exposure)) throw InputError(path, "exposure", str(exposure, " is not finite"));

  const size_t n = static_cast<size_t>(img.width) * img.height;
  const size_t nch = img.channels.size();
  const int alphaIndex = img.channelIndex("A");
  std::vector<float> rgb(3 * n), alpha(alphaIndex >= 0 ? n : 0);
  for (size_t i = 0; i < n; ++i) {
    const float* p = img.pixels.data() + i * nch;
    float r = finiteOrZero(p[0]), g = finiteOrZero(p[1]), b = finiteOrZero(p[2]);
    if (alphaIndex >= 0) {
      const float a = std::clamp(finiteOrZero(p[alphaIndex]), 0.0f, 1.0f);
      alpha[i] = a;
      // Un-premultiply in linear: PNG alpha is straight. With a == 0 there is no
      // coverage to divide by; the colour is kept as it is.
      if (a > 0.0f) r /= a, g /= a, b /= a;
    }
    rgb[3 * i] = r, rgb[3 * i + 1] = g, rgb[3 * i + 2] = b;
  }

  try {
    if (exposure == 0.0f) {
      encodeRGB(defaultEncoder(), rgb.data(), n);
    } else {
      auto proc = makeEncoder(exposure);
      encodeRGB(*proc, rgb.data(), n);
    }
  } catch (const OCIO::Exception& e) {
    throw std::runtime_error(failure(path, str("OpenColorIO: ", e.what())));
  }

  const int outCh = alphaIndex >= 0 ? 4 : 3;
  std::vector<uint8_t> bytes(n * outCh);
  for (size_t i = 0; i < n; ++i) {
    for (int c = 0; c < 3; ++c) bytes[i * outCh + c] = toByte(rgb[3 * i + c]);
    if (outCh == 4) bytes[i * outCh + 3] = toByte(alpha[i]);
  }

  OIIO::ImageSpec spec(img.width, img.height, outCh, OIIO::TypeDesc::UINT8);
  spec.alpha_channel = outCh == 4 ? 3 : -1;
  spec.attribute("oiio:ColorSpace", "sRGB");
  // The bytes are final: stop OIIO from un-premultiplying them a second time.
  spec.attribute("oiio:UnassociatedAlpha", 1);
  return writeAtomically(path, "png", spec, OIIO::TypeDesc::UINT8, bytes.data());
}

bool writeImage(const std::string& path, const Image& img) {
  const std::string ext = lowerExtension(path);
  if (ext == "exr") return writeExr(path, img);
  if (ext == "png") return writePngSrgb(path, img);
  throw InputError(path, "", "unsupported image format '" + ext + "' (use .exr or .png)");
}

Image readImageRGB(const std::string& path, uint64_t* nonFinite) {
  auto in = openFlatImage(path);
  const OIIO::ImageSpec spec = in->spec();

  const size_t n = static_cast<size_t>(spec.width) * spec.height;
  const int nch = spec.nchannels;
  std::vector<float> all(n * nch);
  if (!in->read_image(0, 0, 0, nch, OIIO::TypeDesc::FLOAT, all.data()))
    throw InputError(path, "", "cannot read image: " + in->geterror());
  in->close();

  // Channel picks: named R,G,B when present, else the first three, else grey.
  int src[3] = {0, 0, 0};
  auto named = [&](const char* name) {
    for (int c = 0; c < nch; ++c)
      if (spec.channel_name(c) == name) return c;
    return -1;
  };
  const int r = named("R"), g = named("G"), b = named("B");
  if (r >= 0 && g >= 0 && b >= 0) src[0] = r, src[1] = g, src[2] = b;
  else if (nch >= 3) src[0] = 0, src[1] = 1, src[2] = 2;

  Image img(spec.width, spec.height, {"R", "G", "B"});
  uint64_t bad = 0;
  for (size_t i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) {
      const float v = all[i * nch + src[c]];
      bad += !std::isfinite(v);
      img.pixels[3 * i + c] = finiteOrZero(v);
    }
  if (nonFinite) *nonFinite = bad;

  // 8-bit PNG/JPEG hold sRGB-encoded values; lighting needs linear radiance.
  if (OIIO::Strutil::iequals(spec.get_string_attribute("oiio:ColorSpace"), "sRGB")) {
    try {
      OCIO::PackedImageDesc desc(img.pixels.data(), static_cast<long>(n), 1, 3);
      srgbDecoder().apply(desc);
    } catch (const OCIO::Exception& e) {
      throw InputError(path, "", str("cannot read image: OpenColorIO: ", e.what()));
    }
  }
  for (float& v : img.pixels) v = (std::isfinite(v) && v > 0.0f) ? v : 0.0f;  // also -0 -> +0
  return img;
}

float srgbEncode(float linear) {
  float rgb[3] = {linear, linear, linear};
  encodeRGB(defaultEncoder(), rgb, 1);
  return rgb[0];
}

std::string imageSizeBeyondLimits(int64_t width, int64_t height, int channels) {
  if (width <= kMaxImageSide && height <= kMaxImageSide && width * height <= kMaxImagePixels &&
      channels <= kMaxImageChannels)
    return "";
  return str(width, "x", height, " with ", channels, " channels, beyond the limit of ", kMaxImageSide, " pixels a side, ",
             kMaxImagePixels, " pixels in all and ", kMaxImageChannels, " channels");
}

namespace {

// readExr, and with ours: readTileExr.
Image readExrFile(const std::string& path, bool ours) {
  auto in = openFlatImage(path);
  const OIIO::ImageSpec spec = in->spec();
  if (ours && (std::string(in->format_name()) != "openexr" || spec.get_string_attribute(kWriterAttribute) != kWriterName))
    throw InputError(path, "", str("is not a tile of granular render (an OpenEXR it wrote, read as ",
                                   in->format_name(), "): merge joins only those, whose pixels are linear radiance"));
  if (spec.full_x != 0 || spec.full_y != 0 || spec.x < 0 || spec.y < 0 || spec.x + spec.width > spec.full_width ||
      spec.y + spec.height > spec.full_height)
    throw InputError(path, "", str("cannot read image: data window at (", spec.x, ", ", spec.y, ") of size ", spec.width,
                                   "x", spec.height, " is not inside a display window at the origin (", spec.full_x,
                                   ", ", spec.full_y, ", ", spec.full_width, "x", spec.full_height, ")"));
  Image img(spec.width, spec.height, spec.channelnames);
  img.x = spec.x;
  img.y = spec.y;
  if (spec.full_width != spec.width || spec.full_height != spec.height || spec.x || spec.y) {
    img.fullWidth = spec.full_width;
    img.fullHeight = spec.full_height;
  }
  if (!in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, img.pixels.data()))
    throw InputError(path, "", "cannot read image: " + in->geterror());
  in->close();
  img.attributes = stringAttributes(spec);
  return img;
}

}  // namespace

Image readExr(const std::string& path) { return readExrFile(path, false); }

Image readTileExr(const std::string& path) { return readExrFile(path, true); }

Image mergeTiles(const std::vector<Image>& tiles) {
  if (tiles.empty()) throw InputError("tiles", "", "no tiles to merge");
  const Image& first = tiles.front();
  const int W = first.displayWidth(), H = first.displayHeight();
  auto where = [](size_t k, const Image& t) {
    return str("tile ", k, " (", t.width, "x", t.height, " at ", t.x, ", ", t.y, ")");
  };
  const size_t nch = first.channels.size();
  int x0 = W, x1 = 0, y0 = H, y1 = 0;  // the rectangle the tiles cover
  for (size_t k = 0; k < tiles.size(); ++k) {
    const Image& t = tiles[k];
    if (t.displayWidth() != W || t.displayHeight() != H)
      throw InputError("tiles", "", str(where(k, t), " belongs to a ", t.displayWidth(), "x", t.displayHeight(),
                                        " image, tile 0 to a ", W, "x", H, " one"));
    if (t.channels != first.channels) throw InputError("tiles", "", str(where(k, t), " has other channels than tile 0"));
    if (t.width <= 0 || t.height <= 0 || t.x < 0 || t.y < 0 || t.x + t.width > W || t.y + t.height > H ||
        t.pixels.size() != size_t(t.width) * t.height * nch)
      throw InputError("tiles", "", str(where(k, t), " does not lie inside the ", W, "x", H, " image"));
    x0 = std::min(x0, t.x), x1 = std::max(x1, t.x + t.width);
    y0 = std::min(y0, t.y), y1 = std::max(y1, t.y + t.height);
  }
  Image out(x1 - x0, y1 - y0, first.channels);
  out.attributes = first.attributes;  // one render's tiles: the same metadata
  out.x = x0, out.y = y0;
  if (x0 != 0 || y0 != 0 || x1 != W || y1 != H) out.fullWidth = W, out.fullHeight = H;
  // Which tile wrote each pixel (-1: none): overlaps and gaps are errors, not averages.
  std::vector<int> owner(size_t(out.width) * out.height, -1);
  for (size_t k = 0; k < tiles.size(); ++k) {
    const Image& t = tiles[k];
    for (int y = 0; y < t.height; ++y) {
      for (int x = 0; x < t.width; ++x) {
        int& o = owner[size_t(t.y + y - y0) * out.width + (t.x + x - x0)];
        if (o >= 0) throw InputError("tiles", "", str(where(k, t), " overlaps tile ", o, " at pixel (", t.x + x, ", ", t.y + y, ")"));
        o = int(k);
      }
      std::copy_n(t.at(0, y), size_t(t.width) * nch, out.at(t.x - x0, t.y + y - y0));
    }
  }
  for (size_t i = 0; i < owner.size(); ++i)
    if (owner[i] < 0)
      throw InputError("tiles", "", str("pixel (", x0 + int(i % out.width), ", ", y0 + int(i / out.width), ") of the ",
                                        out.width, "x", out.height, " rectangle at (", x0, ", ", y0, ") the tiles span is in no tile"));
  return out;
}

}  // namespace granular
