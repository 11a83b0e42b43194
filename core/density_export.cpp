// density_export.cpp — coarse density export through OpenVDB (contract in the header).
//
// The boundary is turned into a narrow-band level set (mesh-to-level-set, whose sign is
// right throughout, interior tiles included), its interior (d <= 0 at voxel centres) into
// a mask, and the mask's topology into a float grid whose every active value, voxel or
// tile, is sigmaT.
#include "density_export.h"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <mutex>

#include <openvdb/openvdb.h>
#include <openvdb/io/File.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <openvdb/tools/MeshToVolume.h>

#include "error.h"
#include "grain_density.h"
#include "output_file.h"

namespace granular {

namespace {

void initVdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

std::string className(openvdb::GridClass c) {
  switch (c) {
    case openvdb::GRID_LEVEL_SET: return "level set";
    case openvdb::GRID_FOG_VOLUME: return "fog volume";
    case openvdb::GRID_STAGGERED: return "staggered";
    default: return "unknown";
  }
}

openvdb::GridPtrVecPtr readAll(const std::string& path) {
  initVdb();
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw InputError(path, "", "does not exist");
  try {
    openvdb::io::File file(path);
    file.open();
    openvdb::GridPtrVecPtr grids = file.getGrids();
    file.close();
    return grids;
  } catch (const openvdb::Exception& e) {
    throw InputError(path, "", str("cannot read the VDB file: ", e.what()));
  }
}

// Writes the grids through an OutputFile (output_file.h; OpenVDB writes by name, so by the
// temporary's); the result describes `main`, the grid of the density.
DensityExportResult writeGrids(const std::string& path, const openvdb::GridPtrVec& grids, const openvdb::FloatGrid& main,
                               const openvdb::math::Transform& xform, float voxel) {
  DensityExportResult result;
  result.voxelSize = voxel;
  result.activeVoxels = int64_t(main.activeVoxelCount());
  openvdb::CoordBBox bbox = main.evalActiveVoxelBoundingBox();
  if (!bbox.empty()) {
    openvdb::Vec3d lo = xform.indexToWorld(bbox.min()), hi = xform.indexToWorld(bbox.max());
    result.worldBounds.extend(Vec3(float(lo.x()), float(lo.y()), float(lo.z())));
    result.worldBounds.extend(Vec3(float(hi.x()), float(hi.y()), float(hi.z())));
  }
  OutputFile out(path);
  out.close();
  try {
    openvdb::io::File file(out.temporaryPath());
    file.write(grids);
    file.close();
  } catch (const openvdb::Exception& e) {
    throw std::runtime_error(str("cannot write \"", path, "\": ", e.what()));
  }
  result.replacedOther = out.commit();
  return result;
}

}  // namespace

DensityExportResult writeDensityVdb(const std::string& path, const TriangleMesh& worldBoundary, float sigmaT,
                                    const DensityExportOptions& options, const std::string& object) {
  initVdb();
  validateClosed(worldBoundary, object);
  if (!std::isfinite(sigmaT) || sigmaT < 0)
    throw InputError(object, "sigmaT", str(sigmaT, " must be finite and >= 0"));
  if (options.gridName.empty()) throw InputError(object, "gridName", "is empty");
  if (options.defaultVoxelsAcross < 1 || options.maxVoxelsAcross < 1)
    throw InputError(object, "voxelSize", "voxel counts must be >= 1");

  const Bounds3 mb = worldBoundary.bounds();
  const float extent = maxComponent(mb.extent());
  float voxel = options.voxelSize;
  if (!(voxel > 0)) {
    if (std::isnan(voxel)) throw InputError(object, "voxelSize", "is not a number");
    voxel = extent / float(options.defaultVoxelsAcross);
  }
  if (!std::isfinite(voxel) || !(voxel > 0)) throw InputError(object, "voxelSize", str(voxel, " must be finite and > 0"));
  const double across = double(extent) / voxel;
  if (across > options.maxVoxelsAcross)
    throw InputError(object, "voxelSize",
                     str(voxel, " is too small for the boundary's extent ", extent, ": ", std::ceil(across),
                         " voxels across exceed the limit of ", options.maxVoxelsAcross));

  // The grid is in world space (the file's contract), and OpenVDB refuses linear
  // transforms whose determinant is ~0: voxels below about 1e-5 world units (a scene in
  // tiny units; bench/stress.py). Say so instead of letting ArithmeticError escape.
  openvdb::math::Transform::Ptr xform;
  try {
    xform = openvdb::math::Transform::createLinearTransform(voxel);
  } catch (const openvdb::Exception&) {
    throw InputError(object, "voxelSize",
                     str(voxel, " is below the smallest voxel of an OpenVDB world-space grid (about 1e-5 "
                                "scene units): scale the scene up"));
  }
  std::vector<openvdb::Vec3s> pts;
  pts.reserve(worldBoundary.points.size());
  for (const Vec3& p : worldBoundary.points) pts.emplace_back(p.x, p.y, p.z);
  std::vector<openvdb::Vec3I> tris;
  tris.reserve(worldBoundary.numTriangles());
  for (size_t i = 0; i < worldBoundary.numTriangles(); ++i)
    tris.emplace_back(worldBoundary.indices[3 * i], worldBoundary.indices[3 * i + 1], worldBoundary.indices[3 * i + 2]);

  openvdb::FloatGrid::Ptr sdf = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*xform, pts, tris, 3.0f);
  openvdb::BoolGrid::Ptr interior = openvdb::tools::sdfInteriorMask(*sdf, 0.0f);

