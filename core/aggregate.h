// aggregate.h — a granular aggregate: boundary, tiled sphere packing and grains
// (Meng et al. 2015: the stochastic grain model and explicit path tracing of the grains).
//
// Contract: build() voxelises the world-space boundary into cells of one tile edge
// L = R / r_tile, classified outside / partial / inside from the boundary's signed
// distance field with a margin of half a cell diagonal plus R (so no sphere whose
// centre is inside the boundary can reach an "outside" cell); the field, the classes and
// the sub-cell lists come from the build cache (build_cache.h) when a build of the same
// inputs stored them, bit for bit what this build would compute; boundaries that differ
// by their transform's translation alone share one field (DistanceField::buildShared,
// anchored at the translation). intersect() walks the cells' sub-cells (an M^3 grid per
// cell, M ≈ L / 2R, each listing the tile spheres that
// overlap it) along the ray by 3-D DDA, front to back; in a non-outside cell it tests the
// listed spheres the ray enters there, keeps a sphere only if its centre is inside the
// boundary (exactly, by a ray cast against the boundary mesh, in partial cells),
// instantiates its grain from a hash and traces the prototype's BVH in the grain's
// frame, and stops at the first sub-cell that ends beyond the nearest grain hit. Where
// the distance field shows the boundary's inside further than a grain's reach, the walk
// jumps ahead (sphere tracing). A ray that starts inside a grain traces that grain
// alone. Memory is the tile and its sub-cell lists, the cell classes (one byte per cell)
// and the narrow-band distance field: independent of the number of grains per cell.
// Queries are thread-safe.
#pragma once

#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

#include "distance_field.h"
#include "embree_util.h"
#include "grain.h"
#include "packing.h"
#include "proxy.h"
#include "scene_desc.h"

namespace granular {

enum class CellClass : uint8_t { Outside = 0, Partial = 1, Inside = 2 };
struct BuildProducts;

struct GrainHit {
  float t = kInf;
  Vec3 ng;                 // world, outward from the grain
  int prototype = -1;
  int64_t cell[3] = {0, 0, 0};
  int sphere = -1;
  float radius = 0;        // the grain's bounding radius (polydisperse: its own)
  Mat3 rotation;           // its frame (GrainSelector::choose), kept for a ray from inside it
  unsigned prim = 0;       // the prototype's triangle hit
  Vec3 center;             // proxies (intersectProxy): the sphere's centre
};

// A flight through the packing to the next grain met (Aggregate::flightToGrain): its length
// (kInf: no grain ahead, the ray leaves the packing), where the ray enters that grain's
// sphere, the grain, and the spheres asked on the way (the walk's cost).
struct GrainFlight {
  float t = kInf;
  Vec3 entry;
  GrainHit grain;
  int steps = 0;
  bool met() const { return t < kInf; }
};

// One grain, as the brute-force reference and the exporters see it.
struct GrainInstance {
  Vec3 center;
  float radius;
  int prototype;
  Mat3 rotation;
  int64_t cell[3];
  int sphere;
};

struct AggregateStats {
  int64_t cells = 0, insideCells = 0, partialCells = 0;
  double approxGrains = 0;       // inside cells * N + partial cells * N * inside fraction
  size_t memoryBytes = 0;        // classes + distance field + tile sub-cell lists + prototypes
  double setupSeconds = 0;
  double tileSeconds = 0, sdfSeconds = 0;
  // Largest depth below the boundary of a cell centre (a lower bound of the object's
  // half thickness, exact to about a cell): decides whether VPT and DA can pay off.
  float maxInteriorDepth = 0;
  float fieldVoxel = 0;          // the distance field's voxel edge (world units)
  bool fromCache = false;        // the products above came from the build cache (build_cache.h)
};

class Aggregate {
 public:
  Aggregate() = default;
  Aggregate(const Aggregate&) = delete;
  Aggregate& operator=(const Aggregate&) = delete;

