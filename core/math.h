// math.h — small vector, matrix and frame types used throughout the core.
//
// Contract: plain value types, no allocation. Vec3 is float (radiance, geometry);
// Transform holds a 4x4 affine matrix in double so that world-space placement of
// billions of grains stays exact enough; everything per-ray is float.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

namespace granular {

constexpr double kPiD = 3.14159265358979323846;
constexpr float kPi = float(kPiD);
constexpr float kInvPi = 1.0f / kPi;
constexpr float kInf = std::numeric_limits<float>::infinity();

struct Vec3 {
  float x = 0, y = 0, z = 0;
  constexpr Vec3() = default;
  constexpr Vec3(float a, float b, float c) : x(a), y(b), z(c) {}
  constexpr explicit Vec3(float s) : x(s), y(s), z(s) {}
  float operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  float& operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }
  Vec3 operator-() const { return {-x, -y, -z}; }
  Vec3& operator+=(const Vec3& o) { x += o.x; y += o.y; z += o.z; return *this; }
  Vec3& operator-=(const Vec3& o) { x -= o.x; y -= o.y; z -= o.z; return *this; }
  Vec3& operator*=(const Vec3& o) { x *= o.x; y *= o.y; z *= o.z; return *this; }
  Vec3& operator*=(float s) { x *= s; y *= s; z *= s; return *this; }
  Vec3& operator/=(float s) { float r = 1.0f / s; x *= r; y *= r; z *= r; return *this; }
};

inline Vec3 operator+(Vec3 a, const Vec3& b) { return a += b; }
inline Vec3 operator-(Vec3 a, const Vec3& b) { return a -= b; }
inline Vec3 operator*(Vec3 a, const Vec3& b) { return a *= b; }
inline Vec3 operator*(Vec3 a, float s) { return a *= s; }
inline Vec3 operator*(float s, Vec3 a) { return a *= s; }
inline Vec3 operator/(Vec3 a, float s) { return a /= s; }
inline Vec3 operator/(const Vec3& a, const Vec3& b) { return {a.x / b.x, a.y / b.y, a.z / b.z}; }
inline bool operator==(const Vec3& a, const Vec3& b) { return a.x == b.x && a.y == b.y && a.z == b.z; }
inline bool operator!=(const Vec3& a, const Vec3& b) { return !(a == b); }

inline float dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline float length(const Vec3& a) { return std::sqrt(dot(a, a)); }
inline float length2(const Vec3& a) { return dot(a, a); }
inline Vec3 normalize(const Vec3& a) {
  float l = length(a);
  if (l > 0 && l < kInf) return a / l;
  // The squares left float (|a| beyond ~1e19, as the cross product of a triangle's edges
  // 10^9 units long, or below ~1e-19): rescale by the largest component first.
  const float m = std::max({std::fabs(a.x), std::fabs(a.y), std::fabs(a.z)});
  if (!(m > 0) || !(m < kInf)) return Vec3(0, 0, 1);
  const Vec3 b = a / m;
  return b / length(b);
}
inline Vec3 vmin(const Vec3& a, const Vec3& b) { return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)}; }
inline Vec3 vmax(const Vec3& a, const Vec3& b) { return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)}; }
inline Vec3 vabs(const Vec3& a) { return {std::fabs(a.x), std::fabs(a.y), std::fabs(a.z)}; }
inline Vec3 vexp(const Vec3& a) { return {std::exp(a.x), std::exp(a.y), std::exp(a.z)}; }
inline float maxComponent(const Vec3& a) { return std::max(a.x, std::max(a.y, a.z)); }
inline float minComponent(const Vec3& a) { return std::min(a.x, std::min(a.y, a.z)); }
inline float average(const Vec3& a) { return (a.x + a.y + a.z) * (1.0f / 3.0f); }
inline float luminance(const Vec3& c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }
inline bool isFinite(const Vec3& a) { return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z); }
inline bool isBlack(const Vec3& a) { return a.x == 0 && a.y == 0 && a.z == 0; }