  openvdb::FloatGrid::Ptr density = openvdb::FloatGrid::create(0.0f);
  density->setTransform(xform->copy());
  density->tree().topologyUnion(interior->tree());
  for (auto it = density->beginValueOn(); it; ++it) it.setValue(sigmaT);
  density->setName(options.gridName);
  density->setGridClass(openvdb::GRID_FOG_VOLUME);
  density->setSaveFloatAsHalf(false);
  density->insertMeta("granular:object", openvdb::StringMetadata(object));
  for (const auto& kv : options.floatMetadata) density->insertMeta(kv.first, openvdb::FloatMetadata(kv.second));
  for (const auto& kv : options.vec3Metadata)
    density->insertMeta(kv.first, openvdb::Vec3SMetadata(openvdb::Vec3s(kv.second.x, kv.second.y, kv.second.z)));
  for (const auto& kv : options.stringMetadata) density->insertMeta(kv.first, openvdb::StringMetadata(kv.second));

  return writeGrids(path, {density}, *density, *xform, voxel);
}

namespace {

// A float fog volume of the leaves' values (OpenVDB's leaf layout is theirs), active where > 0.
openvdb::FloatGrid::Ptr leavesToGrid(const VoxelLeaves& leaves, const VoxelLeaves& activeBy, const std::string& name,
                                     const openvdb::math::Transform& xform) {
  using Leaf = openvdb::FloatGrid::TreeType::LeafNodeType;
  openvdb::FloatGrid::Ptr grid = openvdb::FloatGrid::create(0.0f);
  grid->setTransform(xform.copy());
  for (size_t l = 0; l < leaves.origins.size(); ++l) {
    const auto& o = leaves.origins[l];
    auto* leaf = new Leaf(openvdb::Coord(o[0], o[1], o[2]), 0.0f, false);
    const float* v = leaves.values.data() + l * VoxelLeaves::kLeafVoxels;
    const float* a = activeBy.values.data() + l * VoxelLeaves::kLeafVoxels;
    for (openvdb::Index i = 0; i < Leaf::SIZE; ++i)
      if (a[i] > 0) leaf->setValueOn(i, v[i]);
    grid->tree().addLeaf(leaf);
  }
  grid->setName(name);
  grid->setGridClass(openvdb::GRID_FOG_VOLUME);
  grid->setSaveFloatAsHalf(false);
  return grid;
}

}  // namespace

