// math.cpp — the out-of-line parts of Transform (see math.h).
#include "math.h"

namespace granular {

namespace {
struct D3 {
  double x, y, z;
};
D3 sub(D3 a, D3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
D3 crossD(D3 a, D3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
double len(D3 a) { return std::sqrt(a.x * a.x + a.y * a.y + a.z * a.z); }
D3 unit(D3 a) {
  double l = len(a);
  return l > 0 ? D3{a.x / l, a.y / l, a.z / l} : D3{0, 0, 1};
}
}  // namespace

Transform Transform::lookAt(const Vec3& eye, const Vec3& target, const Vec3& up) {
  // Built in double: the frame must stay orthonormal even far from the origin.
  D3 e{eye.x, eye.y, eye.z}, t{target.x, target.y, target.z}, u{up.x, up.y, up.z};
  D3 back = unit(sub(e, t));
  D3 right = crossD(u, back);
  if (len(right) < 1e-9 * std::max(len(u), 1e-300)) {
    // Up is parallel to the view direction: any perpendicular up will do, pick the
    // world axis least aligned with the view so the result is well conditioned.
    D3 alt = std::fabs(back.y) < 0.9 ? D3{0, 1, 0} : D3{0, 0, 1};
    right = crossD(alt, back);
  }
  right = unit(right);
  D3 trueUp = crossD(back, right);
  Transform r;
  const D3 cols[3] = {right, trueUp, back};
  for (int c = 0; c < 3; ++c) {
    r.m[0][c] = cols[c].x;
    r.m[1][c] = cols[c].y;
    r.m[2][c] = cols[c].z;
  }
  r.m[0][3] = e.x;
  r.m[1][3] = e.y;
  r.m[2][3] = e.z;
  return r;
}

bool Transform::inverse(Transform& out) const {
  if (!isFinite()) return false;
  double a[4][8];
  double scale = 0;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) {
      a[i][j] = m[i][j];
      a[i][j + 4] = i == j ? 1.0 : 0.0;
      if (j < 3 || i == 3) scale = std::max(scale, std::fabs(m[i][j]));
    }
  if (scale == 0) return false;
  // Relative tolerance: rounding turns an exactly singular matrix into pivots of
  // ~1e-16 * scale, which must still count as singular. The scale leaves the translation
  // out: a placement 1e14 units away says nothing about whether the matrix inverts.
  const double tiny = 1e-14 * scale;
  for (int c = 0; c < 4; ++c) {
    int p = c;
    for (int r = c + 1; r < 4; ++r)
      if (std::fabs(a[r][c]) > std::fabs(a[p][c])) p = r;
    if (!(std::fabs(a[p][c]) > tiny)) return false;
    if (p != c)
      for (int j = 0; j < 8; ++j) std::swap(a[p][j], a[c][j]);
    double inv = 1.0 / a[c][c];
    for (int j = 0; j < 8; ++j) a[c][j] *= inv;
    for (int r = 0; r < 4; ++r) {
      if (r == c || a[r][c] == 0) continue;
      double f = a[r][c];
      for (int j = 0; j < 8; ++j) a[r][j] -= f * a[c][j];
    }
  }
  Transform r;
  for (int i = 0; i < 4; ++i)
    for (int j = 0; j < 4; ++j) r.m[i][j] = a[i][j + 4];
  if (!r.isFinite()) return false;
  out = r;
  return true;
}

}  // namespace granular