// Orthonormal frame around a unit normal (Duff et al. 2017, branchless).
struct Frame {
  Vec3 s, t, n;
  Frame() : s(1, 0, 0), t(0, 1, 0), n(0, 0, 1) {}
  explicit Frame(const Vec3& normal) : n(normal) {
    float sign = std::copysign(1.0f, n.z);
    float a = -1.0f / (sign + n.z);
    float b = n.x * n.y * a;
    s = Vec3(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    t = Vec3(b, sign + n.y * n.y * a, -n.y);
  }
  Vec3 toLocal(const Vec3& v) const { return {dot(v, s), dot(v, t), dot(v, n)}; }
  Vec3 toWorld(const Vec3& v) const { return s * v.x + t * v.y + n * v.z; }
};

// A point in double, for what must stay exact far from the origin (render space).
struct Vec3d {
  double x = 0, y = 0, z = 0;
  double operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
  bool operator==(const Vec3d& o) const { return x == o.x && y == o.y && z == o.z; }
  bool operator!=(const Vec3d& o) const { return !(*this == o); }
};

// Row-major 3x3 matrix (rotations of grains).
struct Mat3 {
  float m[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  Vec3 operator*(const Vec3& v) const {
    return {m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z, m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z,
            m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z};
  }
  // For a rotation the transpose is the inverse.
  Vec3 transposeMul(const Vec3& v) const {
    return {m[0][0] * v.x + m[1][0] * v.y + m[2][0] * v.z, m[0][1] * v.x + m[1][1] * v.y + m[2][1] * v.z,
            m[0][2] * v.x + m[1][2] * v.y + m[2][2] * v.z};
  }
};

// Rotation matrix of a unit quaternion (w, x, y, z).
inline Mat3 quatToMat3(float w, float x, float y, float z) {
  Mat3 r;
  r.m[0][0] = 1 - 2 * (y * y + z * z); r.m[0][1] = 2 * (x * y - w * z);     r.m[0][2] = 2 * (x * z + w * y);
  r.m[1][0] = 2 * (x * y + w * z);     r.m[1][1] = 1 - 2 * (x * x + z * z); r.m[1][2] = 2 * (y * z - w * x);
  r.m[2][0] = 2 * (x * z - w * y);     r.m[2][1] = 2 * (y * z + w * x);     r.m[2][2] = 1 - 2 * (x * x + y * y);
  return r;
}

// Affine transform, row-major 4x4 in double, acting on column vectors:
// p' = M p. (USD stores row vectors: M_usd = transpose(M); io converts.)
struct Transform {
  double m[4][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};

  static Transform translate(const Vec3& t) {
    Transform r; r.m[0][3] = t.x; r.m[1][3] = t.y; r.m[2][3] = t.z; return r;
  }
  static Transform translate(double x, double y, double z) {
    Transform r; r.m[0][3] = x; r.m[1][3] = y; r.m[2][3] = z; return r;
  }
  static Transform scale(const Vec3& s) {
    Transform r; r.m[0][0] = s.x; r.m[1][1] = s.y; r.m[2][2] = s.z; return r;
  }
  // Camera-style frame: local -Z looks from eye to target, +Y is up (USD camera convention).
  static Transform lookAt(const Vec3& eye, const Vec3& target, const Vec3& up);

