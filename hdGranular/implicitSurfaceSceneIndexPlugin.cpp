// implicitSurfaceSceneIndexPlugin.cpp — turns UsdGeom Cube, Sphere, Cone, Cylinder and
// Capsule into meshes for the Granular renderer (it renders triangle meshes only), with
// Hydra's own implicit-surface scene index.
#include "pxr/imaging/hd/retainedDataSource.h"
#include "pxr/imaging/hd/sceneIndexPlugin.h"
#include "pxr/imaging/hd/sceneIndexPluginRegistry.h"
#include "pxr/imaging/hd/tokens.h"
#include "pxr/imaging/hdsi/implicitSurfaceSceneIndex.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranular_ImplicitSurfaceSceneIndexPlugin final : public HdSceneIndexPlugin {
 public:
  HdGranular_ImplicitSurfaceSceneIndexPlugin() = default;

 protected:
  HdSceneIndexBaseRefPtr _AppendSceneIndex(const HdSceneIndexBaseRefPtr& input,
                                           const HdContainerDataSourceHandle& args) override {
    return HdsiImplicitSurfaceSceneIndex::New(input, args);
  }
};

TF_REGISTRY_FUNCTION(TfType) { HdSceneIndexPluginRegistry::Define<HdGranular_ImplicitSurfaceSceneIndexPlugin>(); }

TF_REGISTRY_FUNCTION(HdSceneIndexPlugin) {
  HdDataSourceBaseHandle const toMesh =
      HdRetainedTypedSampledDataSource<TfToken>::New(HdsiImplicitSurfaceSceneIndexTokens->toMesh);
  HdContainerDataSourceHandle const args = HdRetainedContainerDataSource::New(
      HdPrimTypeTokens->sphere, toMesh, HdPrimTypeTokens->cube, toMesh, HdPrimTypeTokens->cone, toMesh,
      HdPrimTypeTokens->cylinder, toMesh, HdPrimTypeTokens->capsule, toMesh);
  HdSceneIndexPluginRegistry::GetInstance().RegisterSceneIndexForRenderer(
      "Granular", TfToken("HdGranular_ImplicitSurfaceSceneIndexPlugin"), args, 0,
      HdSceneIndexPluginRegistry::InsertionOrderAtStart);
}

PXR_NAMESPACE_CLOSE_SCOPE
