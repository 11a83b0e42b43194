#include "renderDelegate.h"

#include "core/cryptomatte.h"
#include "instancer.h"
#include "light.h"
#include "material.h"
#include "mesh.h"
#include "pxr/base/tf/pyLock.h"
#include "pxr/base/work/detachedTask.h"
#include "pxr/imaging/hd/camera.h"
#include "pxr/imaging/hd/tokens.h"
#include "renderBuffer.h"
#include "renderSettings.h"
#include "renderParam.h"
#include "renderPass.h"
#include "renderer.h"

PXR_NAMESPACE_OPEN_SCOPE

TF_DEFINE_PUBLIC_TOKENS(HdGranularSettingsTokens, HDGRANULAR_SETTINGS_TOKENS);

namespace {
const TfTokenVector kRprimTypes = {HdPrimTypeTokens->mesh};
const TfTokenVector kSprimTypes = {HdPrimTypeTokens->camera,      HdPrimTypeTokens->material,
                                   HdPrimTypeTokens->distantLight, HdPrimTypeTokens->domeLight,
                                   HdPrimTypeTokens->rectLight,    HdPrimTypeTokens->sphereLight,
                                   HdPrimTypeTokens->diskLight,    HdPrimTypeTokens->cylinderLight,
                                   // Not rendered: synced so that core warns about it by name.
                                   HdPrimTypeTokens->pluginLight};
const TfTokenVector kBprimTypes = {HdPrimTypeTokens->renderBuffer, HdPrimTypeTokens->renderSettings};
}  // namespace

HdGranularRenderDelegate::HdGranularRenderDelegate() { _Initialize(); }

HdGranularRenderDelegate::HdGranularRenderDelegate(HdRenderSettingsMap const& settings)
    : HdRenderDelegate(settings) {
  _Initialize();
}

void HdGranularRenderDelegate::_Initialize() {
  _param = std::make_shared<HdGranularRenderParam>();
  _renderer = std::make_unique<HdGranularRenderer>();
  _param->SetRenderer(_renderer.get());
  _registry = std::make_shared<HdResourceRegistry>();
  _descriptors = {
      {"Samples per pixel", HdRenderSettingsTokens->convergedSamplesPerPixel, VtValue(16)},
      {"Noise threshold (relative standard error; 0: off)", HdRenderSettingsTokens->convergedVariance, VtValue(0.0f)},
      {"Threads (0: all cores)", HdRenderSettingsTokens->threadLimit, VtValue(0)},
      {"Seed", HdGranularSettingsTokens->seed, VtValue(0)},
      {"Technique (ept, ept+vpt, hybrid)", HdGranularSettingsTokens->technique, VtValue(std::string("hybrid"))},
      {"Switch spread tau (grain radii)", HdGranularSettingsTokens->tau, VtValue(4.0f)},
      {"Bounces always explicit (-1: from the grains' albedo)", HdGranularSettingsTokens->explicitBounces,
       VtValue(granular::RenderSettings().explicitBounces)},
      {"Diffusion from this many times the paper's depth", HdGranularSettingsTokens->daDepthFactor,
       VtValue(granular::RenderSettings().daDepthFactor)},
      {"Diffusion after this many scatterings", HdGranularSettingsTokens->daMinOrder,
       VtValue(granular::RenderSettings().daMinOrder)},
      {"Diffusion in simulated grains' media too (where uniform enough)", HdGranularSettingsTokens->daInstanced,
       VtValue(granular::RenderSettings().daInstanced)},
      {"Level of detail (0: off)", HdGranularSettingsTokens->lod, VtValue(0.5f)},
      {"Proxies after the first grain (auto: under a narrow sun; on; off)", HdGranularSettingsTokens->proxies,
       VtValue(std::string(granular::proxyUseName(granular::RenderSettings().proxies)))},
      {"The equivalent medium's transport (tt; exits: light moved as grains let it out)",
       HdGranularSettingsTokens->mediumModel,
       VtValue(std::string(granular::mediumModelName(granular::RenderSettings().mediumModel)))},
      {"Roulette or splitting P_a (negative: tuned)", HdGranularSettingsTokens->roulette, VtValue(-1.0f)},
      {"Bundle size", HdGranularSettingsTokens->bundleSize, VtValue(16)},
      {"Default dome light when the stage has none", HdGranularSettingsTokens->defaultLight, VtValue(true)},
      {"Delta suns as the physical sun (0.53 degrees) over smooth grains", HdGranularSettingsTokens->physicalSun,
       VtValue(true)},
      {"Suns narrower than this (degrees) widened for smooth grains' glints (0: exact)",
       HdGranularSettingsTokens->sunRegularization, VtValue(granular::RenderSettings().sunRegularization)},
      {"The switch from proxies to the medium measured for this view too (seconds per aggregate per new view)",
       HdGranularSettingsTokens->switchForView, VtValue(granular::RenderSettings().switchForView)},
      {"Coarse previews before the first pass", HdGranularSettingsTokens->preview, VtValue(true)},
      {"Stand-ins (the medium alone) while aggregates build", HdGranularSettingsTokens->standIns, VtValue(true)},
      {"Denoise the color AOV after each pass (Intel Open Image Denoise)", HdGranularSettingsTokens->denoise,
       VtValue(false)},
      // A scene delegate hands the camera's shutter in time codes but not the stage's
      // timeCodesPerSecond, which velocities (units per second) need: 24 unless told.
      {"Motion blur over the camera's shutter (UsdRender disableMotionBlur also turns it off)",
       HdGranularSettingsTokens->motionBlur, VtValue(true)},
      {"Time codes per second of the stage (the shutter in seconds for velocities)",
       HdGranularSettingsTokens->timeCodesPerSecond, VtValue(24.0)},
  };
  _PopulateDefaultSettings(_descriptors);
}

