// distance_field.h — a narrow-band signed distance field of a closed mesh (OpenVDB).
//
// Contract: built once per boundary mesh with OpenVDB's mesh-to-level-set; distance()
// is negative inside, positive outside, accurate to about one voxel within the band
// and clamped to ±bandWidth() beyond it (with the correct sign). Used to classify
// tile cells (outside / partial / inside), for the distance to the boundary (the
// VPT→DA switch) and for coarse-density export. Thread-safe for queries. write() and
// read() carry a built field through the aggregate build cache (build_cache.h) exactly:
// the same voxels, tiles and values, so every query answers alike.
// A field may be anchored: its voxel lattice sits on anchor() (world = local + anchor),
// so that meshes equal but for a translation have the same voxels and values, and such
// fields share one grid (buildShared()) while any of them lives.
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
  // The field of `local` placed at `anchor` (world = local + anchor), its lattice anchored
  // there: build() of the translated mesh but for the rounding of the translation (the
  // values are those of `local` at the same voxels, whatever the anchor). The grid is the
  // one of a field of the same local mesh (bit for bit: points, triangles), voxel size and
  // band that is alive in this process, or being built by another thread (waited for);
  // else built here and offered to the next. Congruent boundaries (a mesh instanced by
  // translations) thus build it once.
  void buildShared(const TriangleMesh& local, const Vec3d& anchor, float voxelSize, float minBand);
  // As buildShared(), but always builds its own grid (the reference the shared one equals).
  void buildAnchored(const TriangleMesh& local, const Vec3d& anchor, float voxelSize, float minBand);
  // build()'s band in voxels (a whole number, at least 3): bandWidth() is it times the voxel size.
  static float bandVoxels(float voxelSize, float minBand);
  // About what build() of a mesh of this surface area takes in memory: the leaves (blocks
  // of 8³ voxels) that tile the band on both sides of the surface, and the tree's nodes
  // above them.
  static double estimateBytes(double area, float voxelSize, float minBand);
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
  // The grid written by write(), with the voxel size, band and anchor the build had: false
  // (and the field left empty) when the bytes are not such a grid.
  bool read(const char* data, size_t size, float voxelSize, float bandWidth, const Vec3d& anchor = Vec3d{});
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
    explicit NearestProbe(const DistanceField& field) : field_(field), inv_(field.invVoxel_), at_(field.anchor_) {}
    float operator()(const Vec3& p) {
      const int ijk[3] = {int(std::floor((p.x - at_.x) * inv_ + 0.5)), int(std::floor((p.y - at_.y) * inv_ + 0.5)),
                          int(std::floor((p.z - at_.z) * inv_ + 0.5))};
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
    Vec3d at_;
    const void* accessor_ = nullptr;
    int last_[3] = {0, 0, 0};
    bool valid_ = false;
    float value_ = 0;
  };
  float voxelSize() const { return voxel_; }
  float bandWidth() const { return band_; }
  // Where the lattice sits: index = (world − anchor) / voxel. Zero but for anchored fields.
  const Vec3d& anchor() const { return anchor_; }
  size_t memoryBytes() const;             // the grid's, shared or not
  const void* grid() const;             // the openvdb::FloatGrid, in voxel units (index space)

 private:
  struct Impl;
  // The distance at voxel ijk through this thread's accessor (found on first use).
  float voxelValue(const int ijk[3], const void*& accessor) const;
  // Sets the field to `impl`'s grid with its voxel size, band and anchor.
  void adopt(std::shared_ptr<const Impl> impl, float voxelSize, float bandWidth, const Vec3d& anchor);
  std::shared_ptr<const Impl> impl_;  // shared by anchored fields of one local mesh
  float voxel_ = 0, band_ = 0;
  double invVoxel_ = 0;  // 1 / voxel_ (NearestProbe)
  Vec3d anchor_;
};

}  // namespace granular
