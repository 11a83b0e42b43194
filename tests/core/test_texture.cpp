// Image textures (texture.h) and cut-outs (Scene::presence) on ordinary surfaces.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "core/error.h"
#include "core/image_io.h"
#include "core/render.h"
#include "core/scene.h"
#include "core/texture.h"

namespace granular {
namespace {

namespace fs = std::filesystem;

std::string tempPath(const std::string& name) {
  fs::path dir = fs::temp_directory_path() / "granular_test_texture";
  fs::create_directories(dir);
  return (dir / name).string();
}

// A raw float image: values row by row from the top, one channel per name.
std::string writeRaw(const std::string& name, int w, int h, std::vector<std::string> channels,
                     const std::vector<float>& values) {
  Image img(w, h, std::move(channels));
  img.pixels = values;
  std::string path = tempPath(name);
  writeExr(path, img);
  return path;
}

TextureDesc desc(const std::string& file, TextureWrap wrap = TextureWrap::Clamp) {
  TextureDesc t;
  t.file = file;
  t.source = "/Looks/Tex";
  t.wrapS = t.wrapT = wrap;
  return t;
}

TEST(Texture, StFollowsUsdOriginAtTheLowerLeft) {
  // Rows from the top: 1 2 / 3 4.
  std::string file = writeRaw("quadrants.exr", 2, 2, {"R", "G", "B"}, {1, 0, 0, 2, 0, 0, 3, 0, 0, 4, 0, 0});
  Textures tx;
  int t = tx.add(desc(file));
  EXPECT_NEAR(tx.lookupRgb(t, 0.25f, 0.25f, 0).x, 3.0f, 1e-5f);  // lower left
  EXPECT_NEAR(tx.lookupRgb(t, 0.75f, 0.25f, 0).x, 4.0f, 1e-5f);
  EXPECT_NEAR(tx.lookupRgb(t, 0.25f, 0.75f, 0).x, 1.0f, 1e-5f);  // upper left
  EXPECT_NEAR(tx.lookupRgb(t, 0.75f, 0.75f, 0).x, 2.0f, 1e-5f);
  // Bilinear between texel centres.
  EXPECT_NEAR(tx.lookupRgb(t, 0.5f, 0.25f, 0).x, 3.5f, 1e-5f);
}

TEST(Texture, WrapModesAsUsdUVTexture) {
  std::string file = writeRaw("ramp.exr", 4, 1, {"R", "G", "B"}, {1, 0, 0, 2, 0, 0, 3, 0, 0, 4, 0, 0});
  Textures tx;
  int repeat = tx.add(desc(file, TextureWrap::Repeat));
  int clamp = tx.add(desc(file, TextureWrap::Clamp));
  int black = tx.add(desc(file, TextureWrap::Black));
  int mirror = tx.add(desc(file, TextureWrap::Mirror));
  const float u = 1.125f, v = 0.5f;  // an eighth past the right edge: texel 0's centre again
  EXPECT_NEAR(tx.lookupRgb(repeat, u, v, 0).x, 1.0f, 1e-5f);
  EXPECT_NEAR(tx.lookupRgb(clamp, u, v, 0).x, 4.0f, 1e-5f);
  EXPECT_NEAR(tx.lookupRgb(black, u, v, 0).x, 0.0f, 1e-5f);
  EXPECT_NEAR(tx.lookupRgb(mirror, u, v, 0).x, 4.0f, 1e-5f);  // mirrored: the last texel's centre
}

TEST(Texture, ScaleBiasChannelsAndGreyImages) {
  std::string rgba = writeRaw("rgba.exr", 1, 1, {"R", "G", "B", "A"}, {0.1f, 0.2f, 0.3f, 0.4f});
  TextureDesc d = desc(rgba);
  for (int c = 0; c < 4; ++c) d.scale[c] = 2, d.bias[c] = 0.5f;
  Textures tx;
  int t = tx.add(d);
  float out[4];
  tx.lookup(t, 0.5f, 0.5f, 0, out);
  EXPECT_NEAR(out[0], 0.7f, 1e-5f);
  EXPECT_NEAR(out[1], 0.9f, 1e-5f);
  EXPECT_NEAR(out[2], 1.1f, 1e-5f);
  EXPECT_NEAR(out[3], 1.3f, 1e-5f);
  d.channel = 3;
  int alpha = tx.add(d);
  EXPECT_NEAR(tx.lookupChannel(alpha, 0.5f, 0.5f, 0), 1.3f, 1e-5f);
  EXPECT_NEAR(tx.lookupRgb(alpha, 0.5f, 0.5f, 0).y, 1.3f, 1e-5f);  // a float output fills rgb
  // One channel is grey with alpha 1.
  std::string grey = writeRaw("grey.exr", 1, 1, {"Y"}, {0.25f});
  int g = tx.add(desc(grey));
  tx.lookup(g, 0.5f, 0.5f, 0, out);
  EXPECT_NEAR(out[0], 0.25f, 1e-5f);
  EXPECT_NEAR(out[1], 0.25f, 1e-5f);
  EXPECT_NEAR(out[2], 0.25f, 1e-5f);
  EXPECT_NEAR(out[3], 1.0f, 1e-5f);
}

TEST(Texture, EightBitImagesAreSrgbDecodedBeforeFiltering) {
  // Texels encoded 0 and 255 (linear 0 and 1): halfway between their centres the filter
  // averages linear values, 0.5 (decoding after filtering would give 0.214).
  Image img(2, 1, {"R", "G", "B"});
  img.pixels = {0, 0, 0, 1, 1, 1};
  std::string png = tempPath("black_white.png");
  writePngSrgb(png, img);
  Textures tx;
  int t = tx.add(desc(png));
  EXPECT_TRUE(tx.warnings().empty());  // the tests' cache is writable
  EXPECT_NEAR(tx.lookupRgb(t, 0.25f, 0.5f, 0).x, 0.0f, 1e-3f);
  EXPECT_NEAR(tx.lookupRgb(t, 0.75f, 0.5f, 0).x, 1.0f, 1e-3f);
  EXPECT_NEAR(tx.lookupRgb(t, 0.5f, 0.5f, 0).x, 0.5f, 1e-3f);
  // A mid grey: encoded 188/255 is linear 0.5029.
  img.pixels = {0.5029f, 0.5029f, 0.5029f, 0.5029f, 0.5029f, 0.5029f};
  std::string grey = tempPath("grey.png");
  writePngSrgb(grey, img);
  int g = tx.add(desc(grey));
  EXPECT_NEAR(tx.lookupRgb(g, 0.5f, 0.5f, 0).x, srgbToLinear(188.0f / 255.0f), 1e-3f);
  // Raw keeps the encoded values.
  TextureDesc raw = desc(grey);
  raw.colorSpace = TextureColorSpace::Raw;
  int r = tx.add(raw);
  EXPECT_NEAR(tx.lookupRgb(r, 0.5f, 0.5f, 0).x, 188.0f / 255.0f, 1e-3f);
}

TEST(Texture, WideFootprintsAverageTheImage) {
  // A 64-texel stripe pattern seen through a footprint as wide as the image: its mean.
  std::vector<float> v;
  for (int i = 0; i < 64; ++i) v.insert(v.end(), {float(i % 2), 0, 0});
  std::string file = writeRaw("stripes.exr", 64, 1, {"R", "G", "B"}, v);
  Textures tx;
  int t = tx.add(desc(file, TextureWrap::Repeat));
  EXPECT_NEAR(tx.lookupRgb(t, 0.5f, 0.5f, 1.0f).x, 0.5f, 0.02f);
  EXPECT_NEAR(tx.lookupRgb(t, (10 + 0.5f) / 64, 0.5f, 0).x, 0.0f, 1e-5f);  // fine: the texel itself
}

// The message of the InputError that add(d) throws ("" when it throws none).
std::string refusal(const TextureDesc& d) {
  Textures tx;
  try {
    tx.add(d);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(Texture, AMissingFileIsRefusedByTheShaderAndAttribute) {
  std::string what = refusal(desc("/nonexistent/sand.png"));
  ASSERT_FALSE(what.empty()) << "no error";
  EXPECT_NE(what.find("/Looks/Tex"), std::string::npos) << what;
  EXPECT_NE(what.find("inputs:file"), std::string::npos) << what;
}

TEST(Texture, NonFiniteTexelsAreRefusedByTheShaderAndAttribute) {
  // A NaN texel would make NaN pixels wherever it is filtered in.
  std::string file = writeRaw("nan.exr", 2, 1, {"R", "G", "B"}, {0.5f, 0.5f, 0.5f, std::nanf(""), 0.5f, 0.5f});
  std::string what = refusal(desc(file));
  ASSERT_FALSE(what.empty()) << "no error";
  EXPECT_NE(what.find("/Looks/Tex.inputs:file"), std::string::npos) << what;
  EXPECT_NE(what.find("1 texel values that are not finite"), std::string::npos) << what;
}

TEST(Texture, AFileRewrittenBetweenScenesIsReadAnew) {
  // The TextureSystem is shared by every scene of the process (texture.h): an artist who
  // repaints a texture and re-renders must see the new one.
  std::string file = writeRaw("repainted.exr", 1, 1, {"R", "G", "B"}, {0.25f, 0, 0});
  {
    Textures first;
    EXPECT_NEAR(first.lookupRgb(first.add(desc(file)), 0.5f, 0.5f, 0).x, 0.25f, 1e-6f);
  }
  for (int attempt = 0; attempt < 100; ++attempt) {  // until the file's time moves on
    writeRaw("repainted.exr", 1, 1, {"R", "G", "B"}, {0.75f, 0, 0});
    Textures second;
    float v = second.lookupRgb(second.add(desc(file)), 0.5f, 0.5f, 0).x;
    if (v != 0.25f) {
      EXPECT_NEAR(v, 0.75f, 1e-6f);
      return;
    }
  }
  FAIL() << "the rewritten texture was never read anew";
}

// ---- on surfaces ------------------------------------------------------------------------

// A unit quad in the XZ plane (normal +Y), st (0,0) at (-1, 0, 1) and (1,1) at (1, 0, -1),
// seen from above filling an 8 × 8 image (st's u along +X, v along -Z: up in the image),
// under the default white dome of radiance 1: a Lambert surface there reflects its albedo.
SceneDesc texturedQuad(const MaterialDesc& m) {
  SceneDesc d;
  d.settings.width = d.settings.height = 8;
  d.settings.spp = 64;
  d.settings.technique = Technique::Ept;
  d.camera.cameraToWorld = Transform::lookAt(Vec3(0, 10, 0), Vec3(0.0f), Vec3(0, 0, -1));
  d.camera.focalLength = 50;
  d.camera.horizontalAperture = d.camera.verticalAperture = 10;  // exactly the quad (2 at 10)
  MeshDesc quad;
  quad.name = "quad";
  quad.mesh.points = {Vec3(-1, 0, 1), Vec3(1, 0, 1), Vec3(1, 0, -1), Vec3(-1, 0, -1)};
  quad.mesh.indices = {0, 1, 2, 0, 2, 3};
  const float st[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  for (uint32_t i : quad.mesh.indices) quad.mesh.uvs.insert(quad.mesh.uvs.end(), {st[i][0], st[i][1]});
  quad.material = 0;
  d.materials.push_back(m);
  d.meshes.push_back(quad);
  return d;
}

TEST(TexturedSurface, ReflectsItsTexturedAlbedoUnderAUniformDome) {
  // Left half red-ish, right half green-ish (clamped: constant within each quarter).
  std::string file = writeRaw("halves.exr", 2, 1, {"R", "G", "B"}, {0.8f, 0.2f, 0.1f, 0.1f, 0.6f, 0.3f});
  MaterialDesc m;
  m.name = "ground";
  m.albedoTexture = desc(file);
  auto scene = Scene::build(texturedQuad(m));
  Renderer r(*scene);
  ASSERT_TRUE(r.render(64));
  for (int y = 0; y < 8; ++y)
    for (int x : {0, 1, 6, 7}) {  // the outer quarters, u < 0.25 or > 0.75
      Vec3 expected = x < 4 ? Vec3(0.8f, 0.2f, 0.1f) : Vec3(0.1f, 0.6f, 0.3f);
      // Each channel is its albedo times one estimate of the dome's irradiance, so its
      // standard error is the luminance's scaled by albedo / luminance.
      const float lum = 0.2126f * expected.x + 0.7152f * expected.y + 0.0722f * expected.z;
      for (int c = 0; c < 3; ++c)
        EXPECT_NEAR(r.film().mean(x, y)[c], expected[c], 4 * r.film().stdError(x, y) * expected[c] / lum + 1e-4f)
            << x << "," << y;
    }
}

TEST(TexturedSurface, EmissionTexturesEmit) {
  std::string file = writeRaw("glow.exr", 1, 1, {"R", "G", "B"}, {2.0f, 1.0f, 0.5f});
  MaterialDesc m;
  m.name = "glow";
  m.albedo = Vec3(0.0f);
  m.emissionTexture = desc(file);
  SceneDesc d = texturedQuad(m);
  d.settings.defaultLight = false;
  auto scene = Scene::build(d);
  Renderer r(*scene);
  ASSERT_TRUE(r.render(4));
  EXPECT_NEAR(r.film().mean(3, 3).x, 2.0f, 1e-4f);
  EXPECT_NEAR(r.film().mean(3, 3).z, 0.5f, 1e-4f);
}

TEST(Cutout, RaysPassWithTheProbabilityOfTransparency) {
  MaterialDesc m;
  m.name = "veil";
  m.opacity = 0.25f;
  auto scene = Scene::build(texturedQuad(m));
  const int n = 40000;
  int hits = 0, blocked = 0;
  Rng rng(7, 0);
  for (int i = 0; i < n; ++i) {
    Vec3 o(2 * rng.next1D() - 1, 3, 2 * rng.next1D() - 1);
    Ray ray;
    ray.o = o;
    ray.d = Vec3(0, -1, 0);
    Hit h;
    hits += scene->intersect(ray, h);
    blocked += scene->occluded(o, Vec3(0, -1, 0), 10);
  }
  const double se = std::sqrt(0.25 * 0.75 / n);
  EXPECT_NEAR(hits / double(n), 0.25, 4 * se);
  EXPECT_NEAR(blocked / double(n), 0.25, 4 * se);
}

TEST(Cutout, AThresholdMasksByTheOpacityTexture) {
  // Opacity 0 on the left half, 1 on the right; threshold 0.5: never on the left quarter,
  // always on the right quarter.
  std::string file = writeRaw("mask.exr", 2, 1, {"R", "G", "B"}, {0, 0, 0, 1, 1, 1});
  MaterialDesc m;
  m.name = "leaf";
  m.opacityTexture = desc(file);
  m.opacityTexture.channel = 0;
  m.opacityThreshold = 0.5f;
  auto scene = Scene::build(texturedQuad(m));
  for (int i = 0; i < 100; ++i) {
    float z = -0.99f + 0.0198f * i;
    Hit h;
    Ray left;
    left.o = Vec3(-0.75f, 3, z);
    left.d = Vec3(0, -1, 0);
    Ray right = left;
    right.o.x = 0.75f;
    EXPECT_FALSE(scene->intersect(left, h));
    EXPECT_TRUE(scene->intersect(right, h));
  }
}

TEST(Cutout, AHalfPresentSurfaceShowsHalfOfWhatIsBehind) {
  // Albedo 0.5 present half the time over the dome of radiance 1: 0.5 · 0.5 + 0.5 · 1.
  MaterialDesc m;
  m.name = "veil";
  m.opacity = 0.5f;
  auto scene = Scene::build(texturedQuad(m));
  Renderer r(*scene);
  ASSERT_TRUE(r.render(256));
  double sum = 0, var = 0;
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 8; ++x) {
      sum += r.film().mean(x, y).x;
      var += std::pow(r.film().stdError(x, y), 2);
    }
  EXPECT_NEAR(sum / 64, 0.75, 4 * std::sqrt(var) / 64);
}

TEST(Texture, BadValuesAreRefusedByName) {
  MaterialDesc m;
  m.name = "ground";
  m.opacity = 1.5f;
  EXPECT_THROW(validateMaterialDesc(m, "ground"), InputError);
  m.opacity = 1;
  m.albedoTexture = desc("x.png");
  m.albedoTexture.scale[1] = std::nanf("");
  try {
    validateMaterialDesc(m, "ground");
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("/Looks/Tex.inputs:scale"), std::string::npos) << e.what();
  }
  m.albedoTexture.scale[1] = 1;
  m.type = MaterialType::Dielectric;
  EXPECT_THROW(validateMaterialDesc(m, "ground"), InputError);
}

}  // namespace
}  // namespace granular
