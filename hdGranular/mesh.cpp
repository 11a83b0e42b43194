#include <algorithm>
#include <cmath>

#include "mesh.h"

#include "instancer.h"
#include "light.h"
#include "pxr/base/gf/vec3d.h"
#include "pxr/base/gf/vec2f.h"
#include "pxr/base/gf/vec3f.h"
#include "pxr/base/gf/half.h"
#include "pxr/base/vt/array.h"
#include "pxr/imaging/hd/instancer.h"
#include "pxr/imaging/hd/renderIndex.h"
#include "pxr/imaging/hd/sceneDelegate.h"
#include "pxr/imaging/hd/tokens.h"
#include "core/error.h"
#include "core/usd_implicit.h"
#include "core/usd_lights.h"
#include "core/usd_mesh.h"
#include "core/usd_shading.h"
#include "renderParam.h"
#include "usdValue.h"

PXR_NAMESPACE_OPEN_SCOPE

namespace {


// A granular primvar's value for core's schema code (granular_prims.h).
granular::PrimvarValue toPrimvarValue(VtValue const& v) {
  return HdGranularUsdValue(v).value_or(granular::PrimvarValue{});
}

}  // namespace

HdGranularMesh::HdGranularMesh(SdfPath const& id) : HdMesh(id) {}

HdDirtyBits HdGranularMesh::GetInitialDirtyBitsMask() const {
  return HdChangeTracker::Clean | HdChangeTracker::InitRepr | HdChangeTracker::DirtyPoints |
         HdChangeTracker::DirtyTopology | HdChangeTracker::DirtyTransform | HdChangeTracker::DirtyVisibility |
         HdChangeTracker::DirtyPrimvar | HdChangeTracker::DirtyInstancer | HdChangeTracker::DirtyInstanceIndex |
         HdChangeTracker::DirtyMaterialId | HdChangeTracker::DirtyPrimID | HdChangeTracker::DirtyCategories;
}

TfTokenVector const& HdGranularMesh::GetBuiltinPrimvarNames() const {
  static const TfTokenVector names = {HdTokens->points, HdTokens->displayColor};
  return names;
}

