#include "distance_field.h"

#include <atomic>
#include <istream>
#include <mutex>
#include <optional>
#include <ostream>
#include <streambuf>

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

float DistanceField::voxelValue(const int ijk[3], const void*& accessor) const {
  if (!accessor) accessor = &threadAccessor(*impl_->grid, impl_->id);
  return static_cast<const openvdb::FloatGrid::ConstUnsafeAccessor*>(accessor)->getValue(
             openvdb::Coord(ijk[0], ijk[1], ijk[2])) *
         voxel_;
}

size_t DistanceField::memoryBytes() const { return impl_ && impl_->grid ? impl_->grid->memUsage() : 0; }

const void* DistanceField::grid() const { return impl_ ? impl_->grid.get() : nullptr; }

}  // namespace granular
