// test_render_products.cpp — UsdRender products and vars on plain records: what a product
// inherits from its settings prim, frame tokens, the film channels and pixel types of vars,
// every error and warning, and the EXR writeProduct leaves (read back through OIIO).
#include <gtest/gtest.h>

#include <OpenImageIO/imageio.h>

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>

#include "core/error.h"
#include "core/film.h"
#include "core/image_io.h"
#include "core/render_products.h"
#include "usd_records.h"

using namespace granular;
using namespace granular::test;

namespace {

UsdPrimRecord var(const std::string& name, const std::string& source, const std::string& type,
                  const std::string& sourceType = "") {
  UsdPrimRecord r = usdRecord("/Render/Vars/" + name, "RenderVar",
                              {{"sourceName", usdText("string", source)}, {"dataType", usdText("token", type)}});
  if (!sourceType.empty()) r.attributes["sourceType"] = usdText("token", sourceType);
  return r;
}

UsdPrimRecord product(std::initializer_list<std::pair<const std::string, UsdValue>> extra = {}) {
  UsdPrimRecord r = usdRecord("/Render/Beauty", "RenderProduct", {{"productName", usdText("token", "beauty.exr")}});
  for (auto& kv : extra) r.attributes[kv.first] = kv.second;
  return r;
}

std::filesystem::path scratch(const std::string& name) {
  auto dir = std::filesystem::temp_directory_path() / ("granular_products_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  return dir / name;
}

}  // namespace

TEST(RenderProducts, VarsMapOntoTheFilmsChannels) {
  UsdWarnings w;
  auto color = renderVarFromUsd(var("color", "color", "color4f"), w);
  ASSERT_TRUE(color);
  EXPECT_EQ(color->channels, (std::vector<std::string>{"R", "G", "B", "A"}));
  EXPECT_EQ(color->format, ExrPixelType::Float);
  auto ci = renderVarFromUsd(var("ci", "Ci", "half3"), w);
  ASSERT_TRUE(ci);
  EXPECT_EQ(ci->channels, (std::vector<std::string>{"R", "G", "B"}));
  EXPECT_EQ(ci->format, ExrPixelType::Half);
  auto lpe = renderVarFromUsd(var("beauty", "C.*", "color3f", "lpe"), w);
  ASSERT_TRUE(lpe);
  EXPECT_EQ(lpe->channels, (std::vector<std::string>{"R", "G", "B"}));
  auto z = renderVarFromUsd(var("z", "z", "float"), w);
  ASSERT_TRUE(z);
  EXPECT_EQ(z->channels, (std::vector<std::string>{"Z"}));
  auto n = renderVarFromUsd(var("n", "Nn", "normal3f"), w);
  ASSERT_TRUE(n);
  EXPECT_EQ(n->channels, (std::vector<std::string>{"N.X", "N.Y", "N.Z"}));
  auto id = renderVarFromUsd(var("id", "primId", "int"), w);
  ASSERT_TRUE(id);
  EXPECT_EQ(id->format, ExrPixelType::UInt);
  auto albedo = renderVarFromUsd(var("albedo", "albedo", "color3h"), w);
  ASSERT_TRUE(albedo);
  EXPECT_EQ(albedo->channels, (std::vector<std::string>{"albedo.R", "albedo.G", "albedo.B"}));
  auto vpt = renderVarFromUsd(var("vpt", "vpt", "color3f", "intrinsic"), w);
  ASSERT_TRUE(vpt);
  EXPECT_EQ(vpt->channels, (std::vector<std::string>{"vpt.R", "vpt.G", "vpt.B"}));
  // The compositing AOVs and Cryptomatte layers (film.h: filmAovs).
  auto count = renderVarFromUsd(var("n", "sampleCount", "float"), w);
  ASSERT_TRUE(count);
  EXPECT_EQ(count->channels, (std::vector<std::string>{"sampleCount"}));
  auto variance = renderVarFromUsd(var("v", "variance", "color3f"), w);
  ASSERT_TRUE(variance);
  EXPECT_EQ(variance->channels, (std::vector<std::string>{"variance.R", "variance.G", "variance.B"}));
  auto instance = renderVarFromUsd(var("i", "instanceId", "int"), w);
  ASSERT_TRUE(instance);
  EXPECT_EQ(instance->format, ExrPixelType::UInt);
  auto crypto = renderVarFromUsd(var("c", "CryptoObject00", "color4f"), w);
  ASSERT_TRUE(crypto);
  EXPECT_EQ(crypto->channels,
            (std::vector<std::string>{"CryptoObject00.R", "CryptoObject00.G", "CryptoObject00.B", "CryptoObject00.A"}));
  EXPECT_NE(inputErrorOf([&] { renderVarFromUsd(var("c", "CryptoObject00", "half4"), w); }).find("32-bit floats"),
            std::string::npos);
  EXPECT_NE(inputErrorOf([&] { renderVarFromUsd(var("c", "CryptoMaterial01", "int4"), w); }).find("32-bit floats"),
            std::string::npos);
  EXPECT_TRUE(w.empty());
  // Every source's channels are channels of the film's image (film.h), and every AOV of
  // the film is a source.
  std::vector<std::string> film;
  for (const FilmAov& aov : filmAovs(true)) {
    film.insert(film.end(), aov.channels.begin(), aov.channels.end());
    EXPECT_NE(findRenderSource(aov.name, "raw"), nullptr) << aov.name;
  }
  for (const RenderSource& s : renderSources())
    for (const std::string& c : s.channels)
      EXPECT_NE(std::find(film.begin(), film.end(), c), film.end()) << s.name << ": " << c;
}

TEST(RenderProducts, AProductKeepsTheCryptomatteMetadataOfItsLayersOnly) {
  UsdWarnings w;
  auto p = renderProductFromUsd(nullptr, product({{"resolution", usdNumbers("int2", {2, 2})}}),
                                {var("c", "CryptoObject00", "color4f")}, w);
  ASSERT_TRUE(p);
  p->productName = scratch("crypto.exr").string();
  Image img(2, 2, {"R", "CryptoObject00.R", "CryptoObject00.G", "CryptoObject00.B", "CryptoObject00.A"});
  img.attributes = {{"cryptomatte/1111111/name", "CryptoObject"},
                    {"cryptomatte/1111111/manifest", "{\"/World/A\":\"0000abcd\"}"},
                    {"cryptomatte/2222222/name", "CryptoMaterial"},
                    {"cryptomatte/2222222/manifest", "{}"}};
  writeProduct(*p, img, NAN);
  const Image back = readExr(scratch("crypto.exr").string());
  std::map<std::string, std::string> attrs(back.attributes.begin(), back.attributes.end());
  EXPECT_EQ(attrs["cryptomatte/1111111/name"], "CryptoObject");
  EXPECT_EQ(attrs["cryptomatte/1111111/manifest"], "{\"/World/A\":\"0000abcd\"}");
  EXPECT_EQ(attrs.count("cryptomatte/2222222/name"), 0u);
}

TEST(RenderProducts, AnUnknownSourceIsOneWarningNamingTheVar) {
  for (auto [source, type] : {std::pair{"foo", "raw"}, {"C<RD>.*", "lpe"}, {"displayColor", "primvar"}}) {
    UsdWarnings w;
    EXPECT_FALSE(renderVarFromUsd(var("foo", source, "color3f", type), w));
    ASSERT_EQ(w.size(), 1u);
    EXPECT_EQ(w[0].rfind("/Render/Vars/foo.sourceName: ", 0), 0u) << w[0];
  }
  // The product is still written, without it.
  UsdWarnings w;
  auto p = renderProductFromUsd(nullptr, product(), {var("color", "color", "color3f"), var("foo", "foo", "float")}, w);
  ASSERT_TRUE(p);
  EXPECT_EQ(p->channels(), (std::vector<std::string>{"R", "G", "B"}));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_NE(w[0].find("/Render/Vars/foo.sourceName"), std::string::npos);
}

TEST(RenderProducts, ADataTypeThatDoesNotFitTheSourceIsAnInputErrorOnDataType) {
  UsdWarnings w;
  EXPECT_EQ(inputErrorOf([&] { renderVarFromUsd(var("depth", "depth", "color3f"), w); }).rfind(
                "/Render/Vars/depth.dataType: color3f has 3 channels, but depth has 1", 0),
            0u);
  EXPECT_NE(inputErrorOf([&] { renderVarFromUsd(var("n", "N", "float4"), w); }).find("/Render/Vars/n.dataType"),
            std::string::npos);
  EXPECT_NE(inputErrorOf([&] { renderVarFromUsd(var("c", "color", "float"), w); }).find("/Render/Vars/c.dataType"),
            std::string::npos);
  EXPECT_NE(inputErrorOf([&] { renderVarFromUsd(var("c", "color", "int3"), w); }).find("holds integers"),
            std::string::npos);
  EXPECT_NE(inputErrorOf([&] { renderVarFromUsd(var("id", "primId", "half"), w); }).find("round the ids"),
            std::string::npos);
  EXPECT_NE(inputErrorOf([&] { renderVarFromUsd(var("c", "color", "matrix4d"), w); }).find("is not a data type"),
            std::string::npos);
  EXPECT_EQ(inputErrorOf([&] { renderVarFromUsd(var("c", "color", "color3f", "magic"), w); })
                .rfind("/Render/Vars/c.sourceType:", 0),
            0u);
  UsdPrimRecord wrongType = var("c", "color", "color3f");
  wrongType.attributes["sourceName"] = usdNumbers("float", {1});
  EXPECT_EQ(inputErrorOf([&] { renderVarFromUsd(wrongType, w); }).rfind("/Render/Vars/c.sourceName:", 0), 0u);
  EXPECT_TRUE(w.empty());
}

TEST(RenderProducts, AProductInheritsWhatItDoesNotAuthorFromItsSettingsPrim) {
  const UsdPrimRecord settings =
      usdRecord("/Render", "RenderSettings",
                {{"resolution", usdNumbers("int2", {40, 30})},
                 {"pixelAspectRatio", usdNumbers("float", {2})},
                 {"dataWindowNDC", usdNumbers("float4", {0, 0, 0.5, 1})},
                 {"camera", usdText("rel", "/World/Camera")}});
  UsdWarnings w;
  auto inherits = renderProductFromUsd(&settings, product(), {var("color", "color", "color4f")}, w);
  ASSERT_TRUE(inherits);
  EXPECT_EQ(inherits->width, 40);
  EXPECT_EQ(inherits->height, 30);
  EXPECT_EQ(inherits->pixelAspectRatio, 2.0f);
  EXPECT_EQ(inherits->camera, "/World/Camera");
  EXPECT_EQ(inherits->window, (PixelWindow{0, 20, 0, 30}));
  auto own = renderProductFromUsd(&settings,
                                  product({{"resolution", usdNumbers("int2", {20, 10})},
                                           {"pixelAspectRatio", usdNumbers("float", {1})},
                                           {"dataWindowNDC", usdNumbers("float4", {0.5, 0, 1, 1})},
                                           {"camera", usdText("rel", "/World/Other")}}),
                                  {var("color", "color", "color4f")}, w);
  ASSERT_TRUE(own);
  EXPECT_EQ(own->width, 20);
  EXPECT_EQ(own->height, 10);
  EXPECT_EQ(own->pixelAspectRatio, 1.0f);
  EXPECT_EQ(own->camera, "/World/Other");
  EXPECT_EQ(own->window, (PixelWindow{10, 20, 0, 10}));
  // Nothing authored anywhere: UsdRender's fallbacks.
  auto bare = renderProductFromUsd(nullptr, product(), {var("color", "color", "color4f")}, w);
  ASSERT_TRUE(bare);
  EXPECT_EQ(bare->width, 2048);
  EXPECT_EQ(bare->height, 1080);
  EXPECT_EQ(bare->camera, "");
  EXPECT_EQ(bare->window, (PixelWindow{0, 2048, 0, 1080}));
  EXPECT_TRUE(w.empty());
  EXPECT_EQ(unionWindow({*inherits, *own}), (PixelWindow{0, 20, 0, 30}));
}

TEST(RenderProducts, BadProductsAreNamed) {
  UsdWarnings w;
  const std::vector<UsdPrimRecord> vars = {var("color", "color", "color4f")};
  EXPECT_EQ(inputErrorOf([&] {
              renderProductFromUsd(nullptr, product({{"resolution", usdNumbers("int2", {0, 10})}}), vars, w);
            }).rfind("/Render/Beauty.resolution:", 0),
            0u);
  EXPECT_EQ(inputErrorOf([&] {
              renderProductFromUsd(nullptr, product({{"pixelAspectRatio", usdNumbers("float", {-1})}}), vars, w);
            }).rfind("/Render/Beauty.pixelAspectRatio:", 0),
            0u);
  EXPECT_EQ(inputErrorOf([&] {
              renderProductFromUsd(nullptr, product({{"dataWindowNDC", usdNumbers("float4", {0.5, 0, 0.5, 1})}}),
                                   vars, w);
            }).rfind("/Render/Beauty.dataWindowNDC:", 0),
            0u);
  EXPECT_EQ(inputErrorOf([&] {
              renderProductFromUsd(nullptr, product({{"productName", usdText("token", "")}}), vars, w);
            }).rfind("/Render/Beauty.productName: is empty", 0),
            0u);
  EXPECT_TRUE(w.empty());
  // Not a raster: a warning, no product.
  EXPECT_FALSE(renderProductFromUsd(nullptr, product({{"productType", usdText("token", "deepRaster")}}), vars, w));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0].rfind("/Render/Beauty.productType:", 0), 0u);
  // No var it can write: a warning, no product.
  w.clear();
  EXPECT_FALSE(renderProductFromUsd(nullptr, product(), {var("foo", "foo", "float")}, w));
  EXPECT_EQ(w.size(), 2u);
  // Two vars writing one channel: the later one is skipped with a warning.
  w.clear();
  auto p = renderProductFromUsd(nullptr, product(), {var("color", "color", "color4f"), var("a", "a", "float")}, w);
  ASSERT_TRUE(p);
  EXPECT_EQ(p->vars.size(), 1u);
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0].rfind("/Render/Vars/a.sourceName:", 0), 0u);
}

