#include "distance_field.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cstring>
#include <future>
#include <istream>
#include <limits>
#include <list>
#include <mutex>
#include <optional>
#include <ostream>
#include <streambuf>
#include <vector>

#include <openvdb/io/Stream.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/MeshToVolume.h>
#include <openvdb/tools/SignedFloodFill.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "cache.h"

namespace granular {

namespace {
std::atomic<uint64_t> nextFieldId{1};

void initialiseOpenVdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

// An input stream over bytes held elsewhere (a mapped cache entry): no copy.
struct ByteSource : std::streambuf {
  ByteSource(const char* data, size_t size) {
    char* p = const_cast<char*>(data);
    setg(p, p, p + size);
  }
  pos_type seekoff(off_type off, std::ios_base::seekdir dir, std::ios_base::openmode) override {
    const off_type base = dir == std::ios_base::beg ? 0 : dir == std::ios_base::cur ? gptr() - eback() : egptr() - eback();
    return seekpos(pos_type(base + off), std::ios_base::in);
  }
  pos_type seekpos(pos_type pos, std::ios_base::openmode) override {
    if (pos < 0 || pos > egptr() - eback()) return pos_type(off_type(-1));
    setg(eback(), eback() + off_type(pos), egptr());
    return pos;
  }
};
}  // namespace

struct DistanceField::Impl {
  openvdb::FloatGrid::Ptr grid;
  uint64_t id = 0;  // unique per grid: tells a thread's cached accessor which tree it reads

  // The level set of a mesh in index space (points already divided by the voxel size).
  static std::shared_ptr<const Impl> meshToLevelSet(const TriangleMesh& local, float voxelSize, float halfWidth);
  // meshToLevelSet() once per local mesh, voxel size and band among the fields alive.
  static std::shared_ptr<const Impl> shared(const TriangleMesh& local, float voxelSize, float halfWidth);
};

DistanceField::DistanceField() = default;
DistanceField::~DistanceField() = default;
DistanceField::DistanceField(DistanceField&&) noexcept = default;
DistanceField& DistanceField::operator=(DistanceField&&) noexcept = default;

std::shared_ptr<const DistanceField::Impl> DistanceField::Impl::meshToLevelSet(const TriangleMesh& local,
                                                                               float voxelSize, float halfWidth) {
  initialiseOpenVdb();
  // The grid lives in index space (voxel size 1) and the mesh is handed over divided by
  // the voxel size: OpenVDB refuses linear transforms whose determinant is ~0 (voxels
  // below about 1e-5, i.e. scenes in tiny units), and distances scale back exactly.
  openvdb::math::Transform::Ptr xform = openvdb::math::Transform::createLinearTransform(1.0);
  const double inv = 1.0 / double(voxelSize);
  std::vector<openvdb::Vec3s> pts;
  pts.reserve(local.points.size());
  for (const Vec3& p : local.points) pts.emplace_back(float(p.x * inv), float(p.y * inv), float(p.z * inv));
  std::vector<openvdb::Vec3I> tris;
  tris.reserve(local.numTriangles());
  for (size_t i = 0; i < local.numTriangles(); ++i)
    tris.emplace_back(local.indices[3 * i], local.indices[3 * i + 1], local.indices[3 * i + 2]);
  auto impl = std::make_shared<Impl>();
  // Isolated: a thread waiting in its parallel loops takes no other task of the arena (a
  // build that would wait for this very grid, shared()).
  tbb::this_task_arena::isolate(
      [&] { impl->grid = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*xform, pts, tris, halfWidth); });
  impl->grid->setName("boundary_sdf");
  impl->id = nextFieldId++;
  return impl;
}

namespace {

// The grids of anchored fields by local mesh, voxel size and band (a process's builds,
// side by side or one after another): held weakly, so a grid lives as long as a field
// that reads it; an entry being built carries the future its waiters take it from.
struct SharedGrid {
  uint64_t hash;
  std::vector<Vec3> points;
  std::vector<uint32_t> indices;
  float voxelSize, halfWidth;
  std::weak_ptr<const void> built;
  std::shared_future<std::shared_ptr<const void>> building;  // valid while under way
  bool same(const TriangleMesh& m, float v, float h) const {
    return std::memcmp(&voxelSize, &v, sizeof v) == 0 && std::memcmp(&halfWidth, &h, sizeof h) == 0 &&
           points.size() == m.points.size() && indices == m.indices &&
           std::memcmp(points.data(), m.points.data(), points.size() * sizeof(Vec3)) == 0;
  }
};
std::mutex sharedMutex;
std::list<SharedGrid> sharedGrids;

}  // namespace

