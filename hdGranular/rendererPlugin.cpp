#include "rendererPlugin.h"

#include "pxr/imaging/hd/rendererPluginRegistry.h"
#include "renderDelegate.h"

PXR_NAMESPACE_OPEN_SCOPE

TF_REGISTRY_FUNCTION(TfType) { HdRendererPluginRegistry::Define<HdGranularRendererPlugin>(); }

HdRenderDelegate* HdGranularRendererPlugin::CreateRenderDelegate() { return new HdGranularRenderDelegate(); }

HdRenderDelegate* HdGranularRendererPlugin::CreateRenderDelegate(HdRenderSettingsMap const& settings) {
  return new HdGranularRenderDelegate(settings);
}

void HdGranularRendererPlugin::DeleteRenderDelegate(HdRenderDelegate* delegate) { delete delegate; }

PXR_NAMESPACE_CLOSE_SCOPE
