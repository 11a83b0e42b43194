#include "renderParam.h"

#include "renderer.h"

PXR_NAMESPACE_OPEN_SCOPE

void HdGranularRenderParam::SetMesh(SdfPath const& id, Mesh mesh) {
  std::lock_guard<std::mutex> lock(_mutex);
  _meshes[id] = std::move(mesh);
  ++_version;
}

void HdGranularRenderParam::SetLight(SdfPath const& id, granular::LightDesc light) {
  std::lock_guard<std::mutex> lock(_mutex);
  _lights[id] = std::move(light);
  ++_version;
}

void HdGranularRenderParam::SetMaterial(SdfPath const& id, granular::MaterialDesc material, std::string st) {
  std::lock_guard<std::mutex> lock(_mutex);
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
  if (_meshes.erase(id) + _lights.erase(id) + _materials.erase(id)) ++_version;
}

granular::SceneDesc HdGranularRenderParam::Assemble() const {
  std::lock_guard<std::mutex> lock(_mutex);
  granular::SceneDesc desc;
  // Bound materials first (one entry each), then display colours as Lambert albedo.
  std::map<SdfPath, int> materialIndex;
  for (auto const& [path, m] : _materials) {
    materialIndex[path] = int(desc.materials.size());
    desc.materials.push_back(m);
  }
  std::vector<granular::MeshPrim> prims;
  prims.reserve(_meshes.size());
  for (auto const& [path, m] : _meshes) {
    granular::MeshPrim p = m.prim;
    auto it = materialIndex.find(m.materialId);
    if (it != materialIndex.end()) {
      p.material = it->second;
      auto st = _materialSt.find(m.materialId);
      if (st != _materialSt.end() && !st->second.empty()) {
        auto uv = m.uvSets.find(st->second);
        if (uv != m.uvSets.end()) p.mesh.uvs = uv->second;
        else TF_WARN("%s: has no primvars:%s for its material's textures; they read st (0, 0) everywhere",
                     path.GetText(), st->second.c_str());
      }
    } else if (m.hasDisplayColor)  // core makes it Lambert, for ordinary meshes only
      p.displayColor = granular::Vec3(m.displayColor[0], m.displayColor[1], m.displayColor[2]);
    prims.push_back(std::move(p));
  }
  granular::assembleGranularScene(prims, desc);
  for (auto const& [path, l] : _lights) desc.lights.push_back(l);
  return desc;
}

PXR_NAMESPACE_CLOSE_SCOPE
