#include "aggregate.h"

#if defined(__SSE2__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <chrono>
#include <mutex>
#include <cmath>

#include <tbb/parallel_for.h>

#include "build_cache.h"
#include "error.h"

namespace granular {

namespace {

// Context handed through Embree to the tile's user-geometry callback.
// A direction unlikely to run along mesh edges, for the parity inside test.
const Vec3 kInsideProbeDir = normalize(Vec3(0.5773f, 0.5774f, 0.5775f) + Vec3(0.0123f, -0.0311f, 0.0207f));

// Closest point on triangle abc to p (Ericson, Real-Time Collision Detection §5.1.5).
Vec3 closestOnTriangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  Vec3 ab = b - a, ac = c - a, ap = p - a;
  float d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return a;
  Vec3 bp = p - b;
  float d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return b;
  float vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + ab * (d1 / (d1 - d3));
  Vec3 cp = p - c;
  float d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return c;
  float vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + ac * (d2 / (d2 - d6));
  float va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
  float denom = 1.0f / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

struct ClosestQuery {
  const TriangleMesh* mesh;
  Vec3 closest;
};

bool closestPointCallback(RTCPointQueryFunctionArguments* args) {
  auto* q = static_cast<ClosestQuery*>(args->userPtr);
  const TriangleMesh& m = *q->mesh;
  unsigned t = args->primID;
  Vec3 p(args->query->x, args->query->y, args->query->z);
  Vec3 c = closestOnTriangle(p, m.points[m.indices[3 * t]], m.points[m.indices[3 * t + 1]], m.points[m.indices[3 * t + 2]]);
  float d = length(c - p);
  if (d < args->query->radius) {
    args->query->radius = d;  // shrink the search
    q->closest = c;
    return true;
  }
  return false;
}

}  // namespace

bool Aggregate::traceGrain(const TileSphere& s, const int64_t cell[3], const Vec3& oc, const Vec3& d, float tmin,
                           float tmax, bool knownInside, GrainHit& best, const GrainHit* skip,
                           DistanceField::NearestProbe& probe) const {
  int64_t home[3] = {cell[0] + s.home[0], cell[1] + s.home[1], cell[2] + s.home[2]};
  if (skip && skip->sphere == s.id && skip->cell[0] == home[0] && skip->cell[1] == home[1] && skip->cell[2] == home[2])
    return false;
  // The centre from the home cell, computed as forEachGrain does, so that every cell
  // that lists this sphere makes the same inside decision.
  if (!knownInside) {
    const Vec3 worldCenter = sphereCenter(home, s.id);
    if (!sphereIsInside(home, worldCenter, probe)) return false;
  }
  return traceChosen(s, home, selector_.choose(home[0], home[1], home[2], s.id, tile_.sizeClass(s.id)), oc, d, tmin,
                     tmax, best);
}

bool Aggregate::traceChosen(const TileSphere& s, const int64_t home[3], const GrainChoice& g, const Vec3& oc,
                            const Vec3& d, float tmin, float tmax, GrainHit& best) const {
  float t;
  unsigned prim;
  Vec3 ng;
  if (!tracePrototype(prototypes_[g.prototype], g.rotation, s.radius, oc, d, tmin, tmax, t, prim, ng)) return false;
  best.t = t;
  best.ng = normalize(ng);
  best.prototype = g.prototype;
  best.cell[0] = home[0]; best.cell[1] = home[1]; best.cell[2] = home[2];
  best.sphere = s.id;
  best.radius = s.radius;
  best.rotation = g.rotation;
  best.prim = prim;
  return true;
}

void Aggregate::build(const AggregateDesc& desc, const EmbreeDevice& device, const std::vector<int>& prototypeMaterials,
                      bool standIn, const std::function<void(const std::string&)>& log) {
  auto t0 = std::chrono::steady_clock::now();
  standIn_ = standIn;
  name_ = desc.name;
  device_ = device;
  R_ = desc.grainRadius;
  f_ = desc.packingRate;
  prototypeMaterials_ = prototypeMaterials;
  boundary_ = desc.boundary.transformed(desc.xf);
  if (boundary_.signedVolume() < 0) boundary_.flip();
  if (standIn) {  // no tile, no cells: the boundary and the prototypes (the medium's inputs)
    buildStandIn(desc, device);
    stats_.setupSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return;
  }

  // Tile: periodic packing at the requested rate, scaled so its spheres of size 1 have
  // radius R; polydisperse aggregates pack their size classes (grain.h) together.
  auto tt = std::chrono::steady_clock::now();
  const SizeClasses classes = sizeClassesOf(desc);
  TileSizes sizes;  // one class of size 1 without spread: monodisperse (TileSizes::monodisperse)
  sizes.classSize.assign(classes.size.begin(), classes.size.end());
  sizes.classWeight = classes.weight;
  sizes.spread = desc.sizeSpread;
  try {
    tile_ = loadOrGenerateTile(desc.tileSpheres, desc.packingRate, desc.seed, sizes);
  } catch (const InputError& e) {
    // The tile's words for the aggregate's attributes.
    const std::string& a = e.attribute();
    throw InputError(desc.name, a == "numSpheres" ? "tileSpheres" : a, e.detail());
  }
  stats_.tileSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - tt).count();
  L_ = float(R_ / tile_.radius);
  Rmax_ = R_ * tile_.maxSize();
  double meanSize = 0;
  for (int k = 0; k < tile_.numSpheres; ++k) meanSize += tile_.size(k) / double(tile_.numSpheres);

  // Grid over the boundary's bounds grown by the largest radius (spheres centred inside
  // may poke out).
  Bounds3 mb = boundary_.bounds();
  bounds_.lo = mb.lo - Vec3(Rmax_);
  bounds_.hi = mb.hi + Vec3(Rmax_);
  origin_ = bounds_.lo;
  double cells = 1;
  for (int a = 0; a < 3; ++a) {
    double n = std::ceil(double(bounds_.hi[a] - bounds_.lo[a]) / L_);
    n_[a] = std::max<int64_t>(1, int64_t(std::min(n, 1e9)));
    cells *= double(n_[a]);
  }
  const double kMaxCells = double(1u << 28);  // 256 Mi cells = 256 MiB of classes
  if (cells > kMaxCells)
    throw InputError(desc.name, "grainRadius",
                     str(R_, " is too small for the boundary's size: ", cells, " tiles of ", desc.tileSpheres,
                         " grains exceed the limit of ", kMaxCells, " (raise grainRadius or tileSpheres)"));
  for (int a = 0; a < 3; ++a) bounds_.hi[a] = origin_[a] + float(n_[a]) * L_;

  // Distance field: voxels of a quarter cell where such a field stays under
  // desc.fineFieldBytes (paper-scale boundaries would need hundreds of MiB), else half a
  // cell (or coarser for huge grids); the band covers the margin. The finer field classes
  // more cells inside and leaves fewer spheres near the boundary to a ray cast
  // (sphereIsInside), which shortens the walk where rays first meet the aggregate. Which
  // spheres are grains does not depend on it.
  const float extent = maxComponent(mb.extent());
  auto marginFor = [&](float v) { return 0.8661f * L_ + Rmax_ + 1.5f * v; };
  const float fine = 0.25f * L_;
  float voxel = std::max(0.5f * L_, extent / 1024.0f);
  if (fine > extent / 1024.0f &&
      DistanceField::estimateBytes(boundary_.area(), fine, marginFor(fine) + fine) <= desc.fineFieldBytes)
    voxel = fine;
  stats_.fieldVoxel = voxel;
  const float margin = marginFor(voxel);
  stats_.cells = int64_t(cells);

