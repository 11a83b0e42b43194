// test_usd_shading.cpp — the UsdPreviewSurface rule and UsdUVTexture networks on plain
// records: fallbacks, glass or Lambert, textures and their st, warnings and errors.
#include <gtest/gtest.h>

#include "core/error.h"
#include "core/usd_shading.h"
#include "usd_records.h"

using namespace granular;
using namespace granular::test;

namespace {

// Any existing file stands for an image: materialFromUsd checks that it exists only.
const std::string kImage = __FILE__;

UsdShaderRecord shader(const std::string& path, const std::string& id,
                       std::initializer_list<std::pair<const std::string, UsdValue>> inputs = {},
                       std::map<std::string, std::pair<std::string, std::string>> connections = {}) {
  UsdShaderRecord s;
  static_cast<UsdPrimRecord&>(s) = usdRecord(path, id, inputs);
  s.connections = std::move(connections);
  return s;
}

UsdMaterialNetwork network(std::vector<UsdShaderRecord> shaders) {
  UsdMaterialNetwork n;
  n.material = "/Looks/M";
  n.surface = shaders.empty() ? "" : shaders.front().path;
  n.shaders = std::move(shaders);
  return n;
}

// A diffuse texture read through a primvar reader of `varname`.
UsdMaterialNetwork textured(std::initializer_list<std::pair<const std::string, UsdValue>> textureInputs,
                            const std::string& varname = "st", const std::string& output = "rgb") {
  UsdShaderRecord tex = shader("/Looks/M/Tex", "UsdUVTexture", textureInputs, {{"inputs:st", {"/Looks/M/St", "result"}}});
  if (!tex.attributes.count("inputs:file")) tex.attributes["inputs:file"] = usdText("asset", "t.png", kImage);
  return network({shader("/Looks/M/Surface", "UsdPreviewSurface", {}, {{"inputs:diffuseColor", {"/Looks/M/Tex", output}}}),
                  tex, shader("/Looks/M/St", "UsdPrimvarReader_float2", {{"inputs:varname", usdText("token", varname)}})});
}

std::string errorOf(const UsdMaterialNetwork& n) {
  UsdWarnings w;
  return inputErrorOf([&] { materialFromUsd(n, w); });
}

}  // namespace

TEST(UsdShading, UnauthoredInputsTakeUsdPreviewSurfaceFallbacks) {
  UsdWarnings w;
  const auto m = materialFromUsd(network({shader("/Looks/M/Surface", "UsdPreviewSurface")}), w);
  ASSERT_TRUE(m);
  EXPECT_EQ(m->desc.type, MaterialType::Lambert);
  EXPECT_FLOAT_EQ(m->desc.albedo.x, 0.18f);
  EXPECT_FLOAT_EQ(m->desc.emission.y, 0.0f);
  EXPECT_FLOAT_EQ(m->desc.opacity, 1.0f);
  EXPECT_EQ(m->desc.name, "/Looks/M/Surface");
  EXPECT_TRUE(m->st.empty());
  EXPECT_TRUE(w.empty());
}

TEST(UsdShading, OpacityBelowOneIsGlassUnlessAThresholdOrTextureMakesACutOut) {
  UsdWarnings w;
  const auto glass = materialFromUsd(
      network({shader("/S", "UsdPreviewSurface", {{"inputs:opacity", usdNumbers("float", {0.2})},
                                                  {"inputs:ior", usdNumbers("float", {1.33})}})}),
      w);
  EXPECT_EQ(glass->desc.type, MaterialType::Dielectric);
  EXPECT_FLOAT_EQ(glass->desc.ior, 1.33f);
  const auto cut = materialFromUsd(
      network({shader("/S", "UsdPreviewSurface", {{"inputs:opacity", usdNumbers("float", {0.2})},
                                                  {"inputs:opacityThreshold", usdNumbers("float", {0.5})}})}),
      w);
  EXPECT_EQ(cut->desc.type, MaterialType::Lambert);
  EXPECT_FLOAT_EQ(cut->desc.opacityThreshold, 0.5f);
}

