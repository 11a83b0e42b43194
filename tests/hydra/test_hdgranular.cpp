// hdGranular through a real Hydra host (UsdImagingGLEngine without a GPU, as usdrecord
// --disableGpu runs it): plugin discovery, examples without NaN, AOVs that add up, an edit
// that restarts the render, a bad stage that still converges, stopping mid-render.
#include <gtest/gtest.h>

#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <cstring>
#include <regex>
#include <map>
#include <cstdlib>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <cmath>
#include <set>
#include <string>
#include <vector>

#include "pxr/base/gf/camera.h"
#include "pxr/base/plug/registry.h"
#include "pxr/base/tf/errorMark.h"
#include "pxr/base/tf/stringUtils.h"
#include "pxr/base/gf/vec2i.h"
#include "pxr/imaging/cameraUtil/framing.h"
#include "pxr/imaging/hd/renderBuffer.h"
#include "pxr/imaging/hd/tokens.h"
#include "pxr/usd/usd/primRange.h"
#include "pxr/usd/usd/stage.h"
#include "pxr/usd/usdGeom/camera.h"
#include "pxr/usd/usdGeom/xformable.h"
#include "pxr/usd/usdLux/lightAPI.h"
#include "pxr/usdImaging/usdImagingGL/engine.h"

PXR_NAMESPACE_USING_DIRECTIVE

namespace {

// The delegate's and our schema's plugInfo registered with Plug, and the TT and tile cache
// set, before any test runs: ctest passes this program no environment of ours.
const bool kPluginsRegistered = [] {
  PlugRegistry::GetInstance().RegisterPlugins(TfStringSplit(GRANULAR_HD_PLUGIN_PATH, ":"));
  setenv("GRANULAR_CACHE_DIR", GRANULAR_TEST_CACHE_DIR, 0);
  return true;
}();

const TfToken kPlugin("HdGranularRendererPlugin");
const std::string kExamples = GRANULAR_EXAMPLES_DIR;

struct Frame {
  int width = 0, height = 0, channels = 0;
  std::vector<float> values;
  bool converged = false;
};

std::unique_ptr<UsdImagingGLEngine> makeEngine(int spp) {
  auto engine = std::make_unique<UsdImagingGLEngine>(HdDriver(), kPlugin, /*gpuEnabled=*/false);
  engine->SetEnablePresentation(false);
  engine->SetRendererSetting(HdRenderSettingsTokens->convergedSamplesPerPixel, VtValue(spp));
  return engine;
}

// Renders `aov` with the engine's camera, buffer size and AOV as set, at `time`, until
// converged (or 120 s).
Frame converge(UsdImagingGLEngine& engine, UsdStageRefPtr const& stage, TfToken const& aov,
               UsdTimeCode time = UsdTimeCode::Default()) {
  UsdImagingGLRenderParams params;
  params.frame = time;
  Frame f;
  auto t0 = std::chrono::steady_clock::now();
  do {
    engine.Render(stage->GetPseudoRoot(), params);
  } while (!engine.IsConverged() && std::chrono::steady_clock::now() - t0 < std::chrono::seconds(120));
  f.converged = engine.IsConverged();
  HdRenderBuffer* rb = engine.GetAovRenderBuffer(aov);
  if (!rb) return f;
  rb->Resolve();
  f.width = int(rb->GetWidth());
  f.height = int(rb->GetHeight());
  HdFormat fmt = rb->GetFormat();
  f.channels = int(HdGetComponentCount(fmt));
  const void* data = rb->Map();
  const size_t n = size_t(f.width) * f.height * f.channels;
  f.values.resize(n);
  for (size_t i = 0; i < n; ++i) {
    switch (HdGetComponentFormat(fmt)) {
      case HdFormatFloat32: f.values[i] = static_cast<const float*>(data)[i]; break;
      case HdFormatFloat16: f.values[i] = float(static_cast<const GfHalf*>(data)[i]); break;
      case HdFormatInt32: f.values[i] = float(static_cast<const int32_t*>(data)[i]); break;
      case HdFormatUNorm8: f.values[i] = static_cast<const uint8_t*>(data)[i] / 255.0f; break;
      default: f.values[i] = NAN; break;
    }
  }
  rb->Unmap();
  return f;
}

// Renders `aov` of the stage's /World/Camera at w x h, at `time`, until converged (or 120 s).
Frame render(UsdImagingGLEngine& engine, UsdStageRefPtr const& stage, TfToken const& aov, int w, int h,
             UsdTimeCode time = UsdTimeCode::Default()) {
  engine.SetCameraPath(SdfPath("/World/Camera"));
  engine.SetRenderBufferSize(GfVec2i(w, h));
  engine.SetFraming(CameraUtilFraming(GfRect2i(GfVec2i(0, 0), w, h)));
  EXPECT_TRUE(engine.SetRendererAov(aov));
  return converge(engine, stage, aov, time);
}

// An in-memory stage: /World/Camera on the +z axis looking at the origin (square aperture
// of `aperture` mm, focal length 50), a uniform dome of radiance 1, then `prims` in /World.
UsdStageRefPtr domeLitStage(int aperture, std::string const& prims) {
  UsdStageRefPtr stage = UsdStage::CreateInMemory();
  std::string a = std::to_string(aperture);
  stage->GetRootLayer()->ImportFromString(R"(#usda 1.0
def Xform "World" {
  def Camera "Camera" {
    double3 xformOp:translate = (0, 0, 10)
    uniform token[] xformOpOrder = ["xformOp:translate"]
    float focalLength = 50
    float horizontalAperture = )" + a + R"(
    float verticalAperture = )" + a + R"(
  }
  def DomeLight "Sky" {
    float inputs:intensity = 1
  }
)" + prims + "}\n");
  return stage;
}

// domeLitStage(40) with a PointInstancer /World/Inst of `instances` unit quads facing the
// camera, 2 apart along x from x = -2.
UsdStageRefPtr quadInstancerStage(int instances) {
  std::string indices, positions;
  for (int i = 0; i < instances; ++i) {
    indices += std::string(i ? ", " : "") + "0";
    positions += std::string(i ? ", " : "") + "(" + std::to_string(-2 + 2 * i) + ", 0, 0)";
  }
  return domeLitStage(40, R"(
  def PointInstancer "Inst" {
    rel prototypes = </World/Inst/Protos/Quad>
    int[] protoIndices = [)" + indices + "]\n    point3f[] positions = [" + positions + R"(]
    def Scope "Protos" {
      def Mesh "Quad" {
        point3f[] points = [(-0.5, -0.5, 0), (0.5, -0.5, 0), (0.5, 0.5, 0), (-0.5, 0.5, 0)]
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
      }
    }
  }
)");
}

double mean(Frame const& f, int channel) {
  double s = 0;
  for (size_t i = channel; i < f.values.size(); i += f.channels) s += f.values[i];
  return s / (double(f.values.size()) / f.channels);
}

}  // namespace

TEST(HdGranular, PluginIsDiscoveredAsGranular) {
  TfTokenVector plugins = UsdImagingGLEngine::GetRendererPlugins();
  ASSERT_NE(std::find(plugins.begin(), plugins.end(), kPlugin), plugins.end());
  EXPECT_EQ(UsdImagingGLEngine::GetRendererDisplayName(kPlugin), "Granular");
}

TEST(HdGranular, EveryExampleRendersWithoutNaN) {
  for (const char* name : {"snowslab", "sugarcube", "sandcastle", "mixture"}) {
    SCOPED_TRACE(name);
    UsdStageRefPtr stage = UsdStage::Open(kExamples + "/" + name + ".usda");
    ASSERT_TRUE(stage);
    auto engine = makeEngine(2);
    Frame f = render(*engine, stage, HdAovTokens->color, 48, 32);
    ASSERT_TRUE(f.converged);
    ASSERT_EQ(f.values.size(), size_t(48 * 32 * 4));
    for (float v : f.values) ASSERT_TRUE(std::isfinite(v));
    EXPECT_GT(mean(f, 0), 0.0);
    // A sample that was not finite is dropped from the image and counted: none may be.
    VtDictionary stats = engine->GetRenderStats();
    ASSERT_TRUE(stats.count("granular:nonFiniteSamples"));
    EXPECT_EQ(stats["granular:nonFiniteSamples"].Get<int>(), 0);
  }
}

TEST(HdGranular, TransportAovsAddUpToTheColor) {
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  auto engine = makeEngine(4);
  Frame color = render(*engine, stage, HdAovTokens->color, 40, 26);
  Frame parts[4] = {render(*engine, stage, TfToken("ept"), 40, 26), render(*engine, stage, TfToken("vpt"), 40, 26),
                    render(*engine, stage, TfToken("da"), 40, 26), render(*engine, stage, TfToken("ppt"), 40, 26)};
  ASSERT_EQ(parts[0].channels, 3);
  ASSERT_EQ(parts[3].channels, 3);
  double high = 0;
  for (int p = 0; p < 40 * 26; ++p)
    for (int c = 0; c < 3; ++c) {
      float sum = parts[0].values[3 * p + c] + parts[1].values[3 * p + c] + parts[2].values[3 * p + c] +
                  parts[3].values[3 * p + c];
      high += parts[1].values[3 * p + c] + parts[2].values[3 * p + c];
      EXPECT_NEAR(sum, color.values[4 * p + c], 1e-4f * (1 + color.values[4 * p + c]));
    }
  EXPECT_GT(high, 0.0);  // snow: the media carry light
}

TEST(HdGranular, AnEditRestartsTheRender) {
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  auto engine = makeEngine(2);
  Frame before = render(*engine, stage, HdAovTokens->color, 32, 20);
  ASSERT_TRUE(before.converged);
  // Every light 4x as bright: radiance is linear in emission and the sampling does not
  // depend on it, so the restarted render is 4x the first (same seed) if it restarted.
  for (UsdPrim const& prim : stage->Traverse())
    if (prim.HasAPI<UsdLuxLightAPI>()) {
      UsdLuxLightAPI light(prim);
      float intensity = 1;
      light.GetIntensityAttr().Get(&intensity);
      light.GetIntensityAttr().Set(intensity * 4.0f);
    }
  Frame after = render(*engine, stage, HdAovTokens->color, 32, 20);
  ASSERT_TRUE(after.converged);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(mean(after, c), 4.0 * mean(before, c), 0.01 * 4.0 * mean(before, c)) << c;
}

TEST(HdGranular, ABadStageStillConvergesWithNothingRendered) {
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  stage->GetPrimAtPath(SdfPath("/World/Snow")).GetAttribute(TfToken("primvars:granular:packingRate")).Set(0.9f);
  auto engine = makeEngine(2);
  Frame f = render(*engine, stage, HdAovTokens->color, 16, 10);
  EXPECT_TRUE(f.converged);
  ASSERT_EQ(f.values.size(), size_t(16 * 10 * 4));
  for (size_t i = 0; i < f.values.size(); i += 4)  // the clear colour: nothing was drawn
    for (int c = 0; c < 3; ++c) ASSERT_EQ(f.values[i + c], 0.0f) << i;
}

// What `granular render` refuses by name, the delegate refuses with the same words (one
// meaning in core): the error is raised and nothing is drawn.
TEST(HdGranular, AnAggregateAsItsOwnGrainOrAnFStopBeyondAnyLensIsRefusedAsByGranularRender) {
  struct Case {
    std::function<void(UsdStageRefPtr const&)> edit;
    std::string message;
  };
  const std::vector<Case> cases = {
      {[](UsdStageRefPtr const& s) {
         s->GetPrimAtPath(SdfPath("/World/Snow"))
             .GetAttribute(TfToken("primvars:granular:prototypes"))
             .Set(VtStringArray{"../Grains/Flake", "."});
       },
       "/World/Snow.primvars:granular:prototypes: prototype \".\" (/World/Snow) is this aggregate itself"},
      {[](UsdStageRefPtr const& s) {
         UsdGeomCamera cam(s->GetPrimAtPath(SdfPath("/World/Camera")));
         cam.CreateFStopAttr().Set(1e-15f);
         cam.CreateFocusDistanceAttr().Set(0.1f);
       },
       "/World/Camera.fStop: 1e-15 is below 0.5, the fastest a lens in air can be"},
  };
  for (const Case& c : cases) {
    UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
    c.edit(stage);
    TfErrorMark mark;
    auto engine = makeEngine(2);
    Frame f = render(*engine, stage, HdAovTokens->color, 16, 10);
    std::string errors;
    for (auto e = mark.GetBegin(); e != mark.GetEnd(); ++e) errors += e->GetCommentary() + "\n";
    mark.Clear();
    EXPECT_NE(errors.find(c.message), std::string::npos) << errors;
    EXPECT_TRUE(f.converged);
    for (size_t i = 0; i < f.values.size(); i += 4)  // the clear colour: nothing was drawn
      for (int k = 0; k < 3; ++k) ASSERT_EQ(f.values[i + k], 0.0f) << i;
  }
}

