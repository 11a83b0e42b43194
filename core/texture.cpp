#include "texture.h"

#include <unistd.h>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>
#include <OpenImageIO/texture.h>

#include <cstdio>
#include <functional>
#include <map>
#include <mutex>

#include "cache.h"
#include "error.h"
#include "image_io.h"
#include "rng.h"

namespace granular {

namespace OIIO = OIIO_NAMESPACE;

// The process's one shared TextureSystem (OIIO's recommended use: one tile cache for every
// scene). Never destroyed: OIIO 2.4's TextureSystem::destroy deletes through the wrong type
// (AddressSanitizer: new-delete-type-mismatch inside libOpenImageIO), and a process keeps
// one anyway. A file rewritten between scenes is invalidated by its version (FileVersion).
struct Textures::System {
  OIIO::TextureSystem* ts = nullptr;
  System() {
    static OIIO::TextureSystem* shared = [] {
      OIIO::TextureSystem* t = OIIO::TextureSystem::create(true);
      t->attribute("automip", 1);  // MIP-map untiled raw images in memory
      t->attribute("max_memory_MB", 1024.0f);
      return t;
    }();
    ts = shared;
  }
  // The number of texel values of `file` that are not finite (0 for integer formats),
  // known per file version: a file is scanned once, not once per scene (a Hydra host
  // rebuilds the scene on every edit), and one rewritten since it was last seen is dropped
  // from the cache and scanned anew.
  uint64_t nonFiniteTexels(const std::string& file, bool floatingPoint) {
    struct Record {
      FileVersion version;
      uint64_t nonFinite = 0;
    };
    static std::mutex mutex;
    static std::map<std::string, Record> seen;
    const FileVersion version = fileVersion(file);
    if (!version.exists) return 0;  // the open that follows reports it
    std::lock_guard<std::mutex> lock(mutex);
    auto it = seen.find(file);
    if (it != seen.end() && it->second.version == version) return it->second.nonFinite;
    if (it != seen.end()) ts->invalidate(OIIO::ustring(file), true);
    Record r{version, 0};
    if (floatingPoint) {
      const OIIO::ImageBufAlgo::PixelStats stats = OIIO::ImageBufAlgo::computePixelStats(OIIO::ImageBuf(file));
      for (size_t c = 0; c < stats.nancount.size(); ++c) r.nonFinite += stats.nancount[c] + stats.infcount[c];
    }
    seen[file] = r;
    return r.nonFinite;
  }
};

namespace {

int oiioWrap(TextureWrap w) {
  switch (w) {
    case TextureWrap::Black: return int(OIIO::Tex::Wrap::Black);
    case TextureWrap::Clamp: return int(OIIO::Tex::Wrap::Clamp);
    case TextureWrap::Repeat: return int(OIIO::Tex::Wrap::Periodic);
    case TextureWrap::Mirror: return int(OIIO::Tex::Wrap::Mirror);
    case TextureWrap::UseMetadata: break;
  }
  return int(OIIO::Tex::Wrap::Default);  // the file's own "wrapmodes", else black
}

// Decodes the colour channels (not alpha) of a float image from sRGB in place.
void decodeSrgb(OIIO::ImageBuf& buf) {
  const int n = buf.nchannels();
  const int colour = (n == 1 || n == 2) ? 1 : std::min(n, 3);
  for (OIIO::ImageBuf::Iterator<float> it(buf); !it.done(); ++it)
    for (int c = 0; c < colour; ++c) it[c] = srgbToLinear(it[c]);
}

// The cached linear texture of an sRGB image: "" when none can be written.
std::string linearCopy(const std::string& file, const std::string& source) {
  const std::string dir = cacheDirectory();
  const FileVersion v = fileVersion(file);
  if (dir.empty() || !v.exists) return "";
  char key[64];
  std::snprintf(key, sizeof key, "%016llx",
                (unsigned long long)hashInts(hashInts(std::hash<std::string>()(file), v.device, v.inode, v.size),
                                             uint64_t(v.mtimeNs), uint64_t(v.ctimeNs)));
  const std::string out = dir + "/texture-" + key + ".exr";
  if (access(out.c_str(), R_OK) == 0) return out;
  OIIO::ImageSpec config;
  config.attribute("oiio:UnassociatedAlpha", 1);  // PNG colour stays as authored (USD's meaning)
  OIIO::ImageBuf in(file, 0, 0, nullptr, &config);
  OIIO::ImageBuf linear;
  if (!in.read(0, 0, true, OIIO::TypeFloat) || !linear.copy(in, OIIO::TypeFloat))
    throw InputError(source, "inputs:file", str("\"", file, "\" cannot be read: ", in.geterror()));
  decodeSrgb(linear);
  OIIO::ImageSpec tx;
  tx.tile_width = tx.tile_height = 64;
  tx.format = OIIO::TypeHalf;  // 8-bit sources: half keeps every level distinct
  tx.attribute("maketx:filtername", "box");
  const std::string tmp = dir + "/tmp-" + std::to_string(getpid()) + "-" + key + ".exr";
  if (!OIIO::ImageBufAlgo::make_texture(OIIO::ImageBufAlgo::MakeTxTexture, linear, tmp, tx)) {
    std::remove(tmp.c_str());
    return "";
  }
  if (std::rename(tmp.c_str(), out.c_str()) != 0) {
    std::remove(tmp.c_str());
    return "";
  }
  return out;
}

}  // namespace

Textures::Textures() : system_(new System()) {}
Textures::~Textures() = default;

int Textures::add(const TextureDesc& desc) {
  if (desc.file.empty()) throw InputError(desc.source, "inputs:file", "no file is given");
  auto input = OIIO::ImageInput::open(desc.file);
  if (!input)
    throw InputError(desc.source, "inputs:file", str("\"", desc.file, "\" cannot be opened: ", OIIO::geterror()));
  const OIIO::ImageSpec spec = input->spec();
  input.reset();
  Entry e;
  e.channels = spec.nchannels;
  if (e.channels < 1) throw InputError(desc.source, "inputs:file", str("\"", desc.file, "\" has no channels"));
  // Scanning and the sRGB copy read the whole image: refuse a size nothing here allocates.
  const std::string tooLarge = imageSizeBeyondLimits(spec.width, spec.height, spec.nchannels);
  if (!tooLarge.empty()) throw InputError(desc.source, "inputs:file", str("\"", desc.file, "\" is ", tooLarge));
  // A NaN or infinite texel would become a NaN or infinite pixel: refused here, by name.
  if (uint64_t bad = system_->nonFiniteTexels(desc.file, spec.format.is_floating_point()))
    throw InputError(desc.source, "inputs:file",
                     str("\"", desc.file, "\" has ", bad, " texel values that are not finite (NaN or infinity)"));
  for (int c = 0; c < 4; ++c) e.scale[c] = desc.scale[c], e.bias[c] = desc.bias[c];
  e.channel = desc.channel;
  e.wrapS = oiioWrap(desc.wrapS);
  e.wrapT = oiioWrap(desc.wrapT);
  const bool srgb = desc.colorSpace == TextureColorSpace::SRGB ||
                    (desc.colorSpace == TextureColorSpace::Auto && spec.format == OIIO::TypeDesc::UINT8);
  std::string file = desc.file;
  if (srgb) {
    std::string linear = linearCopy(desc.file, desc.source);
    if (linear.empty()) {
      e.decodeAfter = true;
      warnings_.push_back(str(desc.source, ": no writable cache for the linear copy of \"", desc.file,
                              "\"; its sRGB values are decoded after filtering"));
    } else {
      file = linear;
    }
  }
  e.handle = system_->ts->get_texture_handle(OIIO::ustring(file));
  if (!e.handle || !system_->ts->good(static_cast<OIIO::TextureSystem::TextureHandle*>(e.handle)))
    throw InputError(desc.source, "inputs:file",
                     str("\"", desc.file, "\" cannot be read as a texture: ", system_->ts->geterror()));
  entries_.push_back(e);
  return int(entries_.size()) - 1;
}

void Textures::lookup(int texture, float u, float v, float width, float rgba[4]) const {
  const Entry& e = entries_[size_t(texture)];
  OIIO::TextureOpt opt;
  opt.swrap = OIIO::TextureOpt::Wrap(e.wrapS);
  opt.twrap = OIIO::TextureOpt::Wrap(e.wrapT);
  opt.interpmode = OIIO::TextureOpt::InterpBilinear;  // as Storm and Mitsuba's bitmap
  opt.mipmode = OIIO::TextureOpt::MipModeTrilinear;
  float texel[4] = {0, 0, 0, 1};
  const int n = std::min(e.channels, 4);
  // OIIO's t runs down the image; USD's st up it.
  system_->ts->texture(static_cast<OIIO::TextureSystem::TextureHandle*>(e.handle), nullptr, opt, u, 1.0f - v,
                       width, 0.0f, 0.0f, width, n, texel);
  float value[4];
  if (n == 1) value[0] = value[1] = value[2] = texel[0], value[3] = 1;
  else if (n == 2) value[0] = value[1] = value[2] = texel[0], value[3] = texel[1];
  else value[0] = texel[0], value[1] = texel[1], value[2] = texel[2], value[3] = n == 4 ? texel[3] : 1;
  if (e.decodeAfter)
    for (int c = 0; c < 3; ++c) value[c] = srgbToLinear(value[c]);
  for (int c = 0; c < 4; ++c) rgba[c] = value[c] * e.scale[c] + e.bias[c];
}

float Textures::lookupChannel(int texture, float u, float v, float width) const {
  float rgba[4];
  lookup(texture, u, v, width, rgba);
  const int c = entries_[size_t(texture)].channel;
  return c >= 0 ? rgba[c] : (rgba[0] + rgba[1] + rgba[2]) / 3.0f;
}

Vec3 Textures::lookupRgb(int texture, float u, float v, float width) const {
  float rgba[4];
  lookup(texture, u, v, width, rgba);
  const int c = entries_[size_t(texture)].channel;
  return c >= 0 ? Vec3(rgba[c]) : Vec3(rgba[0], rgba[1], rgba[2]);
}

}  // namespace granular
