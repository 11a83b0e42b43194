// implicitSurfaceSceneIndexPlugin.cpp — UsdGeom Cube, Sphere, Cylinder, Cone and Capsule
// reach the Granular renderer as meshes (it renders triangle meshes only) that carry their
// shape's parameters as constant primvars "hdGranular:implicit" (the USD type name) and
// "hdGranular:implicit:<attribute>"; HdGranularMesh tessellates them with core
// (core/usd_implicit.h), so that both front ends draw and check the same surface.
#include <cctype>

#include "pxr/imaging/hd/capsuleSchema.h"
#include "pxr/imaging/hd/coneSchema.h"
#include "pxr/imaging/hd/cubeSchema.h"
#include "pxr/imaging/hd/cylinderSchema.h"
#include "pxr/imaging/hd/filteringSceneIndex.h"
#include "pxr/imaging/hd/overlayContainerDataSource.h"
#include "pxr/imaging/hd/primvarSchema.h"
#include "pxr/imaging/hd/primvarsSchema.h"
#include "pxr/imaging/hd/retainedDataSource.h"
#include "pxr/imaging/hd/sceneIndexPlugin.h"
#include "pxr/imaging/hd/sceneIndexPluginRegistry.h"
#include "pxr/imaging/hd/sphereSchema.h"
#include "pxr/imaging/hd/tokens.h"
#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

namespace {

bool isImplicit(TfToken const& t) {
  return t == HdPrimTypeTokens->cube || t == HdPrimTypeTokens->sphere || t == HdPrimTypeTokens->cylinder ||
         t == HdPrimTypeTokens->cone || t == HdPrimTypeTokens->capsule;
}

HdContainerDataSourceHandle constant(HdSampledDataSourceHandle const& value) {
  return HdPrimvarSchema::Builder()
      .SetPrimvarValue(value)
      .SetInterpolation(HdPrimvarSchema::BuildInterpolationDataSource(HdPrimvarSchemaTokens->constant))
      .Build();
}

// The shape's authored parameters as primvars (their data sources, so time samples flow).
HdContainerDataSourceHandle shapePrimvars(TfToken const& type, HdContainerDataSourceHandle const& ds) {
  std::string usdType = type.GetString();
  usdType[0] = char(std::toupper(usdType[0]));
  std::vector<TfToken> names = {TfToken("hdGranular:implicit")};
  std::vector<HdDataSourceBaseHandle> values = {constant(HdRetainedTypedSampledDataSource<TfToken>::New(TfToken(usdType)))};
  auto add = [&](const char* name, HdSampledDataSourceHandle const& v) {
    if (!v) return;
    names.push_back(TfToken(std::string("hdGranular:implicit:") + name));
    values.push_back(constant(v));
  };
  if (type == HdPrimTypeTokens->cube) {
    add("size", HdCubeSchema::GetFromParent(ds).GetSize());
  } else if (type == HdPrimTypeTokens->sphere) {
    add("radius", HdSphereSchema::GetFromParent(ds).GetRadius());
  } else if (type == HdPrimTypeTokens->cylinder) {
    HdCylinderSchema s = HdCylinderSchema::GetFromParent(ds);
    add("height", s.GetHeight()), add("radius", s.GetRadius()), add("axis", s.GetAxis());
  } else if (type == HdPrimTypeTokens->cone) {
    HdConeSchema s = HdConeSchema::GetFromParent(ds);
    add("height", s.GetHeight()), add("radius", s.GetRadius()), add("axis", s.GetAxis());
  } else if (type == HdPrimTypeTokens->capsule) {
    HdCapsuleSchema s = HdCapsuleSchema::GetFromParent(ds);
    add("height", s.GetHeight()), add("radius", s.GetRadius()), add("axis", s.GetAxis());
  }
  return HdRetainedContainerDataSource::New(names.size(), names.data(), values.data());
}

class ImplicitSurfaceSceneIndex final : public HdSingleInputFilteringSceneIndexBase {
 public:
  static TfRefPtr<ImplicitSurfaceSceneIndex> New(HdSceneIndexBaseRefPtr const& input) {
    return TfCreateRefPtr(new ImplicitSurfaceSceneIndex(input));
  }

