#include "renderProducts.h"

#include <cmath>
#include <map>
#include <memory>
#include <mutex>

#include "core/cryptomatte.h"
#include "core/error.h"
#include "core/scene.h"
#include "pxr/base/tf/diagnostic.h"

PXR_NAMESPACE_OPEN_SCOPE

namespace {

struct Registered {
  std::map<SdfPath, std::vector<granular::RenderProductDesc>> products;  // by settings prim
  std::map<SdfPath, std::string> errors;
  SdfPath active;
  double frame = NAN;
  // The last converged image whose products were written, for which prim and frame.
  std::shared_ptr<const granular::Image> written;
  SdfPath writtenActive;
  double writtenFrame = NAN;
};

std::mutex gMutex;
std::map<HdGranularRenderer const*, Registered> gProducts;

granular::UsdValue text(const std::string& type, const std::string& s) {
  granular::UsdValue v;
  v.typeName = type;
  v.isString = true;
  v.strings = {s};
  return v;
}

granular::UsdValue numbers(const std::string& type, std::vector<double> n) {
  granular::UsdValue v;
  v.typeName = type;
  v.numbers = std::move(n);
  return v;
}

}  // namespace

std::optional<granular::RenderProductDesc> HdGranularProductDesc(HdRenderSettings::RenderProduct const& product,
                                                                  granular::UsdWarnings& warnings) {
  granular::UsdPrimRecord r;
  r.path = product.productPath.GetString();
  r.typeName = "RenderProduct";
  r.attributes["productName"] = text("token", product.name.GetString());
  if (!product.type.IsEmpty()) r.attributes["productType"] = text("token", product.type.GetString());
  if (product.resolution[0] > 0 && product.resolution[1] > 0)  // else UsdRender's fallback
    r.attributes["resolution"] = numbers("int2", {double(product.resolution[0]), double(product.resolution[1])});
  const GfRange2f& ndc = product.dataWindowNDC;
  if (ndc != GfRange2f())  // the default range: nothing authored or flattened (an authored empty one is refused)
    r.attributes["dataWindowNDC"] =
        numbers("float4", {ndc.GetMin()[0], ndc.GetMin()[1], ndc.GetMax()[0], ndc.GetMax()[1]});
  // Hydra fills 0 where no aspect was authored (and conform policies adjust it).
  if (product.pixelAspectRatio > 0) r.attributes["pixelAspectRatio"] = numbers("float", {product.pixelAspectRatio});
  if (!product.cameraPath.IsEmpty()) r.attributes["camera"] = text("rel", product.cameraPath.GetString());
  std::vector<granular::UsdPrimRecord> vars;
  for (auto const& v : product.renderVars) {
    granular::UsdPrimRecord vr;
    vr.path = v.varPath.GetString();
    vr.typeName = "RenderVar";
    vr.attributes["sourceName"] = text("string", v.sourceName);
    if (!v.sourceType.IsEmpty()) vr.attributes["sourceType"] = text("token", v.sourceType.GetString());
    if (!v.dataType.IsEmpty()) vr.attributes["dataType"] = text("token", v.dataType.GetString());
    vars.push_back(std::move(vr));
  }
  return granular::renderProductFromUsd(nullptr, r, vars, warnings);
}

void HdGranularSetRenderProducts(HdGranularRenderer const* renderer, SdfPath const& settings,
                                 std::vector<granular::RenderProductDesc> products, std::string error) {
  std::lock_guard<std::mutex> lock(gMutex);
  Registered& r = gProducts[renderer];
  r.products[settings] = std::move(products);
  if (error.empty()) r.errors.erase(settings);
  else r.errors[settings] = std::move(error);
}

void HdGranularClearRenderProducts(HdGranularRenderer const* renderer, SdfPath const& settings) {
  std::lock_guard<std::mutex> lock(gMutex);
  auto it = gProducts.find(renderer);
  if (it == gProducts.end()) return;
  it->second.products.erase(settings);
  it->second.errors.erase(settings);
  if (it->second.products.empty()) gProducts.erase(it);
}

