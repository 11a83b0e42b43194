#include "renderParam.h"

#include "core/usd_lights.h"
#include "renderer.h"

PXR_NAMESPACE_OPEN_SCOPE

void HdGranularRenderParam::SetMesh(SdfPath const& id, Mesh mesh) {
  std::lock_guard<std::mutex> lock(_mutex);
  _errors.erase(id);
  _meshes[id] = std::move(mesh);
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
  if (_meshes.erase(id) + _lights.erase(id) + _materials.erase(id) + _errors.erase(id)) ++_version;
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
  granular::assembleGranularScene(prims, desc);
  for (auto const& [path, l] : _lights) desc.lights.push_back(l);
  granular::orderUsdLights(desc.lights);  // as granular render orders them
  return desc;
}

PXR_NAMESPACE_CLOSE_SCOPE