TEST(UsdShading, ATextureNetworkGivesTheTextureAndItsPrimvar) {
  UsdWarnings w;
  const auto m = materialFromUsd(textured({{"inputs:wrapS", usdText("token", "repeat")},
                                           {"inputs:scale", usdNumbers("float4", {2, 2, 2, 1})},
                                           {"inputs:sourceColorSpace", usdText("token", "raw")}},
                                          "uv"),
                                 w);
  ASSERT_TRUE(m);
  const TextureDesc& t = m->desc.albedoTexture;
  EXPECT_EQ(t.file, kImage);
  EXPECT_EQ(t.source, "/Looks/M/Tex");
  EXPECT_EQ(t.wrapS, TextureWrap::Repeat);
  EXPECT_EQ(t.wrapT, TextureWrap::UseMetadata);
  EXPECT_FLOAT_EQ(t.scale[0], 2.0f);
  EXPECT_EQ(t.colorSpace, TextureColorSpace::Raw);
  EXPECT_EQ(t.channel, -1);
  EXPECT_EQ(m->st, "uv");
  EXPECT_TRUE(w.empty());
}

TEST(UsdShading, UnsupportedShadersAndConnectionsAreWarnedAbout) {
  UsdWarnings w;
  EXPECT_FALSE(materialFromUsd(network({shader("/S", "ND_standard_surface_surfaceshader")}), w));
  ASSERT_EQ(w.size(), 1u);
  EXPECT_EQ(w[0], "/S: shader 'ND_standard_surface_surfaceshader' is not supported (only UsdPreviewSurface); using "
                  "the default material");
  w.clear();
  EXPECT_FALSE(materialFromUsd(network({}), w));
  EXPECT_EQ(w.at(0), "/Looks/M: no surface shader; using the default material");
  w.clear();
  // A UsdTransform2d between texture and reader is skipped, with a warning.
  UsdMaterialNetwork n = textured({});
  n.shaders[1].connections["inputs:st"] = {"/Looks/M/Xf", "result"};
  n.shaders.push_back(shader("/Looks/M/Xf", "UsdTransform2d", {}, {{"inputs:in", {"/Looks/M/St", "result"}}}));
  EXPECT_EQ(materialFromUsd(n, w)->st, "st");
  EXPECT_EQ(w.at(0), "/Looks/M/Xf: UsdTransform2d is not supported; st is read untransformed");
  // ... unless it reads itself.
  n.shaders.back().connections["inputs:in"] = {"/Looks/M/Xf", "result"};
  EXPECT_EQ(errorOf(n), "/Looks/M/Xf.inputs:in: is connected in a cycle (to its own output)");
}

TEST(UsdShading, BadValuesNameTheShaderAndItsInput) {
  EXPECT_EQ(errorOf(network({shader("/S", "UsdPreviewSurface", {{"inputs:opacity", usdNumbers("float", {1.5})}})})),
            "/S.inputs:opacity: 1.5 is outside [0, 1]");
  EXPECT_EQ(errorOf(network({shader("/S", "UsdPreviewSurface", {{"inputs:diffuseColor", usdNumbers("color3f", {2, 0, 0})}})})),
            "/S.inputs:diffuseColor: (2, 0, 0) is outside [0, 1]");
  EXPECT_EQ(errorOf(network({shader("/S", "UsdPreviewSurface", {{"inputs:ior", usdText("string", "glass")}})})),
            "/S.inputs:ior: has value 'glass', expected a number");
  EXPECT_EQ(errorOf(textured({{"inputs:wrapT", usdText("token", "tile")}})),
            "/Looks/M/Tex.inputs:wrapT: \"tile\" is not black, clamp, repeat, mirror or useMetadata");
  EXPECT_EQ(errorOf(textured({{"inputs:file", usdText("asset", "t.<UDIM>.png")}})),
            "/Looks/M/Tex.inputs:file: \"t.<UDIM>.png\": UDIM textures are not supported");
  EXPECT_EQ(errorOf(textured({{"inputs:file", usdText("asset", "missing.png")}})),
            "/Looks/M/Tex.inputs:file: \"missing.png\" cannot be found");
  EXPECT_EQ(errorOf(textured({{"inputs:file", usdText("asset", "")}})), "/Looks/M/Tex.inputs:file: names no image");
  EXPECT_EQ(errorOf(textured({}, "")), "/Looks/M/St.inputs:varname: names no primvar");
  EXPECT_EQ(errorOf(textured({}, "st", "rgba")), "/Looks/M/Tex.outputs:rgba: \"rgba\" is not rgb, r, g, b or a");
}
