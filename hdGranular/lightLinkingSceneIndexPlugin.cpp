// lightLinkingSceneIndexPlugin.cpp — light linking under the scene-index UsdImaging: OpenUSD's
// HdsiLightLinkingSceneIndex turns each light's collection:lightLink (and shadowLink) into
// a category id on the light and the categories of the meshes it includes, which
// HdGranularLight and HdGranularMesh read as under UsdImagingDelegate (core/usd_lights.h).
// Under UsdImagingDelegate, which computes them itself, it leaves them as they are. It does
// not follow instanced prims (OpenUSD's note): a prototype's mesh keeps its own categories.
#include "pxr/imaging/hd/retainedDataSource.h"
#include "pxr/imaging/hd/sceneIndexPlugin.h"
#include "pxr/imaging/hd/sceneIndexPluginRegistry.h"
#include "pxr/imaging/hd/tokens.h"
#include "pxr/imaging/hdsi/lightLinkingSceneIndex.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranular_LightLinkingSceneIndexPlugin final : public HdSceneIndexPlugin {
 public:
  HdGranular_LightLinkingSceneIndexPlugin() = default;

 protected:
  HdSceneIndexBaseRefPtr _AppendSceneIndex(HdSceneIndexBaseRefPtr const& input,
                                           HdContainerDataSourceHandle const&) override {
    // The lights HdGranularRenderDelegate syncs, and meshes (implicit surfaces are meshes by
    // then: HdGranular_ImplicitSurfaceSceneIndexPlugin comes first).
    const VtArray<TfToken> lights = {HdPrimTypeTokens->distantLight, HdPrimTypeTokens->domeLight,
                                     HdPrimTypeTokens->rectLight,    HdPrimTypeTokens->sphereLight,
                                     HdPrimTypeTokens->diskLight,    HdPrimTypeTokens->cylinderLight};
    const VtArray<TfToken> geometry = {HdPrimTypeTokens->mesh};
    const TfToken names[] = {HdsiLightLinkingSceneIndexTokens->lightPrimTypes,
                             HdsiLightLinkingSceneIndexTokens->geometryPrimTypes};
    const HdDataSourceBaseHandle values[] = {HdRetainedTypedSampledDataSource<VtArray<TfToken>>::New(lights),
                                             HdRetainedTypedSampledDataSource<VtArray<TfToken>>::New(geometry)};
    return HdsiLightLinkingSceneIndex::New(input, HdRetainedContainerDataSource::New(2, names, values));
  }
};

TF_REGISTRY_FUNCTION(TfType) { HdSceneIndexPluginRegistry::Define<HdGranular_LightLinkingSceneIndexPlugin>(); }

TF_REGISTRY_FUNCTION(HdSceneIndexPlugin) {
  HdSceneIndexPluginRegistry::GetInstance().RegisterSceneIndexForRenderer(
      "Granular", TfToken("HdGranular_LightLinkingSceneIndexPlugin"), nullptr, 1,
      HdSceneIndexPluginRegistry::InsertionOrderAtEnd);
}

PXR_NAMESPACE_CLOSE_SCOPE