TEST(RenderProducts, FrameTokensBecomeTheFrameNumber) {
  EXPECT_EQ(expandFrameTokens("out.$F4.exr", 1), "out.0001.exr");
  EXPECT_EQ(expandFrameTokens("out.$F.exr", 12), "out.12.exr");
  EXPECT_EQ(expandFrameTokens("out.####.exr", 7), "out.0007.exr");
  EXPECT_EQ(expandFrameTokens("out.##.exr", 1234), "out.1234.exr");
  EXPECT_EQ(expandFrameTokens("out.####.exr", 1.5), "out.0001.5.exr");
  EXPECT_EQ(expandFrameTokens("out.$F3.exr", -2), "out.-002.exr");
  EXPECT_EQ(expandFrameTokens("a$F2_b#.exr", 3), "a03_b3.exr");
  EXPECT_EQ(expandFrameTokens("plain.exr", NAN), "plain.exr");
  EXPECT_EQ(inputErrorOf([] { expandFrameTokens("out.$F4.exr", NAN, "/Render/Beauty", "productName"); })
                .rfind("/Render/Beauty.productName:", 0),
            0u);
}

TEST(RenderProducts, TheOutputIsCheckedBeforeRendering) {
  UsdWarnings w;
  auto p = renderProductFromUsd(nullptr, product(), {var("color", "color", "color4f")}, w);
  ASSERT_TRUE(p);
  p->productName = (scratch("") / "no_such_folder" / "beauty.exr").string();
  EXPECT_EQ(inputErrorOf([&] { checkProductOutput(*p, 1); }).rfind("/Render/Beauty.productName: folder", 0), 0u);
  p->productName = scratch("beauty.png").string();
  EXPECT_NE(inputErrorOf([&] { checkProductOutput(*p, 1); }).find("must end in .exr"), std::string::npos);
  p->productName = scratch("beauty.$F4.exr").string();
  EXPECT_EQ(inputErrorOf([&] { checkProductOutput(*p, 1); }), "");
}

