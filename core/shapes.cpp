// shapes.cpp — procedural closed meshes (see shapes.h).
#include "shapes.h"

#include <unordered_map>

#include "error.h"
#include "rng.h"

namespace granular {

namespace {

constexpr int kMaxSubdivisions = 8;  // 20 * 4^8 = 1.3M triangles
constexpr int kMaxSegments = 65536;
// Largest procedural mesh: 4 Mi vertices (about 8 Mi triangles, ~150 MB). Each factor's
// own range is not enough: a 65536 x 65536 UV sphere is 4.3e9 vertices, beyond uint32
// indices and any memory (seen as std::bad_alloc, exit 1, from a 72-byte JSON scene).
constexpr int64_t kMaxShapeVertices = int64_t(1) << 22;

void checkSubdivisions(const char* fn, int subdivisions) {
  if (subdivisions < 0 || subdivisions > kMaxSubdivisions)
    throw InputError(fn, "subdivisions", str(subdivisions, " is outside [0, ", kMaxSubdivisions, "]"));
}

void addTri(TriangleMesh& m, uint32_t a, uint32_t b, uint32_t c) {
  m.indices.push_back(a);
  m.indices.push_back(b);
  m.indices.push_back(c);
}

}  // namespace

TriangleMesh makeIcosphere(int subdivisions) {
  checkSubdivisions("makeIcosphere", subdivisions);
  const float t = (1.0f + std::sqrt(5.0f)) * 0.5f;
  TriangleMesh m;
  m.points = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
              {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  m.indices = {0, 11, 5, 0, 5, 1,  0, 1, 7,  0, 7,  10, 0, 10, 11, 1, 5, 9, 5, 11, 4,  11, 10, 2,  10, 7, 6, 7, 1, 8,
               3, 9,  4, 3, 4, 2,  3, 2, 6,  3, 6,  8,  3, 8,  9,  4, 9, 5, 2, 4,  11, 6,  2,  10, 8,  6, 7, 9, 8, 1};
  for (Vec3& p : m.points) p = normalize(p);

  for (int level = 0; level < subdivisions; ++level) {
    // Each edge's midpoint is created once so neighbouring triangles share it.
    std::unordered_map<uint64_t, uint32_t> midpoints;
    midpoints.reserve(m.indices.size());
    auto midpoint = [&](uint32_t a, uint32_t b) {
      uint64_t key = (uint64_t(std::min(a, b)) << 32) | std::max(a, b);
      auto it = midpoints.find(key);
      if (it != midpoints.end()) return it->second;
      uint32_t idx = uint32_t(m.points.size());
      m.points.push_back(normalize(m.points[a] + m.points[b]));
      midpoints.emplace(key, idx);
      return idx;
    };
    std::vector<uint32_t> next;
    next.reserve(m.indices.size() * 4);
    for (size_t i = 0; i < m.indices.size(); i += 3) {
      uint32_t a = m.indices[i], b = m.indices[i + 1], c = m.indices[i + 2];
      uint32_t ab = midpoint(a, b), bc = midpoint(b, c), ca = midpoint(c, a);
      for (uint32_t v : {a, ab, ca, b, bc, ab, c, ca, bc, ab, bc, ca}) next.push_back(v);
    }
    m.indices.swap(next);
  }
  return m;
}

TriangleMesh makeBox(Vec3 lo, Vec3 hi) {
  if (!isFinite(lo)) throw InputError("makeBox", "lo", "is not finite");
  if (!isFinite(hi)) throw InputError("makeBox", "hi", "is not finite");
  if (!(lo.x < hi.x && lo.y < hi.y && lo.z < hi.z))
    throw InputError("makeBox", "hi", str("(", hi.x, ", ", hi.y, ", ", hi.z, ") must exceed lo (", lo.x, ", ", lo.y,
                                          ", ", lo.z, ") on every axis"));
  TriangleMesh m;
  // Corner i has x = hi when bit 0 is set, y when bit 1, z when bit 2.
  for (int i = 0; i < 8; ++i) m.points.push_back({i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z});
  // Quads listed counter-clockwise seen from outside.
  const uint32_t quads[6][4] = {{0, 4, 6, 2}, {1, 3, 7, 5}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 2, 3, 1}, {4, 5, 7, 6}};
  for (auto& q : quads) {
    addTri(m, q[0], q[1], q[2]);
    addTri(m, q[0], q[2], q[3]);
  }
  return m;
}

TriangleMesh makeLathe(const std::vector<std::pair<float, float>>& profile, int segments) {
  if (segments < 3 || segments > kMaxSegments)
    throw InputError("makeLathe", "segments", str(segments, " is outside [3, ", kMaxSegments, "]"));
  if (profile.size() < 2) throw InputError("makeLathe", "profile", str("has ", profile.size(), " points (at least 2 needed)"));
  for (size_t i = 0; i < profile.size(); ++i) {
    float r = profile[i].first, h = profile[i].second;
    if (!std::isfinite(r) || !std::isfinite(h))
      throw InputError("makeLathe", "profile", str("point ", i, " (", r, ", ", h, ") is not finite"));
    if (r < 0) throw InputError("makeLathe", "profile", str("point ", i, " has negative radius ", r));
    if (r == 0 && i != 0 && i + 1 != profile.size())
      throw InputError("makeLathe", "profile",
                       str("point ", i, " has radius 0; only the first and last points may lie on the axis"));
  }
  // Close open ends with an extra point on the axis: a cap is then just a pole fan.
  std::vector<std::pair<float, float>> prof;
  if (profile.front().first > 0) prof.push_back({0.0f, profile.front().second});
  prof.insert(prof.end(), profile.begin(), profile.end());
  if (profile.back().first > 0) prof.push_back({0.0f, profile.back().second});
  if (prof.size() < 3) throw InputError("makeLathe", "profile", "has no point off the axis");
  const int64_t vertices = int64_t(prof.size() - 2) * segments + 2;
  if (vertices > kMaxShapeVertices)
    throw InputError("makeLathe", "segments",
                     str(segments, " segments x ", prof.size() - 2, " rings = ", vertices, " vertices exceed ",
                         kMaxShapeVertices));

  TriangleMesh m;
  const size_t n = prof.size();
  const uint32_t seg = uint32_t(segments);
  std::vector<uint32_t> first(n);  // index of ring i's first vertex (or its pole)
  for (size_t i = 0; i < n; ++i) {
    first[i] = uint32_t(m.points.size());
    float r = prof[i].first, h = prof[i].second;
    if (i == 0 || i + 1 == n) {
      m.points.push_back({0.0f, h, 0.0f});
      continue;
    }
    for (uint32_t j = 0; j < seg; ++j) {
      double a = 2.0 * kPiD * double(j) / double(seg);
      m.points.push_back({float(r * std::cos(a)), h, float(r * std::sin(a))});
    }
  }
  for (size_t i = 0; i + 1 < n; ++i) {
    for (uint32_t j = 0; j < seg; ++j) {
      uint32_t j1 = (j + 1) % seg;
      uint32_t a = first[i] + (i == 0 ? 0 : j), b = first[i] + (i == 0 ? 0 : j1);
      uint32_t c = first[i + 1] + (i + 1 == n - 1 ? 0 : j1), d = first[i + 1] + (i + 1 == n - 1 ? 0 : j);
      // Quad a-b-c-d; at a pole two of its corners coincide and one triangle remains.
      if (a != b) addTri(m, a, b, c);
      if (c != d) addTri(m, a, c, d);
    }
  }
  // The winding above is outward for one sense of the profile; a profile running
  // the other way (or a vase with overhangs) is settled by the volume's sign.
  if (m.signedVolume() < 0) m.flip();
  return m;
}

TriangleMesh makeUVSphere(int segments, int rings) {
  if (rings < 2 || rings > kMaxSegments)
    throw InputError("makeUVSphere", "rings", str(rings, " is outside [2, ", kMaxSegments, "]"));
  if (segments < 3 || segments > kMaxSegments)
    throw InputError("makeUVSphere", "segments", str(segments, " is outside [3, ", kMaxSegments, "]"));
  const int64_t vertices = int64_t(segments) * (rings - 1) + 2;
  if (vertices > kMaxShapeVertices)
    throw InputError("makeUVSphere", "rings",
                     str(segments, " segments x ", rings - 1, " rings = ", vertices, " vertices exceed ",
                         kMaxShapeVertices));
  std::vector<std::pair<float, float>> profile;
  for (int i = 0; i <= rings; ++i) {
    double theta = kPiD * (1.0 - double(i) / rings);  // from the south pole up
    // Exact zeros at the poles: sin(pi) is not 0 in floating point and would add caps.
    float r = (i == 0 || i == rings) ? 0.0f : float(std::sin(theta));
    profile.push_back({r, float(std::cos(theta))});
  }
  return makeLathe(profile, segments);
}

TriangleMesh makeRock(int subdivisions, float roughness, uint64_t seed) {
  checkSubdivisions("makeRock", subdivisions);
  if (!(roughness >= 0.0f && roughness < 0.5f))
    throw InputError("makeRock", "roughness", str(roughness, " is outside [0, 0.5)"));
  TriangleMesh m = makeIcosphere(subdivisions);

  // A few random plane waves cos(f <p,d> + phase) restricted to the sphere: smooth,
  // low-frequency, and cheap; amplitude 1/f keeps the large lobes dominant.
  constexpr int kLobes = 9;
  struct Lobe {
    Vec3 dir;
    float freq, phase, amp;
  };
  Lobe lobes[kLobes];
  for (int k = 0; k < kLobes; ++k) {
    float u1 = toUnitFloat(hashInts(seed, k, 0)), u2 = toUnitFloat(hashInts(seed, k, 1));
    float u3 = toUnitFloat(hashInts(seed, k, 2)), u4 = toUnitFloat(hashInts(seed, k, 3));
    float z = 1.0f - 2.0f * u1, s = std::sqrt(std::max(0.0f, 1.0f - z * z)), phi = 2.0f * kPi * u2;
    float freq = 1.0f + 3.0f * u3;
    lobes[k] = {{s * std::cos(phi), s * std::sin(phi), z}, freq, 2.0f * kPi * u4, 1.0f / freq};
  }
  std::vector<float> noise(m.points.size());
  float peak = 0.0f;
  for (size_t i = 0; i < m.points.size(); ++i) {
    float n = 0.0f;
    for (const Lobe& l : lobes) n += l.amp * std::cos(l.freq * dot(m.points[i], l.dir) + l.phase);
    noise[i] = n;
    peak = std::max(peak, std::fabs(n));
  }
  // Normalising by the observed peak makes `roughness` the actual largest deviation.
  float scale = peak > 0.0f ? roughness / peak : 0.0f;
  for (size_t i = 0; i < m.points.size(); ++i) m.points[i] *= 1.0f + scale * noise[i];
  return m;
}

TriangleMesh makeEllipsoid(Vec3 radii, int subdivisions) {
  checkSubdivisions("makeEllipsoid", subdivisions);
  if (!isFinite(radii) || !(minComponent(radii) > 0.0f))
    throw InputError("makeEllipsoid", "radii", str("(", radii.x, ", ", radii.y, ", ", radii.z, ") must be finite and > 0"));
  TriangleMesh m = makeIcosphere(subdivisions);
  for (Vec3& p : m.points) p *= radii;
  return m;
}

}  // namespace granular
