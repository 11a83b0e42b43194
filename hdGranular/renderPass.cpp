#include "renderPass.h"

#include <cmath>
#include <exception>

#include "core/error.h"
#include "core/usd_camera.h"
#include "pxr/base/tf/getenv.h"
#include "pxr/imaging/hd/camera.h"
#include "pxr/imaging/hd/renderDelegate.h"
#include "pxr/imaging/hd/renderIndex.h"
#include "pxr/imaging/hd/sceneDelegate.h"
#include "pxr/imaging/hd/timeSampleArray.h"
#include "pxr/imaging/hd/tokens.h"
#include "renderBuffer.h"
#include "renderDelegate.h"
#include "renderParam.h"
#include "renderProducts.h"
#include "renderSettings.h"
#include "renderer.h"

PXR_NAMESPACE_OPEN_SCOPE

namespace {


// The perspective camera equivalent to Hydra's view and projection matrices, keeping
// cam's focal length (the camera prim's, so that its lens is checked against it as
// granular render checks it): the window at unit distance is [-1/P00, 1/P00] shifted by
// P20/P00 (x_ndc = P00 u − P20 for a point at film coordinate u), likewise in y; the
// apertures are that window times the focal length; near and far from P22 and P32.
bool cameraFromMatrices(GfMatrix4d const& view, GfMatrix4d const& proj, granular::CameraDesc& cam) {
  if (proj[2][3] != -1.0 || proj[0][0] == 0 || proj[1][1] == 0) return false;  // not a perspective frustum
  const double f = cam.focalLength > 0 && std::isfinite(cam.focalLength) ? cam.focalLength : 1.0;
  cam.cameraToWorld = HdGranularToCore(view.GetInverse());
  cam.focalLength = float(f);
  cam.horizontalAperture = float(f * 2.0 / proj[0][0]);
  cam.verticalAperture = float(f * 2.0 / proj[1][1]);
  cam.horizontalApertureOffset = float(f * proj[2][0] / proj[0][0]);
  cam.verticalApertureOffset = float(f * proj[2][1] / proj[1][1]);
  double n = proj[3][2] / (proj[2][2] - 1.0), fa = proj[3][2] / (proj[2][2] + 1.0);
  cam.clipNear = float(n > 0 ? n : 1e-4);
  cam.clipFar = float(fa > n ? fa : 1e30);
  return true;
}

// The pass's camera as core reads a UsdGeomCamera (core/usd_camera.h: its checks, the thin
// lens from fStop and focusDistance, the shutter), from HdCamera's values (which keeps lengths in scene
// units, a tenth of USD's). Its framing comes from the host's matrices instead, which
// apply the host's window policy. No camera prim (free matrices): a pinhole. `shutter`:
// shutterOf's, in time codes about the frame, made seconds at timeCodesPerSecond.
granular::CameraDesc coreCamera(HdCamera const* camera, GfVec2d const& shutter, double timeCodesPerSecond) {
  if (!camera) {
    granular::CameraDesc pinhole;
    pinhole.focalLength = 1.0f;  // free matrices: only the window matters
    return pinhole;
  }
  granular::UsdPrimRecord r;
  r.path = camera->GetId().GetString();
  r.typeName = "Camera";
  auto number = [&r](const char* name, double v) {
    granular::UsdValue x;
    x.typeName = "float";
    x.numbers = {v};
    r.attributes[name] = x;
  };
  granular::UsdValue projection;
  projection.typeName = "token", projection.isString = true;
  projection.strings = {camera->GetProjection() == HdCamera::Orthographic ? "orthographic" : "perspective"};
  r.attributes["projection"] = projection;
  number("focalLength", 10.0 * camera->GetFocalLength());
  number("horizontalAperture", 10.0 * camera->GetHorizontalAperture());
  number("verticalAperture", 10.0 * camera->GetVerticalAperture());
  number("horizontalApertureOffset", 10.0 * camera->GetHorizontalApertureOffset());
  number("verticalApertureOffset", 10.0 * camera->GetVerticalApertureOffset());
  number("fStop", camera->GetFStop());
  number("focusDistance", camera->GetFocusDistance());
  number("shutter:open", shutter[0]);
  number("shutter:close", shutter[1]);
  granular::UsdValue clip;
  clip.typeName = "float2";
  clip.numbers = {camera->GetClippingRange().GetMin(), camera->GetClippingRange().GetMax()};
  r.attributes["clippingRange"] = clip;
  return granular::cameraFromUsd(r, timeCodesPerSecond);
}

// A setting of the type we want, whatever numeric type (or token) the host stored.
template <typename T>
T setting(HdRenderDelegate* d, TfToken const& key, T fallback) {
  VtValue v = d->GetRenderSetting(key);
  if (v.IsHolding<T>()) return v.UncheckedGet<T>();
  if (v.CanCast<T>()) return v.Cast<T>().template UncheckedGet<T>();
  return fallback;
}

template <>
std::string setting<std::string>(HdRenderDelegate* d, TfToken const& key, std::string fallback) {
  VtValue v = d->GetRenderSetting(key);
  if (v.IsHolding<std::string>()) return v.UncheckedGet<std::string>();
  if (v.IsHolding<TfToken>()) return v.UncheckedGet<TfToken>().GetString();
  return fallback;
}

bool defaultLightSetting(HdRenderDelegate* d) {
  return setting<bool>(d, HdGranularSettingsTokens->defaultLight, granular::RenderSettings().defaultLight);
}

bool physicalSunSetting(HdRenderDelegate* d) {
  return setting<bool>(d, HdGranularSettingsTokens->physicalSun, granular::RenderSettings().physicalSun);
}

// The shutter the image is blurred over, in time codes about the frame (HdCamera's, as
// USD's shutter:open and shutter:close): the camera's, or the instant (0, 0) when motion blur
// is off (render setting granular:motionBlur false, or the active UsdRenderSettings'
// disableMotionBlur or instantaneousShutter as far as Hydra shows them: renderSettings.h;
// as granular render --no-motion-blur and its reading of the prim).
GfVec2d shutterOf(HdCamera const* camera, HdRenderDelegate* d, HdRenderIndex* index) {
  if (!camera || !setting<bool>(d, HdGranularSettingsTokens->motionBlur, true) || HdGranularMotionBlurDisabled(index))
    return GfVec2d(0.0);
  return GfVec2d(camera->GetShutterOpen(), camera->GetShutterClose());
}

// The stage's timeCodesPerSecond, which no scene delegate hands over (HdSceneGlobalsSchema
// has the frame, not the rate): the render setting, 24 unless told. Velocities are per
// second, the shutter in time codes: grains blur by velocity × shutter / timeCodesPerSecond.
double timeCodesPerSecond(HdRenderDelegate* d) {
  const double tcps = setting<double>(d, HdGranularSettingsTokens->timeCodesPerSecond, 24.0);
  if (!(tcps > 0) || !std::isfinite(tcps))
    throw granular::InputError("render settings", "granular:timeCodesPerSecond",
                               granular::str(tcps, " must be finite and > 0"));
  return tcps;
}

// Transform motion blur, as granular render's reading (usd_reader._transform_motion): each
// mesh and each aggregate drawn once (not an instance) whose world transform differs between the
// shutter's ends gets its transforms there (MeshDesc::shutterXf, AggregateDesc::shutterXf),
// sampled from its scene delegate over the shutter (times relative to the frame; the samples
// hold the interval's ends, exact, and resampling gives them whatever the delegate hands
// back). An aggregate is still built where it stands at the frame (core/aggregate_motion.h).
void sampleTransformMotion(HdRenderIndex& index, GfVec2d const& shutter, granular::SceneDesc& desc) {
  if (!(shutter[1] > shutter[0])) return;
  const float open = float(shutter[0]), close = float(shutter[1]);
  auto sample = [&](std::string const& name, int instanceId,
                    std::optional<std::pair<granular::Transform, granular::Transform>>& shutterXf) {
    if (instanceId >= 0 || !SdfPath::IsValidPathString(name)) return;
    const SdfPath id(name);
    HdSceneDelegate* const delegate = index.GetRprim(id) ? index.GetSceneDelegateForRprim(id) : nullptr;
    if (!delegate) return;
    HdTimeSampleArray<GfMatrix4d, 4> xf;
    delegate->SampleTransform(id, open, close, &xf);
    if (xf.count < 2) return;  // one sample: still
    const GfMatrix4d a = xf.Resample(open), b = xf.Resample(close);
    if (a != b) shutterXf = std::make_pair(HdGranularToCore(a), HdGranularToCore(b));
  };
  for (granular::MeshDesc& m : desc.meshes) sample(m.name, m.instanceId, m.shutterXf);
  for (granular::AggregateDesc& a : desc.aggregates) sample(a.name, a.instanceId, a.shutterXf);
}

granular::RenderSettings renderSettings(HdRenderDelegate* d, int width, int height) {
  granular::RenderSettings rs;
  rs.width = width;
  rs.height = height;
  rs.spp = setting<int>(d, HdRenderSettingsTokens->convergedSamplesPerPixel, 16);
  rs.threads = setting<int>(d, HdRenderSettingsTokens->threadLimit, 0);
  rs.seed = uint64_t(std::max(0, setting<int>(d, HdGranularSettingsTokens->seed, 0)));
  rs.technique = granular::techniqueFromName(setting<std::string>(d, HdGranularSettingsTokens->technique, "hybrid"),
                                             "render settings granular:technique");
  rs.tau = setting<float>(d, HdGranularSettingsTokens->tau, 4.0f);
  rs.explicitBounces = setting<int>(d, HdGranularSettingsTokens->explicitBounces, rs.explicitBounces);
  rs.daDepthFactor = setting<float>(d, HdGranularSettingsTokens->daDepthFactor, rs.daDepthFactor);
  rs.daMinOrder = setting<int>(d, HdGranularSettingsTokens->daMinOrder, rs.daMinOrder);
  rs.daInstanced = setting<bool>(d, HdGranularSettingsTokens->daInstanced, rs.daInstanced);
  rs.lod = setting<float>(d, HdGranularSettingsTokens->lod, rs.lod);
  rs.proxies = granular::proxyUseFromName(
      setting<std::string>(d, HdGranularSettingsTokens->proxies, granular::proxyUseName(rs.proxies)),
      "render settings granular:proxies");
  rs.mediumModel = granular::mediumModelFromName(
      setting<std::string>(d, HdGranularSettingsTokens->mediumModel, granular::mediumModelName(rs.mediumModel)),
      "render settings granular:mediumModel");
  rs.roulette = setting<float>(d, HdGranularSettingsTokens->roulette, -1.0f);
  rs.bundleSize = setting<int>(d, HdGranularSettingsTokens->bundleSize, 16);
  rs.domeCameraVisible = setting<bool>(d, HdRenderSettingsTokens->domeLightCameraVisibility, true);
  rs.defaultLight = defaultLightSetting(d);
  rs.physicalSun = physicalSunSetting(d);
  rs.sunRegularization = setting<float>(d, HdGranularSettingsTokens->sunRegularization, rs.sunRegularization);
  rs.switchForView = setting<bool>(d, HdGranularSettingsTokens->switchForView, rs.switchForView);
  return rs;
}

}  // namespace