  HdSceneIndexPrim GetPrim(SdfPath const& path) const override {
    HdSceneIndexPrim prim = _GetInputSceneIndex()->GetPrim(path);
    if (!isImplicit(prim.primType) || !prim.dataSource) return prim;
    HdContainerDataSourceHandle primvars = shapePrimvars(prim.primType, prim.dataSource);
    if (HdContainerDataSourceHandle own = HdPrimvarsSchema::GetFromParent(prim.dataSource).GetContainer())
      primvars = HdOverlayContainerDataSource::New(primvars, own);
    prim.dataSource = HdOverlayContainerDataSource::New(
        HdRetainedContainerDataSource::New(HdPrimvarsSchemaTokens->primvars, primvars), prim.dataSource);
    prim.primType = HdPrimTypeTokens->mesh;
    return prim;
  }

  SdfPathVector GetChildPrimPaths(SdfPath const& path) const override {
    return _GetInputSceneIndex()->GetChildPrimPaths(path);
  }

 protected:
  explicit ImplicitSurfaceSceneIndex(HdSceneIndexBaseRefPtr const& input) : HdSingleInputFilteringSceneIndexBase(input) {}

  void _PrimsAdded(HdSceneIndexBase const&, HdSceneIndexObserver::AddedPrimEntries const& entries) override {
    HdSceneIndexObserver::AddedPrimEntries out(entries);
    for (auto& e : out)
      if (isImplicit(e.primType)) e.primType = HdPrimTypeTokens->mesh;
    _SendPrimsAdded(out);
  }

  void _PrimsRemoved(HdSceneIndexBase const&, HdSceneIndexObserver::RemovedPrimEntries const& entries) override {
    _SendPrimsRemoved(entries);
  }

  // An edited shape parameter is an edited primvar of the mesh.
  void _PrimsDirtied(HdSceneIndexBase const&, HdSceneIndexObserver::DirtiedPrimEntries const& entries) override {
    static const HdDataSourceLocatorSet shapes = {HdCubeSchema::GetDefaultLocator(), HdSphereSchema::GetDefaultLocator(),
                                                  HdCylinderSchema::GetDefaultLocator(), HdConeSchema::GetDefaultLocator(),
                                                  HdCapsuleSchema::GetDefaultLocator()};
    HdSceneIndexObserver::DirtiedPrimEntries out(entries);
    for (auto& e : out)
      if (e.dirtyLocators.Intersects(shapes)) e.dirtyLocators.insert(HdPrimvarsSchema::GetDefaultLocator());
    _SendPrimsDirtied(out);
  }
};

}  // namespace

class HdGranular_ImplicitSurfaceSceneIndexPlugin final : public HdSceneIndexPlugin {
 public:
  HdGranular_ImplicitSurfaceSceneIndexPlugin() = default;

 protected:
  HdSceneIndexBaseRefPtr _AppendSceneIndex(HdSceneIndexBaseRefPtr const& input,
                                           HdContainerDataSourceHandle const&) override {
    return ImplicitSurfaceSceneIndex::New(input);
  }
};

TF_REGISTRY_FUNCTION(TfType) { HdSceneIndexPluginRegistry::Define<HdGranular_ImplicitSurfaceSceneIndexPlugin>(); }

TF_REGISTRY_FUNCTION(HdSceneIndexPlugin) {
  HdSceneIndexPluginRegistry::GetInstance().RegisterSceneIndexForRenderer(
      "Granular", TfToken("HdGranular_ImplicitSurfaceSceneIndexPlugin"), nullptr, 0,
      HdSceneIndexPluginRegistry::InsertionOrderAtStart);
}

PXR_NAMESPACE_CLOSE_SCOPE
