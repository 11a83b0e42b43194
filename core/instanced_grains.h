// instanced_grains.h — explicit grains: every grain given by a simulation (a USD
// PointInstancer: position, orientation, uniform scale, prototype), as Müller et al. 2016
// render them, instead of Meng et al. 2015's tiled packing (aggregate.h).
//
// Contract.
//  - InstancedGrainsDesc is plain data in the instancer's object space. Grain i is prototype
//    protoIndices[i]'s mesh as authored, scaled by scales[i], rotated by orientations[i] and
//    moved to positions[i] (USD's instance transform, without a prototype-root transform);
//    its bounding sphere is the prototype's (makeGrainPrototype's fitCenter, fitRadius: the
//    grain radius at scale 1) under that transform. validateInstancedGrains() names
//    `<name>.<USD attribute>` (positions, orientations, scales, protoIndices, velocities,
//    angularVelocities, prototypes) in every InputError.
//  - InstancedGrains::build() takes the description by value (its arrays, shared with the
//    caller's copies and never copied: shared_array.h, are the only per-grain input kept)
//    and builds a uniform grid over the grains' bounding spheres in
//    object space: cell edge kCellRadii × the largest bounding radius, so a sphere overlaps
//    at most 2 cells per axis (8 in all); each cell lists (CSR, uint32 grain indices, in
//    increasing order) the grains whose bounding spheres overlap it (a moving grain's: the
//    sphere of its sweep over ±motionSpan, InstancedGrainsDesc's velocities and spins;
//    queries place it at the ray's time). Cells are stored per
//    occupied block of 4³ cells, found through an open-addressing hash of the block's
//    coordinates: empty space costs nothing, so sparse and far-flung grains stay cheap.
//    Memory beyond the input arrays: 4 bytes per list entry (at most 8 per grain) plus
//    4 bytes per cell of an occupied block and 12 bytes per hash slot (at most 4 per
//    occupied block); stats().gridBytes counts exactly these. Built in parallel (TBB) in
//    time linear in the grains (the occupied blocks, far fewer, are sorted), deterministic:
//    where the grid's box holds at most max(2^22, grains / 4) blocks (a heap, a slab) they
//    are marked on one bit per block of the box and numbered through a dense table (4 bytes
//    a block) while building, else gathered in a concurrent hash set.
//    With checkOverlaps, build() refuses grains whose bounding spheres interpenetrate by
//    more than kOverlapTolerance of the smaller radius (InputError on <name>.positions,
//    naming both instances: the first pair, smallest index then the other's), checked
//    through the grid: each pair listed in a common cell is judged in the one cell that
//    holds the middle of their overlap (inside both spheres by half its depth, so both are
//    listed there), each grain's sphere placed once per cell it is listed in.
//  - Memory at scale, per grain (bench/README.md, "Explicit grains from a simulation"):
//    the input, 36 bytes (positions 12, orientations 16, scales 4, protoIndices 4; 24 more
//    with velocities and angular velocities), held once however often the description
//    is copied. The grid beyond it, 16.7 bytes on a simulated heap (3.6 list entries of 4
//    bytes at this cell size, 2.0 of cell starts, 0.3 of hash); while building, a count per
//    cell (2 more) and the dense block table (at most 1). The hybrid adds its
//    heterogeneous medium's packing-rate grid (grain_density.h: 4 bytes a voxel at voxels of
//    3 mean radii, 3.4 bytes a grain kept; while building, 4 bytes a grain and three slabs
//    of leaves' grains at 70 bytes each).
//    The promise: at 10^8 grains on the 2-core machine, a stage's set-up (read, grid,
//    overlap check; for the hybrid also the packing-rate grid, TT and proxy tables) under
//    60 s, and memory under 4 GiB beyond the input arrays. Measured 2026-12-04 on a heap of
//    10^8 grains (3.4 GiB of arrays; bench/instanced_grains.py --stage, the read and build
//    of `granular render`): EPT 17 s (read 3.7, grid 8.0, overlap check 5.0), 2.0 GiB
//    beyond the input at its peak; the hybrid 34 s (its packing-rate grid 15 s, TT 1.4 s,
//    proxy tables 0.2 s from the cache, about 3 s without), 2.9 GiB; 55 CPU seconds, so
//    with one core left by other jobs 67 s; pinned to one core, 57–66 s (52–59 CPU
//    seconds of build, half of them the packing-rate grid's): at the promise, not under it.
//    DA in that medium (heterogeneous_diffusion.h, off unless RenderSettings::daInstanced)
//    is not counted: on, its boundary (one distance field) takes about 70 CPU seconds more
//    and 1.3 GiB more (bench/README.md).
//  - Queries take world-space rays (t as given: the direction need not be unit) and are
//    thread-safe. intersect() walks the cells along the ray front to back (3-D DDA), tests
//    each listed grain's bounding sphere, then the prototype's BVH in the grain's frame,
//    and stops at the first cell that ends beyond the nearest hit. occluded() stops at the
//    first hit. forEachGrain() visits, once each and in index order, the grains whose
//    bounding spheres overlap the box mapped into object space (the bounds of its
//    corners: exact under translation and scale).
#pragma once

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "embree_util.h"
#include "grain.h"
#include "math.h"
#include "proxy.h"
#include "scene_desc.h"