std::shared_ptr<const DistanceField::Impl> DistanceField::Impl::shared(const TriangleMesh& local, float voxelSize,
                                                                       float halfWidth) {
  uint64_t h = hashValue(hashInts(0x5344465348ULL /* "SDFSH" */, local.points.size(), local.indices.size()), voxelSize);
  h = hashValue(h, halfWidth);
  for (const Vec3& p : local.points) {
    const float xyz[3] = {p.x, p.y, p.z};
    h = hashBytes(h, xyz, sizeof xyz);
  }
  h = hashBytes(h, local.indices.data(), local.indices.size() * sizeof(uint32_t));
  std::promise<std::shared_ptr<const void>> promise;
  std::list<SharedGrid>::iterator mine;
  {
    std::unique_lock<std::mutex> lock(sharedMutex);
    for (auto it = sharedGrids.begin(); it != sharedGrids.end();) {
      if (!it->building.valid() && it->built.expired()) {  // no field reads it any more
        it = sharedGrids.erase(it);
        continue;
      }
      if (it->hash == h && it->same(local, voxelSize, halfWidth)) {
        if (auto grid = it->built.lock()) return std::static_pointer_cast<const Impl>(grid);
        std::shared_future<std::shared_ptr<const void>> wait = it->building;
        lock.unlock();
        return std::static_pointer_cast<const Impl>(wait.get());  // another build's error is ours too
      }
      ++it;
    }
    mine = sharedGrids.insert(sharedGrids.end(), SharedGrid{h, local.points, local.indices, voxelSize, halfWidth, {},
                                                            promise.get_future().share()});
  }
  std::shared_ptr<const Impl> impl;
  try {
    impl = meshToLevelSet(local, voxelSize, halfWidth);
  } catch (...) {
    {
      std::lock_guard<std::mutex> lock(sharedMutex);
      sharedGrids.erase(mine);
    }
    promise.set_exception(std::current_exception());
    throw;
  }
  {
    std::lock_guard<std::mutex> lock(sharedMutex);
    mine->built = impl;
    mine->building = {};
  }
  promise.set_value(impl);
  return impl;
}

void DistanceField::adopt(std::shared_ptr<const Impl> impl, float voxelSize, float bandWidth, const Vec3d& anchor) {
  impl_ = std::move(impl);
  voxel_ = voxelSize;
  invVoxel_ = 1.0 / double(voxel_);
  band_ = bandWidth;
  anchor_ = anchor;
}

void DistanceField::build(const TriangleMesh& mesh, float voxelSize, float minBand) {
  buildAnchored(mesh, Vec3d{}, voxelSize, minBand);
}

void DistanceField::buildAnchored(const TriangleMesh& local, const Vec3d& anchor, float voxelSize, float minBand) {
  const float halfWidth = bandVoxels(voxelSize, minBand);
  adopt(Impl::meshToLevelSet(local, voxelSize, halfWidth), voxelSize, halfWidth * voxelSize, anchor);
}

void DistanceField::buildShared(const TriangleMesh& local, const Vec3d& anchor, float voxelSize, float minBand) {
  const float halfWidth = bandVoxels(voxelSize, minBand);
  adopt(Impl::shared(local, voxelSize, halfWidth), voxelSize, halfWidth * voxelSize, anchor);
}

