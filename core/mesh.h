// mesh.h — indexed triangle meshes and the checks a boundary or grain mesh must pass.
//
// Contract: TriangleMesh is plain data (points, triangle indices). validateClosed()
// throws InputError naming `object` when the mesh has non-finite points, out-of-range
// indices, degenerate triangles (all of them), open or non-manifold edges, or
// inconsistent winding — everything that makes inside/outside meaningless.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "math.h"

namespace granular {

struct TriangleMesh {
  std::vector<Vec3> points;
  std::vector<uint32_t> indices;  // 3 per triangle
  // Texture coordinates (USD's st), 2 per triangle corner (uvs[2 i], uvs[2 i + 1] for
  // indices[i]), or empty: per corner, so that face-varying seams need no split vertices.
  std::vector<float> uvs;

  size_t numTriangles() const { return indices.size() / 3; }
  Bounds3 bounds() const;
  // Signed volume (positive for outward-facing, counter-clockwise winding).
  double signedVolume() const;
  double area() const;
  TriangleMesh transformed(const Transform& xf) const;
  // Flips the winding of every triangle (and its corners' uvs).
  void flip();
  bool hasUvs() const { return !uvs.empty(); }
};

// Basic checks every mesh needs: finite points, indices in range, at least one triangle.
void validateMesh(const TriangleMesh& mesh, const std::string& object, const std::string& attribute = "points");

// validateMesh plus: closed, 2-manifold with consistent orientation, non-zero volume.
// If the volume is negative the caller may flip() the mesh; returns the signed volume.
double validateClosed(const TriangleMesh& mesh, const std::string& object);

// Polygon soup (face vertex counts + indices, as USD stores them) to triangles by fans.
TriangleMesh triangulate(const std::vector<Vec3>& points, const std::vector<int>& faceVertexCounts,
                         const std::vector<int>& faceVertexIndices, const std::string& object);

// The face-vertex index (into faceVertexIndices, or a face-varying primvar) of each
// corner of the triangles triangulate() makes from these counts, in its order: front ends
// expand any primvar to TriangleMesh::uvs with it (vertex: faceVertexIndices[c];
// faceVarying: c). The counts must be valid (triangulate checks them).
std::vector<uint32_t> triangulatedCorners(const std::vector<int>& faceVertexCounts);

}  // namespace granular
