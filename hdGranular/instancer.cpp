#include "instancer.h"

#include "pxr/base/gf/matrix4d.h"
#include "pxr/base/gf/quatd.h"
#include "pxr/base/gf/quatf.h"
#include "pxr/base/gf/quath.h"
#include "pxr/base/gf/rotation.h"
#include "pxr/base/gf/vec3f.h"
#include "pxr/imaging/hd/renderIndex.h"
#include "pxr/imaging/hd/sceneDelegate.h"
#include "pxr/imaging/hd/tokens.h"
#include "renderParam.h"

PXR_NAMESPACE_OPEN_SCOPE

namespace {

// The i-th element of an instance primvar as a matrix applied before the others.
bool translateAt(VtValue const& v, size_t i, GfMatrix4d& m) {
  if (!v.IsHolding<VtVec3fArray>() || i >= v.GetArraySize()) return false;
  m.SetTranslate(GfVec3d(v.UncheckedGet<VtVec3fArray>()[i]));
  return true;
}

bool scaleAt(VtValue const& v, size_t i, GfMatrix4d& m) {
  if (!v.IsHolding<VtVec3fArray>() || i >= v.GetArraySize()) return false;
  m.SetScale(GfVec3d(v.UncheckedGet<VtVec3fArray>()[i]));
  return true;
}

bool rotateAt(VtValue const& v, size_t i, GfMatrix4d& m) {
  if (i >= v.GetArraySize()) return false;
  GfQuatd q;
  if (v.IsHolding<VtQuathArray>()) q = GfQuatd(v.UncheckedGet<VtQuathArray>()[i]);
  else if (v.IsHolding<VtQuatfArray>()) q = GfQuatd(v.UncheckedGet<VtQuatfArray>()[i]);
  else if (v.IsHolding<VtVec4fArray>()) {  // (w, x, y, z)
    GfVec4f c = v.UncheckedGet<VtVec4fArray>()[i];
    q = GfQuatd(c[0], c[1], c[2], c[3]);
  } else {
    return false;
  }
  m.SetRotate(q);
  return true;
}

bool transformAt(VtValue const& v, size_t i, GfMatrix4d& m) {
  if (!v.IsHolding<VtMatrix4dArray>() || i >= v.GetArraySize()) return false;
  m = v.UncheckedGet<VtMatrix4dArray>()[i];
  return true;
}

// A VtVec3fArray primvar's numbers, 3 per instance; empty for any other value.
std::vector<float> vectors(VtValue const& v) {
  std::vector<float> out;
  if (!v.IsHolding<VtVec3fArray>()) return out;
  VtVec3fArray const& a = v.UncheckedGet<VtVec3fArray>();
  out.reserve(3 * a.size());
  for (GfVec3f const& x : a) out.insert(out.end(), {x[0], x[1], x[2]});
  return out;
}

// Orientations (quath, quatf, or float4 as w, x, y, z) as (w, x, y, z) numbers.
std::vector<float> quaternions(VtValue const& v) {
  std::vector<float> out;
  auto add = [&out](auto const& array) {
    out.reserve(4 * array.size());
    for (auto const& q : array) {
      auto const& i = q.GetImaginary();
      out.insert(out.end(), {float(q.GetReal()), float(i[0]), float(i[1]), float(i[2])});
    }
  };
  if (v.IsHolding<VtQuathArray>()) add(v.UncheckedGet<VtQuathArray>());
  else if (v.IsHolding<VtQuatfArray>()) add(v.UncheckedGet<VtQuatfArray>());
  else if (v.IsHolding<VtVec4fArray>())
    for (GfVec4f const& c : v.UncheckedGet<VtVec4fArray>()) out.insert(out.end(), {c[0], c[1], c[2], c[3]});
  return out;
}

// An integer array attribute as int64 numbers; empty for any other value.
std::vector<int64_t> integers(VtValue const& v) {
  if (v.IsHolding<VtIntArray>()) return {v.UncheckedGet<VtIntArray>().begin(), v.UncheckedGet<VtIntArray>().end()};
  if (v.IsHolding<VtInt64Array>())
    return {v.UncheckedGet<VtInt64Array>().begin(), v.UncheckedGet<VtInt64Array>().end()};
  return {};
}

// Nested instancing, in ComputeInstanceTransforms' order: outer instances, each with all
// of ours; element (a, b) is combine(ours[b], a).
template <class Out, class Ours, class Combine>
Out nested(Ours const& ours, size_t outer, Combine combine) {
  Out all(outer * ours.size());
  for (size_t a = 0; a < outer; ++a)
    for (size_t b = 0; b < ours.size(); ++b) all[a * ours.size() + b] = combine(ours[b], a);
  return all;
}

}  // namespace

HdGranularInstancer::HdGranularInstancer(HdSceneDelegate* delegate, SdfPath const& id) : HdInstancer(delegate, id) {}