  Transform operator*(const Transform& o) const {
    Transform r;
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) {
        double s = 0;
        for (int k = 0; k < 4; ++k) s += m[i][k] * o.m[k][j];
        r.m[i][j] = s;
      }
    return r;
  }
  Vec3 point(const Vec3& p) const {
    double x = m[0][0] * p.x + m[0][1] * p.y + m[0][2] * p.z + m[0][3];
    double y = m[1][0] * p.x + m[1][1] * p.y + m[1][2] * p.z + m[1][3];
    double z = m[2][0] * p.x + m[2][1] * p.y + m[2][2] * p.z + m[2][3];
    return {float(x), float(y), float(z)};
  }
  Vec3d pointD(const Vec3& p) const {
    return {m[0][0] * p.x + m[0][1] * p.y + m[0][2] * p.z + m[0][3], m[1][0] * p.x + m[1][1] * p.y + m[1][2] * p.z + m[1][3],
            m[2][0] * p.x + m[2][1] * p.y + m[2][2] * p.z + m[2][3]};
  }
  Vec3 vector(const Vec3& v) const {
    return {float(m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z), float(m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z),
            float(m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z)};
  }
  // Normals transform by the inverse transpose; pass the inverse.
  static Vec3 normal(const Transform& inv, const Vec3& n) {
    return {float(inv.m[0][0] * n.x + inv.m[1][0] * n.y + inv.m[2][0] * n.z),
            float(inv.m[0][1] * n.x + inv.m[1][1] * n.y + inv.m[2][1] * n.z),
            float(inv.m[0][2] * n.x + inv.m[1][2] * n.y + inv.m[2][2] * n.z)};
  }
  // Entry by entry (1 − s) a + s b: a moving object's transform at fraction s of the
  // shutter (the blend Embree gives a moving mesh's vertices).
  static Transform blend(const Transform& a, const Transform& b, double s) {
    Transform r;
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) r.m[i][j] = (1 - s) * a.m[i][j] + s * b.m[i][j];
    return r;
  }
  double determinant3() const {
    return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
           m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  }
  bool isFinite() const {
    for (auto& row : m)
      for (double v : row)
        if (!std::isfinite(v)) return false;
    return true;
  }
  // General 4x4 inverse; returns false when singular.
  bool inverse(Transform& out) const;
};

struct Bounds3 {
  Vec3 lo{kInf, kInf, kInf};
  Vec3 hi{-kInf, -kInf, -kInf};
  void extend(const Vec3& p) { lo = vmin(lo, p); hi = vmax(hi, p); }
  void extend(const Bounds3& b) { lo = vmin(lo, b.lo); hi = vmax(hi, b.hi); }
  bool empty() const { return lo.x > hi.x || lo.y > hi.y || lo.z > hi.z; }
  Vec3 extent() const { return hi - lo; }
  Vec3 center() const { return (lo + hi) * 0.5f; }
  bool contains(const Vec3& p) const {
    return p.x >= lo.x && p.x <= hi.x && p.y >= lo.y && p.y <= hi.y && p.z >= lo.z && p.z <= hi.z;
  }
  // Slab test; returns the parametric overlap [t0, t1] with [tmin, tmax].
  bool intersect(const Vec3& o, const Vec3& invDir, float tmin, float tmax, float& t0, float& t1) const {
    for (int a = 0; a < 3; ++a) {
      float tn = (lo[a] - o[a]) * invDir[a];
      float tf = (hi[a] - o[a]) * invDir[a];
      if (tn > tf) std::swap(tn, tf);
      if (!(tn <= tf)) { tn = -kInf; tf = kInf; }  // NaN from 0*inf: the slab is parallel and contains o
      tmin = std::max(tmin, tn);
      tmax = std::min(tmax, tf * (1.0f + 2e-7f * 3));  // robust upper bound (pbrt-v4's gamma(3))
      if (tmin > tmax) return false;
    }
    t0 = tmin; t1 = tmax;
    return true;
  }
};

struct Ray {
  Vec3 o, d;
  float tmin = 0.0f;
  float tmax = kInf;
  float time = 0.0f;  // seconds from the frame's time, within the camera's shutter (motion blur)
};

// Spawn a ray leaving a surface, offset along the geometric normal by eps (the hit's
// own error scale: a grain hit uses a fraction of the grain radius, a surface hit a
// fraction of its coordinates' magnitude) to escape self-intersection.
inline Vec3 offsetRayOrigin(const Vec3& p, const Vec3& ng, const Vec3& dir, float eps) {
  Vec3 off = ng * eps;
  return dot(dir, ng) >= 0 ? p + off : p - off;
}

}  // namespace granular