  // The tile's spheres plus every periodic image that reaches into the unit cell.
  spheres_.clear();
  for (int s = 0; s < tile_.numSpheres; ++s) {
    const Vec3& c = tile_.centers[s];
    const double r = tile_.radius * tile_.size(s);
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          double p[3] = {c.x + dx, c.y + dy, c.z + dz};
          double d2 = 0;
          for (double v : p) {
            double e = v < 0 ? -v : (v > 1 ? v - 1 : 0);
            d2 += e * e;
          }
          if (d2 >= r * r) continue;
          const int shift[3] = {dx, dy, dz};
          spheres_.push_back(imageOf(s, shift));
        }
  }
  boundaryBvh_ = buildTriangleScene(device, boundary_);
  buildCells(desc, voxel, margin, meanSize, log);
  buildPrototypes(desc, device);
  selector_ = GrainSelector(desc.weights, classes, desc.seed);

  stats_.memoryBytes = classes_.size() * sizeof(CellClass) + sdf_.memoryBytes() +
                       spheres_.size() * sizeof(TileSphere) + (subList_.size() + subStart_.size()) * sizeof(uint32_t) +
                       boundary_.points.size() * 40;
  for (const auto& p : prototypes_)
    stats_.memoryBytes += p.mesh.points.size() * 40 + p.mesh.indices.size() * 8 + p.normals.size() * sizeof(Vec3);
  stats_.setupSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

void Aggregate::buildCells(const AggregateDesc& desc, float voxel, float margin, double meanSize,
                           const std::function<void(const std::string&)>& log) {
  // The distance field, cell classes, their counts and the sub-cell lists: from the build
  // cache when a build of the same inputs stored them (build_cache.h), else computed and
  // stored. Either way the same values, so the same images.
  auto ts = std::chrono::steady_clock::now();
  BuildProducts products;
  for (int a = 0; a < 3; ++a) products.cells[a] = n_[a];
  products.origin = origin_;
  products.cellSize = L_;
  products.voxelSize = voxel;
  products.bandWidth = DistanceField::bandVoxels(voxel, margin + voxel) * voxel;
  // An axis-aligned box's field is written exactly (DistanceField::buildBox), not voxelised:
  // other values than mesh-to-level-set's, so another cache entry.
  Bounds3 box;
  const bool exactBox = DistanceField::isAxisAlignedBox(boundary_, box);
  // Any other mesh's field is anchored at the transform's translation: the boundary
  // before it (its linear part applied, triangles as boundary_ winds them) is voxelised on
  // a lattice that moves with it, so that boundaries instanced by translation (a castle's
  // towers) share one grid (DistanceField::buildShared).
  TriangleMesh local;
  Vec3d anchor;
  if (!exactBox) {
    Transform linear = desc.xf;
    anchor = Vec3d{linear.m[0][3], linear.m[1][3], linear.m[2][3]};
    linear.m[0][3] = linear.m[1][3] = linear.m[2][3] = 0;
    local.points.reserve(desc.boundary.points.size());
    for (const Vec3& p : desc.boundary.points) local.points.push_back(linear.point(p));
    local.indices = boundary_.indices;
  }
  products.anchor = anchor;
  const uint64_t key = exactBox ? hashInts(buildKey(desc, boundary_, tile_), 0x424f58u /* "BOX" */)
                                : buildKey(desc, boundary_, tile_);
  if (loadBuild(key, spheres_.size(), products) && longestSubList(products.subStart) <= kMaxSubList) {
    exchangeProducts(products);
    stats_.fromCache = true;
    stats_.sdfSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - ts).count();
  } else {
    if (log)
      log(str(name_, ": building its distance field and ", stats_.cells, " cells (not cached yet)"));
    if (exactBox) sdf_.buildBox(box, voxel, margin + voxel);
    else sdf_.buildShared(local, anchor, voxel, margin + voxel);
    stats_.sdfSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - ts).count();
    classifyCells(margin);
    listSubCells(meanSize);
    exchangeProducts(products);
    storeBuild(key, products);
    exchangeProducts(products);
  }

  // The listed centres again, one array per axis, for the walk's vectorised sphere tests.
  for (auto* v : {&subX_, &subY_, &subZ_, &subR2_}) v->resize(subList_.size());
  for (size_t k = 0; k < subList_.size(); ++k) {
    const TileSphere& t = spheres_[subList_[k]];
    subX_[k] = t.center.x;
    subY_[k] = t.center.y;
    subZ_[k] = t.center.z;
    subR2_[k] = t.radius * t.radius;
  }
}

double Aggregate::estimateBuildBytes(const AggregateDesc& desc) {
  double s3 = 1;
  sauterSizeOf(desc, &s3);
  float largest = 0;
  for (float x : sizeClassesOf(desc).size) largest = std::max(largest, x);
  // f = N (4/3) π r³ E[s³] in the unit tile: its sphere radius r, the cell edge L = R / r.
  const double f = std::clamp(double(desc.packingRate), 1e-3, 0.74), n = std::max(1, desc.tileSpheres);
  const double r = std::cbrt(3.0 * f / (4.0 * 3.14159265358979 * n * s3));
  const double L = double(desc.grainRadius) / r, pad = 2.0 * desc.grainRadius * largest * (1.0 + desc.sizeSpread);
  const Bounds3 b = desc.boundary.transformed(desc.xf).bounds();
  double cells = 1;
  for (int a = 0; a < 3; ++a) cells *= std::max(1.0, std::ceil((double(b.extent()[a]) + pad) / L));
  return std::isfinite(cells) ? cells * kBuildBytesPerCell : 0.0;
}

void Aggregate::buildPrototypes(const AggregateDesc& desc, const EmbreeDevice& device) {
  prototypes_.clear();
  for (size_t i = 0; i < desc.prototypes.size(); ++i) {
    prototypes_.push_back(makeGrainPrototype(device, desc.prototypes[i]));
    prototypes_.back().material = prototypeMaterials_[i];
  }
}

void Aggregate::buildStandIn(const AggregateDesc& desc, const EmbreeDevice& device) {
  // Sizes as the tile would hold them (grain.h: sauterSizeOf).
  double s3 = 1;
  sauterSizeOf(desc, &s3);
  float largest = 0;
  for (float x : sizeClassesOf(desc).size) largest = std::max(largest, x);
  Rmax_ = R_ * largest * (1.0f + desc.sizeSpread);
  const Bounds3 mb = boundary_.bounds();
  bounds_.lo = mb.lo - Vec3(Rmax_);
  bounds_.hi = mb.hi + Vec3(Rmax_);
  origin_ = bounds_.lo;
  boundaryBvh_ = buildTriangleScene(device, boundary_);
  buildPrototypes(desc, device);
  estimateStandInDepth();
  const double R = R_, grainVolume = 4.0 / 3.0 * 3.14159265358979 * R * R * R * s3;
  stats_.approxGrains = std::fabs(boundary_.signedVolume()) * f_ / grainVolume;
  stats_.memoryBytes = boundary_.points.size() * 40;
  for (const auto& p : prototypes_)
    stats_.memoryBytes += p.mesh.points.size() * 40 + p.mesh.indices.size() * 8 + p.normals.size() * sizeof(Vec3);
}