  // prototypeMaterials: scene material index of each prototype. standIn: only what the
  // aggregate's equivalent medium needs (the boundary's BVH and the prototypes), no tile
  // and no cells: a first image can be rendered from the medium alone while the full
  // build runs (Scene::build, SceneDetail::StandIns). A stand-in has no grains
  // (intersect() finds none, occluded() is the boundary's; tile() is empty), and its
  // maxInteriorDepth and approxGrains are estimates (a grid of at most 32 points per
  // axis; the boundary's volume × f over the mean grain volume) instead of the cells'.
  // log: told, before it starts, of work the build cache does not hold (the distance
  // field and cells).
  void build(const AggregateDesc& desc, const EmbreeDevice& device, const std::vector<int>& prototypeMaterials,
             bool standIn = false, const std::function<void(const std::string&)>& log = nullptr);
  bool standIn() const { return standIn_; }
  // An estimate of the memory build() takes at its peak (the cells' classes, the distance
  // field and its construction, the sub-cell lists), from the description alone (the
  // tile's sphere radius as the packing rate gives it): kBuildBytesPerCell per cell of
  // the boundary's bounds. Scene::build keeps concurrent builds under a cap by it.
  static double estimateBuildBytes(const AggregateDesc& desc);
  static constexpr double kBuildBytesPerCell = 10.0;

  // from: the grain the ray starts at (its path's last hit, or null), inside it or leaving
  // it. A ray inside a grain leaves it before meeting any other (grains lie in disjoint
  // bounding spheres): only that grain is traced, the walk only if the ray misses it
  // (an origin rounded out of it). One leaving a grain through a face of its convex hull
  // (every face, for a convex grain) cannot meet it again: the walk skips it. Both give the walk's own hits (the grain is traced as from the cell
  // the walk starts in).
  bool intersect(const Vec3& o, const Vec3& d, float tmin, float tmax, GrainHit& hit, const GrainHit* from = nullptr,
                 bool inside = false) const;
  // Whether any grain lies along the ray in [tmin, tmax] (shadow rays): the walk stops at
  // the first grain it meets, not the nearest.
  bool occluded(const Vec3& o, const Vec3& d, float tmin, float tmax) const;
  // Proxies (proxy.h): the nearest bounding sphere centred inside the boundary that the
  // ray enters in [tmin, tmax], not counting `skip` (the sphere the ray leaves); hit gets
  // its entry t, cell, sphere, radius, centre and the prototype of its grain. Once
  // prepareProxies() has run, a ray leaving a sphere is first tested against that sphere's
  // neighbours (their list reaches kNeighbourReach largest radii beyond it): when the
  // nearest one met is near enough that no unlisted sphere can be met before it, that is
  // the answer, without the walk.
  bool intersectProxy(const Vec3& o, const Vec3& d, float tmin, float tmax, GrainHit& hit,
                      const GrainHit* skip = nullptr) const;
  // The packing's flight (vpt.h: the medium takes over at a grain; switching.h's proxy
  // walk): from o along d past the sphere `from` (null: none), the spheres the ray enters,
  // each grain met with its table's chance hit(b) (proxy.h) — one random number per sphere
  // — and else crossed from its far side, until one is met or none is ahead (GrainFlight).
  GrainFlight flightToGrain(Vec3 o, const Vec3& d, const ProxyTables& tables, const GrainHit* from, Rng& rng) const;
  // The centre of the tile sphere of a grain an explicit ray met (intersect's hit: its
  // cell and sphere), as intersectProxy() gives it.
  Vec3 grainCenter(const GrainHit& g) const { return sphereCenter(g.cell, g.sphere); }
  // Light along [tmin, tmax] through the proxies' spheres (ProxyShadow, proxy.h): the
  // products over the spheres it crosses (but `skip`), from each grain's prototype's table
  // at its size, with proxyRoulette() from `seed` below kProxyRoulette.
  ProxyShadow proxyTransmittance(const Vec3& o, const Vec3& d, float tmin, float tmax, const ProxyTables& tables,
                                 const GrainHit* skip, uint64_t seed) const;
  // Builds the neighbour lists the proxy queries use (once; thread-safe). Only scenes that
  // use proxies pay for them: about a second and 45 MiB for a tile of 32768 spheres.
  void prepareProxies() const;
  static constexpr float kNeighbourReach = 2.5f;
  static constexpr uint32_t kMaxNeighbours = 1024;
  static constexpr uint32_t kNeighbourBlock = 4;  // neighbours tested side by side
  // Exact inside test of a world point against the boundary mesh (ray parity by the
  // orientation of the first hit).
  bool insideBoundary(const Vec3& p) const;
  // The same answer, cheaply where it can: the distance field (accurate to about a voxel)
  // where it puts p deeper than a voxel, insideBoundary() elsewhere and for a stand-in (no
  // field). For points asked often near where a path already is (the exits model's moves).
  bool insideBoundaryFast(const Vec3& p) const {
    return (!standIn_ && boundaryDistance(p) < -sdf_.voxelSize()) || insideBoundary(p);
  }
  // Nearest crossing of the boundary mesh in (tmin, tmax): its t and outward unit normal.
  // The medium of VPT/DA is bounded by it (an index-matched interface).
  bool intersectBoundary(const Vec3& o, const Vec3& d, float tmin, float tmax, float& t, Vec3& ng) const;
  // Exact distance from p to the boundary mesh and the closest point on it (Embree
  // point query), for DA, which needs depths beyond the distance field's narrow band.
  float closestBoundaryPoint(const Vec3& p, Vec3& closest) const;
  // Signed distance to the boundary (negative inside), from the distance field.
  float boundaryDistance(const Vec3& p) const { return sdf_.distance(p); }