// Render space: the snow slab moved 10^6 units away (its camera with it) renders the image
// it renders at the origin, value for value.
TEST(HdGranular, AStageMovedFarFromTheOriginRendersAsAtTheOrigin) {
  auto renderMoved = [](double far) {
    UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
    UsdGeomXformable world(stage->GetPrimAtPath(SdfPath("/World")));
    if (far != 0) world.AddTranslateOp(UsdGeomXformOp::PrecisionDouble, TfToken("far")).Set(GfVec3d(far, far, far));
    auto engine = makeEngine(4);
    engine->SetRendererSetting(TfToken("granular:roulette"), VtValue(0.5f));
    return render(*engine, stage, HdAovTokens->color, 32, 20);
  };
  const Frame near = renderMoved(0), far = renderMoved(1e6);
  ASSERT_EQ(near.values.size(), far.values.size());
  EXPECT_GT(mean(near, 0), 0.01);
  EXPECT_EQ(near.values, far.values);
}

TEST(HdGranular, StoppingMidRenderIsClean) {
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/sandcastle.usda");
  for (int i = 0; i < 3; ++i) {
    auto engine = makeEngine(100000);  // never converges: destroyed while rendering
    engine->SetCameraPath(SdfPath("/World/Camera"));
    engine->SetRenderBufferSize(GfVec2i(64, 40));
    engine->SetFraming(CameraUtilFraming(GfRect2i(GfVec2i(0, 0), 64, 40)));
    engine->SetRendererAov(HdAovTokens->color);
    UsdImagingGLRenderParams params;
    engine->Render(stage->GetPseudoRoot(), params);
    EXPECT_FALSE(engine->IsConverged());
  }
}

TEST(HdGranular, PointInstancerInstancesAreRendered) {
  // One instanced quad under a uniform sky, seen from the front: 3 instances cover
  // 3x the pixels of 1 (the alpha channel counts coverage).
  auto coverage = [](int instances) {
    UsdStageRefPtr stage = quadInstancerStage(instances);
    auto engine = makeEngine(4);
    Frame f = render(*engine, stage, HdAovTokens->color, 40, 40);
    EXPECT_TRUE(f.converged);
    return mean(f, 3);
  };
  double one = coverage(1), three = coverage(3);
  EXPECT_GT(one, 0.0);
  EXPECT_NEAR(three, 3.0 * one, 0.15 * one);
}

namespace {

// The snow slab with every light deactivated.
UsdStageRefPtr unlitSnowslab() {
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  for (UsdPrim const& prim : stage->Traverse())
    if (prim.HasAPI<UsdLuxLightAPI>()) prim.SetActive(false);
  return stage;
}

template <typename T>
T stat(VtDictionary const& stats, const char* key) {
  auto it = stats.find(key);
  EXPECT_NE(it, stats.end()) << key;
  if (it == stats.end()) return T();
  EXPECT_TRUE(it->second.template CanCast<T>()) << key;
  // A named copy, read by const reference: the rvalue Get() swaps the value with an
  // uninitialised local (UBSan: a bool loaded with a value that is not 0 or 1).
  const VtValue value = VtValue::Cast<T>(it->second);
  return value.template UncheckedGet<T>();
}

}  // namespace

TEST(HdGranular, EveryDocumentedRenderStatIsReported) {
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  auto engine = makeEngine(4);
  Frame f = render(*engine, stage, HdAovTokens->color, 32, 20);
  ASSERT_TRUE(f.converged);
  VtDictionary stats = engine->GetRenderStats();
  EXPECT_EQ(stat<double>(stats, "percentDone"), 100.0);
  EXPECT_EQ(stat<int>(stats, "numCompletedSamples"), 4);
  EXPECT_GT(stat<double>(stats, "granular:grains"), 1e3);  // the slab holds ~10^4..10^5 grains
  const double sigmaT = stat<double>(stats, "granular:sigmaT");
  EXPECT_TRUE(std::isfinite(sigmaT) && sigmaT > 0) << sigmaT;
  const double lod = stat<double>(stats, "granular:lodFraction");
  EXPECT_TRUE(lod >= 0 && lod <= 1) << lod;
  EXPECT_EQ(stat<int>(stats, "granular:nonFiniteSamples"), 0);
  EXPECT_EQ(stat<int>(stats, "granular:lostPaths"), 0);
  EXPECT_FALSE(stat<bool>(stats, "granular:defaultLight"));
  // 0 where the render kept the stand-ins' image on screen (renderer.h).
  EXPECT_GE(stat<double>(stats, "granular:firstImageSeconds"), 0.0);
  EXPECT_GT(stat<double>(stats, "granular:firstPassSeconds"), 0.0);
  EXPECT_EQ(stat<int>(stats, "granular:widenedSuns"), 0);  // its sun has an angle of 5°
  // Its sun and sky, by their prim paths, with their chances (core: Scene::lightPicksText).
  const std::string picks = stat<std::string>(stats, "granular:lightPicks");
  EXPECT_NE(picks.find("/World/Sun "), std::string::npos) << picks;
  EXPECT_NE(picks.find("/World/Sky "), std::string::npos) << picks;
  EXPECT_NE(picks.find('%'), std::string::npos) << picks;
  EXPECT_EQ(stat<std::string>(stats, "granular:lightLinks"), "");  // no light is linked
  EXPECT_EQ(stat<int>(stats, "granular:sceneBuilds"), 1);
  EXPECT_EQ(stat<int>(stats, "granular:aggregatesBuilt"), 1);
  EXPECT_EQ(stat<int>(stats, "granular:aggregatesReused"), 0);
  EXPECT_EQ(stat<int>(stats, "granular:mediaDerived"), 1);
  EXPECT_EQ(stat<int64_t>(stats, "granular:instancedGrains"), 0);  // no instancer of explicit grains
}

