// usd_render.cpp — UsdRender settings and products on plain records (usd_render.h).
#include "usd_render.h"

#include <cmath>

#include "error.h"

namespace granular {

namespace {
const char* const kDataWindow = "dataWindowNDC";
}

std::optional<std::pair<int, int>> resolutionFromUsd(const UsdPrimRecord& s) {
  if (!s.attributes.count("resolution")) return std::nullopt;
  const std::vector<float> res = usdFloats(s, "resolution", {0.0f, 0.0f});
  for (float v : res)
    if (!(std::isfinite(v) && v == std::floor(v) && v >= 1 && v <= 32768))
      throw InputError(s.path, "resolution", str("(", res[0], ", ", res[1], ") is outside [1, 32768] x [1, 32768]"));
  return std::make_pair(int(res[0]), int(res[1]));
}

std::optional<PixelWindow> dataWindowFromUsd(const UsdPrimRecord* settings, const UsdPrimRecord* product, int width,
                                             int height, UsdWarnings& warnings) {
  const UsdPrimRecord* where = nullptr;
  if (!product) {
    if (settings && settings->attributes.count(kDataWindow))
      warnings.push_back(str(settings->path, ".", kDataWindow,
                             ": ignored: a data window applies to render products, and this settings prim has none "
                             "(add one to its products)"));
    return std::nullopt;
  }
  if (product->attributes.count(kDataWindow)) where = product;
  else if (settings && settings->attributes.count(kDataWindow)) where = settings;
  if (!where) return std::nullopt;
  const std::vector<float> ndc = usdFloats(*where, kDataWindow, {0, 0, 1, 1});
  const std::string text = str("(", ndc[0], ", ", ndc[1], ", ", ndc[2], ", ", ndc[3], ")");
  for (float v : ndc)
    if (!std::isfinite(v))
      throw InputError(where->path, kDataWindow, str(text, " is not four finite numbers (xmin, ymin, xmax, ymax)"));
  if (!(ndc[0] < ndc[2] && ndc[1] < ndc[3]))
    throw InputError(where->path, kDataWindow, str(text, " is empty: xmin < xmax and ymin < ymax are needed"));
  const PixelWindow w = pixelWindowFromNdc(ndc[0], ndc[1], ndc[2], ndc[3], width, height);
  if (w.width() <= 0 || w.height() <= 0)
    throw InputError(where->path, kDataWindow, str(text, " covers no pixel of the ", width, "x", height, " image"));
  if (ndc[0] < 0 || ndc[1] < 0 || ndc[2] > 1 || ndc[3] > 1)
    warnings.push_back(str(where->path, ".", kDataWindow, ": ", text,
                           " reaches outside the image; overscan is not rendered, only the pixels inside (0, 0, 1, 1)"));
  if (w == PixelWindow{0, width, 0, height}) return std::nullopt;
  return w;
}

}  // namespace granular