namespace granular {

// Lengths, finite values, unit orientations, positive scales, prototype indices in range,
// a prototype at least: InputError naming <name>.<attribute> and the first bad instance.
// Every builder of a description calls it (instancedGrainsFromUsd, validateSceneDesc,
// InstancedGrains::build, buildGrainDensity, the Python binding), yet the per-instance
// checks run once per set of arrays: it remembers the arrays it found valid by their
// stamps (shared_array.h: the same values, unwritten since; copies of a description share
// them) with the prototype count, and for those checks only lengths and prototypes again.
void validateInstancedGrains(const InstancedGrainsDesc& desc);

// The smallest index in [0, n) for which bad(i) holds, or -1: in parallel, the answer a loop
// gives (errors name the first bad instance).
template <typename Pred>
int64_t firstBadInstance(size_t n, Pred&& bad) {
  return tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, n, 4096), int64_t(-1),
      [&](const tbb::blocked_range<size_t>& r, int64_t found) {
        if (found >= 0 && size_t(found) < r.begin()) return found;
        for (size_t i = r.begin(); i < r.end(); ++i)
          if (bad(i)) return int64_t(i);
        return found;
      },
      [](int64_t a, int64_t b) { return a < 0 ? b : (b < 0 ? a : std::min(a, b)); });
}

struct InstancedGrainHit {
  float t = kInf;
  int64_t grain = -1;  // index into the description's arrays
  int prototype = -1;
  unsigned prim = 0;   // the prototype's triangle hit
  Vec3 ng;             // world, outward from the grain, unit
  float radius = 0;    // the grain's bounding radius (object space)
};

// One grain's placement, as the grid sees it (object space).
struct InstancedGrain {
  int64_t index = -1;
  int prototype = -1;
  Vec3 center;         // bounding-sphere centre
  float radius = 0;    // bounding radius
  Quat orientation;
  float scale = 1;
};

struct InstancedGrainsStats {
  int64_t grains = 0;
  int64_t cells[3] = {0, 0, 0};  // the grid's resolution over the spheres' bounds
  int64_t occupiedBlocks = 0;    // blocks of 4³ cells holding at least one list
  int64_t entries = 0;           // list entries (grain, cell)
  float cellSize = 0;
  size_t inputBytes = 0;         // the description's per-grain arrays
  size_t gridBytes = 0;          // lists, cell starts, hash (see the contract)
  size_t prototypeBytes = 0;     // prototype meshes and normals (BVHs not counted)
  double buildSeconds = 0;       // grid, prototypes and overlap check excluded
  double overlapSeconds = 0;     // the overlap check
  double bytesPerGrain() const { return grains ? double(gridBytes) / double(grains) : 0.0; }
};

class InstancedGrains {
 public:
  static constexpr float kCellRadii = 3.0f;          // cell edge over the largest bounding radius
  static constexpr float kOverlapTolerance = 0.05f;  // of the smaller bounding radius
  static constexpr int kBlockBits = 2;               // blocks of (1 << kBlockBits)³ cells

  InstancedGrains() = default;
  InstancedGrains(const InstancedGrains&) = delete;
  InstancedGrains& operator=(const InstancedGrains&) = delete;

  // Validates (validateInstancedGrains), builds the prototypes and the grid. motionSpan:
  // the longest |time| a query will ask (motionSpan(CameraDesc)); moving grains are listed
  // by the sphere of their sweep over [−motionSpan, motionSpan].
  void build(InstancedGrainsDesc desc, const EmbreeDevice& device, bool checkOverlaps = true, float motionSpan = 0);

  // time: seconds from the description's time (|time| <= the build's motionSpan), where
  // moving grains are placed (InstancedGrainsDesc: velocities, angularVelocities).
  bool intersect(const Vec3& o, const Vec3& d, float tmin, float tmax, InstancedGrainHit& hit, float time = 0) const;
  bool occluded(const Vec3& o, const Vec3& d, float tmin, float tmax, float time = 0) const;
  void forEachGrain(const Bounds3& box, const std::function<void(const InstancedGrain&)>& fn) const;

