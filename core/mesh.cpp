// mesh.cpp — TriangleMesh operations and the validity checks of mesh.h.
#include "mesh.h"

#include <algorithm>

#include "error.h"

namespace granular {

namespace {

std::string fmtPoint(const Vec3& p) { return str("(", p.x, ", ", p.y, ", ", p.z, ")"); }

struct DVec {
  double x, y, z;
};
DVec toD(const Vec3& p, const DVec& origin) { return {p.x - origin.x, p.y - origin.y, p.z - origin.z}; }
DVec crossD(const DVec& a, const DVec& b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
double dotD(const DVec& a, const DVec& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

// Volume relative to the bounds centre: keeps the cancellation between the large
// positive and negative tetrahedra small for meshes far from the origin.
double volumeAbout(const TriangleMesh& mesh, const DVec& o) {
  double v = 0;
  for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
    DVec a = toD(mesh.points[mesh.indices[t]], o);
    DVec b = toD(mesh.points[mesh.indices[t + 1]], o);
    DVec c = toD(mesh.points[mesh.indices[t + 2]], o);
    v += dotD(a, crossD(b, c));
  }
  return v / 6.0;
}

DVec centreOf(const TriangleMesh& mesh) {
  Bounds3 b = mesh.bounds();
  if (b.empty()) return {0, 0, 0};
  return {0.5 * (double(b.lo.x) + b.hi.x), 0.5 * (double(b.lo.y) + b.hi.y), 0.5 * (double(b.lo.z) + b.hi.z)};
}

}  // namespace

Bounds3 TriangleMesh::bounds() const {
  Bounds3 b;
  for (const Vec3& p : points) b.extend(p);
  return b;
}

double TriangleMesh::signedVolume() const { return volumeAbout(*this, centreOf(*this)); }

double TriangleMesh::area() const {
  double a = 0;
  for (size_t t = 0; t + 2 < indices.size(); t += 3) {
    const Vec3 &p0 = points[indices[t]], &p1 = points[indices[t + 1]], &p2 = points[indices[t + 2]];
    a += 0.5 * double(length(cross(p1 - p0, p2 - p0)));
  }
  return a;
}

TriangleMesh TriangleMesh::transformed(const Transform& xf) const {
  TriangleMesh r;
  r.points.reserve(points.size());
  for (const Vec3& p : points) r.points.push_back(xf.point(p));
  r.indices = indices;
  r.uvs = uvs;
  // A mirroring transform turns outward-facing winding inward; undo that.
  if (xf.determinant3() < 0) r.flip();
  return r;
}

void TriangleMesh::flip() {
  for (size_t t = 0; t + 2 < indices.size(); t += 3) std::swap(indices[t + 1], indices[t + 2]);
  if (uvs.size() == 2 * indices.size())
    for (size_t t = 0; t + 2 < indices.size(); t += 3) {
      std::swap(uvs[2 * (t + 1)], uvs[2 * (t + 2)]);
      std::swap(uvs[2 * (t + 1) + 1], uvs[2 * (t + 2) + 1]);
    }
}

void validateMesh(const TriangleMesh& mesh, const std::string& object, const std::string& attribute) {
  if (!mesh.uvs.empty() && mesh.uvs.size() != 2 * mesh.indices.size())
    throw InputError(object, "uvs", str(mesh.uvs.size(), " values for ", mesh.indices.size(), " triangle corners (2 each needed)"));
  for (size_t i = 0; i < mesh.uvs.size(); ++i)
    if (!std::isfinite(mesh.uvs[i])) throw InputError(object, "uvs", str("value ", i, " is not finite"));
  for (size_t i = 0; i < mesh.points.size(); ++i)
    if (!isFinite(mesh.points[i]))
      throw InputError(object, attribute, str("point ", i, " is not finite ", fmtPoint(mesh.points[i])));
  if (mesh.indices.size() % 3 != 0)
    throw InputError(object, "faceVertexIndices",
                     str("has ", mesh.indices.size(), " entries, not a multiple of 3 (triangles expected)"));
  if (mesh.indices.empty()) throw InputError(object, "faceVertexIndices", "has no triangles");
  for (size_t i = 0; i < mesh.indices.size(); ++i)
    if (mesh.indices[i] >= mesh.points.size())
      throw InputError(object, "faceVertexIndices",
                       str("index ", i, " = ", mesh.indices[i], " is out of range [0, ", mesh.points.size(), ")"));
}

double validateClosed(const TriangleMesh& mesh, const std::string& object) {
  validateMesh(mesh, object, "points");
  const size_t nt = mesh.numTriangles();

  // One record per directed edge, keyed by the undirected edge; sorting groups the
  // uses of each edge together (deterministic, unlike a hash map's iteration order).
  struct EdgeUse {
    uint64_t key;
    uint32_t tri;
    bool forward;  // traversed from the lower to the higher index
  };
  std::vector<EdgeUse> uses;
  uses.reserve(nt * 3);
  bool anyArea = false;
  for (size_t t = 0; t < nt; ++t) {
    const uint32_t* v = &mesh.indices[3 * t];
    // A triangle that repeats an index has no interior and its edges cancel each
    // other; it adds nothing to the surface, so it is left out of the topology.
    if (v[0] == v[1] || v[1] == v[2] || v[2] == v[0]) continue;
    for (int e = 0; e < 3; ++e) {
      uint32_t a = v[e], b = v[(e + 1) % 3];
      uint32_t lo = std::min(a, b), hi = std::max(a, b);
      uses.push_back({(uint64_t(lo) << 32) | hi, uint32_t(t), a < b});
    }
    if (!anyArea) {
      DVec o{0, 0, 0};
      DVec p0 = toD(mesh.points[v[0]], o), p1 = toD(mesh.points[v[1]], o), p2 = toD(mesh.points[v[2]], o);
      DVec n = crossD({p1.x - p0.x, p1.y - p0.y, p1.z - p0.z}, {p2.x - p0.x, p2.y - p0.y, p2.z - p0.z});
      anyArea = dotD(n, n) > 0;
    }
  }
  std::sort(uses.begin(), uses.end(), [](const EdgeUse& a, const EdgeUse& b) {
    return a.key != b.key ? a.key < b.key : a.tri < b.tri;
  });

  // Report the problem edge whose first triangle comes earliest: the message then
  // points at the same place however the edges happen to sort.
  uint32_t badTri = UINT32_MAX;
  std::string badMsg;
  for (size_t i = 0; i < uses.size();) {
    size_t j = i;
    int forward = 0;
    while (j < uses.size() && uses[j].key == uses[i].key) forward += uses[j++].forward ? 1 : 0;
    size_t count = j - i;
    uint32_t firstTri = uses[i].tri;
    if ((count != 2 || forward != 1) && firstTri < badTri) {
      uint32_t lo = uint32_t(uses[i].key >> 32), hi = uint32_t(uses[i].key);
      badTri = firstTri;
      if (count == 1)
        badMsg = str("open boundary: edge (", lo, ",", hi, ") is used by 1 triangle(s)");
      else if (count > 2)
        badMsg = str("non-manifold edge (", lo, ",", hi, ") is used by ", count, " triangles");
      else
        badMsg = str("inconsistent winding at edge (", lo, ",", hi, "): triangles ", uses[i].tri, " and ",
                     uses[i + 1].tri, " both traverse it as ", forward == 2 ? lo : hi, "->", forward == 2 ? hi : lo);
    }
    i = j;
  }
  if (badTri != UINT32_MAX) throw InputError(object, "faceVertexIndices", badMsg);

  if (!anyArea) throw InputError(object, "points", "degenerate: all triangles have zero area");
  double vol = mesh.signedVolume();
  Vec3 ext = mesh.bounds().extent();
  double diag = std::sqrt(double(ext.x) * ext.x + double(ext.y) * ext.y + double(ext.z) * ext.z);
  if (!(std::fabs(vol) >= 1e-12 * diag * diag * diag) || vol == 0)
    throw InputError(object, "points", "degenerate: encloses no volume");
  return vol;
}

TriangleMesh triangulate(const std::vector<Vec3>& points, const std::vector<int>& faceVertexCounts,
                         const std::vector<int>& faceVertexIndices, const std::string& object) {
  // Check the counts first so the fan loop below never reads past the indices.
  size_t total = 0, triangles = 0;
  for (size_t f = 0; f < faceVertexCounts.size(); ++f) {
    int c = faceVertexCounts[f];
    if (c < 3)
      throw InputError(object, "faceVertexCounts", str("face ", f, " has ", c, " vertices (at least 3 needed)"));
    total += size_t(c);
    triangles += size_t(c) - 2;
  }
  if (total != faceVertexIndices.size())
    throw InputError(object, "faceVertexCounts",
                     str("counts sum to ", total, " but faceVertexIndices has ", faceVertexIndices.size(), " entries"));
  for (size_t i = 0; i < faceVertexIndices.size(); ++i) {
    int v = faceVertexIndices[i];
    if (v < 0 || size_t(v) >= points.size())
      throw InputError(object, "faceVertexIndices",
                       str("index ", i, " = ", v, " is out of range [0, ", points.size(), ")"));
  }
  TriangleMesh m;
  m.points = points;
  m.indices.reserve(triangles * 3);
  size_t base = 0;
  for (int c : faceVertexCounts) {
    for (int k = 1; k + 1 < c; ++k) {
      m.indices.push_back(uint32_t(faceVertexIndices[base]));
      m.indices.push_back(uint32_t(faceVertexIndices[base + k]));
      m.indices.push_back(uint32_t(faceVertexIndices[base + k + 1]));
    }
    base += size_t(c);
  }
  return m;
}

std::vector<uint32_t> triangulatedCorners(const std::vector<int>& faceVertexCounts) {
  std::vector<uint32_t> corners;
  uint32_t base = 0;
  for (int c : faceVertexCounts) {
    for (int k = 1; k + 1 < c; ++k) {  // the fan of triangulate()
      corners.push_back(base);
      corners.push_back(base + uint32_t(k));
      corners.push_back(base + uint32_t(k) + 1);
    }
    base += uint32_t(std::max(c, 0));
  }
  return corners;
}

}  // namespace granular