void Aggregate::estimateStandInDepth() {
  // Points of a grid of at most 32 per axis (and at least a grain diameter apart) over the
  // boundary's bounds: the deepest one inside (as classifyCells takes the deepest cell
  // centre).
  const Bounds3 b = boundary_.bounds();
  int n[3];
  for (int a = 0; a < 3; ++a) n[a] = int(std::clamp(std::ceil(double(b.extent()[a]) / (2.0 * R_)), 1.0, 32.0));
  std::vector<float> deepest(size_t(n[2]), 0.0f);
  tbb::parallel_for(0, n[2], [&](int k) {
    for (int j = 0; j < n[1]; ++j)
      for (int i = 0; i < n[0]; ++i) {
        const Vec3 p(b.lo.x + (i + 0.5f) * b.extent().x / n[0], b.lo.y + (j + 0.5f) * b.extent().y / n[1],
                     b.lo.z + (k + 0.5f) * b.extent().z / n[2]);
        if (!insideBoundary(p)) continue;
        Vec3 closest;
        deepest[size_t(k)] = std::max(deepest[size_t(k)], closestBoundaryPoint(p, closest));
      }
  });
  stats_.maxInteriorDepth = *std::max_element(deepest.begin(), deepest.end());
}

void Aggregate::exchangeProducts(BuildProducts& p) {
  std::swap(sdf_, p.sdf);
  std::swap(classes_, p.classes);
  std::swap(stats_.insideCells, p.insideCells);
  std::swap(stats_.partialCells, p.partialCells);
  std::swap(stats_.approxGrains, p.approxGrains);
  std::swap(stats_.maxInteriorDepth, p.maxInteriorDepth);
  std::swap(sub_, p.sub);
  std::swap(subStart_, p.subStart);
  std::swap(subList_, p.subList);
}

size_t Aggregate::longestSubList(const std::vector<uint32_t>& start) {
  size_t longest = 0;
  for (size_t i = 0; i + 1 < start.size(); ++i) longest = std::max<size_t>(longest, start[i + 1] - start[i]);
  return longest;
}

void Aggregate::classifyCells(float margin) {
  const double cells = double(stats_.cells);
  classes_.assign(size_t(cells), CellClass::Outside);
  // Cell classes, slice by slice (z) in parallel: each slice keeps its own counts, sum
  // and clamped centres, combined below in slice order, so the result does not depend on
  // the thread count (10^10 grains: 3.8·10^7 cells, a third of the set-up when serial).
  struct Slice {
    int64_t inside = 0, partial = 0;
    double insideFraction = 0;
    float deepest = 0;
    std::vector<Vec3> clamped;  // centres deeper than the field's band (every keepStride-th cell)
  };
  // The deep cells' centres are kept only for the exact depth samples below (at most 4096
  // are measured): every keepStride-th cell, so that at most ~65536 are held. Holding them
  // all took 560 MiB at 10^11 grains (half of 9.4·10^7 cells, 12 bytes each).
  const int64_t keepStride = std::max<int64_t>(1, int64_t(cells) / 65536);
  const float deep = 0.99f * sdf_.bandWidth();  // a centre this deep reads the clamped band
  std::vector<Slice> slices(static_cast<size_t>(n_[2]));
  tbb::parallel_for(int64_t(0), n_[2], [&](int64_t k) {
    Slice& sl = slices[size_t(k)];
    // A row's centres and their distances at once (DistanceField::distances: the values
    // distance() gives, at a fraction of its cost over 10^8 cells).
    std::vector<Vec3> centres(static_cast<size_t>(n_[0]));
    std::vector<float> dists(centres.size());
    for (int64_t j = 0; j < n_[1]; ++j) {
      for (int64_t i = 0; i < n_[0]; ++i)
        centres[size_t(i)] = origin_ + Vec3(float(i) + 0.5f, float(j) + 0.5f, float(k) + 0.5f) * L_;
      sdf_.distances(centres.data(), centres.size(), dists.data());
      const int64_t row = (k * n_[1] + j) * n_[0];
      int64_t phase = row % keepStride;  // the cell's index modulo keepStride
      for (int64_t i = 0; i < n_[0]; ++i, phase = phase + 1 == keepStride ? 0 : phase + 1) {
        const Vec3& c = centres[size_t(i)];
        const float dist = dists[size_t(i)];
        CellClass cls = dist > margin ? CellClass::Outside : (dist < -margin ? CellClass::Inside : CellClass::Partial);
        classes_[size_t(row + i)] = cls;
        if (cls == CellClass::Inside) ++sl.inside;
        if (-dist > sl.deepest) sl.deepest = -dist;
        if (-dist >= deep && phase == 0) sl.clamped.push_back(c);
        if (cls == CellClass::Partial) {
          ++sl.partial;
          sl.insideFraction += std::min(1.0, std::max(0.0, 0.5 - double(dist) / L_));
        }
      }
    }
  });
  double insideFractionSum = 0;
  float deepest = 0;
  size_t clampedCount = 0;
  for (const Slice& sl : slices) {
    stats_.insideCells += sl.inside;
    stats_.partialCells += sl.partial;
    insideFractionSum += sl.insideFraction;
    deepest = std::max(deepest, sl.deepest);
    clampedCount += sl.clamped.size();
  }
  stats_.approxGrains = double(tile_.numSpheres) * (double(stats_.insideCells) + insideFractionSum);

  // The field is clamped at its band: beyond it, measure up to 4096 of the deep cell
  // centres exactly (evenly strided).
  stats_.maxInteriorDepth = deepest;
  if (clampedCount > 0) {
    // Every stride-th of them in slice order (the slices' centres are not copied together).
    const size_t stride = std::max<size_t>(1, clampedCount / 4096);
    size_t index = 0;
    for (const Slice& sl : slices)
      for (const Vec3& c : sl.clamped) {
        if (index++ % stride != 0) continue;
        Vec3 closest;
        stats_.maxInteriorDepth = std::max(stats_.maxInteriorDepth, closestBoundaryPoint(c, closest));
      }
  }
  slices.clear();
  slices.shrink_to_fit();
}