void DistanceField::buildBox(const Bounds3& box, float voxelSize, float minBand) {
  using Leaf = openvdb::FloatTree::LeafNodeType;
  initialiseOpenVdb();
  // Index space, the corners rounded as build() rounds a mesh's points.
  const double inv = 1.0 / double(voxelSize);
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = double(float(box.lo[a] * inv));
    hi[a] = double(float(box.hi[a] * inv));
  }
  const float halfWidth = bandVoxels(voxelSize, minBand);
  const double band = halfWidth;
  openvdb::FloatGrid::Ptr grid = openvdb::FloatGrid::create(halfWidth);
  grid->setTransform(openvdb::math::Transform::createLinearTransform(1.0));
  grid->setGridClass(openvdb::GRID_LEVEL_SET);
  // The leaves (blocks of 8³ voxels) that reach into the band: not wholly deeper than the
  // band inside the box, nor a band or more outside it.
  const int dim = int(Leaf::DIM);
  int first[3], last[3];
  for (int a = 0; a < 3; ++a) {
    first[a] = int(std::floor((lo[a] - band) / dim)) * dim;
    last[a] = int(std::floor((hi[a] + band) / dim)) * dim;
  }
  std::vector<openvdb::Coord> origins;
  for (int z = first[2]; z <= last[2]; z += dim)
    for (int y = first[1]; y <= last[1]; y += dim)
      for (int x = first[0]; x <= last[0]; x += dim) {
        const int o[3] = {x, y, z};
        double outside2 = 0;
        bool deep = true;
        for (int a = 0; a < 3; ++a) {
          const double b0 = o[a], b1 = o[a] + dim - 1;  // the block's voxel centres
          const double e = std::max({lo[a] - b1, 0.0, b0 - hi[a]});
          outside2 += e * e;
          deep = deep && b0 - lo[a] >= band && hi[a] - b1 >= band;
        }
        if (!deep && outside2 < band * band) origins.emplace_back(x, y, z);
      }
  openvdb::FloatTree& tree = grid->tree();
  std::vector<Leaf*> leaves(origins.size());
  for (size_t n = 0; n < origins.size(); ++n) leaves[n] = tree.touchLeaf(origins[n]);
  tbb::parallel_for(size_t(0), leaves.size(), [&](size_t n) {
    Leaf& leaf = *leaves[n];
    const openvdb::Coord o = leaf.origin();
    // Outside: the distance to the nearest point of the box; inside: to the nearest face.
    // Each axis's part depends on the voxel's coordinate on that axis alone: the squared
    // distance beyond the box's slab and the depth within it, for the leaf's 8 positions.
    double beyond2[3][Leaf::DIM], within[3][Leaf::DIM];
    for (int a = 0; a < 3; ++a)
      for (openvdb::Index t = 0; t < Leaf::DIM; ++t) {
        const double p = double(o[a] + int(t));
        const double e = std::max({lo[a] - p, 0.0, p - hi[a]});
        beyond2[a][t] = e * e;
        within[a][t] = std::min(p - lo[a], hi[a] - p);
      }
    // Written straight into the new leaf (all its voxels inactive at the background).
    float* values = leaf.buffer().data();
    auto& active = leaf.getValueMask();
    for (openvdb::Index i = 0; i < Leaf::SIZE; ++i) {
      const openvdb::Index x = i >> (2 * Leaf::LOG2DIM), y = (i >> Leaf::LOG2DIM) & (Leaf::DIM - 1),
                           z = i & (Leaf::DIM - 1);  // Leaf::offsetToLocalCoord
      double outside2 = 0;
      outside2 += beyond2[0][x];
      outside2 += beyond2[1][y];
      outside2 += beyond2[2][z];
      const double d = outside2 > 0 ? std::sqrt(outside2) : -std::min({within[0][x], within[1][y], within[2][z]});
      if (d >= band) values[i] = halfWidth;
      else if (d <= -band) values[i] = -halfWidth;
      else {
        values[i] = float(d);
        active.setOn(i);
      }
    }
  });
  // The tiles between the leaves take the inside's or the outside's value.
  openvdb::tools::signedFloodFill(tree);
  grid->setName("boundary_sdf");
  auto impl = std::make_shared<Impl>();
  impl->grid = grid;
  impl->id = nextFieldId++;
  adopt(std::move(impl), voxelSize, halfWidth * voxelSize, Vec3d{});
}

bool DistanceField::isAxisAlignedBox(const TriangleMesh& mesh, Bounds3& box) {
  if (mesh.numTriangles() != 12 || mesh.points.empty()) return false;
  box = mesh.bounds();
  for (int a = 0; a < 3; ++a)
    if (!(box.hi[a] > box.lo[a])) return false;
  for (const Vec3& p : mesh.points)
    for (int a = 0; a < 3; ++a)
      if (p[a] != box.lo[a] && p[a] != box.hi[a]) return false;
  // Each triangle three corners of one face; a face two triangles that leave out opposite
  // corners (they meet on a diagonal and cover it). With every point a corner, that is the
  // box's surface. A corner's id: bit a set where it lies on the box's high side of axis a.
  std::array<int, 6> perFace{}, leftOut{};
  for (size_t t = 0; t < mesh.numTriangles(); ++t) {
    int id[3];
    for (int k = 0; k < 3; ++k) {
      const Vec3& p = mesh.points[mesh.indices[3 * t + size_t(k)]];
      id[k] = int(p.x == box.hi.x) | int(p.y == box.hi.y) << 1 | int(p.z == box.hi.z) << 2;
    }
    if (id[0] == id[1] || id[1] == id[2] || id[0] == id[2]) return false;
    int face = -1;
    for (int a = 0; a < 3 && face < 0; ++a) {
      const int bit = 1 << a;
      if ((id[0] & bit) == (id[1] & bit) && (id[1] & bit) == (id[2] & bit)) face = 2 * a + ((id[0] & bit) ? 1 : 0);
    }
    if (face < 0 || perFace[size_t(face)] == 2) return false;
    // The face's fourth corner: its four ids XOR to 0 (each in-plane bit set twice).
    leftOut[size_t(face)] ^= (perFace[size_t(face)]++ ? 0 : 8) | (id[0] ^ id[1] ^ id[2]);
  }
  for (int f = 0; f < 6; ++f) {
    const int a = f / 2, inPlane = 7 & ~(1 << a);
    // 8 | o1, then XOR o2: 8 | (o1 ^ o2), opposite corners when o1 ^ o2 is both in-plane bits.
    if (perFace[size_t(f)] != 2 || leftOut[size_t(f)] != (8 | inPlane)) return false;
  }
  return true;
}