DensityExportResult writeGrainDensityVdb(const std::string& path, const GrainDensity& density,
                                         const DensityExportOptions& options, const std::string& object) {
  initVdb();
  if (options.gridName.empty()) throw InputError(object, "gridName", "is empty");
  const float voxel = density.packing.voxelSize;
  openvdb::math::Transform::Ptr xform;
  try {
    xform = openvdb::math::Transform::createLinearTransform(voxel);
  } catch (const openvdb::Exception&) {
    throw InputError(object, "voxelSize",
                     str(voxel, " is below the smallest voxel of an OpenVDB world-space grid (about 1e-5 "
                                "scene units): scale the scene up"));
  }
  openvdb::GridPtrVec grids;
  openvdb::FloatGrid::Ptr f = leavesToGrid(density.packing, density.packing, options.gridName, *xform);
  f->insertMeta("granular:object", openvdb::StringMetadata(object));
  f->insertMeta("granular:kernelWidth", openvdb::FloatMetadata(density.kernelWidth));
  f->insertMeta("granular:meanRadius", openvdb::FloatMetadata(density.stats.meanRadius));
  f->insertMeta("granular:grains", openvdb::Int64Metadata(density.stats.grains));
  for (const auto& kv : options.floatMetadata) f->insertMeta(kv.first, openvdb::FloatMetadata(kv.second));
  for (const auto& kv : options.vec3Metadata)
    f->insertMeta(kv.first, openvdb::Vec3SMetadata(openvdb::Vec3s(kv.second.x, kv.second.y, kv.second.z)));
  for (const auto& kv : options.stringMetadata) f->insertMeta(kv.first, openvdb::StringMetadata(kv.second));
  grids.push_back(f);
  for (size_t k = 0; k < density.fractions.size(); ++k) {
    openvdb::FloatGrid::Ptr g = leavesToGrid(density.fractions[k], density.packing, str("fraction.", k), *xform);
    g->insertMeta("granular:object", openvdb::StringMetadata(object));
    if (k < density.prototypeNames.size())
      g->insertMeta("granular:prototype", openvdb::StringMetadata(density.prototypeNames[k]));
    grids.push_back(g);
  }

  return writeGrids(path, grids, *f, *xform, voxel);
}

std::vector<VdbGridInfo> readVdbGrids(const std::string& path) {
  std::vector<VdbGridInfo> infos;
  const openvdb::GridPtrVecPtr grids = readAll(path);  // kept alive across the loop
  for (const openvdb::GridBase::Ptr& g : *grids) {
    VdbGridInfo info;
    info.name = g->getName();
    info.valueType = g->valueType();
    info.gridClass = className(g->getGridClass());
    openvdb::Vec3d v = g->voxelSize();
    info.voxelSize = Vec3(float(v.x()), float(v.y()), float(v.z()));
    info.activeVoxels = int64_t(g->activeVoxelCount());
    for (auto it = g->beginMeta(); it != g->endMeta(); ++it) info.metadata[it->first] = it->second->str();
    infos.push_back(std::move(info));
  }
  return infos;
}

std::vector<float> sampleVdbGrid(const std::string& path, const std::string& gridName,
                                 const std::vector<Vec3>& worldPoints) {
  openvdb::FloatGrid::Ptr grid;
  std::vector<std::string> names;
  const openvdb::GridPtrVecPtr grids = readAll(path);
  for (const openvdb::GridBase::Ptr& g : *grids) {
    names.push_back(g->getName());
    if (g->getName() == gridName) {
      grid = openvdb::gridPtrCast<openvdb::FloatGrid>(g);
      if (!grid) throw InputError(path, gridName, str("is a ", g->valueType(), " grid, not a float grid"));
      break;
    }
  }
  if (!grid) {
    std::string list;
    for (const std::string& n : names) list += (list.empty() ? "" : ", ") + n;
    throw InputError(path, gridName, str("no such grid (the file has: ", list.empty() ? "none" : list, ")"));
  }
  // The sampler keeps a reference to the accessor: it must be a named local that outlives
  // it, not a temporary (ASan: stack-use-after-scope, as distance_field.cpp once had).
  openvdb::FloatGrid::ConstAccessor accessor = grid->getConstAccessor();
  openvdb::tools::GridSampler<openvdb::FloatGrid::ConstAccessor, openvdb::tools::PointSampler> sampler(
      accessor, grid->transform());
  std::vector<float> values;
  values.reserve(worldPoints.size());
  for (const Vec3& p : worldPoints) values.push_back(sampler.wsSample(openvdb::Vec3d(p.x, p.y, p.z)));
  return values;
}

}  // namespace granular