void Aggregate::listSubCells(double meanSize) {
  // Sub-cells: an M^3 grid over the unit cell, M ≈ L / 2R (one or two spheres across),
  // each listing the spheres (and images) that overlap it, for the front-to-back walk.
  // A list then holds about 8 spheres whatever the tile (at most ~20 from 8 to 10^5
  // spheres per tile); the walk's buffers hold kMaxSubList.
  // (Polydisperse: M from the mean radius.)
  sub_ = std::clamp(int(std::lround(L_ / (2.0f * R_ * float(meanSize)))), 1, 32);
  const float Ls = L_ / float(sub_);
  std::vector<std::vector<uint32_t>> lists(size_t(sub_) * sub_ * sub_);
  size_t longest = 0;
  for (size_t i = 0; i < spheres_.size(); ++i) {
    const Vec3& c = spheres_[i].center;
    const float reach = spheres_[i].radius * (1.0f + 1e-3f);
    int lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::clamp(int(std::floor((c[a] - reach) / Ls)), 0, sub_ - 1);
      hi[a] = std::clamp(int(std::floor((c[a] + reach) / Ls)), 0, sub_ - 1);
    }
    for (int z = lo[2]; z <= hi[2]; ++z)
      for (int y = lo[1]; y <= hi[1]; ++y)
        for (int x = lo[0]; x <= hi[0]; ++x) {
          const int idx[3] = {x, y, z};
          float d2 = 0;  // sphere centre to the sub-cell box
          for (int a = 0; a < 3; ++a) {
            float e = std::max({float(idx[a]) * Ls - c[a], 0.0f, c[a] - float(idx[a] + 1) * Ls});
            d2 += e * e;
          }
          if (d2 > reach * reach) continue;
          auto& l = lists[size_t((z * sub_ + y) * sub_ + x)];
          l.push_back(uint32_t(i));
          longest = std::max(longest, l.size());
        }
  }
  if (longest > kMaxSubList)
    throw InputError(name_, "tileSpheres", "the tile's spheres crowd its sub-cells beyond " + std::to_string(kMaxSubList));
  subStart_.assign(1, 0);
  subList_.clear();
  for (const auto& l : lists) {
    subList_.insert(subList_.end(), l.begin(), l.end());
    subStart_.push_back(uint32_t(subList_.size()));
  }
}

Aggregate::TileSphere Aggregate::imageOf(int id, const int shift[3]) const {
  const Vec3& c = tile_.centers[id];
  // The sum in float, the product in double: the listed centres' own rounding.
  const double p[3] = {c.x + shift[0], c.y + shift[1], c.z + shift[2]};
  TileSphere ts;
  ts.center = Vec3(float(p[0] * L_), float(p[1] * L_), float(p[2] * L_));
  for (int a = 0; a < 3; ++a) ts.home[a] = int8_t(shift[a]);
  ts.id = id;
  ts.radius = R_ * tile_.size(id);
  return ts;
}

CellClass Aggregate::cellClass(int64_t i, int64_t j, int64_t k) const {
  if (i < 0 || j < 0 || k < 0 || i >= n_[0] || j >= n_[1] || k >= n_[2] || classes_.empty()) return CellClass::Outside;
  return classes_[size_t((k * n_[1] + j) * n_[0] + i)];
}

