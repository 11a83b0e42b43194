// usd_mesh.cpp — a UsdGeomMesh on plain arrays (usd_mesh.h).
#include "usd_mesh.h"

#include <cmath>

#include "error.h"

namespace granular {

namespace {

// meshFromUsd's triangles as face-vertex indices (three per triangle, wound as core
// wants them) and the face of each.
struct Corners {
  std::vector<uint32_t> faceVertex;
  std::vector<uint32_t> face;
};

Corners cornersOf(const UsdMeshRecord& r) {
  if (r.orientation != "rightHanded" && r.orientation != "leftHanded")
    throw InputError(r.path, "orientation", str("\"", r.orientation, "\" is not rightHanded or leftHanded"));
  std::vector<bool> hole(r.faceVertexCounts.size(), false);
  for (int h : r.holeIndices) {
    if (h < 0 || size_t(h) >= hole.size())
      throw InputError(r.path, "holeIndices", str(h, " is not a face index [0, ", hole.size(), ")"));
    hole[size_t(h)] = true;
  }
  const bool flip = r.orientation == "leftHanded";
  Corners c;
  uint32_t base = 0;
  for (size_t f = 0; f < r.faceVertexCounts.size(); ++f) {
    const int n = r.faceVertexCounts[f];
    for (int k = 1; k + 1 < n && !hole[f]; ++k) {
      c.faceVertex.push_back(base);
      c.faceVertex.push_back(base + uint32_t(flip ? k + 1 : k));
      c.faceVertex.push_back(base + uint32_t(flip ? k : k + 1));
      c.face.push_back(uint32_t(f));
    }
    base += uint32_t(std::max(n, 0));
  }
  return c;
}

}  // namespace

TriangleMesh meshFromUsd(const UsdMeshRecord& r) {
  if (r.points.empty()) throw InputError(r.path, "points", "has no points");
  if (r.faceVertexCounts.empty()) throw InputError(r.path, "faceVertexCounts", "has no faces");
  // triangulate() checks the counts and indices, naming them.
  TriangleMesh checked = triangulate(r.points, r.faceVertexCounts, r.faceVertexIndices, r.path);
  const Corners c = cornersOf(r);
  TriangleMesh m;
  m.points = std::move(checked.points);
  m.indices.reserve(c.faceVertex.size());
  for (uint32_t fv : c.faceVertex) m.indices.push_back(uint32_t(r.faceVertexIndices[fv]));
  return m;
}

size_t usdPrimvarElements(const UsdMeshRecord& r, const std::string& interp) {
  if (interp == "constant") return 1;
  if (interp == "uniform") return r.faceVertexCounts.size();
  if (interp == "vertex" || interp == "varying") return r.points.size();
  if (interp == "faceVarying") return r.faceVertexIndices.size();
  return 0;
}

std::vector<float> usdPrimvarAtCorners(const UsdMeshRecord& r, const UsdValue& primvar, int width,
                                       const std::string& attribute) {
  const std::string& where = primvar.source.empty() ? r.path : primvar.source;
  const size_t elements = width > 0 ? primvar.numbers.size() / size_t(width) : 0;
  if (width <= 0 || primvar.numbers.size() % size_t(width) != 0)
    throw InputError(where, attribute, str("has ", primvar.numbers.size(), " numbers, not a multiple of ", width));
  for (double v : primvar.numbers)
    if (!std::isfinite(v)) throw InputError(where, attribute, "has values that are not finite");
  const Corners c = cornersOf(r);
  const std::string& interp = primvar.interpolation;
  const size_t expected = usdPrimvarElements(r, interp);
  if (expected == 0)
    throw InputError(where, attribute, str("has interpolation \"", interp, "\", which UsdGeom does not define"));
  if (elements != expected)
    throw InputError(where, attribute, str("has ", elements, " values; ", interp, " interpolation needs ", expected));
  std::vector<float> out;
  out.reserve(c.faceVertex.size() * size_t(width));
  for (size_t k = 0; k < c.faceVertex.size(); ++k) {
    const uint32_t fv = c.faceVertex[k];
    size_t e = 0;
    if (interp == "uniform") e = c.face[k / 3];
    else if (interp == "vertex" || interp == "varying") e = size_t(r.faceVertexIndices[fv]);
    else if (interp == "faceVarying") e = fv;
    for (int j = 0; j < width; ++j) out.push_back(float(primvar.numbers[e * size_t(width) + size_t(j)]));
  }
  return out;
}

}  // namespace granular