HdGranularRenderDelegate::~HdGranularRenderDelegate() {
  _param->SetRenderer(nullptr);
  _renderer.reset();  // stops the render thread before the prims go
  // A host's engine destroys its scene indices and render index before its delegate, some
  // of their caches in OpenUSD's detached tasks (WorkSwapDestroyAsync). One still running
  // when a Python host such as usdrecord finalises its interpreter takes the GIL, is ended
  // by the interpreter, and aborts the process ("terminate called without an active
  // exception") after its images are written. Finish them before the engine is gone, with
  // the GIL released for those that need it.
  TF_PY_ALLOW_THREADS_IN_SCOPE();
  Work_GetDetachedDispatcher().Wait();
}

HdRenderParam* HdGranularRenderDelegate::GetRenderParam() const { return _param.get(); }
const TfTokenVector& HdGranularRenderDelegate::GetSupportedRprimTypes() const { return kRprimTypes; }
const TfTokenVector& HdGranularRenderDelegate::GetSupportedSprimTypes() const { return kSprimTypes; }
const TfTokenVector& HdGranularRenderDelegate::GetSupportedBprimTypes() const { return kBprimTypes; }

VtDictionary HdGranularRenderDelegate::GetRenderStats() const {
  VtDictionary stats = _renderer->GetStats();
  // What core said about the stage, as granular render prints it: each warning once, and
  // the error that refused the image.
  VtStringArray warnings;
  for (std::string const& w : _param->Warnings()) warnings.push_back(w);
  stats["granular:warnings"] = VtValue(warnings);
  stats["granular:error"] = VtValue(_param->RenderError());
  VtDictionary manifests;  // per Cryptomatte type, what GetCryptomatteManifest gives
  for (auto type : {granular::CryptomatteType::Object, granular::CryptomatteType::Material}) {
    const TfToken name(granular::cryptomatteTypeName(type));
    manifests[name] = VtValue(GetCryptomatteManifest(name));
  }
  stats["granular:cryptomatte"] = VtValue(manifests);
  return stats;
}