HdGranularRenderPass::HdGranularRenderPass(HdRenderIndex* index, HdRprimCollection const& collection,
                                           HdGranularRenderParam* param, HdGranularRenderer* renderer)
    : HdRenderPass(index, collection), _param(param), _renderer(renderer) {}

HdGranularRenderPass::~HdGranularRenderPass() { _renderer->Stop(); }

// Not while a full build is still to replace the stand-ins being rendered, nor while the
// view's switch measurement is still to choose its visits.
bool HdGranularRenderPass::IsConverged() const {
  return _renderer->IsConverged() && !_renderer->GetBuilder().Pending() && !_renderer->GetViewSwitch().Pending();
}

void HdGranularRenderPass::_Execute(HdRenderPassStateSharedPtr const& state, TfTokenVector const&) {
  HdRenderDelegate* delegate = GetRenderIndex()->GetRenderDelegate();
  HdRenderPassAovBindingVector bindings = state->GetAovBindings();
  HdRenderBuffer* first = nullptr;
  for (auto const& b : bindings)
    if (b.renderBuffer) {
      first = b.renderBuffer;
      break;
    }
  if (!first) return;  // nothing bound: nothing to render into
  const int width = int(first->GetWidth()), height = int(first->GetHeight());
  // The active UsdRenderSettings' dataWindowNDC: only those pixels are rendered, the rest
  // keep the buffers' clear values (as granular render writes only them).
  granular::PixelWindow crop{0, width, 0, height};
  std::optional<granular::InputError> cropError;  // reported below, with the scene's errors
  try {
    granular::UsdWarnings warnings;
    crop = HdGranularDataWindow(GetRenderIndex(), width, height, warnings);
    _param->Warn(warnings);
  } catch (granular::InputError const& e) {
    cropError = e;
  }
  const GfMatrix4d view = state->GetWorldToViewMatrix(), proj = state->GetProjectionMatrix();
  HdCamera const* const camera = state->GetCamera();
  const GfVec2f lens = camera ? GfVec2f(camera->GetFStop(), camera->GetFocusDistance()) : GfVec2f(0.0f);
  const GfVec2d shutter = shutterOf(camera, delegate, GetRenderIndex());

  _param->RefreshMeshLights(*GetRenderIndex());
  const int sceneVersion = _param->Version(), settingsVersion = delegate->GetRenderSettingsVersion();
  // An edit of the scene or of the settings: the description is assembled again and
  // compared with the one the scene was built from (compareScenes), which decides between
  // a new view and a build. A camera move or a resize alone is a new view; a new shutter
  // samples moving meshes anew.
  const bool edited = !_started || sceneVersion != _sceneVersion || settingsVersion != _settingsVersion ||
                      shutter != _shutter;
  const bool reframe = edited || view != _view || proj != _projection || width != _width || height != _height ||
                       crop != _crop || lens != _lens;
  // The full build behind stand-ins has ended (renderer.h): its scene takes their place.
  HdGranularSceneBuilder& builder = _renderer->GetBuilder();
  const bool landed = builder.Ready();
  // The view's switch measurement has ended (viewSwitch.h): its choice takes over.
  HdGranularViewSwitch& viewSwitch = _renderer->GetViewSwitch();
  const bool measured = viewSwitch.Ready();
  // A render buffer reallocated or freed under the loop stopped it (renderBuffer.h).
  const bool rebind = reframe || bindings != _bindings || _renderer->WasInterrupted();
  if (!rebind && !landed && !measured) return;  // the loop goes on
  // Only the full scene replacing its stand-ins, or the view's choice the provisional one:
  // the image stays until the new render's tiles (or finer previews: renderer.h) come.
  bool keepImage = (landed || measured) && !rebind;

  _renderer->Stop();
  _started = true;
  _sceneVersion = sceneVersion;
  _settingsVersion = settingsVersion;
  _view = view;
  _projection = proj;
  _lens = lens;
  _shutter = shutter;
  _width = width;
  _height = height;
  _crop = crop;
  _bindings = bindings;
  try {
    if (cropError) throw *cropError;
    granular::CameraDesc cam = coreCamera(camera, shutter, timeCodesPerSecond(delegate));
    if (!cameraFromMatrices(view, proj, cam))
      throw granular::InputError("camera", "projection", "only perspective cameras are supported");
    granular::RenderSettings rs = renderSettings(delegate, width, height);
    // The film keeps Cryptomatte tables only while a Cryptomatte layer is bound (core/film.h).
    for (auto const& b : bindings) {
      granular::CryptomatteType type;
      rs.cryptomatte = rs.cryptomatte || granular::cryptomatteTypeOfLayer(b.aovName.GetString(), type);
    }
    // Or while the active render settings' products hold one (the delegate writes them).
    rs.cryptomatte = rs.cryptomatte || HdGranularActiveProductsNeedCryptomatte(_renderer);
    if (crop != granular::PixelWindow{0, width, 0, height})
      rs.cropX0 = crop.x0, rs.cropX1 = crop.x1, rs.cropY0 = crop.y0, rs.cropY1 = crop.y1;
    // What a new scene warns about, once each.
    auto reportBuild = [this] {
      const std::string suns = _renderer->GetScene()->widenedSunsWarning();
      if (!suns.empty() && suns != _sunsWarned) TF_WARN("hdGranular: %s", suns.c_str());
      _sunsWarned = suns;  // once, until the lights change
      _param->Warn(_renderer->GetScene()->textureWarnings());  // once each
      if (_renderer->GetScene()->defaultLightAdded())
        TF_WARN("hdGranular: the stage has no light (no UsdLux light, no emissive surface): it is lit by the "
                "default white dome of radiance 1 (render setting granular:defaultLight false renders it black)");
    };
    if (measured) {
      HdGranularViewSwitch::Measured m = viewSwitch.Take();  // rethrows what the measurement threw
      // Refused when the scene has taken another view, or been replaced, meanwhile.
      if (granular::Scene* s = _renderer->GetScene()) s->applyViewSwitch(m.work, m.measures);
    }
    // A camera move never waits for the view's switch measurement: it is made apart.
    constexpr auto apart = granular::Scene::ViewSwitchTiming::Apart;
    if (landed) {
      std::unique_ptr<granular::Scene> full = builder.Take();  // rethrows what the build threw
      full->setView(cam, rs, apart);  // the view as it is now: the camera may have moved meanwhile
      _renderer->SetScene(std::move(full));
    }
    granular::Scene* const scene = _renderer->GetScene();  // none: the last attempt failed (e.g. a bad camera)
    if (edited || !scene || !_built) {
      granular::SceneDesc desc = _param->Assemble();
      sampleTransformMotion(*GetRenderIndex(), shutter, desc);
      if (TfGetenvBool("GRANULAR_HD_DEBUG", false)) {  // what the core is given, for users' bug reports
        for (auto const& l : desc.lights)
          fprintf(stderr, "hdGranular: light %s type %d intensity %g\n", l.name.c_str(), int(l.type), l.intensity);
        for (auto const& m : desc.meshes)
          fprintf(stderr, "hdGranular: mesh %s%s\n", m.name.c_str(), m.shutterXf ? " (moving over the shutter)" : "");
        for (auto const& a : desc.aggregates) {
          fprintf(stderr, "hdGranular: aggregate %s radius %g packing %g seed %llu tile %d points %zu t (%g %g %g)%s",
                  a.name.c_str(), a.grainRadius, a.packingRate, (unsigned long long)a.seed, a.tileSpheres,
                  a.boundary.points.size(), a.xf.m[0][3], a.xf.m[1][3], a.xf.m[2][3],
                  a.shutterXf ? " (moving over the shutter)" : "");
          for (size_t i = 0; i < a.prototypes.size(); ++i)
            fprintf(stderr, " [%s w %g mat %d]", a.prototypes[i].name.c_str(), a.weights[i], a.prototypes[i].material);
          fprintf(stderr, "\n");
        }
        for (auto const& g : desc.instancedGrains) {
          fprintf(stderr, "hdGranular: instanced grains %s: %zu grains, t (%g %g %g)", g.name.c_str(), g.size(),
                  g.xf.m[0][3], g.xf.m[1][3], g.xf.m[2][3]);
          for (auto const& p : g.prototypes)
            fprintf(stderr, " [%s points %zu mat %d]", p.name.c_str(), p.mesh.points.size(), p.material);
          fprintf(stderr, "\n");
        }
        for (auto const& m : desc.materials)
          fprintf(stderr, "hdGranular: material %s type %d ior %g absorption (%g %g %g) albedo (%g %g %g)\n",
                  m.name.c_str(), int(m.type), m.ior, m.absorption.x, m.absorption.y, m.absorption.z, m.albedo.x,
                  m.albedo.y, m.albedo.z);
      }
      desc.camera = cam;
      desc.settings = rs;
      // An edit Hydra reported may leave the description as it was (a time-sampled value
      // that holds still), or change only what a new view sets.
      const bool build =
          !scene || !_built || granular::compareScenes(*_built, desc).level() > granular::SceneChange::View;
      _built.reset();  // until the scene matches desc again
      if (!build) {
        scene->setView(cam, rs, apart);
      } else {
        // The scene before lends its unchanged aggregates (a light or mesh edit voxelises
        // nothing; a deformed boundary, only its aggregate). With stand-ins, aggregates it
        // cannot lend are rendered from their medium at once while their full build runs.
        const bool standIns = setting<bool>(delegate, HdGranularSettingsTokens->standIns, true);
        _renderer->SetScene(granular::Scene::build(
            desc, scene, standIns ? granular::SceneDetail::StandIns : granular::SceneDetail::Full));
        if (_renderer->GetScene()->standIns()) builder.Start(desc, _renderer->GetSharedScene());
        else builder.Abandon();
        reportBuild();
      }
      keepImage = false;
      _built = std::move(desc);
      _param->SetRenderError("");
    } else if (reframe || rs.cryptomatte != _built->settings.cryptomatte) {
      scene->setView(cam, rs, apart);
      _built->camera = cam;
      _built->settings = rs;
    }
  } catch (std::exception const& e) {
    TF_RUNTIME_ERROR("hdGranular: %s", e.what());
    _param->SetRenderError(e.what());
    builder.Abandon();
    viewSwitch.Abandon();
    _renderer->SetScene(nullptr);
    _built.reset();
    keepImage = false;
  }
  if (!keepImage) {
    for (auto const& b : bindings)
      if (auto* rb = dynamic_cast<HdGranularRenderBuffer*>(b.renderBuffer)) rb->Clear(b.clearValue);
    _renderer->BuffersCleared();
  }
  _renderer->SetAovBindings(bindings);
  _renderer->SetProjection(proj);
  _renderer->SetNoiseThreshold(setting<float>(delegate, HdRenderSettingsTokens->convergedVariance, 0.0f));
  _renderer->SetDenoise(setting<bool>(delegate, HdGranularSettingsTokens->denoise, false));
  _renderer->SetPreview(setting<bool>(delegate, HdGranularSettingsTokens->preview, true));
  viewSwitch.Update(_renderer->GetSharedScene());  // what the scene's view left to measure
  _renderer->SetProvisional(builder.Pending() || viewSwitch.Pending());
  _renderer->Start();
}

PXR_NAMESPACE_CLOSE_SCOPE
