// usd_mesh.h — a UsdGeomMesh on plain arrays, for both USD front ends: its polygons as
// triangles, and any primvar at the triangles' corners by its interpolation.
//
// Faces are fanned from their first vertex; faces listed in holeIndices are left out; a
// leftHanded mesh's triangles are wound the other way, so that every mesh reaches core
// counter-clockwise seen from outside (UsdGeomMesh's orientation).
#pragma once

#include <string>
#include <vector>

#include "mesh.h"
#include "usd_values.h"

namespace granular {

struct UsdMeshRecord {
  std::string path;
  std::vector<Vec3> points;
  std::vector<int> faceVertexCounts, faceVertexIndices, holeIndices;
  std::string orientation = "rightHanded";
};

// The triangles, in the mesh's own space. InputError naming path.points (none),
// .faceVertexCounts (none, or fewer than 3 vertices), .faceVertexIndices, .holeIndices or
// .orientation on bad topology.
TriangleMesh meshFromUsd(const UsdMeshRecord& mesh);

// How many elements a primvar of this interpolation has on the mesh (constant 1, uniform
// one per face, vertex and varying one per point, faceVarying one per face-vertex); 0 for
// an interpolation UsdGeom does not define.
size_t usdPrimvarElements(const UsdMeshRecord& mesh, const std::string& interpolation);

// A primvar's values (primvar.numbers: `width` numbers per element, flattened as
// authored) at every corner of meshFromUsd's triangles, in their order: constant (one
// element), uniform (one per face), vertex and varying (one per point), faceVarying (one
// per face-vertex). InputError on <primvar.source or mesh.path>.<attribute> when the count
// does not fit the interpolation or a value is not finite.
std::vector<float> usdPrimvarAtCorners(const UsdMeshRecord& mesh, const UsdValue& primvar, int width,
                                       const std::string& attribute);

}  // namespace granular