float DistanceField::bandVoxels(float voxelSize, float minBand) {
  return std::max(3.0f, std::ceil(minBand / voxelSize) + 1.0f);
}

double DistanceField::estimateBytes(double area, float voxelSize, float minBand) {
  using Tree = openvdb::FloatTree;
  using Leaf = Tree::LeafNodeType;
  using Lower = Tree::RootNodeType::ChildNodeType::ChildNodeType;  // blocks of 128³ voxels
  using Upper = Tree::RootNodeType::ChildNodeType;                  // blocks of 4096³ voxels
  const double edge = double(Leaf::DIM) * voxelSize, lowerEdge = double(Lower::DIM) * voxelSize;
  const double layers = 2.0 * bandVoxels(voxelSize, minBand) / double(Leaf::DIM) + 1.0;
  const double leaves = area / (edge * edge) * layers, lowers = 2.0 * area / (lowerEdge * lowerEdge) + 8.0;
  // The upper nodes: up to eight where the mesh straddles its anchor's octants.
  return leaves * double(sizeof(Leaf) + Leaf::SIZE * sizeof(float)) + lowers * double(sizeof(Lower)) +
         8.0 * double(sizeof(Upper));
}

bool DistanceField::empty() const { return !impl_ || !impl_->grid; }

void DistanceField::write(std::ostream& out) const {
  openvdb::io::Stream stream(out);
  // Uncompressed but for the active masks: a load copies, it does not inflate. No
  // statistics metadata, so that the grid read back is the one built.
  stream.setCompression(openvdb::io::COMPRESS_ACTIVE_MASK);
  stream.setGridStatsMetadataEnabled(false);
  openvdb::GridCPtrVec grids{impl_->grid};
  stream.write(grids);
}

bool DistanceField::read(const char* data, size_t size, float voxelSize, float bandWidth, const Vec3d& anchor) {
  initialiseOpenVdb();
  impl_.reset();
  std::shared_ptr<Impl> impl;
  try {
    ByteSource source(data, size);
    std::istream is(&source);
    openvdb::io::Stream stream(is, /*delayLoad=*/false);
    openvdb::GridPtrVecPtr grids = stream.getGrids();
    if (!grids || grids->size() != 1) return false;
    openvdb::FloatGrid::Ptr grid = openvdb::gridPtrCast<openvdb::FloatGrid>((*grids)[0]);
    if (!grid || grid->getName() != "boundary_sdf" || !grid->transform().isIdentity()) return false;
    impl = std::make_shared<Impl>();
    impl->grid = grid;
    impl->id = nextFieldId++;
  } catch (const std::exception&) {
    return false;
  }
  adopt(std::move(impl), voxelSize, bandWidth, anchor);
  return true;
}

namespace {

// This thread's accessor of `grid`, kept between queries so that its node cache pays off
// (rays query nearby points); rebuilt when the thread turns to another field (ids are
// unique per build, so a cached accessor never reads a freed tree). Unregistered
// ("unsafe"): a registered accessor locks the tree's accessor table when made and
// destroyed, which cost a sixth of a render; the tree never changes after build().
const openvdb::FloatGrid::ConstUnsafeAccessor& threadAccessor(const openvdb::FloatGrid& grid, uint64_t id) {
  thread_local uint64_t cachedId = 0;
  thread_local std::optional<openvdb::FloatGrid::ConstUnsafeAccessor> accessor;
  if (cachedId != id) {
    accessor.emplace(grid.getConstUnsafeAccessor());
    cachedId = id;
  }
  return *accessor;
}

}  // namespace

float DistanceField::distance(const Vec3& p) const {
  // The grid is in index space (build()): index = (world − anchor) / voxel, distance =
  // value * voxel.
  const double inv = 1.0 / double(voxel_);
  openvdb::Vec3d ijk((p.x - anchor_.x) * inv, (p.y - anchor_.y) * inv, (p.z - anchor_.z) * inv);
  float value = 0;
  openvdb::tools::BoxSampler::sample(threadAccessor(*impl_->grid, impl_->id), ijk, value);  // trilinear
  return value * voxel_;
}

