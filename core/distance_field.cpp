#include "distance_field.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <istream>
#include <limits>
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
  uint64_t id = 0;  // unique per build: tells a thread's cached accessor which tree it reads
};

DistanceField::DistanceField() = default;
DistanceField::~DistanceField() = default;
DistanceField::DistanceField(DistanceField&&) noexcept = default;
DistanceField& DistanceField::operator=(DistanceField&&) noexcept = default;

void DistanceField::build(const TriangleMesh& mesh, float voxelSize, float minBand) {
  initialiseOpenVdb();
  // The grid lives in index space (voxel size 1) and the mesh is handed over divided by
  // the voxel size: OpenVDB refuses linear transforms whose determinant is ~0 (voxels
  // below about 1e-5, i.e. scenes in tiny units), and distances scale back exactly.
  openvdb::math::Transform::Ptr xform = openvdb::math::Transform::createLinearTransform(1.0);
  const double inv = 1.0 / double(voxelSize);
  std::vector<openvdb::Vec3s> pts;
  pts.reserve(mesh.points.size());
  for (const Vec3& p : mesh.points) pts.emplace_back(float(p.x * inv), float(p.y * inv), float(p.z * inv));
  std::vector<openvdb::Vec3I> tris;
  tris.reserve(mesh.numTriangles());
  for (size_t i = 0; i < mesh.numTriangles(); ++i)
    tris.emplace_back(mesh.indices[3 * i], mesh.indices[3 * i + 1], mesh.indices[3 * i + 2]);
  const float halfWidthVoxels = bandVoxels(voxelSize, minBand);
  impl_ = std::make_unique<Impl>();
  impl_->grid = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*xform, pts, tris, halfWidthVoxels);
  impl_->grid->setName("boundary_sdf");
  impl_->id = nextFieldId++;
  voxel_ = voxelSize;
  invVoxel_ = 1.0 / double(voxel_);
  band_ = halfWidthVoxels * voxelSize;
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
    for (openvdb::Index i = 0; i < Leaf::SIZE; ++i) {
      const openvdb::Coord c = o + Leaf::offsetToLocalCoord(i);
      const double p[3] = {double(c.x()), double(c.y()), double(c.z())};
      // Outside: the distance to the nearest point of the box; inside: to the nearest face.
      double outside2 = 0, depth = std::numeric_limits<double>::infinity();
      for (int a = 0; a < 3; ++a) {
        const double e = std::max({lo[a] - p[a], 0.0, p[a] - hi[a]});
        outside2 += e * e;
        depth = std::min({depth, p[a] - lo[a], hi[a] - p[a]});
      }
      const double d = outside2 > 0 ? std::sqrt(outside2) : -depth;
      if (d >= band) leaf.setValueOff(i, halfWidth);
      else if (d <= -band) leaf.setValueOff(i, -halfWidth);
      else leaf.setValueOn(i, float(d));
    }
  });
  // The tiles between the leaves take the inside's or the outside's value.
  openvdb::tools::signedFloodFill(tree);
  grid->setName("boundary_sdf");
  impl_ = std::make_unique<Impl>();
  impl_->grid = grid;
  impl_->id = nextFieldId++;
  voxel_ = voxelSize;
  invVoxel_ = 1.0 / double(voxel_);
  band_ = halfWidth * voxelSize;
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

bool DistanceField::read(const char* data, size_t size, float voxelSize, float bandWidth) {
  initialiseOpenVdb();
  impl_.reset();
  try {
    ByteSource source(data, size);
    std::istream is(&source);
    openvdb::io::Stream stream(is, /*delayLoad=*/false);
    openvdb::GridPtrVecPtr grids = stream.getGrids();
    if (!grids || grids->size() != 1) return false;
    openvdb::FloatGrid::Ptr grid = openvdb::gridPtrCast<openvdb::FloatGrid>((*grids)[0]);
    if (!grid || grid->getName() != "boundary_sdf" || !grid->transform().isIdentity()) return false;
    impl_ = std::make_unique<Impl>();
    impl_->grid = grid;
    impl_->id = nextFieldId++;
  } catch (const std::exception&) {
    return false;
  }
  voxel_ = voxelSize;
  invVoxel_ = 1.0 / double(voxel_);
  band_ = bandWidth;
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
  // The grid is in index space (build()): index = world / voxel, distance = value * voxel.
  const double inv = 1.0 / double(voxel_);
  openvdb::Vec3d ijk(p.x * inv, p.y * inv, p.z * inv);
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
  // z and z + 1) are copied once, a leaf at a time, and BoxSampler interpolates.
  const double y = p[0].y * inv, z = p[0].z * inv;
  const int iy = int(std::floor(y)), iz = int(std::floor(z));
  int lo = std::numeric_limits<int>::max(), hi = std::numeric_limits<int>::min();
  for (size_t m = 0; m < n; ++m) {
    const int ix = int(std::floor(p[m].x * inv));
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
  for (size_t m = 0; m < n; ++m) {
    const openvdb::Vec3d xyz(p[m].x * inv, y, z);
    const openvdb::Vec3i idx(int(std::floor(xyz[0])), iy, iz);
    const openvdb::Vec3d uvw = xyz - idx;
    const size_t i = size_t(idx[0] - lo);
    float data[2][2][2];
    bool uniform = true;
    for (int a = 0; a < 2; ++a)
      for (int b = 0; b < 2; ++b)
        for (int c = 0; c < 2; ++c) {
          data[a][b][c] = lines[(b * 2 + c) * len + i + a];
          uniform &= data[a][b][c] == data[0][0][0];
        }
    // Eight equal values (deep inside, far outside): each lerp a + (a − a) w returns a
    // exactly (but for a = −0, which it turns into +0).
    if (uniform && data[0][0][0] != 0) out[m] = data[0][0][0] * voxel_;
    else out[m] = openvdb::tools::BoxSampler::trilinearInterpolation(data, uvw) * voxel_;
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