// The albedo AOV is core's: a Lambert card's displayColor wherever the card is seen, as
// granular render writes it (tests/python/test_denoise.py).
TEST(HdGranular, TheAlbedoAovIsTheFirstHitsReflectance) {
  UsdStageRefPtr stage = domeLitStage(40, R"(
  def Mesh "Card" {
    point3f[] points = [(-9, -9, 0), (9, -9, 0), (9, 9, 0), (-9, 9, 0)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    color3f[] primvars:displayColor = [(0.3, 0.5, 0.7)]
  }
)");
  auto engine = makeEngine(2);
  Frame f = render(*engine, stage, TfToken("albedo"), 12, 12);
  ASSERT_TRUE(f.converged);
  ASSERT_EQ(f.channels, 3);
  for (size_t i = 0; i < f.values.size(); i += 3) {
    EXPECT_NEAR(f.values[i], 0.3f, 1e-6f) << i;
    EXPECT_NEAR(f.values[i + 1], 0.5f, 1e-6f) << i;
    EXPECT_NEAR(f.values[i + 2], 0.7f, 1e-6f) << i;
  }
}

namespace {

// A grey card behind a smaller white quad, seen whole under the uniform dome: every pixel
// is covered by one of the two.
UsdStageRefPtr cardAndQuad() {
  return domeLitStage(40, R"(
  def Mesh "Card" {
    point3f[] points = [(-9, -9, -1), (9, -9, -1), (9, 9, -1), (-9, 9, -1)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    color3f[] primvars:displayColor = [(0.5, 0.5, 0.5)]
  }
  def Mesh "Front" {
    point3f[] points = [(-2, -2, 0), (0.5, -2, 0), (0.5, 2, 0), (-2, 2, 0)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    color3f[] primvars:displayColor = [(0.9, 0.9, 0.9)]
  }
)");
}

uint32_t bitsOf(float f) {
  uint32_t u;
  std::memcpy(&u, &f, 4);
  return u;
}

// {name: id bits} of a Cryptomatte manifest ({"name":"8 hex digits",...}, names without quotes).
std::map<std::string, uint32_t> parseManifest(std::string const& json) {
  std::map<std::string, uint32_t> out;
  static const std::regex entry(R"re("([^"]*)":"([0-9a-f]{8})")re");
  for (std::sregex_iterator it(json.begin(), json.end(), entry), end; it != end; ++it)
    out[(*it)[1]] = uint32_t(std::stoul((*it)[2], nullptr, 16));
  return out;
}

}  // namespace

// sampleCount is the converged spp everywhere; the variance AOV, the estimated variance of
// each pixel's mean, agrees on average with what two seeds' images differ by
// (E[(c1 - c2)^2] / 2 is that variance, pixel by pixel).
TEST(HdGranular, SampleCountAndVarianceAovsAreTheFilms) {
  UsdStageRefPtr stage = domeLitStage(40, R"(
  def Mesh "Card" {
    point3f[] points = [(-9, -9, -1), (9, -9, -1), (9, 9, -1), (-9, 9, -1)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
  }
  def Cube "Box" {
    double size = 1.5
  }
)");
  const int spp = 8;
  auto engine = makeEngine(spp);
  Frame count = render(*engine, stage, TfToken("sampleCount"), 32, 32);
  ASSERT_TRUE(count.converged);
  ASSERT_EQ(count.channels, 1);
  for (float n : count.values) EXPECT_EQ(n, float(spp));
  Frame variance = render(*engine, stage, TfToken("variance"), 32, 32);
  ASSERT_EQ(variance.channels, 3);
  // Both sides are sums over pixels of independent terms (a pixel's three channels
  // together: they are correlated): their standard errors come from the terms' own spread.
  double predicted = 0, observed = 0, predicted2 = 0, observed2 = 0;
  for (size_t p = 0; p + 2 < variance.values.size(); p += 3) {
    double term = 0;
    for (int c = 0; c < 3; ++c) {
      EXPECT_GE(variance.values[p + c], 0.0f);
      term += variance.values[p + c];
    }
    predicted += term;
    predicted2 += term * term;
  }
  Frame c1 = render(*engine, stage, HdAovTokens->color, 32, 32);
  auto other = makeEngine(spp);
  other->SetRendererSetting(TfToken("granular:seed"), VtValue(7));
  Frame c2 = render(*other, stage, HdAovTokens->color, 32, 32);
  ASSERT_EQ(c1.values.size(), c2.values.size());
  for (size_t p = 0; p + 3 < c1.values.size(); p += 4) {
    double term = 0;
    for (int c = 0; c < 3; ++c) term += 0.5 * double(c1.values[p + c] - c2.values[p + c]) * (c1.values[p + c] - c2.values[p + c]);
    observed += term;
    observed2 += term * term;
  }
  ASSERT_GT(observed, 0.0);
  // (c1 - c2)^2 / 2 estimates each pixel's variance of the mean, as the AOV does: their sums
  // agree within 4 standard errors of the ratio (the relative errors of both sums, added).
  auto relativeError = [](double sum, double sum2, double n) {
    return std::sqrt(std::max(0.0, sum2 - sum * sum / n)) / sum;  // sqrt(n var) / (n mean)
  };
  const double n = double(variance.values.size() / 3);
  const double tolerance = 4.0 * std::hypot(relativeError(predicted, predicted2, n), relativeError(observed, observed2, n));
  EXPECT_NEAR(predicted / observed, 1.0, tolerance) << predicted << " " << observed;
  std::printf("variance AOV over the two seeds' spread: %.4f (tolerance %.4f)\n", predicted / observed, tolerance);
}

// instanceId: each PointInstancer instance's index where it is seen, -1 elsewhere;
// aggregateId: the aggregate's prim id (its primId) where its grains are seen, -1 elsewhere.
TEST(HdGranular, InstanceAndAggregateIdAovs) {
  UsdStageRefPtr stage = quadInstancerStage(3);
  auto engine = makeEngine(1);
  Frame f = render(*engine, stage, HdAovTokens->instanceId, 40, 40);
  ASSERT_TRUE(f.converged);
  ASSERT_EQ(f.channels, 1);
  std::map<int, std::pair<int, int>> columns;  // instance -> leftmost, rightmost column
  for (int y = 0; y < f.height; ++y)
    for (int x = 0; x < f.width; ++x) {
      const int id = int(f.values[size_t(y) * f.width + x]);
      ASSERT_GE(id, -1);
      ASSERT_LE(id, 2);
      auto [it, fresh] = columns.try_emplace(id, x, x);
      it->second.first = std::min(it->second.first, x);
      it->second.second = std::max(it->second.second, x);
    }
  ASSERT_EQ(columns.size(), 4u);
  EXPECT_LT(columns[0].second, columns[1].first);
  EXPECT_LT(columns[1].second, columns[2].first);
  Frame aggregates = render(*engine, stage, TfToken("aggregateId"), 40, 40);
  for (float v : aggregates.values) EXPECT_EQ(v, -1.0f);

  UsdStageRefPtr slab = unlitSnowslab();
  auto slabEngine = makeEngine(1);
  Frame agg = render(*slabEngine, slab, TfToken("aggregateId"), 32, 20);
  Frame prim = render(*slabEngine, slab, HdAovTokens->primId, 32, 20);
  ASSERT_EQ(agg.values.size(), prim.values.size());
  int seen = 0;
  for (size_t i = 0; i < agg.values.size(); ++i) {
    if (agg.values[i] == -1.0f) continue;
    ++seen;
    EXPECT_EQ(agg.values[i], prim.values[i]) << i;
    EXPECT_GE(agg.values[i], 0.0f);
  }
  EXPECT_GT(seen, int(agg.values.size()) / 10);  // the slab fills about a fifth of the view
}

// CryptoObject00 and CryptoMaterial00 (float4: id, coverage, id, coverage): decoded with the
// manifest the delegate reports, the quad's pixels are the quad's, the rest the card's, and
// each pixel's coverages add up to 1 (every pixel is covered).
TEST(HdGranular, CryptomatteAovsDecodeWithTheReportedManifest) {
  UsdStageRefPtr stage = cardAndQuad();
  auto engine = makeEngine(4);
  Frame obj = render(*engine, stage, TfToken("CryptoObject00"), 32, 32);
  ASSERT_TRUE(obj.converged);
  ASSERT_EQ(obj.channels, 4);
  VtDictionary stats = engine->GetRenderStats();
  VtDictionary manifests = stat<VtDictionary>(stats, "granular:cryptomatte");
  auto objects = parseManifest(stat<std::string>(manifests, "CryptoObject"));
  ASSERT_EQ(objects.size(), 2u) << stat<std::string>(manifests, "CryptoObject");
  const uint32_t card = objects["/World/Card"], front = objects["/World/Front"];
  int frontPixels = 0;
  for (int y = 0; y < obj.height; ++y)
    for (int x = 0; x < obj.width; ++x) {
      const float* p = &obj.values[(size_t(y) * obj.width + x) * 4];
      EXPECT_NEAR(p[1] + p[3], 1.0f, 1e-6f) << x << "," << y;
      EXPECT_TRUE(bitsOf(p[0]) == card || bitsOf(p[0]) == front) << x << "," << y;
      if (p[1] == 1.0f && bitsOf(p[0]) == front) ++frontPixels;
    }
  // The view is [-4, 4]^2 at the quad's distance, 4 pixels a unit: the quad is columns
  // [8, 18) and rows [8, 24), 160 pixels (less a few on its edges).
  EXPECT_GT(frontPixels, 140);
  EXPECT_LE(frontPixels, 160);
  // The left half of the centre row is the quad's, the right edge the card's.
  EXPECT_EQ(bitsOf(obj.values[(size_t(16) * 32 + 12) * 4]), front);
  EXPECT_EQ(bitsOf(obj.values[(size_t(16) * 32 + 30) * 4]), card);

  Frame mat = render(*engine, stage, TfToken("CryptoMaterial00"), 32, 32);
  auto materials = parseManifest(stat<std::string>(stat<VtDictionary>(engine->GetRenderStats(), "granular:cryptomatte"),
                                                   "CryptoMaterial"));
  ASSERT_EQ(materials.size(), 2u);
  EXPECT_EQ(bitsOf(mat.values[(size_t(16) * 32 + 12) * 4]), materials["/World/Front.displayColor"]);
  EXPECT_EQ(bitsOf(mat.values[(size_t(16) * 32 + 30) * 4]), materials["/World/Card.displayColor"]);
  // Ranks 2 and 3 are empty: two objects at most per pixel.
  Frame rest = render(*engine, stage, TfToken("CryptoObject01"), 32, 32);
  for (float v : rest.values) EXPECT_EQ(v, 0.0f);
}

// Core's warnings and errors reach the host as granular render prints them: once each in
// the render stats granular:warnings, and the error that refused the image in granular:error.
TEST(HdGranular, CoresWarningsAndErrorsAreRenderStats) {
  UsdStageRefPtr stage = domeLitStage(40, R"(
  def PluginLight "Plugin" {
  }
  def SphereLight "Bulb" {
    bool treatAsPoint = 1
  }
)");
  auto engine = makeEngine(2);
  Frame f = render(*engine, stage, HdAovTokens->color, 16, 16);
  ASSERT_TRUE(f.converged);
  VtDictionary stats = engine->GetRenderStats();
  VtStringArray warnings = stat<VtStringArray>(stats, "granular:warnings");
  std::set<std::string> given(warnings.begin(), warnings.end());
  EXPECT_EQ(given.count("/World/Plugin: PluginLight lights are not supported; skipped"), 1u);
  EXPECT_EQ(given.count("/World/Bulb.treatAsPoint: not supported; rendered as a sphere of inputs:radius"), 1u);
  EXPECT_EQ(warnings.size(), given.size());  // each once
  EXPECT_EQ(stat<std::string>(stats, "granular:error"), "");

  stage->GetPrimAtPath(SdfPath("/World/Bulb")).GetAttribute(TfToken("inputs:intensity")).Set(-1.0f);
  Frame bad = render(*engine, stage, HdAovTokens->color, 16, 16);
  EXPECT_TRUE(bad.converged);
  EXPECT_EQ(stat<std::string>(engine->GetRenderStats(), "granular:error"),
            "/World/Bulb.inputs:intensity: -1 must be finite and >= 0");
}

TEST(HdGranular, AStageWithoutLightsGetsTheDefaultDomeUnlessTurnedOff) {
  UsdStageRefPtr stage = unlitSnowslab();
  auto engine = makeEngine(2);
  Frame lit = render(*engine, stage, HdAovTokens->color, 32, 20);
  ASSERT_TRUE(lit.converged);
  EXPECT_GT(mean(lit, 0), 0.05);  // white snow under a white sky of radiance 1
  EXPECT_TRUE(stat<bool>(engine->GetRenderStats(), "granular:defaultLight"));

  engine->SetRendererSetting(TfToken("granular:defaultLight"), VtValue(false));
  Frame dark = render(*engine, stage, HdAovTokens->color, 32, 20);
  ASSERT_TRUE(dark.converged);
  for (size_t i = 0; i < dark.values.size(); i += 4)
    for (int c = 0; c < 3; ++c) ASSERT_EQ(dark.values[i + c], 0.0f);
  EXPECT_FALSE(stat<bool>(engine->GetRenderStats(), "granular:defaultLight"));
}

TEST(HdGranular, TheNoiseThresholdStopsSimpleScenesEarlierThanHardOnes) {
  // A grey card under a uniform sky against the snow slab, at the same threshold: the
  // card's pixels are quiet after a few samples, the slab's grains need many more.
  UsdStageRefPtr card = domeLitStage(10, R"(
  def Mesh "Card" {
    point3f[] points = [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
  }
)");
  UsdStageRefPtr slab = UsdStage::Open(kExamples + "/snowslab.usda");
  const int cap = 4096;
  auto samplesAtThreshold = [&](UsdStageRefPtr const& stage) {
    auto engine = makeEngine(cap);
    engine->SetRendererSetting(HdRenderSettingsTokens->convergedVariance, VtValue(0.05f));
    Frame f = render(*engine, stage, HdAovTokens->color, 24, 16);
    EXPECT_TRUE(f.converged);
    return stat<int>(engine->GetRenderStats(), "numCompletedSamples");
  };
  const int simple = samplesAtThreshold(card), hard = samplesAtThreshold(slab);
  std::printf("noise threshold 0.05: grey card %d samples per pixel, snow slab %d\n", simple, hard);
  EXPECT_LT(simple, hard);
  EXPECT_LT(hard, cap);  // the threshold, not the sample cap, ended it
  EXPECT_GE(simple, 2);
}

// granular:denoise: the color AOV shows core's denoised beauty (nearer a 256-sample
// reference than the raw 4-sample one is), every other AOV stays raw, bit for bit.
TEST(HdGranular, DenoiseShowsTheDenoisedBeautyAndLeavesOtherAovsRaw) {
  // A ball in front of a card under a uniform sky: the card's shadowing makes the noise.
  UsdStageRefPtr stage = domeLitStage(40, R"(
  def Mesh "Card" {
    point3f[] points = [(-9, -9, 0), (9, -9, 0), (9, 9, 0), (-9, 9, 0)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    color3f[] primvars:displayColor = [(0.7, 0.6, 0.5)]
  }
  def Sphere "Ball" {
    double radius = 2
    double3 xformOp:translate = (0, 0, 2.5)
    uniform token[] xformOpOrder = ["xformOp:translate"]
  }
)");
  const int w = 48, h = 48;
  const TfToken kDenoise("granular:denoise"), kAlbedo("albedo");
  auto engine = makeEngine(4);
  Frame raw = render(*engine, stage, HdAovTokens->color, w, h);
  Frame rawAlbedo = render(*engine, stage, kAlbedo, w, h);
  Frame rawNormal = render(*engine, stage, HdAovTokens->normal, w, h);
  ASSERT_TRUE(raw.converged && rawAlbedo.converged && rawNormal.converged);
  const bool available = stat<bool>(engine->GetRenderStats(), "granular:denoiserAvailable");
  engine->SetRendererSetting(kDenoise, VtValue(true));
  Frame den = render(*engine, stage, HdAovTokens->color, w, h);
  Frame denAlbedo = render(*engine, stage, kAlbedo, w, h);
  Frame denNormal = render(*engine, stage, HdAovTokens->normal, w, h);
  ASSERT_TRUE(den.converged && denAlbedo.converged && denNormal.converged);
  EXPECT_EQ(denAlbedo.values, rawAlbedo.values);
  EXPECT_EQ(denNormal.values, rawNormal.values);
  if (!available) {  // one warning, and the raw beauty
    EXPECT_EQ(den.values, raw.values);
    GTEST_SKIP() << "this build has no Intel Open Image Denoise";
  }
  auto refEngine = makeEngine(256);
  Frame ref = render(*refEngine, stage, HdAovTokens->color, w, h);
  ASSERT_TRUE(ref.converged);
  ASSERT_EQ(den.values.size(), ref.values.size());
  auto relmse = [&](Frame const& f) {
    double s = 0;
    for (size_t i = 0; i < f.values.size(); i += 4)
      for (int c = 0; c < 3; ++c) {
        const double r = ref.values[i + c], d = f.values[i + c] - r;
        s += d * d / (r * r + 1e-2);
      }
    return s / double(f.values.size() / 4 * 3);
  };
  for (size_t i = 0; i < den.values.size(); i += 4) {
    ASSERT_TRUE(std::isfinite(den.values[i]) && std::isfinite(den.values[i + 1]) && std::isfinite(den.values[i + 2]));
    EXPECT_EQ(den.values[i + 3], raw.values[i + 3]) << "alpha stays raw at " << i / 4;
  }
  const double before = relmse(raw), after = relmse(den);
  std::printf("granular:denoise: relative MSE to 256 spp %.4g raw, %.4g denoised\n", before, after);
  // The reference's own noise is 64 times below the raw image's.
  EXPECT_LT(after, 0.5 * before);
}

TEST(HdGranular, BuffersSurviveResizesAovSwitchesAndCameraMovesWhileRendering) {
  // 200 cycles of a new buffer size, a new AOV (buffers freed and made) and a moved free
  // camera, each while the loop renders (the sample count never converges); then the
  // final image must equal a fresh render of the same view, value for value.
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  auto engine = makeEngine(100000);
  GfCamera camera = UsdGeomCamera(stage->GetPrimAtPath(SdfPath("/World/Camera"))).GetCamera(UsdTimeCode::Default());
  const TfToken aovs[] = {HdAovTokens->color, HdAovTokens->depth, HdAovTokens->normal, TfToken("ept"),
                          HdAovTokens->primId};
  UsdImagingGLRenderParams params;
  for (int i = 0; i < 200; ++i) {
    const int w = 40 + 8 * (i % 3), h = 24 + 8 * (i % 2);
    engine->SetRenderBufferSize(GfVec2i(w, h));
    engine->SetFraming(CameraUtilFraming(GfRect2i(GfVec2i(0, 0), w, h)));
    engine->SetRendererAov(aovs[(i / 2) % 5]);
    GfCamera moved = camera;
    moved.SetTransform(camera.GetTransform() * GfMatrix4d().SetTranslate(GfVec3d(0.01 * (i % 7), 0, 0)));
    engine->SetCameraState(moved.GetFrustum().ComputeViewMatrix(), moved.GetFrustum().ComputeProjectionMatrix());
    engine->Render(stage->GetPseudoRoot(), params);
    ASSERT_FALSE(engine->IsConverged());
  }
  engine->SetRendererSetting(HdRenderSettingsTokens->convergedSamplesPerPixel, VtValue(2));
  Frame after = render(*engine, stage, HdAovTokens->color, 32, 20);
  auto fresh = makeEngine(2);
  Frame expected = render(*fresh, stage, HdAovTokens->color, 32, 20);
  ASSERT_TRUE(after.converged && expected.converged);
  ASSERT_EQ(after.values.size(), expected.values.size());
  for (size_t i = 0; i < after.values.size(); ++i) {
    ASSERT_TRUE(std::isfinite(after.values[i]));
    ASSERT_EQ(after.values[i], expected.values[i]) << i;
  }
  EXPECT_EQ(stat<int>(engine->GetRenderStats(), "granular:nonFiniteSamples"), 0);
}

// Animation through the delegate: each frame rebuilds only what it dirties (renderPass.cpp:
// the scene before lends its unchanged aggregates; a camera move is Scene::setView).
namespace {

struct BuildCounts {
  int scenes, built, reused, media;
};

BuildCounts buildCounts(UsdImagingGLEngine& engine) {
  VtDictionary s = engine.GetRenderStats();
  return {stat<int>(s, "granular:sceneBuilds"), stat<int>(s, "granular:aggregatesBuilt"),
          stat<int>(s, "granular:aggregatesReused"), stat<int>(s, "granular:mediaDerived")};
}

void expectSameFrame(Frame const& a, Frame const& b, double time) {
  ASSERT_TRUE(a.converged && b.converged) << time;
  ASSERT_EQ(a.values.size(), b.values.size()) << time;
  for (size_t i = 0; i < a.values.size(); ++i) ASSERT_EQ(a.values[i], b.values[i]) << "frame " << time << " value " << i;
}

}  // namespace

TEST(HdGranularAnimation, ALightThatDoublesPerFrameDoublesTheImageAndVoxelisesNothing) {
  // The sun alone (the sky deactivated), its intensity 500, 1000, 2000 at frames 1, 2, 3; the
  // roulette fixed, so the same seed traces the same paths and only the weights double —
  // exactly, a factor of 2 being exact in binary floating point.
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  stage->GetPrimAtPath(SdfPath("/World/Sky")).SetActive(false);
  UsdAttribute intensity = stage->GetPrimAtPath(SdfPath("/World/Sun")).GetAttribute(TfToken("inputs:intensity"));
  for (int frame = 1; frame <= 3; ++frame) ASSERT_TRUE(intensity.Set(500.0f * float(1 << (frame - 1)), UsdTimeCode(frame)));
  auto engine = makeEngine(4);
  engine->SetRendererSetting(TfToken("granular:roulette"), VtValue(0.5f));
  Frame previous;
  for (int frame = 1; frame <= 3; ++frame) {
    Frame f = render(*engine, stage, HdAovTokens->color, 32, 20, UsdTimeCode(frame));
    ASSERT_TRUE(f.converged) << frame;
    const BuildCounts counts = buildCounts(*engine);
    EXPECT_EQ(counts.scenes, frame);
    EXPECT_EQ(counts.built, 1) << "frame " << frame << " voxelised the slab again";
    EXPECT_EQ(counts.reused, frame - 1);
    EXPECT_EQ(counts.media, 1) << "frame " << frame << " derived the medium again";
    if (frame > 1) {
      ASSERT_EQ(f.values.size(), previous.values.size());
      for (size_t i = 0; i < f.values.size(); i += 4)
        for (int c = 0; c < 3; ++c) ASSERT_EQ(f.values[i + c], 2.0f * previous.values[i + c]) << frame << " " << i;
      EXPECT_GT(mean(previous, 0), 0.01);
    }
    previous = f;
  }
}

TEST(HdGranularAnimation, AnEditThatLeavesTheDescriptionAsItWasBuildsNothing) {
  // The sun's intensity is time-sampled but holds still from frame 1 to 2: Hydra syncs the
  // light again, the description compares equal (compareScenes), and the scene is kept.
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  UsdAttribute intensity = stage->GetPrimAtPath(SdfPath("/World/Sun")).GetAttribute(TfToken("inputs:intensity"));
  ASSERT_TRUE(intensity.Set(500.0f, UsdTimeCode(1)));
  ASSERT_TRUE(intensity.Set(500.0f, UsdTimeCode(2)));
  ASSERT_TRUE(intensity.Set(1000.0f, UsdTimeCode(3)));
  auto engine = makeEngine(2);
  const int builds[] = {1, 1, 2};
  for (int frame = 1; frame <= 3; ++frame) {
    ASSERT_TRUE(render(*engine, stage, HdAovTokens->color, 32, 20, UsdTimeCode(frame)).converged) << frame;
    const BuildCounts counts = buildCounts(*engine);
    EXPECT_EQ(counts.scenes, builds[frame - 1]) << "frame " << frame;
    EXPECT_EQ(counts.built, 1) << "frame " << frame;
  }
}

TEST(HdGranularAnimation, AMovingCameraMatchesSingleFrameRendersAndRebuildsNothing) {
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  UsdAttribute xf = stage->GetPrimAtPath(SdfPath("/World/Camera")).GetAttribute(TfToken("xformOp:transform"));
  GfMatrix4d m;
  ASSERT_TRUE(xf.Get(&m));
  for (int frame = 1; frame <= 3; ++frame)
    ASSERT_TRUE(xf.Set(m * GfMatrix4d().SetTranslate(GfVec3d(-0.15 * frame, 0.05 * frame, 0)), UsdTimeCode(frame)));
  auto engine = makeEngine(2);
  for (int frame = 1; frame <= 3; ++frame) {
    Frame moving = render(*engine, stage, HdAovTokens->color, 32, 20, UsdTimeCode(frame));
    auto fresh = makeEngine(2);
    expectSameFrame(moving, render(*fresh, stage, HdAovTokens->color, 32, 20, UsdTimeCode(frame)), frame);
    const BuildCounts counts = buildCounts(*engine);
    EXPECT_EQ(counts.scenes, 1) << "frame " << frame;
    EXPECT_EQ(counts.built, 1);
  }
}

TEST(HdGranularAnimation, AMovingBoundaryRebuildsOnlyItsAggregateAndMatchesSingleFrameRenders) {
  // A second slab on top of the first, moving up by 5 cm a frame.
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  UsdPrim top = stage->DefinePrim(SdfPath("/World/SnowTop"));
  ASSERT_TRUE(top.GetReferences().AddInternalReference(SdfPath("/World/Snow")));
  UsdGeomXformOp translate = UsdGeomXformable(top).AddTranslateOp();
  for (int frame = 1; frame <= 3; ++frame) ASSERT_TRUE(translate.Set(GfVec3d(0, 0.3 + 0.05 * frame, 0), UsdTimeCode(frame)));
  auto engine = makeEngine(2);
  for (int frame = 1; frame <= 3; ++frame) {
    Frame moving = render(*engine, stage, HdAovTokens->color, 32, 20, UsdTimeCode(frame));
    const BuildCounts counts = buildCounts(*engine);
    EXPECT_EQ(counts.scenes, frame);
    EXPECT_EQ(counts.built, 2 + (frame - 1)) << "frame " << frame << ": only the moving slab is voxelised again";
    EXPECT_EQ(counts.reused, frame - 1);
    EXPECT_EQ(counts.media, 2 + (frame - 1));
    auto fresh = makeEngine(2);
    expectSameFrame(moving, render(*fresh, stage, HdAovTokens->color, 32, 20, UsdTimeCode(frame)), frame);
  }
}

TEST(HdGranular, ADeltaSunOverSmoothGrainsIsThePhysicalSunUnlessTurnedOff) {
  // The snow slab's sun made a delta light (angle 0): core renders it as the 0.53° sun of
  // the same irradiance (scene.h: widenedSuns), as granular render does.
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  ASSERT_TRUE(stage->GetPrimAtPath(SdfPath("/World/Sun")).GetAttribute(TfToken("inputs:angle")).Set(0.0f));
  auto engine = makeEngine(2);
  Frame widened = render(*engine, stage, HdAovTokens->color, 32, 20);
  ASSERT_TRUE(widened.converged);
  EXPECT_EQ(stat<int>(engine->GetRenderStats(), "granular:widenedSuns"), 1);
  engine->SetRendererSetting(TfToken("granular:physicalSun"), VtValue(false));
  Frame delta = render(*engine, stage, HdAovTokens->color, 32, 20);
  ASSERT_TRUE(delta.converged);
  EXPECT_EQ(stat<int>(engine->GetRenderStats(), "granular:widenedSuns"), 0);
  EXPECT_EQ(stat<int>(engine->GetRenderStats(), "granular:sceneBuilds"), 2);  // a setting that rebuilds
}

namespace {

// A floor (40 x 40, the z = 0 plane) facing domeLitStage's camera, 10 away.
const char* const kFloorFacingCamera = R"(
  def Mesh "Floor" {
    point3f[] points = [(-20, -20, 0), (20, -20, 0), (20, 20, 0), (-20, 20, 0)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
  }
)";

// The mean red radiance of a size x size render of the stage and its standard error, from
// the variance AOV (per pixel, the variance of its mean; the pixels are independent).
double meanAndError(UsdImagingGLEngine& engine, UsdStageRefPtr const& stage, int size, double& se) {
  Frame c = render(engine, stage, HdAovTokens->color, size, size);
  EXPECT_TRUE(c.converged);
  Frame v = render(engine, stage, TfToken("variance"), size, size);
  double variance = 0;
  for (size_t p = 0; p < v.values.size(); p += 3) variance += v.values[p];
  se = std::sqrt(variance) / (double(size) * size);
  return mean(c, 0);
}

}  // namespace

TEST(HdGranular, AnAreaLightHidesWhatLiesBehindItFromShadowRaysAsFromEveryRay) {
  // A floor facing the camera (10 away) under the dome and a 20° sun behind the camera, and
  // a black sphere light of radius 5 centred on the camera (its rays start inside it, which
  // does not stop them). From the floor in view the bulb hides the whole sun and the
  // projected solid angle π (r/δ)² cos θ of the dome (δ to its centre, cos θ = 10/δ), as
  // in core's AreaLightOcclusion test: the floor's radiance is that under the dome alone
  // times 1 − 250/δ³. When shadow rays crossed area lights, light sampling found the sun.
  const std::string floor = kFloorFacingCamera;
  UsdStageRefPtr hidden = domeLitStage(4, floor + R"(
  def DistantLight "Sun" {
    float inputs:angle = 20
    float inputs:intensity = 10
  }
  def SphereLight "Bulb" {
    float inputs:radius = 5
    float inputs:intensity = 0
    double3 xformOp:translate = (0, 0, 10)
    uniform token[] xformOpOrder = ["xformOp:translate"]
  }
)");
  UsdStageRefPtr open = domeLitStage(4, floor);
  // An engine per stage.
  double seHidden = 0, seOpen = 0;
  const double withBulb = meanAndError(*makeEngine(64), hidden, 16, seHidden);
  const double underDome = meanAndError(*makeEngine(64), open, 16, seOpen);
  ASSERT_GT(underDome, 0.0);
  // The camera (focal length 50, aperture 4) sees the floor over [−0.4, 0.4]²: the mean of
  // 1 − 250/δ³ over it by the midpoint rule (a smooth integrand: error < 1e-6).
  double fraction = 0;
  const int n = 200;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      const double x = -0.4 + 0.8 * (i + 0.5) / n, y = -0.4 + 0.8 * (j + 0.5) / n;
      const double delta = std::sqrt(x * x + y * y + 100);
      fraction += (1 - 250 / (delta * delta * delta)) / (n * n);
    }
  // The ratio's standard error from both means' (their relative errors added in quadrature).
  const double ratio = withBulb / underDome;
  const double se = ratio * std::hypot(seHidden / withBulb, seOpen / underDome);
  EXPECT_GT(se, 0.0);
  EXPECT_NEAR(ratio, fraction, 4 * se) << "se " << se;
  std::printf("under the black bulb / under the dome alone: %.4f (exact %.4f, se %.4f)\n", ratio, fraction, se);
}

TEST(HdGranular, LightLinkingLightsOnlyTheLinkedPrimsAndFollowsEditsOfTheCollection) {
  // A floor facing the camera under the dome and a normalised 20° sun from behind the camera
  // (irradiance 3), the sun's collection:lightLink excluding the floor: the floor is as under
  // the dome alone (nothing else is there to pass the sun's light on), as granular render
  // renders it (tests/conformance: light_link_*). Then the exclusion is removed from the
  // stage: the same engine renders the sunlit floor.
  const std::string floor = kFloorFacingCamera;
  UsdStageRefPtr linked = domeLitStage(4, floor + R"(
  def DistantLight "Sun" {
    float inputs:angle = 20
    float inputs:intensity = 3
    bool inputs:normalize = 1
    rel collection:lightLink:excludes = </World/Floor>
  }
)");
  UsdStageRefPtr domeAlone = domeLitStage(4, floor);
  auto engine = makeEngine(32);
  double seLinked = 0, seDome = 0, seSunlit = 0;
  const double withLink = meanAndError(*engine, linked, 8, seLinked);
  EXPECT_EQ(stat<std::string>(engine->GetRenderStats(), "granular:lightLinks"), "/World/Sun lights 0 of 1 objects");
  const double underDome = meanAndError(*makeEngine(32), domeAlone, 8, seDome);
  EXPECT_NEAR(withLink, underDome, 4 * std::hypot(seLinked, seDome));
  UsdRelationship excludes = linked->GetPrimAtPath(SdfPath("/World/Sun")).GetRelationship(TfToken("collection:lightLink:excludes"));
  ASSERT_TRUE(excludes.ClearTargets(true));
  const double sunlit = meanAndError(*engine, linked, 8, seSunlit);
  EXPECT_GT(sunlit, 1.5 * underDome);  // the sun's irradiance 3 against the dome's π
  std::printf("floor: linked away %.4f ± %.4f, dome alone %.4f ± %.4f, sunlit %.4f\n", withLink, seLinked, underDome,
              seDome, sunlit);
}

TEST(HdGranular, AnIesProfileScalesTheLightByItsCandelaAndFollowsEdits) {
  // The floor facing the camera under a disk light 3 above it (the dome off), its IES
  // profile 5 candela in every direction of its lower half: the image is 5 times the one
  // without it, sample for sample, as in granular render (tests/python/test_ies.py;
  // tests/conformance: light_ies*). Normalised on the live stage, it is the plain image.
  const std::string file = (std::filesystem::temp_directory_path() /
                            ("granular_hydra_ies_" + std::to_string(::getpid()) + ".ies")).string();
  std::ofstream(file) << "IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 3 1 1 2 0 0 0\n1 1 10\n0 45 90\n0\n5 5 5\n";
  auto stageWith = [&](std::string const& shaping) {
    UsdStageRefPtr stage = domeLitStage(4, std::string(kFloorFacingCamera) + R"(
  def DiskLight "Disk" (
    prepend apiSchemas = ["ShapingAPI"]
  ) {
    float inputs:radius = 0.5
    float inputs:intensity = 4
    double3 xformOp:translate = (0, 0, 3)
    uniform token[] xformOpOrder = ["xformOp:translate"]
)" + shaping + "  }\n");
    EXPECT_TRUE(stage->GetPrimAtPath(SdfPath("/World/Sky")).SetActive(false));
    return stage;
  };
  UsdStageRefPtr profiled = stageWith("    asset inputs:shaping:ies:file = @" + file + "@\n");
  auto engine = makeEngine(8);
  const Frame plain = render(*makeEngine(8), stageWith(""), HdAovTokens->color, 8, 8);
  const Frame five = render(*engine, profiled, HdAovTokens->color, 8, 8);
  ASSERT_TRUE(plain.converged && five.converged);
  EXPECT_EQ(stat<std::string>(engine->GetRenderStats(), "granular:iesProfiles"),
            "/World/Disk: " + std::filesystem::path(file).filename().string() + " (3 × 1 angles, peak 5 cd, mean 5 cd)");
  ASSERT_EQ(plain.values.size(), five.values.size());
  EXPECT_GT(mean(plain, 0), 0);
  for (size_t i = 0; i < plain.values.size(); ++i)
    if (i % plain.channels < 3) EXPECT_NEAR(five.values[i], 5 * plain.values[i], 1e-5f * (1 + five.values[i])) << i;
  ASSERT_TRUE(profiled->GetPrimAtPath(SdfPath("/World/Disk"))
                  .CreateAttribute(TfToken("inputs:shaping:ies:normalize"), SdfValueTypeNames->Bool)
                  .Set(true));
  const Frame normalized = render(*engine, profiled, HdAovTokens->color, 8, 8);
  for (size_t i = 0; i < plain.values.size(); ++i)
    if (i % plain.channels < 3) EXPECT_NEAR(normalized.values[i], plain.values[i], 1e-5f * (1 + plain.values[i])) << i;
  std::filesystem::remove(file);
}

TEST(HdGranular, ShadowLinkingPassesTheObjectsLeftOutOfALightsShadowLinkAndFollowsEdits) {
  // The floor facing the camera under the dome and a normalised 20° sun that leans 27° to
  // +x, and a black card out of view (z = 5, x from 0.5) that stands between the floor in
  // view and the sun, and hides some of the dome. The card left out of both lights'
  // collection:shadowLink: the floor is as without the card (nothing else casts shadows,
  // and the card returns no light), as granular render renders it (tests/conformance:
  // shadow_*). Then the exclusions are removed: the same engine renders the shadow.
  const std::string floor = kFloorFacingCamera;
  const std::string sun = R"(
  def DistantLight "Sun" {
    float inputs:angle = 20
    float inputs:intensity = 3
    bool inputs:normalize = 1
    float3 xformOp:rotateXYZ = (0, 26.6, 0)
    uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    rel collection:shadowLink:excludes = </World/Card>
  }
)";
  const std::string card = R"(
  def Mesh "Card" {
    point3f[] points = [(0.5, -3, 5), (3, -3, 5), (3, 3, 5), (0.5, 3, 5)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    color3f[] primvars:displayColor = [(0, 0, 0)]
  }
)";
  UsdStageRefPtr linked = domeLitStage(4, floor + card + sun);
  ASSERT_TRUE(linked->GetPrimAtPath(SdfPath("/World/Sky"))
                  .CreateRelationship(TfToken("collection:shadowLink:excludes"))
                  .AddTarget(SdfPath("/World/Card")));
  UsdStageRefPtr open = domeLitStage(4, floor + sun);
  auto engine = makeEngine(32);
  double seLinked = 0, seOpen = 0, seShaded = 0;
  const double withLink = meanAndError(*engine, linked, 8, seLinked);
  EXPECT_EQ(stat<std::string>(engine->GetRenderStats(), "granular:shadowLinks"),
            "/World/Sky: 1 of 2 objects cast shadows; /World/Sun: 1 of 2 objects cast shadows");
  const double withoutCard = meanAndError(*makeEngine(32), open, 8, seOpen);
  EXPECT_NEAR(withLink, withoutCard, 4 * std::hypot(seLinked, seOpen));
  for (const char* light : {"/World/Sun", "/World/Sky"})
    ASSERT_TRUE(linked->GetPrimAtPath(SdfPath(light))
                    .GetRelationship(TfToken("collection:shadowLink:excludes"))
                    .ClearTargets(true));
  const double shaded = meanAndError(*engine, linked, 8, seShaded);
  EXPECT_EQ(stat<std::string>(engine->GetRenderStats(), "granular:shadowLinks"), "");
  EXPECT_LT(shaded, 0.6 * withoutCard);  // the sun's irradiance 3 against the dome's π, its rest shaded too
  std::printf("floor: card left out %.4f ± %.4f, no card %.4f ± %.4f, in the card's shadow %.4f\n", withLink,
              seLinked, withoutCard, seOpen, shaded);
}

// The snow slab's grains alone (ground and sky hidden) under its 0.53° sun, explicit grains
// of the given roughness: regularised to 5°, the image is the one of a normalised 5° sun with
// the setting at 0, as granular render's (tests/python/test_physical_sun.py); 0 keeps the
// 0.53° disk exact. A change of view.
namespace {
void expectTheRegularisedSunIsTheWiderDisk(float roughness) {
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  ASSERT_TRUE(stage->GetPrimAtPath(SdfPath("/World/Ground")).SetActive(false));
  ASSERT_TRUE(stage->GetPrimAtPath(SdfPath("/World/Sky")).SetActive(false));
  for (const char* grain : {"/World/Grains/Flake", "/World/Grains/Pellet"}) {
    UsdAttribute attr = stage->GetPrimAtPath(SdfPath(grain)).GetAttribute(TfToken("primvars:granular:roughness"));
    ASSERT_TRUE(attr.Set(roughness)) << grain;
  }
  UsdPrim sun = stage->GetPrimAtPath(SdfPath("/World/Sun"));  // normalised in the example
  auto engine = makeEngine(16);
  engine->SetRendererSetting(TfToken("granular:technique"), VtValue(std::string("ept")));
  engine->SetRendererSetting(TfToken("granular:sunRegularization"), VtValue(5.0f));
  Frame regularised = render(*engine, stage, HdAovTokens->color, 32, 20);
  engine->SetRendererSetting(TfToken("granular:sunRegularization"), VtValue(0.0f));
  Frame exact = render(*engine, stage, HdAovTokens->color, 32, 20);
  EXPECT_EQ(stat<int>(engine->GetRenderStats(), "granular:sceneBuilds"), 1);
  ASSERT_TRUE(sun.GetAttribute(TfToken("inputs:angle")).Set(5.0f));
  Frame wide = render(*engine, stage, HdAovTokens->color, 32, 20);
  ASSERT_TRUE(regularised.converged && exact.converged && wide.converged);
  ASSERT_EQ(regularised.values.size(), wide.values.size());
  double sum = 0;
  bool differs = false;
  for (size_t i = 0; i < wide.values.size(); ++i) {
    ASSERT_NEAR(regularised.values[i], wide.values[i], 1e-5f * std::max(1.0f, std::fabs(wide.values[i]))) << i;
    sum += regularised.values[i];
    differs = differs || regularised.values[i] != exact.values[i];
  }
  EXPECT_GT(sum, 0);
  EXPECT_TRUE(differs);
}
}  // namespace

TEST(HdGranular, SunRegularizationShowsSmoothChainsTheNarrowSunAsTheWiderDiskAsInGranularRender) {
  // Smooth grains: nothing samples the sun, their chains meet the 5° disk.
  expectTheRegularisedSunIsTheWiderDisk(0.0f);
}

TEST(HdGranular, SunRegularizationShowsRoughGrainsTheNarrowSunAsTheWiderDiskAsInGranularRender) {
  // Rough grains sample the 5° disk, and their escapes meet it with its MIS weights.
  expectTheRegularisedSunIsTheWiderDisk(0.3f);
}

TEST(HdGranular, SwitchForViewMeasuresTheSwitchForThisViewAsGranularRenderDoes) {
  // granular:switchForView, as granular render's --switch-for-view: the switch from proxies
  // to the medium is measured for this camera and these lights too (core/switching.h:
  // measureViewSwitch), and granular:switching says so in granular render's words. A
  // change of view: nothing rebuilt.
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  auto engine = makeEngine(4);
  Frame dome = render(*engine, stage, HdAovTokens->color, 32, 20);
  const std::string before = stat<std::string>(engine->GetRenderStats(), "granular:switching");
  EXPECT_NE(before.find("/World/Snow: proxies for"), std::string::npos) << before;
  EXPECT_EQ(before.find("for this view"), std::string::npos) << before;
  engine->SetRendererSetting(TfToken("granular:switchForView"), VtValue(true));
  Frame view = render(*engine, stage, HdAovTokens->color, 32, 20);
  const std::string after = stat<std::string>(engine->GetRenderStats(), "granular:switching");
  EXPECT_NE(after.find("for this view"), std::string::npos) << after;
  EXPECT_EQ(stat<int>(engine->GetRenderStats(), "granular:sceneBuilds"), 1);
  ASSERT_TRUE(dome.converged && view.converged);
  for (float v : view.values) ASSERT_TRUE(std::isfinite(v));
}

TEST(HdGranular, SwitchForViewIsMeasuredApartSoACameraMoveNeverWaitsForIt) {
  // In a viewport the view's measurement is made on a thread of its own (viewSwitch.h):
  // after each camera move the frame renders at once with the dome's choice, provisional
  // (never converged, granular:viewSwitchPending); once the camera stays, the view's
  // choice takes over, and the converged image equals a fresh render of that view, value
  // for value.
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  GfCamera camera = UsdGeomCamera(stage->GetPrimAtPath(SdfPath("/World/Camera"))).GetCamera(UsdTimeCode::Default());
  auto look = [&](UsdImagingGLEngine& engine, double dx) {
    GfCamera moved = camera;
    moved.SetTransform(camera.GetTransform() * GfMatrix4d().SetTranslate(GfVec3d(dx, 0, 0)));
    engine.SetCameraState(moved.GetFrustum().ComputeViewMatrix(), moved.GetFrustum().ComputeProjectionMatrix());
  };
  auto setUp = [&](UsdImagingGLEngine& engine) {
    engine.SetRendererSetting(TfToken("granular:switchForView"), VtValue(true));
    engine.SetRenderBufferSize(GfVec2i(32, 20));
    engine.SetFraming(CameraUtilFraming(GfRect2i(GfVec2i(0, 0), 32, 20)));
    EXPECT_TRUE(engine.SetRendererAov(HdAovTokens->color));
  };
  auto forThisView = [](UsdImagingGLEngine& engine) {
    return stat<std::string>(engine.GetRenderStats(), "granular:switching").find("for this view") != std::string::npos;
  };
  auto engine = makeEngine(2);
  setUp(*engine);
  look(*engine, 0.0);
  ASSERT_TRUE(converge(*engine, stage, HdAovTokens->color).converged);
  EXPECT_TRUE(forThisView(*engine));
  EXPECT_FALSE(stat<bool>(engine->GetRenderStats(), "granular:viewSwitchPending"));
  UsdImagingGLRenderParams params;
  for (int i = 1; i <= 8; ++i) {
    look(*engine, 0.02 * i);
    engine->Render(stage->GetPseudoRoot(), params);
    ASSERT_TRUE(stat<bool>(engine->GetRenderStats(), "granular:viewSwitchPending")) << i;
    ASSERT_FALSE(forThisView(*engine)) << i;
    ASSERT_FALSE(engine->IsConverged()) << i;
  }
  Frame after = converge(*engine, stage, HdAovTokens->color);
  ASSERT_TRUE(after.converged);
  EXPECT_TRUE(forThisView(*engine));
  EXPECT_FALSE(stat<bool>(engine->GetRenderStats(), "granular:viewSwitchPending"));
  EXPECT_EQ(stat<int>(engine->GetRenderStats(), "granular:sceneBuilds"), 1);
  auto fresh = makeEngine(2);
  setUp(*fresh);
  look(*fresh, 0.16);
  Frame expected = converge(*fresh, stage, HdAovTokens->color);
  ASSERT_TRUE(expected.converged);
  ASSERT_EQ(after.values.size(), expected.values.size());
  for (size_t i = 0; i < after.values.size(); ++i) {
    ASSERT_TRUE(std::isfinite(after.values[i]));
    ASSERT_EQ(after.values[i], expected.values[i]) << i;
  }
}

TEST(HdGranular, MediumModelMakesTheMediaAnewAsGranularRendersMediumModelDoes) {
  // granular:mediumModel, as granular render's --medium-model (core/vpt.h): "exits" makes
  // every aggregate's medium anew, a new build, and granular:switching says so in granular
  // render's words; unknown words are refused by name.
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  auto engine = makeEngine(4);
  Frame tt = render(*engine, stage, HdAovTokens->color, 32, 20);
  EXPECT_EQ(stat<std::string>(engine->GetRenderStats(), "granular:switching").find("exits"), std::string::npos);
  engine->SetRendererSetting(TfToken("granular:mediumModel"), VtValue(std::string("exits")));
  Frame exits = render(*engine, stage, HdAovTokens->color, 32, 20);
  const std::string switching = stat<std::string>(engine->GetRenderStats(), "granular:switching");
  EXPECT_NE(switching.find("the medium (exits)"), std::string::npos) << switching;
  EXPECT_EQ(stat<int>(engine->GetRenderStats(), "granular:sceneBuilds"), 2);
  ASSERT_TRUE(tt.converged && exits.converged);
  bool differs = false;
  for (size_t i = 0; i < exits.values.size(); ++i) {
    ASSERT_TRUE(std::isfinite(exits.values[i]));
    differs = differs || exits.values[i] != tt.values[i];
  }
  EXPECT_TRUE(differs);
  engine->SetRendererSetting(TfToken("granular:mediumModel"), VtValue(std::string("teleport")));
  Frame refused = render(*engine, stage, HdAovTokens->color, 32, 20);
  EXPECT_TRUE(refused.converged);
  EXPECT_NE(stat<std::string>(engine->GetRenderStats(), "granular:error").find("medium_model"), std::string::npos);
}

TEST(HdGranular, ProxiesCarryTheLowOrdersUnderANarrowSunAsInGranularRender) {
  // The snow slab's 0.53° sun: the setting's default (auto) uses proxies there, as
  // granular render does; "off" turns them off as a change of view (no rebuild). Their
  // accuracy is core's to test (tests/core/test_ppt.cpp).
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  auto engine = makeEngine(4);
  Frame proxies = render(*engine, stage, HdAovTokens->color, 32, 20);
  ASSERT_TRUE(proxies.converged);
  EXPECT_TRUE(stat<bool>(engine->GetRenderStats(), "granular:proxies"));
  // What carries the low orders, per aggregate, with the measured bias (core/switching.h),
  // in granular render's words.
  const std::string switching = stat<std::string>(engine->GetRenderStats(), "granular:switching");
  EXPECT_NE(switching.find("/World/Snow: proxies for"), std::string::npos) << switching;
  EXPECT_NE(switching.find("measured: the medium's bias there"), std::string::npos) << switching;
  // Measured toward the sun too, whatever the camera (core/scene.h: sunSwitchMeasure).
  EXPECT_NE(switching.find("toward the sun"), std::string::npos) << switching;
  engine->SetRendererSetting(TfToken("granular:proxies"), VtValue(std::string("off")));
  Frame medium = render(*engine, stage, HdAovTokens->color, 32, 20);
  ASSERT_TRUE(medium.converged);
  EXPECT_FALSE(stat<bool>(engine->GetRenderStats(), "granular:proxies"));
  EXPECT_EQ(stat<int>(engine->GetRenderStats(), "granular:sceneBuilds"), 1);
  for (Frame const* f : {&proxies, &medium})
    for (float v : f->values) ASSERT_TRUE(std::isfinite(v));
  // Unknown words are refused by name, as granular render refuses them: nothing rendered.
  engine->SetRendererSetting(TfToken("granular:proxies"), VtValue(std::string("sometimes")));
  Frame refused = render(*engine, stage, HdAovTokens->color, 32, 20);
  EXPECT_TRUE(refused.converged);
  for (size_t i = 0; i < refused.values.size(); i += size_t(refused.channels))
    for (int c = 0; c < 3; ++c) ASSERT_EQ(refused.values[i + size_t(c)], 0.0f) << i;
}

// The stage's render settings prim with a data window (UsdRender dataWindowNDC: x from 1/4
// to 3/4, the upper half) on it and, when `product`, a render product that inherits it.
UsdStageRefPtr dataWindowStage(bool product) {
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  UsdPrim settings = stage->DefinePrim(SdfPath("/Render/CropSettings"), TfToken("RenderSettings"));
  settings.CreateAttribute(TfToken("dataWindowNDC"), SdfValueTypeNames->Float4, false, SdfVariabilityUniform)
      .Set(GfVec4f(0.25f, 0.5f, 0.75f, 1.0f));
  settings.CreateRelationship(TfToken("camera")).SetTargets({SdfPath("/World/Camera")});
  if (product) {
    UsdPrim p = stage->DefinePrim(SdfPath("/Render/CropSettings/Product"), TfToken("RenderProduct"));
    settings.CreateRelationship(TfToken("products")).SetTargets({p.GetPath()});
  }
  return stage;
}

TEST(HdGranular, TheActiveRenderSettingsDataWindowCropsTheRender) {
  UsdStageRefPtr stage = dataWindowStage(true);
  auto engine = makeEngine(2);
  Frame full = render(*engine, stage, HdAovTokens->color, 40, 30);
  ASSERT_TRUE(full.converged);
  auto cropping = makeEngine(2);
  cropping->SetActiveRenderSettingsPrimPath(SdfPath("/Render/CropSettings"));
  Frame crop = render(*cropping, stage, HdAovTokens->color, 40, 30);
  ASSERT_TRUE(crop.converged);
  ASSERT_EQ(crop.values.size(), full.values.size());
  // Pixels [10, 30) x [0, 15) from the top (granular::pixelWindowFromNdc) hold the full
  // render's values; the rest keep the host's clear colour (black). Row 0 of a Hydra buffer
  // is the bottom of the image.
  int inside = 0, lit = 0, litOutside = 0;
  for (int row = 0; row < 30; ++row)
    for (int x = 0; x < 40; ++x) {
      const int y = 29 - row;  // from the top
      const float* c = &crop.values[(size_t(row) * 40 + x) * crop.channels];
      const float* f = &full.values[(size_t(row) * 40 + x) * full.channels];
      if (x >= 10 && x < 30 && y < 15) {
        ++inside;
        for (int k = 0; k < 4; ++k) ASSERT_EQ(c[k], f[k]) << "pixel " << x << ", " << y;
        lit += f[0] > 0;
      } else {
        for (int k = 0; k < 3; ++k) ASSERT_EQ(c[k], 0.0f) << "pixel " << x << ", " << y << " outside the window";
        litOutside += f[0] > 0;
      }
    }
  EXPECT_EQ(inside, 300);
  EXPECT_GT(lit, 150);         // the window holds something to compare
  EXPECT_GT(litOutside, 500);  // and so does what it leaves out
}

TEST(HdGranular, ADataWindowWithoutARenderProductCropsNothing) {
  // UsdRender: the data window belongs to render products (a settings prim's value is its
  // products' default); granular render reads it the same way (usd_reader.py).
  UsdStageRefPtr stage = dataWindowStage(false);
  auto engine = makeEngine(2);
  Frame full = render(*engine, stage, HdAovTokens->color, 40, 30);
  auto settingsAlone = makeEngine(2);
  settingsAlone->SetActiveRenderSettingsPrimPath(SdfPath("/Render/CropSettings"));
  Frame f = render(*settingsAlone, stage, HdAovTokens->color, 40, 30);
  ASSERT_TRUE(full.converged && f.converged);
  EXPECT_EQ(f.values, full.values);
}

TEST(HdGranular, StandInsShowFirstAndTheFullBuildReplacesThemAsAnEagerBuild) {
  // The first Execute builds stand-ins (the medium alone, core/scene.h) and starts the full
  // build on its own thread; the pass is not converged until the full scene has replaced
  // them and rendered, and its image is then bit for bit that of a delegate that built
  // everything before its first image (granular:standIns false).
  UsdStageRefPtr stage = UsdStage::Open(kExamples + "/snowslab.usda");
  auto engine = makeEngine(4);
  engine->SetCameraPath(SdfPath("/World/Camera"));
  engine->SetRenderBufferSize(GfVec2i(32, 20));
  engine->SetFraming(CameraUtilFraming(GfRect2i(GfVec2i(0, 0), 32, 20)));
  ASSERT_TRUE(engine->SetRendererAov(HdAovTokens->color));
  engine->Render(stage->GetPseudoRoot(), UsdImagingGLRenderParams());
  VtDictionary first = engine->GetRenderStats();
  EXPECT_TRUE(stat<bool>(first, "granular:standIns"));
  EXPECT_TRUE(stat<bool>(first, "granular:fullBuildPending"));
  EXPECT_FALSE(engine->IsConverged());
  EXPECT_EQ(stat<int>(first, "granular:standInsBuilt"), 1);
  EXPECT_EQ(stat<int>(first, "granular:aggregatesBuilt"), 0);
  Frame lazy = render(*engine, stage, HdAovTokens->color, 32, 20);
  VtDictionary last = engine->GetRenderStats();
  EXPECT_FALSE(stat<bool>(last, "granular:standIns"));
  EXPECT_FALSE(stat<bool>(last, "granular:fullBuildPending"));
  EXPECT_EQ(stat<int>(last, "granular:aggregatesBuilt"), 1);
  EXPECT_EQ(stat<int>(last, "granular:mediaDerived"), 1);  // the full build took the stand-in's
  auto eagerEngine = makeEngine(4);
  eagerEngine->SetRendererSetting(TfToken("granular:standIns"), VtValue(false));
  Frame eager = render(*eagerEngine, stage, HdAovTokens->color, 32, 20);
  EXPECT_EQ(stat<int>(eagerEngine->GetRenderStats(), "granular:standInsBuilt"), 0);
  expectSameFrame(lazy, eager, 0);
  EXPECT_GT(mean(lazy, 0), 0.01);
}

// ---- explicit grains: a PointInstancer of a simulation's grains --------------------------------

namespace {

// An octahedron of radius r (closed), as a Mesh's attribute lines.
std::string octahedron(double r) {
  const std::string s = std::to_string(r);
  return "point3f[] points = [(" + s + ", 0, 0), (-" + s + ", 0, 0), (0, " + s + ", 0), (0, -" + s + ", 0), (0, 0, " +
         s + "), (0, 0, -" + s + R"()]
        int[] faceVertexCounts = [3, 3, 3, 3, 3, 3, 3, 3]
        int[] faceVertexIndices = [0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5])";
}

struct GrainLayout {
  std::vector<GfVec3f> positions;
  std::vector<int> protoIndices;
};

// 6 x 6 grains 1 apart in the plane z = 0, x and y in [-2.5, 2.5] (row by row from the
// bottom); every third one of prototype 1 ("Small"), the others of prototype 0 ("Big").
GrainLayout sixBySix() {
  GrainLayout g;
  for (int i = 0; i < 36; ++i) {
    g.positions.emplace_back(-2.5f + float(i % 6), -2.5f + float(i / 6), 0.0f);
    g.protoIndices.push_back(i % 3 == 0 ? 1 : 0);
  }
  return g;
}

// The text of /World/Sim, a PointInstancer (with GranularInstancedAggregateAPI unless
// `api` is false) of two grain prototypes carrying GranularGrainAPI primvars, as a
// simulation writes them.
std::string grainInstancer(GrainLayout const& g, bool api = true) {
  std::string positions, indices, orientations;
  for (size_t i = 0; i < g.positions.size(); ++i) {
    const GfVec3f& p = g.positions[i];
    positions += TfStringPrintf("%s(%.9g, %.9g, %.9g)", i ? ", " : "", p[0], p[1], p[2]);
    indices += TfStringPrintf("%s%d", i ? ", " : "", g.protoIndices[i]);
    orientations += std::string(i ? ", " : "") + (i % 2 ? "(0.92388, 0, 0, 0.38268)" : "(1, 0, 0, 0)");
  }
  return std::string(R"(
  def PointInstancer "Sim" )") + (api ? R"((
    prepend apiSchemas = ["GranularInstancedAggregateAPI"]
  ) )" : "") + R"({
    rel prototypes = [</World/Sim/Protos/Big>, </World/Sim/Protos/Small>]
    int[] protoIndices = [)" + indices + R"(]
    point3f[] positions = [)" + positions + R"(]
    quath[] orientations = [)" + orientations + R"(]
    def Scope "Protos" {
      def Mesh "Big" (
        prepend apiSchemas = ["GranularGrainAPI"]
      ) {
        )" + octahedron(0.4) + R"(
        float primvars:granular:ior = 1.5
        color3f primvars:granular:absorption = (0.5, 1, 2)
      }
      def Mesh "Small" (
        prepend apiSchemas = ["GranularGrainAPI"]
      ) {
        )" + octahedron(0.25) + R"(
        float primvars:granular:ior = 1.31
      }
    }
  }
)";
}

// domeLitStage(40) (the view is [-4, 4]^2 at z = 0) with grainInstancer(g).
UsdStageRefPtr grainInstancerStage(GrainLayout const& g) { return domeLitStage(40, grainInstancer(g)); }

// The pixel (column, row from the bottom, as render buffers hold rows) of a point of the
// plane z = 0 in an image of w x w pixels of the view [-4, 4]^2 (its samples are jittered
// over the pixel: a grain is seen there when it covers the whole pixel).
std::pair<int, int> pixelOf(GfVec3f const& p, int w) {
  return {int((p[0] + 4.0f) / 8.0f * float(w)), int((p[1] + 4.0f) / 8.0f * float(w))};
}

}  // namespace

// A thick block of absorbing simulated grains gets its heterogeneous medium; what carries the
// low orders after the first grain is said in granular render's words (core:
// Scene::instancedLowOrdersText): proxies, or explicit grains with granular:proxies off.
TEST(HdGranularExplicitGrains, AThickInstancerUsesProxiesAsGranularRenderSays) {
  GrainLayout block;
  for (int z = 0; z < 16; ++z)
    for (int y = 0; y < 16; ++y)
      for (int x = 0; x < 16; ++x) {
        block.positions.emplace_back(-6.0f + 0.8f * float(x), -6.0f + 0.8f * float(y), -0.8f * float(z));
        block.protoIndices.push_back(0);
      }
  UsdStageRefPtr stage = grainInstancerStage(block);
  auto engine = makeEngine(1);
  engine->SetRendererSetting(TfToken("granular:proxies"), VtValue(std::string("on")));
  Frame f = render(*engine, stage, HdAovTokens->color, 16, 16);
  ASSERT_TRUE(f.converged);
  VtDictionary stats = engine->GetRenderStats();
  EXPECT_EQ(stat<std::string>(stats, "granular:error"), "");
  EXPECT_TRUE(stat<bool>(stats, "granular:proxies"));
  const std::string on = stat<std::string>(stats, "granular:switching");
  EXPECT_NE(on.find("/World/Sim: proxies for "), std::string::npos) << on;
  EXPECT_NE(on.find("visits, then its heterogeneous medium (the rule for "), std::string::npos) << on;
  for (float v : f.values) ASSERT_TRUE(std::isfinite(v));
  engine->SetRendererSetting(TfToken("granular:proxies"), VtValue(std::string("off")));
  f = render(*engine, stage, HdAovTokens->color, 16, 16);
  ASSERT_TRUE(f.converged);
  const std::string off = stat<std::string>(engine->GetRenderStats(), "granular:switching");
  EXPECT_NE(off.find("/World/Sim: explicit grains to bounce "), std::string::npos) << off;
  EXPECT_NE(off.find("/World/Sim: no DA (da_instanced off)"), std::string::npos) << off;
  for (float v : f.values) ASSERT_TRUE(std::isfinite(v));
  // granular:daInstanced reaches core as --instanced-da does: DA is asked for, and the rule
  // (core/heterogeneous_diffusion.h) says where.
  engine->SetRendererSetting(TfToken("granular:daInstanced"), VtValue(true));
  f = render(*engine, stage, HdAovTokens->color, 16, 16);
  ASSERT_TRUE(f.converged);
  const std::string da = stat<std::string>(engine->GetRenderStats(), "granular:switching");
  EXPECT_EQ(da.find("da_instanced off"), std::string::npos) << da;
  EXPECT_NE(da.find("/World/Sim: DA where the medium is deep"), std::string::npos) << da;
  for (float v : f.values) ASSERT_TRUE(std::isfinite(v));
}

// An instancer of 36 simulated grains reaches core as one InstancedGrainsDesc: 36 grains (render
// stat granular:instancedGrains), grain i where its position projects (instanceId AOV i there),
// of its prototype (the CryptoMaterial layer names the prototype's grain material), not as
// instanced meshes (no mesh hit: primId and aggregateId are the grains' one id). An edit of
// the positions moves them; invisibleIds hide grains, as USD masks instances.
TEST(HdGranularExplicitGrains, AnInstancerOfGrainsIsReadIntoCoresInstancedGrains) {
  GrainLayout g = sixBySix();
  UsdStageRefPtr stage = grainInstancerStage(g);
  auto engine = makeEngine(1);
  const int w = 40;  // 5 pixels a unit: every grain's centre is a pixel's centre, before and after the move
  auto expectGrainsAt = [&](GrainLayout const& layout, std::set<int> const& hidden) {
    Frame ids = render(*engine, stage, HdAovTokens->instanceId, w, w);
    ASSERT_TRUE(ids.converged);
    ASSERT_EQ(ids.channels, 1);
    for (size_t i = 0; i < layout.positions.size(); ++i) {
      auto [x, y] = pixelOf(layout.positions[i], w);
      const int seen = int(ids.values[size_t(y) * w + x]);
      if (hidden.count(int(i))) EXPECT_EQ(seen, -1) << "grain " << i << " is hidden";
      else if (hidden.empty()) EXPECT_EQ(seen, int(i)) << "grain " << i << " at pixel " << x << ", " << y;
      else EXPECT_GE(seen, 0) << "grain " << i;
    }
    VtDictionary stats = engine->GetRenderStats();
    EXPECT_EQ(stat<std::string>(stats, "granular:error"), "");
    EXPECT_EQ(stat<int64_t>(stats, "granular:instancedGrains"), int64_t(layout.positions.size() - hidden.size()));
  };
  expectGrainsAt(g, {});

  // Each grain's prototype: its grain material's name (the prototype's Hydra prim) names it.
  Frame mat = render(*engine, stage, TfToken("CryptoMaterial00"), w, w);
  auto materials = parseManifest(
      stat<std::string>(stat<VtDictionary>(engine->GetRenderStats(), "granular:cryptomatte"), "CryptoMaterial"));
  std::map<uint32_t, std::string> nameOf;
  for (auto const& [name, id] : materials) nameOf[id] = name;
  for (size_t i = 0; i < g.positions.size(); ++i) {
    auto [x, y] = pixelOf(g.positions[i], w);
    const std::string name = nameOf[bitsOf(mat.values[(size_t(y) * w + x) * 4])];
    EXPECT_NE(name.find(g.protoIndices[i] ? "Small" : "Big"), std::string::npos) << "grain " << i << ": " << name;
  }
  // One object id over all grains, and no mesh: the aggregateId AOV is the primId wherever seen.
  Frame agg = render(*engine, stage, TfToken("aggregateId"), w, w);
  Frame prim = render(*engine, stage, HdAovTokens->primId, w, w);
  std::set<float> aggregateIds;
  for (size_t i = 0; i < agg.values.size(); ++i)
    if (prim.values[i] >= 0) {
      EXPECT_EQ(agg.values[i], prim.values[i]) << i;
      aggregateIds.insert(agg.values[i]);
    }
  EXPECT_EQ(aggregateIds.size(), 1u);

  // The simulation's next frame: every grain a pixel (0.2) to the right.
  VtVec3fArray moved;
  for (GfVec3f& p : g.positions) moved.push_back(p += GfVec3f(0.2f, 0, 0));
  stage->GetPrimAtPath(SdfPath("/World/Sim")).GetAttribute(TfToken("positions")).Set(moved);
  expectGrainsAt(g, {});
  stage->GetPrimAtPath(SdfPath("/World/Sim")).CreateAttribute(TfToken("invisibleIds"), SdfValueTypeNames->Int64Array)
      .Set(VtInt64Array{0, 7});
  expectGrainsAt(g, {0, 7});
}

// Bad instancer data is refused with core's error naming the instancer and the attribute, as
// granular render refuses it: nothing drawn, the render converges, the error is reported.
TEST(HdGranularExplicitGrains, BadInstancerDataIsRefusedNamingTheAttribute) {
  struct Case {
    std::function<void(GrainLayout&)> edit;
    std::string message;
  };
  const std::vector<Case> cases = {
      {[](GrainLayout& g) { g.protoIndices[4] = 7; },
       "/World/Sim.protoIndices: instance 4 has 7, not the index of one of its 2 prototypes"},
      {[](GrainLayout& g) { g.positions[5][0] = std::nanf(""); }, "/World/Sim.positions: instance 5 is at (nan, "},
      {[](GrainLayout& g) { g.positions[9] = g.positions[8] + GfVec3f(0.1f, 0, 0); },
       "/World/Sim.positions: instances 8 and 9 overlap"},
  };
  for (const Case& c : cases) {
    GrainLayout g = sixBySix();
    c.edit(g);
    UsdStageRefPtr stage = grainInstancerStage(g);
    TfErrorMark mark;
    auto engine = makeEngine(1);
    Frame f = render(*engine, stage, HdAovTokens->color, 16, 16);
    std::string errors;
    for (auto e = mark.GetBegin(); e != mark.GetEnd(); ++e) errors += e->GetCommentary() + "\n";
    mark.Clear();
    EXPECT_NE(errors.find(c.message), std::string::npos) << errors;
    EXPECT_EQ(stat<std::string>(engine->GetRenderStats(), "granular:error").rfind(c.message, 0), 0u)
        << stat<std::string>(engine->GetRenderStats(), "granular:error");
    EXPECT_EQ(stat<int64_t>(engine->GetRenderStats(), "granular:instancedGrains"), 0);
    EXPECT_TRUE(f.converged);
    for (size_t i = 0; i < f.values.size(); i += 4)  // the clear colour: nothing was drawn
      for (int k = 0; k < 3; ++k) ASSERT_EQ(f.values[i + k], 0.0f) << i;
  }
}

// Without GranularInstancedAggregateAPI (which Hydra does not see) the prototypes' grain
// primvars decide, as core's isExplicitGrainInstancer says; an instancer whose prototypes
// carry none stays an instancer of meshes. Nested in another instancer, grains are not read
// either (as before: their prototypes, meshes with grain primvars, are not drawn).
TEST(HdGranularExplicitGrains, ThePrototypesGrainPrimvarsDecide) {
  auto grainsOf = [](UsdStageRefPtr const& stage) {
    auto engine = makeEngine(1);
    Frame f = render(*engine, stage, HdAovTokens->color, 16, 16);
    EXPECT_TRUE(f.converged);
    EXPECT_EQ(stat<std::string>(engine->GetRenderStats(), "granular:error"), "");
    return stat<int64_t>(engine->GetRenderStats(), "granular:instancedGrains");
  };
  UsdStageRefPtr stage = domeLitStage(40, grainInstancer(sixBySix(), /*api=*/false));
  EXPECT_EQ(grainsOf(stage), 36);
  // One prototype without grain primvars (a grain of a bound material, say): not seen as grains.
  for (const char* name : {"primvars:granular:ior", "primvars:granular:absorption"})
    stage->GetPrimAtPath(SdfPath("/World/Sim/Protos/Big")).RemoveProperty(TfToken(name));
  EXPECT_EQ(grainsOf(stage), 0);
  EXPECT_EQ(grainsOf(quadInstancerStage(3)), 0);
  // /World/Outer instancing the grain instancer twice.
  std::string inner = grainInstancer(sixBySix());
  inner = TfStringReplace(inner, "</World/Sim/", "</World/Outer/Protos/Sim/");
  EXPECT_EQ(grainsOf(domeLitStage(40, R"(
  def PointInstancer "Outer" {
    rel prototypes = [</World/Outer/Protos/Sim>]
    int[] protoIndices = [0, 0]
    point3f[] positions = [(0, 0, -1), (0, 0, -3)]
    def Scope "Protos" {)" + inner + R"(
    }
  }
)")), 0);
}

// ---- motion blur: the shutter in seconds, and turned off -------------------------------------

namespace {

// grainInstancerStage(sixBySix()) with every grain moving along +x at `speed` units per
// second, the camera's shutter open over [-0.5, 0.5] time codes, at `tcps` time codes per
// second (shutter: false leaves the shutter closed).
UsdStageRefPtr movingGrainsStage(double speed, double tcps, bool shutter = true) {
  std::string velocities;
  for (int i = 0; i < 36; ++i) velocities += TfStringPrintf("%s(%.9g, 0, 0)", i ? ", " : "", speed);
  std::string text = grainInstancer(sixBySix());
  const std::string at = "    quath[] orientations";
  text.insert(text.find(at), "    vector3f[] velocities = [" + velocities + "]\n");
  UsdStageRefPtr stage = domeLitStage(40, text);
  stage->SetTimeCodesPerSecond(tcps);
  if (shutter) {
    UsdGeomCamera cam(stage->GetPrimAtPath(SdfPath("/World/Camera")));
    cam.CreateShutterOpenAttr(VtValue(-0.5));
    cam.CreateShutterCloseAttr(VtValue(0.5));
  }
  return stage;
}

// The color AOV of /World/Camera at w x w, by an engine of its own (one stage each) with
// `settings` set; the render stat granular:error into *error when given.
Frame renderColor(UsdStageRefPtr const& stage, int spp, int w, std::map<std::string, VtValue> const& settings = {},
                  std::string* error = nullptr) {
  auto engine = makeEngine(spp);
  for (auto const& [key, value] : settings) engine->SetRendererSetting(TfToken(key), value);
  Frame f = render(*engine, stage, HdAovTokens->color, w, w);
  if (error) *error = stat<std::string>(engine->GetRenderStats(), "granular:error");
  return f;
}

double sumAbsDifference(Frame const& a, Frame const& b) {
  double s = 0;
  for (size_t i = 0; i < a.values.size() && i < b.values.size(); ++i) s += std::fabs(a.values[i] - b.values[i]);
  return s;
}

}  // namespace

// A scene delegate hands the shutter in time codes, not the stage's rate: the render setting
// granular:timeCodesPerSecond makes it seconds for the grains' velocities (units per second).
// At 48 per second, grains at 24 units/s sweep what grains at 12 units/s sweep on a stage of
// 24 per second (the same motion but for float rounding), and half of what the same stage
// sweeps read at the default 24.
TEST(HdGranularMotionBlur, TheTimeCodesPerSecondSettingMakesTheShutterSeconds) {
  const int w = 40;
  std::string error;
  const Frame reference = renderColor(movingGrainsStage(12, 24), 4, w);
  const Frame at24 = renderColor(movingGrainsStage(24, 48), 4, w);
  const Frame at48 =
      renderColor(movingGrainsStage(24, 48), 4, w, {{"granular:timeCodesPerSecond", VtValue(48.0)}}, &error);
  ASSERT_TRUE(reference.converged && at24.converged && at48.converged);
  EXPECT_EQ(error, "");
  const double same = sumAbsDifference(at48, reference), twice = sumAbsDifference(at24, reference);
  std::printf("sum |difference| vs 12 units/s at 24 tcps: %.3g read at 48 tcps, %.3g read at 24\n", same, twice);
  EXPECT_GT(twice, 0.0);
  EXPECT_LT(same, 0.1 * twice);
  // Not a rate: refused naming the setting.
  renderColor(movingGrainsStage(24, 48), 1, w, {{"granular:timeCodesPerSecond", VtValue(0.0)}}, &error);
  EXPECT_NE(error.find("granular:timeCodesPerSecond"), std::string::npos) << error;
}

// granular:motionBlur false renders the frame's instant: the image of the same stage with the
// shutter closed, bit for bit (the same description).
TEST(HdGranularMotionBlur, TurnedOffTheImageIsTheStillFrame) {
  const int w = 40;
  const Frame still = renderColor(movingGrainsStage(24, 24, /*shutter=*/false), 2, w);
  const Frame blurred = renderColor(movingGrainsStage(24, 24), 2, w);
  const Frame off = renderColor(movingGrainsStage(24, 24), 2, w, {{"granular:motionBlur", VtValue(false)}});
  ASSERT_TRUE(still.converged && blurred.converged && off.converged);
  EXPECT_GT(sumAbsDifference(blurred, still), 0.0);
  EXPECT_EQ(off.values, still.values);
}

TEST(HdGranular, AMeshLightLightsAsTheRectOfItsQuadAndFollowsEdits) {
  // The floor facing the camera under a unit quad 3 above it with MeshLightAPI (the dome
  // off), facing the floor: the same light as a RectLight there, within the two renders'
  // noise, as granular render renders both (tests/python/test_mesh_light.py; tests/conformance:
  // mesh_light). Its intensity doubled on the live stage doubles the image sample for sample.
  const std::string quad = R"(
  def Mesh "Panel" (
    prepend apiSchemas = ["MeshLightAPI"]
  ) {
    point3f[] points = [(-0.5, -0.5, 3), (-0.5, 0.5, 3), (0.5, 0.5, 3), (0.5, -0.5, 3)]
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    float inputs:intensity = 4
  }
)";
  const std::string rect = R"(
  def RectLight "Panel" {
    float inputs:intensity = 4
    double3 xformOp:translate = (0, 0, 3)
    uniform token[] xformOpOrder = ["xformOp:translate"]
  }
)";
  auto stageWith = [&](std::string const& light) {
    UsdStageRefPtr stage = domeLitStage(4, std::string(kFloorFacingCamera) + light);
    EXPECT_TRUE(stage->GetPrimAtPath(SdfPath("/World/Sky")).SetActive(false));
    return stage;
  };
  UsdStageRefPtr meshLit = stageWith(quad);
  auto engine = makeEngine(64);
  double seMesh = 0, seRect = 0;
  const double byMesh = meanAndError(*engine, meshLit, 8, seMesh);
  const double byRect = meanAndError(*makeEngine(64), stageWith(rect), 8, seRect);
  EXPECT_GT(byMesh, 0);
  EXPECT_NEAR(byMesh, byRect, 4 * std::hypot(seMesh, seRect)) << "se " << seMesh << ", " << seRect;
  const Frame before = render(*engine, meshLit, HdAovTokens->color, 8, 8);
  ASSERT_TRUE(meshLit->GetPrimAtPath(SdfPath("/World/Panel")).GetAttribute(TfToken("inputs:intensity")).Set(8.0f));
  const Frame after = render(*engine, meshLit, HdAovTokens->color, 8, 8);
  ASSERT_EQ(before.values.size(), after.values.size());
  for (size_t i = 0; i < before.values.size(); ++i)
    if (i % before.channels < 3) EXPECT_NEAR(after.values[i], 2 * before.values[i], 1e-5f * (1 + after.values[i])) << i;
  std::printf("floor: mesh light %.5f ± %.5f, rect light %.5f ± %.5f\n", byMesh, seMesh, byRect, seRect);
}