void DistanceField::distances(const Vec3* p, size_t n, float* out) const {
  using Leaf = openvdb::FloatTree::LeafNodeType;
  if (n == 0) return;
  bool row = true;
  for (size_t m = 1; m < n && row; ++m) row = p[m].y == p[0].y && p[m].z == p[0].z;
  if (!row) {
    for (size_t m = 0; m < n; ++m) out[m] = distance(p[m]);
    return;
  }
  const auto& acc = threadAccessor(*impl_->grid, impl_->id);
  const double inv = 1.0 / double(voxel_);
  // The stencils' corners and weights as BoxSampler::sample (distance()) computes them;
  // along a row only x moves, so the four voxel lines the stencils read (y and y + 1,
  // z and z + 1) are copied once, a leaf at a time, and interpolated as BoxSampler does.
  const double y = (p[0].y - anchor_.y) * inv, z = (p[0].z - anchor_.z) * inv;
  const int iy = int(std::floor(y)), iz = int(std::floor(z));
  int lo = std::numeric_limits<int>::max(), hi = std::numeric_limits<int>::min();
  for (size_t m = 0; m < n; ++m) {
    const int ix = int(std::floor((p[m].x - anchor_.x) * inv));
    lo = std::min(lo, ix);
    hi = std::max(hi, ix);
  }
  const size_t len = size_t(int64_t(hi) - lo + 2);
  if (len > 4 * n + 64) {  // sparse along the row: copying the lines would cost more
    for (size_t m = 0; m < n; ++m) out[m] = distance(p[m]);
    return;
  }
  thread_local std::vector<float> lines;
  lines.resize(4 * len);
  for (int b = 0; b < 2; ++b)
    for (int c = 0; c < 2; ++c) {
      float* line = lines.data() + (b * 2 + c) * len;
      for (int64_t x = lo; x <= int64_t(hi) + 1;) {
        const openvdb::Coord v(int(x), iy + b, iz + c);
        const int64_t end = std::min<int64_t>(int64_t(hi) + 1, (x & ~int64_t(Leaf::DIM - 1)) + Leaf::DIM - 1);
        if (const Leaf* leaf = acc.probeConstLeaf(v)) {
          const float* values = leaf->buffer().data();
          for (int64_t k = x; k <= end; ++k) line[k - lo] = values[Leaf::coordToOffset(v.offsetBy(int(k - x), 0, 0))];
        } else {
          const float tile = acc.getValue(v);  // no leaf: the whole block holds the tile's value
          for (int64_t k = x; k <= end; ++k) line[k - lo] = tile;
        }
        x = end + 1;
      }
    }
  // BoxSampler's trilinear interpolation lerps in z, then y, then x (a + (b − a) w, the
  // difference in float, its product in double). Along a row the y and z weights are the
  // same for every point, so each voxel column's first six lerps are made once, in that
  // order and arithmetic (the loop vectorises), and a point lerps its two columns in x:
  // BoxSampler's value bit for bit.
  const auto lerp = [](float a, float b, double w) { return a + float(double(b - a) * w); };
  const double wy = y - double(iy), wz = z - double(iz);
  thread_local std::vector<float> columns;
  columns.resize(len);
  const float *l00 = lines.data(), *l01 = l00 + len, *l10 = l01 + len, *l11 = l10 + len;
  float* col = columns.data();
  for (size_t x = 0; x < len; ++x) col[x] = lerp(lerp(l00[x], l01[x], wz), lerp(l10[x], l11[x], wz), wy);
  for (size_t m = 0; m < n; ++m) {
    const double xi = (p[m].x - anchor_.x) * inv;
    const int ix = int(std::floor(xi));
    const size_t i = size_t(ix - lo);
    out[m] = lerp(col[i], col[i + 1], xi - double(ix)) * voxel_;
  }
}

float DistanceField::voxelValue(const int ijk[3], const void*& accessor) const {
  if (!accessor) accessor = &threadAccessor(*impl_->grid, impl_->id);
  return static_cast<const openvdb::FloatGrid::ConstUnsafeAccessor*>(accessor)->getValue(
             openvdb::Coord(ijk[0], ijk[1], ijk[2])) *
         voxel_;
}

size_t DistanceField::memoryBytes() const { return impl_ && impl_->grid ? impl_->grid->memUsage() : 0; }

const void* DistanceField::grid() const { return impl_ ? impl_->grid.get() : nullptr; }

}  // namespace granular
