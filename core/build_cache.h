// build_cache.h — the on-disk cache of aggregate builds, beside the tiles and TT
// parameters (cache.h): what Aggregate::build computes from the boundary (cell classes,
// the distance field, the deep cells' depth, counts), and the tile's sub-cell lists.
//
// Contract: an entry is named build-v<version>-<key>.bin in cacheDirectory(), key =
// buildKey() of everything those products depend on. It starts with a header (magic,
// format version, key, payload length and checksum, the header's own checksum);
// loadBuild() maps the file and trusts it only when every check passes and the payload
// parses to its exact length into products that fit the grid the caller computed itself.
// Anything else — truncated, a byte flipped, another version or key — gives exactly one
// warning on stderr and a miss; the caller rebuilds and storeBuild() replaces the entry.
// storeBuild() writes a unique temporary file in the cache folder and renames it into
// place: concurrent writers of one key both succeed, readers never see half an entry.
// Then the least recently used build entries (by modification time; a hit touches its
// entry) are removed while all of them together exceed buildCacheLimitBytes().
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "aggregate.h"
#include "distance_field.h"
#include "math.h"
#include "mesh.h"
#include "packing.h"
#include "scene_desc.h"

namespace granular {

constexpr uint32_t kBuildFormatVersion = 3;  // 2: the distance field's anchor; 3: fields of a quarter tile

struct BuildProducts {
  // The grid the products belong to: the loading build computes these itself and takes
  // the entry only when they agree (a guard against a colliding key).
  int64_t cells[3] = {0, 0, 0};
  Vec3 origin;
  float cellSize = 0, voxelSize = 0, bandWidth = 0;
  Vec3d anchor;  // the distance field's (DistanceField::anchor())

  std::vector<CellClass> classes;  // cells[0] * cells[1] * cells[2], x fastest
  int64_t insideCells = 0, partialCells = 0;
  double approxGrains = 0;
  float maxInteriorDepth = 0;
  int32_t sub = 1;                    // sub-cells per cell edge
  std::vector<uint32_t> subStart;     // sub^3 + 1 offsets into subList (CSR)
  std::vector<uint32_t> subList;      // sphere indices (Aggregate's tile spheres and images)
  DistanceField sdf;
};

// Everything build() reads that the products depend on: the world-space boundary as
// build() voxelises it (points and triangles after the transform and any flip), the
// boundary's own points and its transform (an anchored field is voxelised before the
// translation), the aggregate's grain radius, sizes, spread, weights, packing rate, seed
// and tile size, the tile itself, the format version and the OpenVDB and Embree versions.
// Not the name, the prototypes' meshes or materials: build() derives nothing cached from
// them.
uint64_t buildKey(const AggregateDesc& desc, const TriangleMesh& worldBoundary, const Tile& tile);
std::string buildCacheName(uint64_t key);

// $GRANULAR_CACHE_MAX_MB mebibytes (default 4096); 0 turns the build cache off.
uint64_t buildCacheLimitBytes();

// The entry of `key` into `out`, whose cells, origin, cellSize, voxelSize and bandWidth
// the caller has set to its own values; sphereCount bounds subList. False on a miss
// (absent, damaged — with its warning —, cache off or no cache folder).
bool loadBuild(uint64_t key, size_t sphereCount, BuildProducts& out);
// Writes the entry of `key`; false (no exception, nothing left behind) when it cannot.
bool storeBuild(uint64_t key, const BuildProducts& products);

}  // namespace granular
