// density_export.h — an aggregate's coarse density as an OpenVDB volume, and reading
// such a volume back.
//
// Contract: writeDensityVdb() voxelises a closed world-space boundary mesh into a float
// grid (default name "density", class fog volume, world-space linear transform of the
// given voxel size, voxel centres at integer multiples of it) whose active voxels are
// exactly those whose centre lies inside the boundary, each holding sigmaT; everything
// else is the background 0. sigmaT is a parameter (the caller derives it, e.g. from the
// teleportation-transport model), so the export does not depend on how it was obtained.
// The grid carries the given metadata. The file is written through an OutputFile (output_file.h),
// so a failure never leaves a partial file at <path>. Bad input (an open mesh, a
// non-finite or negative sigmaT, a voxel size too small for the boundary) throws
// InputError naming `object`; I/O failures throw std::runtime_error naming the path.
//
// writeGrainDensityVdb() writes explicit grains' packing rate (grain_density.h) the same
// way: a float fog volume "density" holding f (grain volume per volume, dimensionless) at
// the density's voxels, with voxel size Δ and voxel centres at integer multiples of it
// (world space), active where some grain's kernel reaches; and, where several prototypes
// mix, one float grid "fraction.<k>" per prototype k (its number fraction; metadata
// "granular:prototype" names it). Metadata granular:kernelWidth, granular:meanRadius,
// granular:grains and the options' own.
//
// readVdbGrids()/sampleVdbGrid() read any .vdb file back (for tests and tools): the
// grids' names, types, voxel sizes, active-voxel counts and metadata, and a float grid's
// values at world points (nearest voxel). They throw InputError(path, grid, ...) when
// the file or grid cannot be read.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "math.h"
#include "mesh.h"

namespace granular {

struct DensityExportOptions {
  float voxelSize = 0;                         // world units; <= 0: largest extent / defaultVoxelsAcross
  int defaultVoxelsAcross = 128;
  int maxVoxelsAcross = 4096;                  // along any axis; beyond it the voxel size is rejected
  std::string gridName = "density";
  std::map<std::string, float> floatMetadata;  // e.g. "granular:packingRate"
  std::map<std::string, Vec3> vec3Metadata;    // e.g. "granular:sigmaT" (per channel)
  std::map<std::string, std::string> stringMetadata;
};

struct DensityExportResult {
  float voxelSize = 0;
  int64_t activeVoxels = 0;   // voxels holding sigmaT (tiles counted by their voxels)
  Bounds3 worldBounds;        // of the active voxels' centres
  bool replacedOther = false; // a claimed output another process wrote meanwhile (output_file.h)
};

// worldBoundary: closed, in world space. Throws InputError(object, ...) or runtime_error.
DensityExportResult writeDensityVdb(const std::string& path, const TriangleMesh& worldBoundary, float sigmaT,
                                    const DensityExportOptions& options, const std::string& object);

struct GrainDensity;
DensityExportResult writeGrainDensityVdb(const std::string& path, const GrainDensity& density,
                                         const DensityExportOptions& options, const std::string& object);

struct VdbGridInfo {
  std::string name;
  std::string valueType;      // "float", "vec3s", ...
  std::string gridClass;      // "fog volume", "level set", ...
  Vec3 voxelSize;
  int64_t activeVoxels = 0;
  std::map<std::string, std::string> metadata;  // every metadata item, as text
};

std::vector<VdbGridInfo> readVdbGrids(const std::string& path);

// Values of the float grid `gridName` at world-space points, nearest voxel.
std::vector<float> sampleVdbGrid(const std::string& path, const std::string& gridName,
                                 const std::vector<Vec3>& worldPoints);

}  // namespace granular