  CellClass cellClass(int64_t i, int64_t j, int64_t k) const;
  void forEachGrain(const Bounds3& box, const std::function<void(const GrainInstance&)>& fn) const;

  const std::string& name() const { return name_; }
  const Bounds3& bounds() const { return bounds_; }
  // The radius of size 1 (AggregateDesc::grainRadius), and the largest grain's.
  float grainRadius() const { return R_; }
  float maxGrainRadius() const { return Rmax_; }
  float cellSize() const { return L_; }
  const Tile& tile() const { return tile_; }
  const std::vector<GrainPrototype>& prototypes() const { return prototypes_; }
  const AggregateStats& stats() const { return stats_; }
  const DistanceField& distanceField() const { return sdf_; }
  const TriangleMesh& boundary() const { return boundary_; }
  float packingRate() const { return f_; }

 private:
  struct TileSphere {
    Vec3 center;            // relative to the cell's origin, world units
    int8_t home[3];         // offset of the cell that holds the centre
    int id;                 // sphere index in the tile
    float radius;           // world units
  };
  bool sphereIsInside(const int64_t home[3], const Vec3& worldCenter, DistanceField::NearestProbe& probe) const;
  // The centre of tile sphere `id` of cell `home`, computed one way for every query, so
  // that all of them make the same inside decision (sphereIsInside).
  Vec3 sphereCenter(const int64_t home[3], int id) const;
  // The home cell of neighbour entry k of a sphere in `cell`.
  void neighbourHome(const int64_t cell[3], uint32_t k, int64_t home[3]) const;
  // One ray's walk through the cells (intersect(), occluded()).
  enum class WalkMode { Grains, NearestProxy, ProxyTransmittance };
  struct RayWalk {
    Vec3 o, d, invD;
    float tmin;
    float best;                   // the nearest hit's t so far (the walk's tmax)
    GrainHit& hit;                // written with each nearer hit
    const GrainHit* skip;         // a grain not to trace, or null
    bool anyHit;                  // stop at the first hit (occluded())
    DistanceField::NearestProbe probe;
    bool found = false;
    WalkMode mode = WalkMode::Grains;
    const ProxyTables* tables = nullptr;  // ProxyTransmittance
    ProxyShadow transmittance{};
    uint64_t seed = 0;   // roulette's random numbers (ProxyTransmittance)
    uint64_t draws = 0;
    float tEnterMin = -kInf;  // ProxyTransmittance: spheres entered before are counted already
    // The spheres counted last (a sphere may be listed by two sub-cells the ray enters it
    // between): (home cell hash, sphere id).
    uint64_t recent[8] = {};
    int nRecent = 0, cursor = 0;
  };
  // The cell walk (3-D DDA, front to back) over [t0, t1], the ray's span in the bounds;
  // true when a grain is hit.
  bool walk(RayWalk& r, float t0, float t1) const;
  // Its sub-cell walk through one non-outside (partial or inside) cell between tEnter and
  // tExit, lowering r.best. True when a hit is found and no later sphere can be nearer:
  // the walk may stop. resume: set beyond tExit when the distance field shows nothing to
  // meet before it.
  bool walkCell(RayWalk& r, const int64_t cell[3], bool partial, float tEnter, float tExit, float& resume) const;
  // The grain of tile sphere s listed by `cell`, if its centre is inside (knownInside:
  // the caller knows it is): its nearest hit in [tmin, tmax] along oc + t d (oc: the
  // ray's origin relative to the sphere's centre). skip: a grain not to trace, or null.
  bool traceGrain(const TileSphere& s, const int64_t cell[3], const Vec3& oc, const Vec3& d, float tmin, float tmax,
                  bool knownInside, GrainHit& best, const GrainHit* skip, DistanceField::NearestProbe& probe) const;
  // A proxy walk's visit of tile sphere s listed by `cell`, entered at tEntry: true when it
  // ends the walk's search (NearestProxy: the sphere is the new nearest).
  bool visitProxy(RayWalk& r, const TileSphere& s, const int64_t cell[3], const Vec3& oc, float tEntry,
                  bool knownInside) const;
  // The neighbour test of intersectProxy(): true when it answers (hit or a sure miss of
  // every sphere before tmax is not claimed: false means "walk").
  bool nearestNeighbour(const Vec3& o, const Vec3& d, float tmin, float tmax, GrainHit& hit, const GrainHit& from) const;
  // The grain of sphere s (home: its cell) with its prototype and rotation chosen.
  bool traceChosen(const TileSphere& s, const int64_t home[3], const GrainChoice& g, const Vec3& oc, const Vec3& d,
                   float tmin, float tmax, GrainHit& best) const;
  // build()'s parts that the build cache holds: the cell classes with their counts and
  // the deep cells' depth (after the distance field), and the sub-cell lists.
  void classifyCells(float margin);
  void listSubCells(double meanSize);
  // The distance field, the classes and the sub-cell lists: from the build cache, or
  // computed (and stored there).
  void buildCells(const AggregateDesc& desc, float voxel, float margin, double meanSize,
                  const std::function<void(const std::string&)>& log);
  // Swaps those products (and the distance field) with p's.
  void exchangeProducts(BuildProducts& p);
  static size_t longestSubList(const std::vector<uint32_t>& start);
  // Tile sphere `id`'s periodic image offset by `shift` cells (in -1..1): as build() lists it.
  TileSphere imageOf(int id, const int shift[3]) const;
  // The ray from inside grain `g`: its exit, traced as the walk would from its first cell.
  bool traceFromInside(const GrainHit& g, const Vec3& o, const Vec3& d, float tmin, float tmax, GrainHit& hit) const;