TEST(RenderProducts, WriteProductWritesExactlyItsChannelsInTheirTypesOverItsDataWindow) {
  UsdWarnings w;
  auto p = renderProductFromUsd(
      nullptr,
      product({{"resolution", usdNumbers("int2", {8, 4})},
               {"dataWindowNDC", usdNumbers("float4", {0.5, 0, 1, 1})},
               {"pixelAspectRatio", usdNumbers("float", {1.5})}}),
      {var("color", "color", "half4"), var("z", "depth", "float"), var("id", "primId", "int")}, w);
  ASSERT_TRUE(p);
  p->productName = scratch("product.####.exr").string();
  // A render of the whole 8 × 4 image with more channels than the product asks for.
  Image img(8, 4, {"R", "G", "B", "A", "Z", "primId", "N.X"});
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 8; ++x) {
      float* px = img.at(x, y);
      px[0] = 0.1f * x, px[1] = 0.2f * y, px[2] = 1.0f / 3.0f, px[3] = 1;
      px[4] = x == 7 ? INFINITY : 2.5f + x, px[5] = x == 6 ? -1.0f : float(100000 + x), px[6] = 9;
    }
  writeProduct(*p, img, 3);
  const std::string file = scratch("product.0003.exr").string();
  ASSERT_TRUE(std::filesystem::exists(file));
  auto in = OIIO::ImageInput::open(file);
  ASSERT_TRUE(in);
  const OIIO::ImageSpec& spec = in->spec();
  EXPECT_EQ(spec.channelnames, (std::vector<std::string>{"R", "G", "B", "A", "Z", "primId"}));
  ASSERT_EQ(spec.channelformats.size(), 6u);
  EXPECT_EQ(spec.channelformats[0], OIIO::TypeDesc::HALF);
  EXPECT_EQ(spec.channelformats[4], OIIO::TypeDesc::FLOAT);
  EXPECT_EQ(spec.channelformats[5], OIIO::TypeDesc::UINT);
  EXPECT_EQ(spec.x, 4);
  EXPECT_EQ(spec.width, 4);
  EXPECT_EQ(spec.full_width, 8);
  EXPECT_EQ(spec.full_height, 4);
  EXPECT_FLOAT_EQ(spec.get_float_attribute("PixelAspectRatio"), 1.5f);
  std::vector<float> rgbaz(size_t(4) * 4 * 5);
  ASSERT_TRUE(in->read_image(0, 0, 0, 5, OIIO::TypeDesc::FLOAT, rgbaz.data()));
  std::vector<uint32_t> ids(size_t(4) * 4);
  ASSERT_TRUE(in->read_image(0, 0, 5, 6, OIIO::TypeDesc::UINT, ids.data()));
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 4; ++x) {
      const float* px = &rgbaz[(size_t(y) * 4 + x) * 5];
      const int ix = x + 4;
      EXPECT_NEAR(px[0], 0.1f * ix, 1e-3f);       // half: 11 significant bits
      EXPECT_NEAR(px[2], 1.0f / 3.0f, 2e-4f);
      EXPECT_EQ(px[4], ix == 7 ? INFINITY : 2.5f + ix);  // float: exact
      EXPECT_EQ(int32_t(ids[size_t(y) * 4 + x]), ix == 6 ? -1 : 100000 + ix);
    }
  // A render that does not fit the product writes nothing.
  Image small(4, 4, {"R", "G", "B", "A", "Z", "primId"});
  EXPECT_THROW(writeProduct(*p, small, 4), std::runtime_error);
  Image noId(8, 4, {"R", "G", "B", "A", "Z"});
  EXPECT_THROW(writeProduct(*p, noId, 4), std::runtime_error);
  EXPECT_FALSE(std::filesystem::exists(scratch("product.0004.exr")));
  std::filesystem::remove_all(scratch("").parent_path());
}