bool Aggregate::insideBoundary(const Vec3& p) const {
  if (!traceable(p, kInsideProbeDir, 0.0f, kInf)) return false;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh = makeRayHit(p, kInsideProbeDir, 0.0f, kInf);
  rtcIntersect1(boundaryBvh_.get(), &ctx, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  return dot(triangleNormal(boundary_, rh.hit.primID), kInsideProbeDir) > 0;
}

bool Aggregate::intersectBoundary(const Vec3& o, const Vec3& d, float tmin, float tmax, float& t, Vec3& ng) const {
  if (!traceable(o, d, tmin, tmax)) return false;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh = makeRayHit(o, d, tmin, tmax);
  rtcIntersect1(boundaryBvh_.get(), &ctx, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  t = rh.ray.tfar;
  ng = triangleNormal(boundary_, rh.hit.primID);
  return true;
}

float Aggregate::closestBoundaryPoint(const Vec3& p, Vec3& closest) const {
  RTCPointQuery q;
  q.x = p.x; q.y = p.y; q.z = p.z;
  q.time = 0;
  q.radius = kInf;
  RTCPointQueryContext ctx;
  rtcInitPointQueryContext(&ctx);
  ClosestQuery cq{&boundary_, p};
  rtcPointQuery(boundaryBvh_.get(), &q, &ctx, closestPointCallback, &cq);
  closest = cq.closest;
  return length(closest - p);
}

bool Aggregate::sphereIsInside(const int64_t home[3], const Vec3& worldCenter,
                               DistanceField::NearestProbe& probe) const {
  switch (cellClass(home[0], home[1], home[2])) {
    case CellClass::Inside: return true;
    case CellClass::Outside: return false;
    case CellClass::Partial: break;
  }
  // Far enough from the surface, the field's sign is certain (the nearest voxel's value
  // is within 0.87 voxel of the field there); near it, cast a ray.
  float d = probe(worldCenter);
  if (std::fabs(d) > 2.0f * sdf_.voxelSize()) return d < 0;
  return insideBoundary(worldCenter);
}

namespace {

// A 3-D DDA (Amanatides & Woo 1987) over a grid of n cells of edge `size` from `origin`,
// for a ray of direction d entering at t0 at point p: the current cell, and per axis the t
// of the next crossing and the t between crossings.
// The cell of a grid of n cells of edge `size` from `origin` that holds p along axis a
// (clamped into the grid).
int64_t cellIndex(const Vec3& p, int a, const Vec3& origin, float size, const int64_t n[3]) {
  return std::min<int64_t>(std::max<int64_t>(int64_t(std::floor((p[a] - origin[a]) / size)), 0), n[a] - 1);
}

struct GridWalk {
  int64_t cell[3], step[3];
  float tNext[3], tDelta[3];
  GridWalk(const Vec3& p, float t0, const Vec3& d, const Vec3& invD, const Vec3& origin, float size,
           const int64_t n[3]) {
    for (int a = 0; a < 3; ++a) {
      cell[a] = cellIndex(p, a, origin, size, n);
      if (d[a] > 0) {
        step[a] = 1;
        tNext[a] = t0 + (origin[a] + float(cell[a] + 1) * size - p[a]) * invD[a];
        tDelta[a] = size * invD[a];
      } else if (d[a] < 0) {
        step[a] = -1;
        tNext[a] = t0 + (origin[a] + float(cell[a]) * size - p[a]) * invD[a];
        tDelta[a] = -size * invD[a];
      } else {
        step[a] = 0;
        tNext[a] = kInf;
        tDelta[a] = kInf;
      }
    }
  }
  // The axis of the next crossing.
  int axis() const { return tNext[0] < tNext[1] ? (tNext[0] < tNext[2] ? 0 : 2) : (tNext[1] < tNext[2] ? 1 : 2); }
  // Into the next cell along `axis`; false when that leaves the grid.
  bool advance(int axis, const int64_t n[3]) {
    cell[axis] += step[axis];
    if (cell[axis] < 0 || cell[axis] >= n[axis]) return false;
    tNext[axis] += tDelta[axis];
    return true;
  }
};

}  // namespace

bool Aggregate::intersect(const Vec3& o, const Vec3& d, float tmin, float tmax, GrainHit& hit, const GrainHit* from,
                          bool inside) const {
  // A non-finite ray (a numerical failure upstream) hits nothing: the cell walk below
  // would convert NaN to an integer (undefined behaviour; found by the USD fuzzer).
  if (!isFinite(o) || !isFinite(d) || standIn_) return false;
  if (from && inside && traceFromInside(*from, o, d, tmin, tmax, hit)) return true;
  const Vec3 invD(1.0f / d.x, 1.0f / d.y, 1.0f / d.z);
  float t0, t1;
  if (!bounds_.intersect(o, invD, tmin, tmax, t0, t1)) return false;
  const GrainHit* skip =
      from && !inside && prototypes_[size_t(from->prototype)].hullFace[from->prim] ? from : nullptr;
  RayWalk r{o, d, invD, tmin, tmax, hit, skip, false, DistanceField::NearestProbe(sdf_)};
  return walk(r, t0, t1);
}

bool Aggregate::occluded(const Vec3& o, const Vec3& d, float tmin, float tmax) const {
  if (!isFinite(o) || !isFinite(d)) return false;
  if (standIn_) {  // no grains: the boundary blocks, as a dense packing would
    float t;
    Vec3 ng;
    return intersectBoundary(o, d, tmin, tmax, t, ng) || insideBoundary(o);
  }
  const Vec3 invD(1.0f / d.x, 1.0f / d.y, 1.0f / d.z);
  float t0, t1;
  if (!bounds_.intersect(o, invD, tmin, tmax, t0, t1)) return false;
  GrainHit hit;
  RayWalk r{o, d, invD, tmin, tmax, hit, nullptr, true, DistanceField::NearestProbe(sdf_)};
  return walk(r, t0, t1);
}

Vec3 Aggregate::sphereCenter(const int64_t home[3], int id) const {
  return origin_ + Vec3(float(home[0]), float(home[1]), float(home[2])) * L_ + tile_.centers[size_t(id)] * L_;
}

void Aggregate::neighbourHome(const int64_t cell[3], uint32_t k, int64_t home[3]) const {
  for (int a = 0; a < 3; ++a) home[a] = cell[a] + nbShift_[3 * size_t(k) + size_t(a)];
}

void Aggregate::prepareProxies() const {
  std::call_once(nbOnce_, [this] { buildNeighbours(); });
}

void Aggregate::buildNeighbours() const {
  // Every sphere centre within the reach (with its image's offset: the reach stays under
  // the tile's edge, so offsets of -1..1 cells find them), nearest first by how soon a ray
  // could enter it (centre distance less radius); found through a periodic grid of
  // buckets at least one reach wide.
  nbStart_.assign(1, 0);
  const float maxReach = Rmax_ * (2.0f + kNeighbourReach);
  if (maxReach < L_) {
    const int G = std::max(1, std::min(64, int(L_ / maxReach)));  // buckets per tile edge
    std::vector<std::vector<int>> buckets(size_t(G) * G * G);
    auto bucketOf = [&](const Vec3& c, int a) { return std::clamp(int(c[a] * float(G)), 0, G - 1); };
    for (int j = 0; j < tile_.numSpheres; ++j) {
      const Vec3& c = tile_.centers[size_t(j)];
      buckets[size_t((bucketOf(c, 2) * G + bucketOf(c, 1)) * G + bucketOf(c, 0))].push_back(j);
    }
    struct Entry { float key; Vec3 q; float r2; int id; int8_t shift[3]; };
    std::vector<Entry> found;
    for (int i = 0; i < tile_.numSpheres; ++i) {
      const Vec3& ui = tile_.centers[size_t(i)];
      const Vec3 ci = ui * L_;
      const float reach = R_ * tile_.size(i) + kNeighbourReach * Rmax_ + Rmax_;
      nbReach_.push_back(reach - Rmax_);  // a sphere met within this of ci is listed whole
      found.clear();
      const int b0[3] = {bucketOf(ui, 0), bucketOf(ui, 1), bucketOf(ui, 2)};
      std::vector<int> seen;  // with fewer than 3 buckets a side, neighbouring ones repeat
      for (int bz = -1; bz <= 1; ++bz)
        for (int by = -1; by <= 1; ++by)
          for (int bx = -1; bx <= 1; ++bx) {
            const int idx[3] = {((b0[0] + bx) % G + G) % G, ((b0[1] + by) % G + G) % G, ((b0[2] + bz) % G + G) % G};
            const int key = (idx[2] * G + idx[1]) * G + idx[0];
            if (std::find(seen.begin(), seen.end(), key) != seen.end()) continue;
            seen.push_back(key);
            for (int j : buckets[size_t(key)])
              for (int dz = -1; dz <= 1; ++dz)
                for (int dy = -1; dy <= 1; ++dy)
                  for (int dx = -1; dx <= 1; ++dx) {
                    if (j == i && dx == 0 && dy == 0 && dz == 0) continue;
                    const Vec3 q = (tile_.centers[size_t(j)] + Vec3(float(dx), float(dy), float(dz))) * L_ - ci;
                    if (length2(q) > reach * reach) continue;
                    const float rj = R_ * tile_.size(j);
                    found.push_back({std::sqrt(length2(q)) - rj, q, rj * rj, j, {int8_t(dx), int8_t(dy), int8_t(dz)}});
                  }
          }
      if (found.size() > kMaxNeighbours) {  // crowded: no lists, the walk answers
        nbStart_.assign(1, 0);
        for (auto* v : {&nbX_, &nbY_, &nbZ_, &nbR2_, &nbKey_, &nbReach_}) v->clear();
        nbId_.clear();
        nbShift_.clear();
        return;
      }
      std::sort(found.begin(), found.end(), [](const Entry& a, const Entry& b) {
        return a.key < b.key || (a.key == b.key && a.id < b.id);
      });
      for (const Entry& e : found) {
        nbX_.push_back(e.q.x);
        nbY_.push_back(e.q.y);
        nbZ_.push_back(e.q.z);
        nbR2_.push_back(e.r2);
        nbKey_.push_back(e.key);
        nbId_.push_back(e.id);
        for (int8_t v : e.shift) nbShift_.push_back(v);
      }
      nbStart_.push_back(uint32_t(nbId_.size()));
    }
    // Padding for the last list's block (nearestNeighbour reads whole blocks): never met.
    for (uint32_t k = 0; k < kNeighbourBlock; ++k) {
      for (auto* v : {&nbX_, &nbY_, &nbZ_, &nbKey_}) v->push_back(0.0f);
      nbR2_.push_back(-1.0f);
    }
  }

}

namespace {
// Listed spheres k … k + 3 (centres X, Y, Z; squared radii R2) against a ray at offset oc
// from the list's sphere, direction d, from tmin: the lanes whose sphere the ray enters
// before `below` (bit l: sphere k + l), side by side and without branches (a ray's meeting
// a neighbour is a coin toss to the branch predictor). When some are, entry[l] holds where
// the ray enters sphere k + l (kInf: it does not) and w2[l] the squared distance of the line
// from its centre. Lanes past the list read the next list or padding: the caller masks them.
static_assert(Aggregate::kNeighbourBlock == 4, "a block: one SSE register");
int neighbourBlock(const float* X, const float* Y, const float* Z, const float* R2, uint32_t k, const Vec3& oc,
                   const Vec3& d, float tmin, float below, float entry[4], float w2[4]) {
#if defined(__SSE2__)
  const __m128 zero = _mm_setzero_ps(), vtmin = _mm_set1_ps(tmin);
  const __m128 ox = _mm_sub_ps(_mm_set1_ps(oc.x), _mm_loadu_ps(X + k));
  const __m128 oy = _mm_sub_ps(_mm_set1_ps(oc.y), _mm_loadu_ps(Y + k));
  const __m128 oz = _mm_sub_ps(_mm_set1_ps(oc.z), _mm_loadu_ps(Z + k));
  const __m128 b = _mm_add_ps(_mm_add_ps(_mm_mul_ps(ox, _mm_set1_ps(d.x)), _mm_mul_ps(oy, _mm_set1_ps(d.y))),
                              _mm_mul_ps(oz, _mm_set1_ps(d.z)));
  const __m128 o2 = _mm_add_ps(_mm_add_ps(_mm_mul_ps(ox, ox), _mm_mul_ps(oy, oy)), _mm_mul_ps(oz, oz));
  const __m128 lw2 = _mm_max_ps(_mm_sub_ps(o2, _mm_mul_ps(b, b)), zero);
  const __m128 disc = _mm_sub_ps(_mm_loadu_ps(R2 + k), lw2);
  const __m128 sq = _mm_sqrt_ps(_mm_max_ps(disc, zero));
  const __m128 met = _mm_and_ps(_mm_cmpge_ps(disc, zero), _mm_cmpge_ps(_mm_sub_ps(sq, b), vtmin));
  const __m128 te = _mm_or_ps(_mm_and_ps(met, _mm_max_ps(_mm_sub_ps(_mm_sub_ps(zero, b), sq), vtmin)),
                              _mm_andnot_ps(met, _mm_set1_ps(kInf)));
  const int lanes = _mm_movemask_ps(_mm_cmplt_ps(te, _mm_set1_ps(below)));
  if (lanes != 0) {
    _mm_storeu_ps(entry, te);
    _mm_storeu_ps(w2, lw2);
  }
  return lanes;
#else
  int lanes = 0;
  for (uint32_t l = 0; l < 4; ++l) {
    const float ox = oc.x - X[k + l], oy = oc.y - Y[k + l], oz = oc.z - Z[k + l];
    const float b = ox * d.x + oy * d.y + oz * d.z;
    w2[l] = std::max(ox * ox + oy * oy + oz * oz - b * b, 0.0f);
    const float disc = R2[k + l] - w2[l];
    const float sq = std::sqrt(std::max(disc, 0.0f));
    entry[l] = disc >= 0 && sq - b >= tmin ? std::max(-b - sq, tmin) : kInf;
    if (entry[l] < below) lanes |= 1 << l;
  }
  return lanes;
#endif
}
}  // namespace

bool Aggregate::nearestNeighbour(const Vec3& o, const Vec3& d, float tmin, float tmax, GrainHit& hit,
                                 const GrainHit& from) const {
  if (nbReach_.empty() || from.sphere < 0) return false;
  const int i = from.sphere;
  const Vec3 ci = sphereCenter(from.cell, i);
  const Vec3 oc = o - ci;
  const float r0 = std::sqrt(length2(oc));
  // Along the ray, every sphere met before `bound` is listed (within the reach of ci).
  const float bound = std::min(tmax, nbReach_[size_t(i)] - r0);
  const uint32_t k0 = nbStart_[size_t(i)], k1 = nbStart_[size_t(i) + 1];
  DistanceField::NearestProbe probe(sdf_);
  // Listed spheres found centred outside the boundary; beyond a few, the walk answers.
  constexpr int kMaxOutside = 8;
  uint32_t outside[kMaxOutside];
  int nOutside = 0;
  for (;;) {
    float best = bound;
    uint32_t bestK = k1;
    // Nearest first: sphere k cannot be entered before nbKey_[k] − r0, so the scan ends
    // once that passes the best entry so far; a block of kNeighbourBlock at a time, one
    // test for the block (most hold no sphere nearer than the best so far).
    const float *X = nbX_.data(), *Y = nbY_.data(), *Z = nbZ_.data(), *R2 = nbR2_.data();
    for (uint32_t kb = k0; kb < k1 && nbKey_[kb] - r0 < best; kb += kNeighbourBlock) {
      float te[kNeighbourBlock], w2[kNeighbourBlock];
      int lanes = neighbourBlock(X, Y, Z, R2, kb, oc, d, tmin, best, te, w2);
      lanes &= (1 << std::min(kNeighbourBlock, k1 - kb)) - 1;  // past k1: the next list, or padding
      for (; lanes != 0; lanes &= lanes - 1) {
        const uint32_t l = uint32_t(__builtin_ctz(unsigned(lanes)));
        // Spheres found outside the boundary before are passed over (rare: near the boundary).
        if (te[l] < best && (nOutside == 0 || std::find(outside, outside + nOutside, kb + l) == outside + nOutside)) {
          best = te[l];
          bestK = kb + l;
        }
      }
    }
    if (bestK == k1) return false;  // nothing listed is met within the bound: the walk decides
    const int j = nbId_[bestK];
    int64_t home[3];
    neighbourHome(from.cell, bestK, home);
    const Vec3 c = sphereCenter(home, j);
    if (!sphereIsInside(home, c, probe)) {  // rare: near the boundary
      if (nOutside == kMaxOutside) return false;
      outside[nOutside++] = bestK;
      continue;
    }
    hit.t = best;
    hit.prototype = selector_.prototype(home[0], home[1], home[2], j, tile_.sizeClass(j));
    for (int a = 0; a < 3; ++a) hit.cell[a] = home[a];
    hit.sphere = j;
    hit.radius = R_ * tile_.size(j);
    hit.center = c;
    hit.ng = normalize(o + d * best - c);
    return true;
  }
}

bool Aggregate::intersectProxy(const Vec3& o, const Vec3& d, float tmin, float tmax, GrainHit& hit,
                               const GrainHit* skip) const {
  if (!isFinite(o) || !isFinite(d) || standIn_) return false;
  if (skip && nearestNeighbour(o, d, tmin, tmax, hit, *skip)) return true;
  const Vec3 invD(1.0f / d.x, 1.0f / d.y, 1.0f / d.z);
  float t0, t1;
  if (!bounds_.intersect(o, invD, tmin, tmax, t0, t1)) return false;
  RayWalk r{o, d, invD, tmin, tmax, hit, skip, false, DistanceField::NearestProbe(sdf_)};
  r.mode = WalkMode::NearestProxy;
  return walk(r, t0, t1);
}

GrainFlight Aggregate::flightToGrain(Vec3 o, const Vec3& d, const ProxyTables& tables, const GrainHit* from,
                                     Rng& rng) const {
  GrainFlight f;
  GrainHit h, left;
  if (from) left = *from;
  float flown = 0;
  for (int crossed = 0; crossed < kMaxProxyCrossings; ++crossed) {
    ++f.steps;
    if (!intersectProxy(o, d, 0.0f, kInf, h, from ? &left : nullptr)) return f;
    const ProxyTable& table = tables.at(h.prototype, h.radius / grainRadius());
    const Vec3 entry = o + d * h.t;
    if (rng.next1D() < table.hitProbability(table.bBin(ProxyFrame(d, (entry - h.center) / h.radius).b))) {
      f.t = flown + h.t;
      f.entry = entry;
      f.grain = h;
      return f;
    }
    const float advance = std::max(sphereFarSide(o - h.center, d, h.radius), h.t);  // crossed: on from its far side
    o = o + d * advance;
    flown += advance;
    left = h;
    from = &left;
  }
  return f;
}

ProxyShadow Aggregate::proxyTransmittance(const Vec3& o, const Vec3& d, float tmin, float tmax,
                                          const ProxyTables& tables, const GrainHit* skip, uint64_t seed) const {
  if (!isFinite(o) || !isFinite(d) || standIn_) return ProxyShadow();
  const Vec3 invD(1.0f / d.x, 1.0f / d.y, 1.0f / d.z);
  float t0, t1;
  if (!bounds_.intersect(o, invD, tmin, tmax, t0, t1)) return ProxyShadow();
  GrainHit hit;
  RayWalk r{o, d, invD, tmin, tmax, hit, skip, false, DistanceField::NearestProbe(sdf_)};
  r.mode = WalkMode::ProxyTransmittance;
  r.tables = &tables;
  r.seed = seed;
  if (skip && skip->sphere >= 0 && !nbReach_.empty()) {
    // The spheres met first are the one left's neighbours: every sphere met before tDone
    // is listed. The walk then counts only spheres entered from tDone on.
    const int i = skip->sphere;
    const Vec3 ci = sphereCenter(skip->cell, i);
    const Vec3 oc = o - ci;
    const float r0 = std::sqrt(length2(oc));
    const float tDone = std::min(tmax, nbReach_[size_t(i)] - r0);
    const uint32_t k0 = nbStart_[size_t(i)], k1 = nbStart_[size_t(i) + 1];
    // Which listed spheres the ray crosses before tDone, a block at a time as in
    // nearestNeighbour(); then each crossed one's chance of letting the light cross, in order.
    const float *X = nbX_.data(), *Y = nbY_.data(), *Z = nbZ_.data(), *R2 = nbR2_.data(), *K = nbKey_.data();
    for (uint32_t kb = k0; kb < k1 && K[kb] - r0 < tDone; kb += kNeighbourBlock) {
      float te[kNeighbourBlock], w2[kNeighbourBlock];
      int crossed = neighbourBlock(X, Y, Z, R2, kb, oc, d, tmin, tDone, te, w2);
      crossed &= (1 << std::min(kNeighbourBlock, k1 - kb)) - 1;  // past k1: the next list, or padding
      for (; crossed != 0; crossed &= crossed - 1) {
        const uint32_t l = uint32_t(__builtin_ctz(unsigned(crossed))), k = kb + l;
        if (K[k] - r0 >= tDone) break;  // sorted: the rest of the list is beyond tDone too
        const int j = nbId_[k];
        int64_t home[3];
        neighbourHome(skip->cell, k, home);
        if (!sphereIsInside(home, sphereCenter(home, j), r.probe)) continue;
        const ProxyTable& t =
            tables.at(selector_.prototype(home[0], home[1], home[2], j, tile_.sizeClass(j)), tile_.size(j));
        r.transmittance *= t.shadow(t.bBin(std::sqrt(w2[l] / R2[k])));
      }
    }
    if (!proxyRoulette(r.transmittance, r.seed, r.draws)) return r.transmittance;
    if (tDone >= tmax) return r.transmittance;
    r.tEnterMin = tDone;
  }
  walk(r, t0, t1);
  return r.transmittance;
}

bool Aggregate::visitProxy(RayWalk& r, const TileSphere& s, const int64_t cell[3], const Vec3& oc, float tEntry,
                           bool knownInside) const {
  const int64_t home[3] = {cell[0] + s.home[0], cell[1] + s.home[1], cell[2] + s.home[2]};
  const GrainHit* skip = r.skip;
  if (skip && skip->sphere == s.id && skip->cell[0] == home[0] && skip->cell[1] == home[1] && skip->cell[2] == home[2])
    return false;
  const uint64_t id = hashInts(uint64_t(home[0]), uint64_t(home[1]), uint64_t(home[2]), uint64_t(s.id));
  if (r.mode == WalkMode::ProxyTransmittance) {
    for (int i = 0; i < r.nRecent; ++i)
      if (r.recent[i] == id) return false;
  }
  // The centre as traceGrain computes it: every cell listing the sphere decides alike.
  const Vec3 worldCenter = sphereCenter(home, s.id);
  if (!knownInside && !sphereIsInside(home, worldCenter, r.probe)) return false;
  const int prototype = selector_.prototype(home[0], home[1], home[2], s.id, tile_.sizeClass(s.id));
  if (r.mode == WalkMode::NearestProxy) {
    GrainHit& h = r.hit;
    h.t = tEntry;
    h.prototype = prototype;
    for (int a = 0; a < 3; ++a) h.cell[a] = home[a];
    h.sphere = s.id;
    h.radius = s.radius;
    h.center = worldCenter;
    h.ng = normalize(oc + r.d * tEntry);
    return true;
  }
  const float along = dot(oc, r.d);
  const Vec3 w = oc - r.d * along;  // the ray's offset from the centre
  const float w2 = length2(w);
  // Counted already (the neighbours of the sphere left): entered before tEnterMin.
  if (-along - std::sqrt(std::max(0.0f, s.radius * s.radius - w2)) < r.tEnterMin) return false;
  r.recent[r.cursor++ & 7] = id;
  r.nRecent = std::min(r.nRecent + 1, 8);
  const ProxyTable& t = r.tables->at(prototype, tile_.size(s.id));
  r.transmittance *= t.shadow(t.bBin(std::sqrt(w2) / s.radius));
  return !proxyRoulette(r.transmittance, r.seed, r.draws);  // true ends the walk
}

bool Aggregate::walk(RayWalk& r, float t0, float t1) const {
  GridWalk w(r.o + r.d * t0, t0, r.d, r.invD, origin_, L_, n_);
  float tEnter = t0;
  for (;;) {
    const int axis = w.axis();
    const float tExit = std::min(w.tNext[axis], t1);
    const CellClass c = cellClass(w.cell[0], w.cell[1], w.cell[2]);
    float resume = -kInf;  // where a partial cell's walk found the ray may jump to
    if (c != CellClass::Outside && walkCell(r, w.cell, c == CellClass::Partial, tEnter, tExit, resume)) return true;
    if (tExit >= t1) return r.found;
    if (resume > tExit + 1e-3f * L_) {
      // Nothing to meet before `resume`: restart the walk there (past rounding's reach
      // of this cell's exit, so it never lands back in this cell).
      if (resume >= t1 || (r.found && resume >= r.best)) return r.found;
      w = GridWalk(r.o + r.d * resume, resume, r.d, r.invD, origin_, L_, n_);
      tEnter = resume;
      continue;
    }
    tEnter = w.tNext[axis];
    if (!w.advance(axis, n_)) return r.found;
  }
}

bool Aggregate::walkCell(RayWalk& r, const int64_t cell[3], bool partial, float tEnter, float tExit,
                         float& resume) const {
  // 3-D DDA over the cell's sub-cells from tEnter to tExit, front to back. A sphere is
  // traced in the sub-cell where the ray enters it (its entry t within the sub-cell's
  // span, padded against rounding: at worst traced twice, never missed).
  const Vec3& d = r.d;
  const float tmin = r.tmin;
  const int64_t M = sub_, nSub[3] = {M, M, M};
  const float Ls = L_ / float(M), pad = 1e-4f * Ls;
  // The entry t and the sub-cells' spans are each a few ulps of t off (they are computed
  // from different origins): pads of 1e-5 t (~80 ulps) on top of 1e-4 of a sub-cell.
  constexpr float kRelPad = 1e-5f;
  const Vec3 cellOrigin = origin_ + Vec3(float(cell[0]), float(cell[1]), float(cell[2])) * L_;
  const Vec3 oCell = r.o - cellOrigin;
  GridWalk w(oCell + d * tEnter, tEnter, d, r.invD, Vec3(0.0f), Ls, nSub);
  float sEnter = tEnter;
  // In a partial cell, one distance per sub-cell decides for all its spheres where it
  // can: the centres of the spheres that overlap it lie within its half diagonal plus R
  // of its centre, whose distance the nearest voxel gives within 0.87 voxel. Further
  // outside than that: no sphere centred inside (skip the sub-cell); further inside than
  // that and sphereIsInside's 2 voxels: every one inside (no test per sphere).
  const float skipBeyond = 0.8661f * Ls + Rmax_ + sdf_.voxelSize(), sureWithin = -(skipBeyond + 2.0f * sdf_.voxelSize());
  for (;;) {
    const int axis = w.axis();
    const float sExit = std::min(w.tNext[axis], tExit);
    const int64_t* sc = w.cell;
    const float dSub =
        partial ? r.probe(cellOrigin + Vec3(sc[0] + 0.5f, sc[1] + 0.5f, sc[2] + 0.5f) * Ls) : -kInf;
    if (dSub <= skipBeyond) {
      const size_t sub = size_t((sc[2] * M + sc[1]) * M + sc[0]);
      const float lo = sEnter - pad - kRelPad * std::fabs(sEnter), hi = sExit + pad + kRelPad * std::fabs(sExit);
      // Ray–sphere by the closest approach (b² − c would cancel catastrophically for a
      // sphere far along the ray): disc = R² − |oc − b d|². First for the whole list,
      // branch-free (a loop the compiler vectorises): the entry t of each sphere the ray
      // enters here before `best`, else +inf. Then those spheres, in list order (a rare,
      // well-predicted branch: about one sphere is entered per sub-cell).
      const uint32_t k0 = subStart_[sub], n = subStart_[sub + 1] - k0;
      float entry[kMaxSubList];
      const float bestHere = r.best;
      for (uint32_t i = 0; i < n; ++i) {
        const float ox = oCell.x - subX_[k0 + i], oy = oCell.y - subY_[k0 + i], oz = oCell.z - subZ_[k0 + i];
        const float b = ox * d.x + oy * d.y + oz * d.z;
        const float wx = ox - d.x * b, wy = oy - d.y * b, wz = oz - d.z * b;
        const float disc = subR2_[k0 + i] - (wx * wx + wy * wy + wz * wz);
        const float sq = std::sqrt(std::max(disc, 0.0f));
        const float te = std::max(-b - sq, tmin);
        const bool enters = (disc >= 0) & (-b + sq >= tmin) & (te < bestHere) & (te >= lo) & (te < hi);
        entry[i] = enters ? te : kInf;
      }
      for (uint32_t i = 0; i < n; ++i) {
        if (!(entry[i] < r.best)) continue;
        const TileSphere& s = spheres_[subList_[k0 + i]];
        if (r.mode != WalkMode::Grains) {
          if (visitProxy(r, s, cell, oCell - s.center, entry[i], dSub < sureWithin)) {
            r.best = entry[i];
            r.found = true;
          }
          continue;
        }
        if (traceGrain(s, cell, oCell - s.center, d, tmin, r.best, dSub < sureWithin, r.hit, r.skip, r.probe)) {
          r.best = r.hit.t;
          r.found = true;
          if (r.anyHit) return true;
        }
      }
      // Spheres not traced yet enter at t >= hi: none can be nearer.
      if (r.found && r.best <= hi) return true;
    } else {
      // Outside by dSub: along the ray, no point is within Rmax of the boundary's inside
      // before sEnter + dSub − skipBeyond (the field is 1-Lipschitz; the sub-cell's point
      // at sEnter lies within its half diagonal of the probe): no sphere centred inside
      // is entered there. Jump (sphere tracing), within the cell or beyond it.
      const float jumpTo = sEnter + (dSub - skipBeyond) - pad - kRelPad * std::fabs(sEnter);
      if (jumpTo >= tExit) {
        resume = jumpTo;
        return false;
      }
      if (jumpTo > sExit) {
        w = GridWalk(oCell + d * jumpTo, jumpTo, d, r.invD, Vec3(0.0f), Ls, nSub);
        sEnter = jumpTo;
        continue;
      }
    }
    if (sExit >= tExit) return false;
    sEnter = w.tNext[axis];
    if (!w.advance(axis, nSub)) return false;
  }
}

bool Aggregate::traceFromInside(const GrainHit& g, const Vec3& o, const Vec3& d, float tmin, float tmax,
                                GrainHit& hit) const {
  // The cell the walk starts in (intersect(): the origin is within the bounds, so the
  // walk starts at tmin), and the grain's image listed there.
  const Vec3 p = o + d * tmin;
  if (!bounds_.contains(p)) return false;
  int64_t cell[3];
  int shift[3];
  for (int a = 0; a < 3; ++a) {
    cell[a] = cellIndex(p, a, origin_, L_, n_);  // as GridWalk finds it
    const int64_t s = g.cell[a] - cell[a];
    if (s < -1 || s > 1) return false;
    shift[a] = int(s);
  }
  const TileSphere s = imageOf(g.sphere, shift);
  const Vec3 oCell = o - (origin_ + Vec3(float(cell[0]), float(cell[1]), float(cell[2])) * L_);
  GrainChoice choice;
  choice.prototype = g.prototype;
  choice.rotation = g.rotation;
  return traceChosen(s, g.cell, choice, oCell - s.center, d, tmin, tmax, hit);
}

void Aggregate::forEachGrain(const Bounds3& box, const std::function<void(const GrainInstance&)>& fn) const {
  if (standIn_) return;  // no cells
  int64_t lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::max<int64_t>(0, int64_t(std::floor((box.lo[a] - Rmax_ - origin_[a]) / L_)));
    hi[a] = std::min<int64_t>(n_[a] - 1, int64_t(std::floor((box.hi[a] + Rmax_ - origin_[a]) / L_)));
  }
  DistanceField::NearestProbe probe(sdf_);
  for (int64_t k = lo[2]; k <= hi[2]; ++k)
    for (int64_t j = lo[1]; j <= hi[1]; ++j)
      for (int64_t i = lo[0]; i <= hi[0]; ++i) {
        if (cellClass(i, j, k) == CellClass::Outside) continue;
        int64_t home[3] = {i, j, k};
        for (int s = 0; s < tile_.numSpheres; ++s) {
          const Vec3 c = sphereCenter(home, s);
          if (!sphereIsInside(home, c, probe)) continue;
          GrainChoice g = selector_.choose(i, j, k, s, tile_.sizeClass(s));
          fn(GrainInstance{c, R_ * tile_.size(s), g.prototype, g.rotation, {i, j, k}, s});
        }
      }
}

}  // namespace granular