  EmbreeDevice device_;  // first: it outlives the BVHs below (scenes share aggregates)
  std::string name_;
  float R_ = 0, Rmax_ = 0, L_ = 0, f_ = 0;
  Tile tile_;
  std::vector<TileSphere> spheres_;
  int sub_ = 1;                        // sub-cells per cell edge
  std::vector<uint32_t> subStart_;     // per sub-cell, its first entry in subList_ (CSR)
  std::vector<uint32_t> subList_;      // indices into spheres_
  std::vector<float> subX_, subY_, subZ_;  // their centres (parallel to subList_)
  std::vector<float> subR2_;               // and squared radii
  // Per tile sphere, the spheres (and images) whose centres lie within its radius plus
  // kNeighbourReach largest radii of its centre (CSR): centre offsets, squared radii, id
  // and the offset of their home cell. Empty until prepareProxies(), or when that reach
  // exceeds the tile.
  void buildNeighbours() const;
  mutable std::once_flag nbOnce_;
  mutable std::vector<uint32_t> nbStart_;
  mutable std::vector<float> nbX_, nbY_, nbZ_, nbR2_, nbReach_;  // nbReach_: per tile sphere, the list's reach
  mutable std::vector<float> nbKey_;  // centre distance less radius: no ray from within the sphere enters before key − |oc|
  mutable std::vector<int32_t> nbId_;
  mutable std::vector<int8_t> nbShift_;  // 3 per entry
  static constexpr uint32_t kMaxSubList = 256;  // longest list (M >= 1 keeps it far below)
  std::vector<GrainPrototype> prototypes_;
  std::vector<int> prototypeMaterials_;
  GrainSelector selector_;
  TriangleMesh boundary_;
  DistanceField sdf_;
  EmbreeScene boundaryBvh_;
  Vec3 origin_;
  int64_t n_[3] = {0, 0, 0};
  std::vector<CellClass> classes_;
  Bounds3 bounds_;
  AggregateStats stats_;
  bool standIn_ = false;
  // build()'s stand-in: no tile, no cells; estimates of maxInteriorDepth and approxGrains.
  void buildStandIn(const AggregateDesc& desc, const EmbreeDevice& device);
  void estimateStandInDepth();
  void buildPrototypes(const AggregateDesc& desc, const EmbreeDevice& device);
};

}  // namespace granular
