#include "renderParam.h"

#include "core/usd_lights.h"
#include "light.h"
#include "pxr/imaging/hd/renderIndex.h"
#include "renderer.h"

PXR_NAMESPACE_OPEN_SCOPE

void HdGranularRenderParam::SetMesh(SdfPath const& id, Mesh mesh) {
  std::lock_guard<std::mutex> lock(_mutex);
  _errors.erase(id);
  _meshes[id] = std::move(mesh);
  ++_version;
}

void HdGranularRenderParam::SetInstancer(SdfPath const& id, Instancer instancer) {
  std::lock_guard<std::mutex> lock(_mutex);
  _instancers[id] = std::move(instancer);
  ++_version;
}

void HdGranularRenderParam::SetLight(SdfPath const& id, granular::LightDesc light) {
  std::lock_guard<std::mutex> lock(_mutex);
  _errors.erase(id);
  _lights[id] = std::move(light);
  ++_version;
}

void HdGranularRenderParam::SetMaterial(SdfPath const& id, std::optional<granular::MaterialDesc> material,
                                        std::string st) {
  std::lock_guard<std::mutex> lock(_mutex);
  _errors.erase(id);
  _materials[id] = std::move(material);
  _materialSt[id] = std::move(st);
  ++_version;
}

void HdGranularRenderParam::StopRenderForEdit() {
  if (_renderer) _renderer->StopForEdit();
}

void HdGranularRenderParam::Remove(SdfPath const& id) {
  std::lock_guard<std::mutex> lock(_mutex);
  // Only a real removal is a scene edit: hosts re-sync prims we do not keep (usdview's
  // camera light follows the camera), and a rebuild on every camera move would be wrong.
  _materialSt.erase(id);
  if (_meshes.erase(id) + _instancers.erase(id) + _lights.erase(id) + _materials.erase(id) + _errors.erase(id))
    ++_version;
}

void HdGranularRenderParam::SetError(SdfPath const& id, granular::InputError const& error) {
  std::lock_guard<std::mutex> lock(_mutex);
  _meshes.erase(id);
  _lights.erase(id);
  _materials.erase(id);
  _materialSt.erase(id);
  _errors.insert_or_assign(id, error);
  ++_version;
}

void HdGranularRenderParam::RefreshMeshLights(HdRenderIndex& index) {
  std::vector<std::pair<SdfPath, granular::UsdPrimRecord>> lights;
  {
    std::lock_guard<std::mutex> lock(_mutex);
    for (auto const& [id, m] : _meshes)
      if (m.lightRecord) lights.emplace_back(id, *m.lightRecord);
  }
  for (auto const& [id, before] : lights) {
    HdSceneDelegate* delegate = index.GetSceneDelegateForRprim(id);
    if (!delegate) continue;
    granular::UsdPrimRecord now = HdGranularLightRecord(delegate, id, before.typeName);
    if (now.attributes == before.attributes) continue;
    std::optional<granular::LightDesc> light;
    std::optional<granular::InputError> error;
    granular::UsdWarnings warnings;
    try {
      light = granular::lightFromUsd(now, warnings);
    } catch (granular::InputError const& e) {
      error = e;
    }
    Warn(warnings);
    std::lock_guard<std::mutex> lock(_mutex);
    auto m = _meshes.find(id);
    if (m == _meshes.end()) continue;
    m->second.lightRecord = std::move(now);
    if (error) {
      _errors.insert_or_assign(id, *error);
    } else {
      m->second.prim.light = std::move(light);
      _errors.erase(id);
    }
    ++_version;
  }
}

void HdGranularRenderParam::Warn(granular::UsdWarnings const& warnings) {
  std::lock_guard<std::mutex> lock(_mutex);
  for (std::string const& w : warnings)
    if (_warned.insert(w).second) {
      _warnings.push_back(w);
      TF_WARN("hdGranular: %s", w.c_str());
    }
}

std::vector<std::string> HdGranularRenderParam::Warnings() const {
  std::lock_guard<std::mutex> lock(_mutex);
  return _warnings;
}

void HdGranularRenderParam::SetRenderError(std::string error) {
  std::lock_guard<std::mutex> lock(_mutex);
  _renderError = std::move(error);
}

std::string HdGranularRenderParam::RenderError() const {
  std::lock_guard<std::mutex> lock(_mutex);
  return _renderError;
}

std::map<SdfPath, std::vector<size_t>> HdGranularRenderParam::_GrainInstancers(
    std::vector<granular::MeshPrim> const& prims) const {
  std::map<SdfPath, std::vector<size_t>> out;
  if (_instancers.empty()) return out;
  std::map<SdfPath, std::vector<size_t>> meshesOf;  // instancer -> its prototype meshes
  size_t i = 0;
  for (auto const& [path, m] : _meshes) {  // prims holds _meshes in this order
    if (!m.instancerId.IsEmpty()) meshesOf[m.instancerId].push_back(i);
    ++i;
  }
  std::set<SdfPath> outer;  // instancers that instance an instancer
  for (auto const& [id, inst] : _instancers)
    if (!inst.parentId.IsEmpty()) outer.insert(inst.parentId);
  for (auto const& [id, inst] : _instancers) {
    auto it = meshesOf.find(id);
    if (it == meshesOf.end() || !inst.parentId.IsEmpty() || outer.count(id) || inst.transforms) continue;
    std::vector<granular::MeshPrim> seen;  // what decides: their granular primvars
    for (size_t k : it->second) {
      granular::MeshPrim p;
      p.path = prims[k].path;
      p.granular = prims[k].granular;
      seen.push_back(std::move(p));
    }
    if (granular::isExplicitGrainInstancer(std::nullopt, seen)) out.emplace(id, it->second);
  }
  return out;
}

