// renderDelegate.h — the Granular render delegate: which Hydra prims it supports, the
// render settings it exposes to hosts, its render stats, and the objects it shares
// with them (the render param: the scene as plain data; the renderer: the render loop).
#ifndef HDGRANULAR_RENDER_DELEGATE_H
#define HDGRANULAR_RENDER_DELEGATE_H

#include <memory>

#include "pxr/base/tf/staticTokens.h"
#include "pxr/imaging/hd/renderDelegate.h"
#include "pxr/imaging/hd/resourceRegistry.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

// Settings of ours (besides Hydra's convergedSamplesPerPixel, convergedVariance and
// threadLimit), mirroring core's RenderSettings.
#define HDGRANULAR_SETTINGS_TOKENS                    \
  ((seed, "granular:seed"))                           \
  ((technique, "granular:technique"))                 \
  ((tau, "granular:tau"))                             \
  ((explicitBounces, "granular:explicitBounces"))     \
  ((daDepthFactor, "granular:daDepthFactor"))         \
  ((daMinOrder, "granular:daMinOrder"))               \
  ((daInstanced, "granular:daInstanced"))             \
  ((lod, "granular:lod"))                             \
  ((proxies, "granular:proxies"))                     \
  ((mediumModel, "granular:mediumModel"))             \
  ((roulette, "granular:roulette"))                   \
  ((bundleSize, "granular:bundleSize"))               \
  ((defaultLight, "granular:defaultLight"))           \
  ((physicalSun, "granular:physicalSun"))             \
  ((sunRegularization, "granular:sunRegularization")) \
  ((switchForView, "granular:switchForView"))         \
  ((preview, "granular:preview"))                     \
  ((standIns, "granular:standIns"))                   \
  ((denoise, "granular:denoise"))                   \
  ((motionBlur, "granular:motionBlur"))             \
  ((timeCodesPerSecond, "granular:timeCodesPerSecond"))

TF_DECLARE_PUBLIC_TOKENS(HdGranularSettingsTokens, HDGRANULAR_SETTINGS_TOKENS);

class HdGranularRenderParam;
class HdGranularRenderer;

class HdGranularRenderDelegate final : public HdRenderDelegate {
 public:
  HdGranularRenderDelegate();
  explicit HdGranularRenderDelegate(HdRenderSettingsMap const& settings);
  ~HdGranularRenderDelegate() override;

  HdRenderParam* GetRenderParam() const override;
  const TfTokenVector& GetSupportedRprimTypes() const override;
  const TfTokenVector& GetSupportedSprimTypes() const override;
  const TfTokenVector& GetSupportedBprimTypes() const override;
  HdResourceRegistrySharedPtr GetResourceRegistry() const override { return _registry; }
  HdRenderSettingDescriptorList GetRenderSettingDescriptors() const override { return _descriptors; }
  VtDictionary GetRenderStats() const override;
  HdAovDescriptor GetDefaultAovDescriptor(TfToken const& name) const override;
  // The Cryptomatte manifest (JSON {name: 8 hex digits of its id}, core/cryptomatte.h) of
  // the scene being rendered, for a layer ("CryptoObject", "CryptoObject00", ...,
  // "CryptoMaterial02"), for a host's or a product's file header; "" for another name or
  // without a scene. The render stats hold them too (granular:cryptomatte).
  std::string GetCryptomatteManifest(TfToken const& layer) const;

  HdRenderPassSharedPtr CreateRenderPass(HdRenderIndex* index, HdRprimCollection const& collection) override;
  HdInstancer* CreateInstancer(HdSceneDelegate* delegate, SdfPath const& id) override;
  void DestroyInstancer(HdInstancer* instancer) override;
  HdRprim* CreateRprim(TfToken const& typeId, SdfPath const& rprimId) override;
  void DestroyRprim(HdRprim* rprim) override;
  HdSprim* CreateSprim(TfToken const& typeId, SdfPath const& sprimId) override;
  HdSprim* CreateFallbackSprim(TfToken const& typeId) override;
  void DestroySprim(HdSprim* sprim) override;
  HdBprim* CreateBprim(TfToken const& typeId, SdfPath const& bprimId) override;
  HdBprim* CreateFallbackBprim(TfToken const& typeId) override;
  void DestroyBprim(HdBprim* bprim) override;
  void CommitResources(HdChangeTracker* tracker) override {}
  TfToken GetMaterialBindingPurpose() const override { return HdTokens->full; }

 private:
  void _Initialize();
  std::shared_ptr<HdGranularRenderParam> _param;
  std::unique_ptr<HdGranularRenderer> _renderer;
  HdResourceRegistrySharedPtr _registry;
  HdRenderSettingDescriptorList _descriptors;
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