void HdGranularInstancer::Sync(HdSceneDelegate* delegate, HdRenderParam* renderParam, HdDirtyBits* dirtyBits) {
  _UpdateInstancer(delegate, dirtyBits);
  std::lock_guard<std::mutex> lock(_mutex);
  if (HdChangeTracker::IsAnyPrimvarDirty(*dirtyBits, GetId())) {
    _primvars.clear();
    for (HdPrimvarDescriptor const& pv : delegate->GetPrimvarDescriptors(GetId(), HdInterpolationInstance))
      _primvars[pv.name] = delegate->Get(GetId(), pv.name);
  }
  // What explicit grains are read from (core decides whether they are grains), on any edit.
  auto get = [&](TfToken const& t) {
    auto it = _primvars.find(t);
    return it == _primvars.end() ? VtValue() : it->second;
  };
  HdGranularRenderParam::Instancer r;
  r.parentId = GetParentId();
  r.xf = HdGranularToCore(delegate->GetInstancerTransform(GetId()));
  r.positions = vectors(get(HdInstancerTokens->instanceTranslations));
  r.orientations = quaternions(get(HdInstancerTokens->instanceRotations));
  r.scales = vectors(get(HdInstancerTokens->instanceScales));
  r.velocities = vectors(get(HdTokens->velocities));
  r.angularVelocities = vectors(get(HdTokens->angularVelocities));
  r.transforms = !get(HdInstancerTokens->instanceTransforms).IsEmpty();
  r.protoIndices = integers(delegate->Get(GetId(), TfToken("protoIndices")));
  for (TfToken const& c : delegate->GetCategories(GetId())) r.categories.push_back(c.GetString());
  static_cast<HdGranularRenderParam*>(renderParam)->SetInstancer(GetId(), std::move(r));
}

void HdGranularInstancer::Finalize(HdRenderParam* renderParam) {
  static_cast<HdGranularRenderParam*>(renderParam)->Remove(GetId());
}

VtMatrix4dArray HdGranularInstancer::ComputeInstanceTransforms(SdfPath const& prototypeId) {
  HdSceneDelegate* d = GetDelegate();
  const GfMatrix4d instancer = d->GetInstancerTransform(GetId());
  const VtIntArray indices = d->GetInstanceIndices(GetId(), prototypeId);
  VtMatrix4dArray out(indices.size());
  std::lock_guard<std::mutex> lock(_mutex);
  auto get = [&](TfToken const& t) {
    auto it = _primvars.find(t);
    return it == _primvars.end() ? VtValue() : it->second;
  };
  const VtValue tr = get(HdInstancerTokens->instanceTranslations), ro = get(HdInstancerTokens->instanceRotations),
                sc = get(HdInstancerTokens->instanceScales), xf = get(HdInstancerTokens->instanceTransforms);
  for (size_t k = 0; k < indices.size(); ++k) {
    const size_t i = size_t(indices[k]);
    GfMatrix4d m = instancer, t(1.0);
    if (translateAt(tr, i, t)) m = t * m;
    t.SetIdentity();
    if (rotateAt(ro, i, t)) m = t * m;
    t.SetIdentity();
    if (scaleAt(sc, i, t)) m = t * m;
    t.SetIdentity();
    if (transformAt(xf, i, t)) m = t * m;
    out[k] = m;
  }
  HdGranularInstancer* parent = _Parent();
  if (!parent) return out;
  const VtMatrix4dArray outer = parent->ComputeInstanceTransforms(GetId());
  return nested<VtMatrix4dArray>(out, outer.size(), [&](GfMatrix4d const& m, size_t a) { return m * outer[a]; });
}

VtIntArray HdGranularInstancer::ComputeInstanceIndices(SdfPath const& prototypeId) {
  HdSceneDelegate* d = GetDelegate();
  const VtIntArray indices = d->GetInstanceIndices(GetId(), prototypeId);
  HdGranularInstancer* parent = _Parent();
  if (!parent) return indices;
  return nested<VtIntArray>(indices, parent->ComputeInstanceIndices(GetId()).size(), [](int i, size_t) { return i; });
}

std::vector<std::vector<std::string>> HdGranularInstancer::ComputeInstanceCategories(SdfPath const& prototypeId) {
  HdSceneDelegate* d = GetDelegate();
  const VtIntArray indices = d->GetInstanceIndices(GetId(), prototypeId);
  const std::vector<VtArray<TfToken>> own = d->GetInstanceCategories(GetId());
  bool any = false;
  std::vector<std::vector<std::string>> out(indices.size());
  for (size_t k = 0; k < indices.size(); ++k) {
    const size_t i = size_t(indices[k]);
    if (i >= own.size()) continue;
    for (TfToken const& t : own[i]) out[k].push_back(t.GetString());
    any = any || !own[i].empty();
  }
  HdGranularInstancer* parent = _Parent();
  if (!parent) return any ? out : std::vector<std::vector<std::string>>();
  std::vector<std::vector<std::string>> outer = parent->ComputeInstanceCategories(GetId());
  if (outer.empty() && !any) return {};
  if (outer.empty()) outer.resize(parent->ComputeInstanceIndices(GetId()).size());
  return nested<std::vector<std::vector<std::string>>>(out, outer.size(), [&](std::vector<std::string> c, size_t a) {
    c.insert(c.end(), outer[a].begin(), outer[a].end());
    return c;
  });
}

HdGranularInstancer* HdGranularInstancer::_Parent() {
  if (GetParentId().IsEmpty()) return nullptr;
  return static_cast<HdGranularInstancer*>(GetDelegate()->GetRenderIndex().GetInstancer(GetParentId()));
}

PXR_NAMESPACE_CLOSE_SCOPE