granular::InstancedGrainsDesc HdGranularRenderParam::_ReadGrains(SdfPath const& id,
                                                                 std::vector<size_t> const& prototypes,
                                                                 std::vector<granular::MeshPrim> const& prims,
                                                                 granular::SceneDesc& desc) const {
  Instancer const& inst = _instancers.at(id);
  granular::InstancerPrim prim;
  prim.path = id.GetString();
  prim.xf = inst.xf;
  prim.positions = inst.positions;
  prim.orientations = inst.orientations;
  prim.scales = inst.scales;
  prim.velocities = inst.velocities;
  prim.angularVelocities = inst.angularVelocities;
  prim.linkCategories = inst.categories;
  // The primId and aggregateId AOVs' id: an instancer is no rprim; its first prototype's
  // id and a grain's instanceId are what a Hydra host resolves an instance pick from.
  prim.id = prims[prototypes.front()].id;
  std::vector<std::vector<int64_t>> instancesOf;
  for (size_t k : prototypes) {
    prim.prototypes.push_back(prims[k].path);
    prim.prototypeXforms.push_back(_meshes.at(SdfPath(prims[k].path)).local);
    instancesOf.emplace_back(prims[k].instanceIds.begin(), prims[k].instanceIds.end());
  }
  auto lookup = [&](std::string const& path, granular::MeshPrim& found) {
    for (size_t k : prototypes)
      if (prims[k].path == path) {
        found = prims[k];
        return true;
      }
    return false;
  };
  return granular::instancedGrainsFromPrototypeInstances(std::move(prim), instancesOf, inst.protoIndices, desc,
                                                         lookup);
}

granular::SceneDesc HdGranularRenderParam::Assemble() const {
  std::lock_guard<std::mutex> lock(_mutex);
  if (!_errors.empty()) throw _errors.begin()->second;
  granular::SceneDesc desc;
  // Bound materials first (one entry each; -1 for those without a supported surface),
  // then display colours as Lambert albedo.
  std::map<SdfPath, int> materialIndex;
  for (auto const& [path, m] : _materials) {
    if (!m) {
      materialIndex[path] = -1;
      continue;
    }
    materialIndex[path] = int(desc.materials.size());
    desc.materials.push_back(*m);
  }
  std::vector<granular::MeshPrim> prims;
  prims.reserve(_meshes.size());
  for (auto const& [path, m] : _meshes) {
    granular::MeshPrim p = m.prim;
    auto it = materialIndex.find(m.materialId);
    if (it != materialIndex.end()) {
      p.material = it->second;
      p.displayColor.reset();  // a bound material decides, even the default one
      auto st = _materialSt.find(m.materialId);
      if (st != _materialSt.end() && !st->second.empty()) {
        auto uv = m.uvSets.find(st->second);
        if (uv != m.uvSets.end())
          p.mesh.uvs = granular::usdPrimvarAtCorners(m.topology, uv->second, 2, "primvars:" + st->second);
        else {
          const std::string w = path.GetString() + ": has no primvars:" + st->second +
                                " for its material's textures; they read st (0, 0) everywhere";
          if (_warned.insert(w).second) {
            _warnings.push_back(w);
            TF_WARN("hdGranular: %s", w.c_str());
          }
        }
      }
    }
    prims.push_back(std::move(p));
  }
  // Explicit grains' prototypes are not meshes of the scene; the grains come after the
  // meshes, as granular render reads them.
  const std::map<SdfPath, std::vector<size_t>> grains = _GrainInstancers(prims);
  if (grains.empty()) {
    granular::assembleGranularScene(prims, desc);
  } else {
    std::set<size_t> grainPrototypes;
    for (auto const& [id, protos] : grains) grainPrototypes.insert(protos.begin(), protos.end());
    std::vector<granular::MeshPrim> meshes;
    for (size_t i = 0; i < prims.size(); ++i)
      if (!grainPrototypes.count(i)) meshes.push_back(std::move(prims[i]));
    granular::assembleGranularScene(meshes, desc);
    for (auto const& [id, protos] : grains) desc.instancedGrains.push_back(_ReadGrains(id, protos, prims, desc));
  }
  for (auto const& [path, l] : _lights) desc.lights.push_back(l);
  granular::orderUsdLights(desc.lights);  // as granular render orders them
  return desc;
}

PXR_NAMESPACE_CLOSE_SCOPE
