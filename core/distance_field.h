// distance_field.h — a narrow-band signed distance field of a closed mesh (OpenVDB).
//
// Contract: built once per boundary mesh with OpenVDB's mesh-to-level-set; distance()
// is negative inside, positive outside, accurate to about one voxel within the band
// and clamped to ±bandWidth() beyond it (with the correct sign). Used to classify
// tile cells (outside / partial / inside), for the distance to the boundary (the
// VPT→DA switch) and for coarse-density export. Thread-safe for queries. write() and
// read() carry a built field through the aggregate build cache (build_cache.h) exactly:
// the same voxels, tiles and values, so every query answers alike.
#pragma once

#include <cmath>
#include <cstddef>
#include <iosfwd>
#include <memory>

#include "math.h"
#include "mesh.h"

namespace granular {

class DistanceField {
 public:
  DistanceField();
  ~DistanceField();
  DistanceField(DistanceField&&) noexcept;
  DistanceField& operator=(DistanceField&&) noexcept;

  // mesh in world space, closed; the band reaches at least minBand on each side.
  void build(const TriangleMesh& mesh, float voxelSize, float minBand);
  // build()'s band in voxels (a whole number, at least 3): bandWidth() is it times the voxel size.
  static float bandVoxels(float voxelSize, float minBand);
  // The field of an axis-aligned box, its exact distance written straight into the grid:
  // the layout build() gives the box's mesh (index space, the same band, ±band beyond it),
  // at a few nanoseconds a voxel instead of mesh-to-level-set's search of the triangles.
  // Not bit for bit build()'s: OpenVDB's renormalisation and its final offset by its
  // tolerance move every value by up to about 1e-6 voxel (more near edges and corners).
  void buildBox(const Bounds3& box, float voxelSize, float minBand);
  // True (and the box) when a closed mesh is exactly an axis-aligned box: every point a
  // corner of its bounds, two triangles on each of the six faces, covering it.
  static bool isAxisAlignedBox(const TriangleMesh& mesh, Bounds3& box);
  bool empty() const;
  // The grid in OpenVDB's stream format (uncompressed but for the active masks).
  void write(std::ostream& out) const;
  // The grid written by write(), with the voxel size and band the build had: false (and
  // the field left empty) when the bytes are not such a grid.
  bool read(const char* data, size_t size, float voxelSize, float bandWidth);
  float distance(const Vec3& p) const;  // trilinear
  // distance() of each of n points into out, bit for bit. Made for a row of cell centres
  // (points that share y and z), whose stencils read four lines of voxels: those are
  // copied once, a leaf at a time, instead of eight tree lookups per point.
  void distances(const Vec3* p, size_t n, float* out) const;
  // The value at the voxel centre nearest p: within √3/2 voxel of distance(p)'s field
  // (1-Lipschitz), an eighth of its cost; for sign tests with a margin. Made for many
  // probes in a row by one thread (a ray's walk through its cells): the thread's accessor
  // is found once and the last voxel's value kept (neighbouring sub-cells mostly share a
  // voxel).
  class NearestProbe {
   public:
    explicit NearestProbe(const DistanceField& field) : field_(field), inv_(field.invVoxel_) {}
    float operator()(const Vec3& p) {
      const int ijk[3] = {int(std::floor(p.x * inv_ + 0.5)), int(std::floor(p.y * inv_ + 0.5)),
                          int(std::floor(p.z * inv_ + 0.5))};
      if (!valid_ || ijk[0] != last_[0] || ijk[1] != last_[1] || ijk[2] != last_[2]) {
        value_ = field_.voxelValue(ijk, accessor_);
        last_[0] = ijk[0]; last_[1] = ijk[1]; last_[2] = ijk[2];
        valid_ = true;
      }
      return value_;
    }

   private:
    const DistanceField& field_;
    double inv_;
    const void* accessor_ = nullptr;
    int last_[3] = {0, 0, 0};
    bool valid_ = false;
    float value_ = 0;
  };
  float voxelSize() const { return voxel_; }
  float bandWidth() const { return band_; }
  size_t memoryBytes() const;
  const void* grid() const;             // the openvdb::FloatGrid, in voxel units (index space)

 private:
  struct Impl;
  // The distance at voxel ijk through this thread's accessor (found on first use).
  float voxelValue(const int ijk[3], const void*& accessor) const;
  std::unique_ptr<Impl> impl_;
  float voxel_ = 0, band_ = 0;
  double invVoxel_ = 0;  // 1 / voxel_ (NearestProbe)
};

}  // namespace granular