  // Proxies (proxy.h, ppt.h): the grains' bounding spheres at their positions. intersectProxy()
  // finds the nearest sphere the world-space ray enters (t: where, tmin when it starts inside
  // one) other than grain `skip` (the one it leaves; -1: none); grain in object space.
  // proxyTransmittance() is the passage of light through the spheres the ray enters before
  // tmax (ProxyShadow, proxy.h): the product of shadow(grain, b) over them (b: the impact
  // parameter over the radius; ProxyTable::shadow), each counted once; proxyRoulette()
  // from seed.
  bool intersectProxy(const Vec3& o, const Vec3& d, float tmin, float tmax, int64_t skip, InstancedGrain& grain,
                      float& t, float time = 0) const;
  ProxyShadow proxyTransmittance(const Vec3& o, const Vec3& d, float tmin, float tmax, int64_t skip,
                                 const std::function<ProxyShadow(const InstancedGrain&, float)>& shadow,
                                 uint64_t seed, float time = 0) const;

  InstancedGrain grain(int64_t i, float time = 0) const;
  // A brute-force reference over every grain (tests, benchmarks): intersect()'s answer.
  bool intersectAll(const Vec3& o, const Vec3& d, float tmin, float tmax, InstancedGrainHit& hit,
                    float time = 0) const;
  float motionSpan() const { return motionSpan_; }  // 0: nothing moves (or no blur asked)

  const InstancedGrainsDesc& desc() const { return desc_; }
  const std::vector<GrainPrototype>& prototypes() const { return prototypes_; }
  const InstancedGrainsStats& stats() const { return stats_; }
  Bounds3 objectBounds() const { return bounds_; }

 private:
  struct Walk;
  // Grain i's bounding sphere against the object-space ray; then its prototype's BVH.
  bool traceGrain(int64_t i, const Vec3& o, const Vec3& d, float tmin, float tmax, float time,
                  InstancedGrainHit& hit) const;
  bool walk(const Vec3& o, const Vec3& d, float tmin, float tmax, float time, bool anyHit, InstancedGrainHit& hit) const;
  // Visits the cells along an object-space ray front to back (3-D DDA): visit(k0, k1,
  // tEnter, tExit) with the cell's list list_[k0, k1) and its range of t (the first from
  // −∞, the last to +∞); returns false to stop.
  template <class Visit>
  void forCellsAlong(const Vec3& o, const Vec3& d, float tmin, float tmax, Visit&& visit) const;
  // Grain i's bounding sphere at time 0 (grain(i)'s centre and radius, the same numbers),
  // inline for the build's passes over every grain.
  inline void sphere(size_t i, Vec3& center, float& radius) const;
  // The index of a block in starts_ (times the cells per block), or -1 when unoccupied.
  int64_t findBlock(uint64_t key) const;
  uint64_t blockKey(int64_t x, int64_t y, int64_t z) const {
    return uint64_t(x >> kBlockBits) | (uint64_t(y >> kBlockBits) << 21) | (uint64_t(z >> kBlockBits) << 42);
  }
  static int localCell(int64_t x, int64_t y, int64_t z) {
    constexpr int64_t m = (1 << kBlockBits) - 1;
    return int((x & m) | ((y & m) << kBlockBits) | ((z & m) << (2 * kBlockBits)));
  }
  // The cells a sphere's box covers (clamped to the grid).
  void cellRange(const Vec3& c, float r, int64_t lo[3], int64_t hi[3]) const;
  bool sphereTouchesCell(const Vec3& c, float r, int64_t x, int64_t y, int64_t z) const;
  void buildGrid();
  void checkOverlaps();

  EmbreeDevice device_;  // first: it outlives the BVHs
  InstancedGrainsDesc desc_;
  std::vector<GrainPrototype> prototypes_;
  Transform inv_;
  bool identity_ = true;
  Bounds3 bounds_;
  Vec3 origin_;
  // How far grain i's bounding sphere can move within motionSpan_ (0 when still).
  float sweep(int64_t i) const;
  float motionSpan_ = 0;
  float cell_ = 1, invCell_ = 1;
  int64_t n_[3] = {0, 0, 0};
  std::vector<uint64_t> hashKeys_;   // kEmptyKey where free
  std::vector<uint32_t> hashBlock_;  // occupied block's index
  uint64_t hashMask_ = 0;
  std::vector<uint32_t> starts_;     // per cell of each occupied block, then one end
  std::vector<uint32_t> list_;       // grain indices
  InstancedGrainsStats stats_;
};

}  // namespace granular
