// rendererPlugin.h — the plugin class Hydra hosts discover: it names the renderer
// "Granular" (plugInfo.json) and makes one HdGranularRenderDelegate per render index.
#ifndef HDGRANULAR_RENDERER_PLUGIN_H
#define HDGRANULAR_RENDERER_PLUGIN_H

#include "pxr/imaging/hd/rendererPlugin.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularRendererPlugin final : public HdRendererPlugin {
 public:
  HdGranularRendererPlugin() = default;
  HdRenderDelegate* CreateRenderDelegate() override;
  HdRenderDelegate* CreateRenderDelegate(HdRenderSettingsMap const& settings) override;
  void DeleteRenderDelegate(HdRenderDelegate* delegate) override;
  // A CPU renderer: supported with or without a GPU.
  bool IsSupported(bool gpuEnabled = true) const override { return true; }
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
