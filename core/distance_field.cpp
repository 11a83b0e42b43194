#include "distance_field.h"

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
