// distance_field.h — a narrow-band signed distance field of a closed mesh (OpenVDB).
//
// Contract: built once per boundary mesh with OpenVDB's mesh-to-level-set; distance()
// is negative inside, positive outside, accurate to about one voxel within the band
// and clamped to ±bandWidth() beyond it (with the correct sign). Used to classify
// tile cells (outside / partial / inside), for the distance to the boundary (the
// VPT→DA switch) and for coarse-density export. Thread-safe for queries.
#pragma once

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
  bool empty() const;
  float distance(const Vec3& p) const;  // trilinear
  // The value at the voxel centre nearest p: within √3/2 voxel of distance(p)'s field
  // (1-Lipschitz), an eighth of its cost; for sign tests with a margin.
  float nearestDistance(const Vec3& p) const;
  Vec3 gradient(const Vec3& p) const;   // central differences, unit length where defined
  float voxelSize() const { return voxel_; }
  float bandWidth() const { return band_; }
  size_t memoryBytes() const;
  const void* grid() const;             // the openvdb::FloatGrid, in voxel units (index space)

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  float voxel_ = 0, band_ = 0;
};

}  // namespace granular