namespace {

void writeAll(std::vector<granular::RenderProductDesc> const& products, granular::Image const& image, double frame) {
  for (granular::RenderProductDesc const& p : products) {
    if (p.width != image.displayWidth() || p.height != image.displayHeight()) {
      TF_WARN("hdGranular: render product %s is %dx%d but the render is %dx%d: not written (render it at its "
              "resolution)",
              p.path.c_str(), p.width, p.height, image.displayWidth(), image.displayHeight());
      continue;
    }
    try {
      const std::string file = granular::productFileName(p, frame);
      granular::writeProduct(p, image, frame);
      TF_STATUS("hdGranular: wrote %s (render product %s)", file.c_str(), p.path.c_str());
    } catch (std::exception const& e) {
      TF_RUNTIME_ERROR("hdGranular: %s", e.what());
    }
  }
}

bool sameFrame(double a, double b) { return a == b || (std::isnan(a) && std::isnan(b)); }

}  // namespace

bool HdGranularActiveProductsNeedCryptomatte(HdGranularRenderer const* renderer) {
  std::lock_guard<std::mutex> lock(gMutex);
  auto it = gProducts.find(renderer);
  if (it == gProducts.end()) return false;
  auto found = it->second.products.find(it->second.active);
  if (found == it->second.products.end()) return false;
  for (granular::RenderProductDesc const& p : found->second)
    if (p.needsCryptomatte()) return true;
  return false;
}

void HdGranularActivateRenderProducts(HdGranularRenderer const* renderer, SdfPath const& active, double frame) {
  std::vector<granular::RenderProductDesc> products;
  std::shared_ptr<const granular::Image> again;  // a converged image to write for a new frame
  {
    std::lock_guard<std::mutex> lock(gMutex);
    auto it = gProducts.find(renderer);
    if (it == gProducts.end()) return;
    Registered& r = it->second;
    r.active = active;
    r.frame = frame;
    auto error = r.errors.find(active);
    if (error != r.errors.end()) throw granular::InputError(active.GetString(), "products", error->second);
    auto found = r.products.find(active);
    if (found != r.products.end()) products = found->second;
    // A new frame of a scene that holds still is not rendered again (the render pass sees
    // no edit): its products are the last converged image's. When the scene did change,
    // the new render's products replace these when it converges.
    if (r.written && r.writtenActive == active && !sameFrame(r.writtenFrame, frame)) {
      again = r.written;
      r.writtenFrame = frame;
    }
  }
  for (granular::RenderProductDesc const& p : products) granular::checkProductOutput(p, frame);
  if (again) writeAll(products, *again, frame);
}

void HdGranularWriteRenderProducts(HdGranularRenderer const* renderer, granular::Film const& film,
                                   granular::Scene const* scene) {
  std::vector<granular::RenderProductDesc> products;
  double frame = NAN;
  {
    std::lock_guard<std::mutex> lock(gMutex);
    auto it = gProducts.find(renderer);
    if (it == gProducts.end() || it->second.active.IsEmpty()) return;
    products = it->second.products[it->second.active];
    frame = it->second.frame;
  }
  if (products.empty()) return;
  auto image = std::make_shared<granular::Image>(film.toImage());
  // The Cryptomatte manifests (as core's Renderer::image adds them), for products holding its layers.
  if (scene && film.hasCryptomatte())
    for (auto t : {granular::CryptomatteType::Object, granular::CryptomatteType::Material})
      for (auto& kv : granular::cryptomatteMetadata(t, scene->cryptomatteNames(t))) image->attributes.push_back(kv);
  writeAll(products, *image, frame);
  std::lock_guard<std::mutex> lock(gMutex);
  auto it = gProducts.find(renderer);
  if (it == gProducts.end()) return;
  it->second.written = image;
  it->second.writtenActive = it->second.active;
  it->second.writtenFrame = frame;
}

PXR_NAMESPACE_CLOSE_SCOPE