void HdGranularMesh::Sync(HdSceneDelegate* delegate, HdRenderParam* renderParam, HdDirtyBits* dirtyBits,
                          TfToken const&) {
  auto* param = static_cast<HdGranularRenderParam*>(renderParam);
  const SdfPath& id = GetId();
  _UpdateVisibility(delegate, dirtyBits);
  _UpdateInstancer(delegate, dirtyBits);
  HdInstancer::_SyncInstancerAndParents(delegate->GetRenderIndex(), GetInstancerId());

  // Everything is read again on any change: meshes are cheap next to rebuilding the
  // core scene, which any edit does anyway.
  HdGranularRenderParam::Mesh m;
  m.prim.path = id.GetString();
  m.prim.visible = IsVisible();
  m.prim.id = GetPrimId();

  // An implicit surface carries its parameters (implicitSurfaceSceneIndexPlugin.cpp): core
  // tessellates it (core/usd_implicit.h). A mesh: points and topology as UsdGeomMesh holds
  // them, triangulated by core (core/usd_mesh.h).
  granular::UsdMeshRecord& record = m.topology;
  record.path = id.GetString();
  try {
    const VtValue implicitType = delegate->Get(id, TfToken("hdGranular:implicit"));
    if (implicitType.IsHolding<TfToken>()) {
      granular::UsdPrimRecord shape;
      shape.path = id.GetString();
      shape.typeName = implicitType.UncheckedGet<TfToken>().GetString();
      for (std::string const& name : granular::usdImplicitAttributeNames())
        if (auto v = HdGranularUsdValue(delegate->Get(id, TfToken("hdGranular:implicit:" + name))))
          shape.attributes[name] = *v;
      m.prim.typeName = shape.typeName;
      m.prim.mesh = granular::implicitSurfaceFromUsd(shape);
    } else {
      VtValue pointsValue = delegate->Get(id, HdTokens->points);
      if (pointsValue.IsHolding<VtVec3fArray>())
        for (GfVec3f const& p : pointsValue.UncheckedGet<VtVec3fArray>()) record.points.emplace_back(p[0], p[1], p[2]);
      HdMeshTopology topology = GetMeshTopology(delegate);
      record.faceVertexCounts.assign(topology.GetFaceVertexCounts().begin(), topology.GetFaceVertexCounts().end());
      record.faceVertexIndices.assign(topology.GetFaceVertexIndices().begin(),
                                      topology.GetFaceVertexIndices().end());
      record.holeIndices.assign(topology.GetHoleIndices().begin(), topology.GetHoleIndices().end());
      record.orientation = topology.GetOrientation().GetString();
      m.prim.mesh = granular::meshFromUsd(record);
    }
  } catch (granular::InputError const& e) {
    param->SetError(id, e);  // refused as granular render refuses it
    *dirtyBits &= ~HdChangeTracker::AllSceneDirtyBits;
    return;
  }
  // Texture coordinates: every float2 primvar as found; the bound material picks one.
  for (HdInterpolation interp : {HdInterpolationConstant, HdInterpolationUniform, HdInterpolationVarying,
                                 HdInterpolationVertex, HdInterpolationFaceVarying}) {
    static const char* const kNames[] = {"constant", "uniform", "varying", "vertex", "faceVarying"};
    for (HdPrimvarDescriptor const& pv : delegate->GetPrimvarDescriptors(id, interp)) {
      if (pv.name == HdTokens->points || pv.name.GetString().rfind("granular:", 0) == 0) continue;
      VtValue value = delegate->Get(id, pv.name);
      if (!value.IsHolding<VtVec2fArray>()) continue;
      granular::UsdValue uv;
      uv.typeName = "texCoord2f[]";
      uv.isArray = true;
      uv.interpolation = kNames[interp];
      for (GfVec2f const& x : value.UncheckedGet<VtVec2fArray>()) uv.numbers.insert(uv.numbers.end(), {x[0], x[1]});
      m.uvSets[pv.name.GetString()] = std::move(uv);
    }
  }

  // Granular primvars of any interpolation: core rejects all but constant, by name.
  static const std::pair<HdInterpolation, const char*> kInterpolations[] = {
      {HdInterpolationUniform, "uniform"}, {HdInterpolationVarying, "varying"}, {HdInterpolationVertex, "vertex"},
      {HdInterpolationFaceVarying, "faceVarying"}, {HdInterpolationInstance, "instance"}};
  for (auto const& [interp, interpName] : kInterpolations)
    for (HdPrimvarDescriptor const& pv : delegate->GetPrimvarDescriptors(id, interp))
      if (pv.name.GetString().rfind("granular:", 0) == 0) {
        granular::PrimvarValue v = toPrimvarValue(delegate->Get(id, pv.name));
        v.interpolation = interpName;
        m.prim.granular[pv.name.GetString().substr(9)] = v;
      }
  for (HdPrimvarDescriptor const& pv : delegate->GetPrimvarDescriptors(id, HdInterpolationConstant)) {
    std::string name = pv.name.GetString();
    if (name.rfind("primvars:", 0) == 0) name = name.substr(9);
    if (name.rfind("granular:", 0) == 0) m.prim.granular[name.substr(9)] = toPrimvarValue(delegate->Get(id, pv.name));
  }
  // Light linking: the light-link collections that include the prim (core/usd_lights.h).
  for (TfToken const& c : delegate->GetCategories(id)) m.prim.linkCategories.push_back(c.GetString());
  const GfMatrix4d xf = delegate->GetTransform(id);
  m.local = HdGranularToCore(xf);
  m.instancerId = GetInstancerId();
  if (GetInstancerId().IsEmpty()) {
    m.prim.instances = {m.local};
  } else if (HdInstancer* inst = delegate->GetRenderIndex().GetInstancer(GetInstancerId())) {
    auto* instancer = static_cast<HdGranularInstancer*>(inst);
    const VtIntArray indices = instancer->ComputeInstanceIndices(id);  // the instanceId AOV's
    // A mesh with grain primvars is never drawn as a mesh (core/granular_prims.h): a grain
    // prototype needs its instances' indices only, not 10^6 transforms.
    if (std::any_of(m.prim.granular.begin(), m.prim.granular.end(),
                    [](auto const& v) { return granular::isGrainPrimvar(v.first); })) {
      m.prim.instanceIds.assign(indices.begin(), indices.end());
    } else {
      for (GfMatrix4d const& i : instancer->ComputeInstanceTransforms(id))
        m.prim.instances.push_back(HdGranularToCore(xf * i));  // row vectors: mesh, then instance
      if (indices.size() == m.prim.instances.size()) m.prim.instanceIds.assign(indices.begin(), indices.end());
      m.prim.instanceLinkCategories = instancer->ComputeInstanceCategories(id);
      if (m.prim.instanceLinkCategories.size() != m.prim.instances.size()) m.prim.instanceLinkCategories.clear();
    }
  }

  // MeshLightAPI: the surface is a mesh light's body (core/granular_prims.h). UsdImaging
  // answers a light's parameter for a prim with LightAPI applied, nothing for another.
  if (!delegate->GetLightParamValue(id, HdLightTokens->intensity).IsEmpty()) {
    try {
      granular::UsdWarnings warnings;
      m.lightRecord = HdGranularLightRecord(delegate, id, m.prim.typeName);
      m.prim.light = granular::lightFromUsd(*m.lightRecord, warnings);
      param->Warn(warnings);
    } catch (granular::InputError const& e) {
      param->SetError(id, e);
      *dirtyBits &= ~HdChangeTracker::AllSceneDirtyBits;
      return;
    }
    m.prim.doubleSided = delegate->GetDoubleSided(id);
    // OpenUSD 24.08's UsdImaging names the light-link collections of light prims alone: a
    // mesh light's are not seen, and it lights (and is shadowed by) every object. Said where
    // its collection leaves the root out, which the attribute shows.
    for (const char* link : {"lightLink", "shadowLink"}) {
      const VtValue root = delegate->Get(id, TfToken(std::string("collection:") + link + ":includeRoot"));
      if (root.IsHolding<bool>() && !root.UncheckedGet<bool>())
        param->Warn({id.GetString() + ".collection:" + link +
                     ": a mesh light's collections are not seen by hdGranular (OpenUSD 24.08's UsdImaging resolves "
                     "those of light prims alone); it reaches every object"});
    }
  }

  // displayColor of any interpolation, as found; core averages and checks it.
  static const char* const kInterpolationNames[] = {"constant", "uniform", "varying", "vertex", "faceVarying"};
  for (HdInterpolation interp : {HdInterpolationConstant, HdInterpolationUniform, HdInterpolationVarying,
                                 HdInterpolationVertex, HdInterpolationFaceVarying})
    for (HdPrimvarDescriptor const& pv : delegate->GetPrimvarDescriptors(id, interp)) {
      if (pv.name != HdTokens->displayColor) continue;
      std::optional<granular::UsdValue> c = HdGranularUsdValue(delegate->Get(id, pv.name));
      if (!c) continue;
      c->interpolation = kInterpolationNames[interp];
      try {
        granular::UsdWarnings warnings;
        m.prim.displayColor = granular::displayColorFromUsd(*c, m.prim.typeName == "Mesh" ? &m.topology : nullptr,
                                                            id.GetString(), warnings);
        param->Warn(warnings);
      } catch (granular::InputError const& e) {
        param->SetError(id, e);
        *dirtyBits &= ~HdChangeTracker::AllSceneDirtyBits;
        return;
      }
    }
  m.materialId = delegate->GetMaterialId(id);
  param->SetMesh(id, std::move(m));
  *dirtyBits &= ~HdChangeTracker::AllSceneDirtyBits;
}

void HdGranularMesh::Finalize(HdRenderParam* renderParam) {
  static_cast<HdGranularRenderParam*>(renderParam)->Remove(GetId());
}

PXR_NAMESPACE_CLOSE_SCOPE