HdAovDescriptor HdGranularRenderDelegate::GetDefaultAovDescriptor(TfToken const& name) const {
  if (name == HdAovTokens->color) return HdAovDescriptor(HdFormatFloat32Vec4, false, VtValue(GfVec4f(0.0f)));
  if (name == HdAovTokens->depth) return HdAovDescriptor(HdFormatFloat32, false, VtValue(1.0f));
  if (name == HdAovTokens->cameraDepth) return HdAovDescriptor(HdFormatFloat32, false, VtValue(0.0f));
  if (name == HdAovTokens->primId) return HdAovDescriptor(HdFormatInt32, false, VtValue(-1));
  if (name == HdAovTokens->normal || name == "ept" || name == "vpt" || name == "da" || name == "ppt" ||
      name == "albedo" || name == "variance")
    return HdAovDescriptor(HdFormatFloat32Vec3, false, VtValue(GfVec3f(0.0f)));
  // The compositing AOVs (core/film.h); a Cryptomatte layer makes the film keep its tables.
  if (name == "sampleCount") return HdAovDescriptor(HdFormatFloat32, false, VtValue(0.0f));
  if (name == HdAovTokens->instanceId || name == "aggregateId")
    return HdAovDescriptor(HdFormatInt32, false, VtValue(-1));
  granular::CryptomatteType type;
  if (granular::cryptomatteTypeOfLayer(name.GetString(), type) && name.GetString() != granular::cryptomatteTypeName(type))
    return HdAovDescriptor(HdFormatFloat32Vec4, false, VtValue(GfVec4f(0.0f)));
  return HdAovDescriptor();  // unsupported
}

std::string HdGranularRenderDelegate::GetCryptomatteManifest(TfToken const& layer) const {
  granular::CryptomatteType type;
  granular::Scene const* scene = _renderer->GetScene();
  if (!scene || !granular::cryptomatteTypeOfLayer(layer.GetString(), type)) return "";
  return granular::cryptomatteManifest(scene->cryptomatteNames(type));
}

HdRenderPassSharedPtr HdGranularRenderDelegate::CreateRenderPass(HdRenderIndex* index,
                                                                 HdRprimCollection const& collection) {
  return std::make_shared<HdGranularRenderPass>(index, collection, _param.get(), _renderer.get());
}

HdInstancer* HdGranularRenderDelegate::CreateInstancer(HdSceneDelegate* delegate, SdfPath const& id) {
  return new HdGranularInstancer(delegate, id);
}

void HdGranularRenderDelegate::DestroyInstancer(HdInstancer* instancer) { delete instancer; }

HdRprim* HdGranularRenderDelegate::CreateRprim(TfToken const& typeId, SdfPath const& rprimId) {
  if (typeId == HdPrimTypeTokens->mesh) return new HdGranularMesh(rprimId);
  TF_CODING_ERROR("hdGranular: unknown rprim type %s", typeId.GetText());
  return nullptr;
}

void HdGranularRenderDelegate::DestroyRprim(HdRprim* rprim) { delete rprim; }

HdSprim* HdGranularRenderDelegate::CreateSprim(TfToken const& typeId, SdfPath const& sprimId) {
  if (typeId == HdPrimTypeTokens->camera) return new HdCamera(sprimId);
  if (typeId == HdPrimTypeTokens->material) return new HdGranularMaterial(sprimId);
  if (HdPrimTypeIsLight(typeId)) return new HdGranularLight(sprimId, typeId);
  TF_CODING_ERROR("hdGranular: unknown sprim type %s", typeId.GetText());
  return nullptr;
}

HdSprim* HdGranularRenderDelegate::CreateFallbackSprim(TfToken const& typeId) {
  return CreateSprim(typeId, SdfPath::EmptyPath());
}

void HdGranularRenderDelegate::DestroySprim(HdSprim* sprim) { delete sprim; }

HdBprim* HdGranularRenderDelegate::CreateBprim(TfToken const& typeId, SdfPath const& bprimId) {
  if (typeId == HdPrimTypeTokens->renderBuffer) return new HdGranularRenderBuffer(bprimId);
  if (typeId == HdPrimTypeTokens->renderSettings) return new HdGranularRenderSettings(bprimId, _renderer.get());
  TF_CODING_ERROR("hdGranular: unknown bprim type %s", typeId.GetText());
  return nullptr;
}

HdBprim* HdGranularRenderDelegate::CreateFallbackBprim(TfToken const& typeId) {
  return CreateBprim(typeId, SdfPath::EmptyPath());
}

void HdGranularRenderDelegate::DestroyBprim(HdBprim* bprim) { delete bprim; }

PXR_NAMESPACE_CLOSE_SCOPE
