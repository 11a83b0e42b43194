// render_products.h — UsdRender products and vars on plain records (usd_values.h): which
// files a RenderSettings prim asks for, which of the film's channels each holds and in what
// pixel type, and writing them. Both USD front ends (granular render without -o, and
// hdGranular when a render converges) describe products here and write them with
// writeProduct, so they write the same files.
//
// Contract:
// - A product (renderProductFromUsd): productType must be "raster" (else a warning and no
//   product); resolution, camera, dataWindowNDC and pixelAspectRatio are the product's own
//   where it authors them, else the settings prim's, else UsdRender's fallbacks
//   ((2048, 1080), none, (0, 0, 1, 1), 1). productName names the EXR to write (relative
//   names against the working folder); frame tokens $F, $Fn (n a digit) and runs of '#'
//   become the frame number, zero-padded to n digits or to the run's length.
// - A var (renderVarFromUsd): sourceType raw, intrinsic (a name of this renderer's film),
//   lpe (only "C.*", the beauty) or primvar (none can be written). A sourceName nothing
//   here produces is one warning naming `var.sourceName`; the product is written without
//   it. A dataType whose channel count does not fit the source (color3f for depth) is an
//   InputError on `var.dataType`. Channels are named as in every EXR of this renderer
//   (film.h): a var's EXR channels are the film's channels of its source (R, G, B, A, Z,
//   N.X, ..., albedo.R, ...), not the var prim's name, so a product's file and a
//   `granular render -o` file name the same data the same way.
// - Pixel types: half* dataTypes are written as EXR half, float/color/normal/vector ones
//   as float, int and uint as EXR uint (an int's two's-complement bits: primId -1 is
//   4294967295). Ids and Cryptomatte ranks are never written as half (they would round).
// - writeProduct writes exactly the product's channels over its data window (the EXR data
//   window; the display window is the product's resolution) with the pixel aspect in the
//   header, through an OutputFile: the file is whole or absent. checkProductOutput says,
//   before anything is rendered, whether the file can be written (InputError on
//   `product.productName`).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "image_io.h"
#include "scene_desc.h"
#include "usd_values.h"

namespace granular {

// One output of the film: a name a var's sourceName may use, the film channels it fills
// (film.h), the Hydra AOV of the same meaning ("" when the delegate has none), and whether
// its values are ids (written as float or uint, never half).
struct RenderSource {
  std::string name;
  std::vector<std::string> channels;
  std::string hydraAov;
  bool ids = false;
  bool optionalAlpha = false;  // the beauty: 3 channels (R, G, B) or 4 (with A)
};

// The one table of what the film can write, with the usual aliases (Ci, a, z, N, Nn, ...).
const std::vector<RenderSource>& renderSources();
// The source a var asks for, or null when this renderer has none (unknown name, an LPE
// other than the beauty, any primvar). sourceType as UsdRender names it.
const RenderSource* findRenderSource(const std::string& sourceName, const std::string& sourceType);

struct RenderVarDesc {
  std::string path;
  std::string sourceName, sourceType, dataType;
  std::vector<std::string> channels;  // film (and EXR) channel names, in order
  ExrPixelType format = ExrPixelType::Float;
};

struct RenderProductDesc {
  std::string path;
  std::string productName;  // as authored: frame tokens not yet expanded
  int width = 2048, height = 1080;
  std::string camera;       // prim path; "" when neither product nor settings names one
  float dataWindowNDC[4] = {0, 0, 1, 1};
  PixelWindow window;       // the pixels the data window covers at width × height
  float pixelAspectRatio = 1;
  std::vector<RenderVarDesc> vars;
  // Every channel of the file, in var order.
  std::vector<std::string> channels() const;
  // Some var is a Cryptomatte layer (the film must keep its tables: RenderSettings::cryptomatte).
  bool needsCryptomatte() const;
};

// The attributes a front end reads on products and settings prims (authored values only,
// so that a product inherits what it does not author), and on vars. A camera relationship
// is handed as attribute "camera" holding its first target path as a string.
const std::vector<std::string>& usdRenderProductAttributeNames();
const std::vector<std::string>& usdRenderVarAttributeNames();

// A var as core reads it; nothing (with one warning) when this renderer cannot produce it.
std::optional<RenderVarDesc> renderVarFromUsd(const UsdPrimRecord& var, UsdWarnings& warnings);

// A product from its prim, its settings prim (null: a host that merged them, Hydra's) and
// its ordered vars' prims; nothing (with a warning) when it is not a raster product or has
// no var this renderer writes. InputError on prim.attribute for bad values.
std::optional<RenderProductDesc> renderProductFromUsd(const UsdPrimRecord* settings, const UsdPrimRecord& product,
                                                      const std::vector<UsdPrimRecord>& vars,
                                                      UsdWarnings& warnings);

// name with its frame tokens replaced by `frame` (1 -> "$F4" "0001"; 1.5 -> "0001.5").
// A name with tokens and a frame that is not finite: InputError(object, attribute).
std::string expandFrameTokens(const std::string& name, double frame, const std::string& object = "",
                              const std::string& attribute = "");
// The product's file for that frame (NaN: no frame; only a name without tokens).
std::string productFileName(const RenderProductDesc& product, double frame);
// InputError on product.productName unless the file can be written: a name ending in
// .exr whose folder exists and is writable.
void checkProductOutput(const RenderProductDesc& product, double frame);

// The smallest window holding every product's data window (the pixels to render once for
// products sharing resolution and camera); the whole image for an empty list.
PixelWindow unionWindow(const std::vector<RenderProductDesc>& products);

// Writes the product's file from a render of its camera at its resolution: `image` holds
// the film's channels (Film::toImage: its x, y and full size place it in the image) and
// must cover the product's data window. Returns what writeExr returns (true when another
// process replaced a claimed output meanwhile). std::runtime_error when the image does not
// fit the product (a different size, a missing channel or pixel); InputError as
// checkProductOutput.
bool writeProduct(const RenderProductDesc& product, const Image& image, double frame);

}  // namespace granular
