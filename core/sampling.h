// sampling.h — warps from uniform numbers to directions and discrete choices.
//
// Contract: every sample function states the density (pdf) of what it returns, with
// respect to solid angle for directions and to the unit square for 2-D maps, so the
// integrators can weight samples and combine strategies by MIS.
#pragma once

#include <cmath>
#include <cstdint>
#include <vector>

#include "math.h"

namespace granular {

// A guide table (Chen & Asau 1974) for inverting a piecewise-constant cdf of n bins
// (cdf[0] = 0 ≤ … ≤ cdf[n], the total): g + 1 starting points, guide[j] the last bin
// whose cdf is at most j/g of the total, from which a step or two finds u's bin instead of
// a binary search. cdfGuide() writes them to guide (g + 1 entries).
void cdfGuide(const float* cdf, int n, int g, uint32_t* guide);
// u's bin in [0, cdf[n]]: the largest i < n with cdf[i] ≤ u whose bin has mass (u = cdf[n]:
// the last such bin), as a binary search would find it.
int guidedBin(const float* cdf, int n, const uint32_t* guide, int g, float u);

// Cosine-weighted hemisphere around +Z (Malley). pdf = cos(theta) / pi.
inline Vec3 sampleCosineHemisphere(float u1, float u2) {
  float r = std::sqrt(u1), phi = 2.0f * kPi * u2;
  return {r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(0.0f, 1.0f - u1))};
}
// Uniform point of the unit disk (Shirley & Chiu's concentric map: strata stay compact);
// pdf 1/π per unit area. Returns (x, y, 0).
inline Vec3 sampleConcentricDisk(float u1, float u2) {
  float a = 2.0f * u1 - 1.0f, b = 2.0f * u2 - 1.0f;
  if (a == 0 && b == 0) return Vec3(0.0f);
  float r, phi;
  if (std::fabs(a) > std::fabs(b)) {
    r = a;
    phi = 0.25f * kPi * (b / a);
  } else {
    r = b;
    phi = 0.5f * kPi - 0.25f * kPi * (a / b);
  }
  return Vec3(r * std::cos(phi), r * std::sin(phi), 0.0f);
}

inline float cosineHemispherePdf(float cosTheta) { return cosTheta > 0 ? cosTheta * kInvPi : 0.0f; }

// Uniform direction on the sphere. pdf = 1 / (4 pi).
inline Vec3 sampleUniformSphere(float u1, float u2) {
  float z = 1.0f - 2.0f * u1, r = std::sqrt(std::max(0.0f, 1.0f - z * z)), phi = 2.0f * kPi * u2;
  return {r * std::cos(phi), r * std::sin(phi), z};
}
constexpr float kUniformSpherePdf = 1.0f / (4.0f * kPi);

// Uniform direction in the cone around +Z given by the sin² of its half-angle;
// pdf = 1 / (2π (1 − cos θ_max)). Every cone light uses it: 1 − cos θ_max in float loses
// ~0.5% on the 0.53° sun and rounds to 0 for a sphere light of radius r seen from beyond
// ~4000 r (sin² = r²/d² below ~6e-8), so 1 − cos is formed stably in double:
// sin² / (1 + sqrt(1 − sin²)).
inline double coneOneMinusCos(double sin2) { return sin2 / (1.0 + std::sqrt(std::max(0.0, 1.0 - sin2))); }
inline Vec3 sampleUniformConeSin2(float u1, float u2, double sin2) {
  double w = u1 * coneOneMinusCos(sin2);  // 1 − z
  float z = float(1.0 - w), r = float(std::sqrt(std::max(0.0, w * (2.0 - w)))), phi = 2.0f * kPi * u2;
  return {r * std::cos(phi), r * std::sin(phi), z};
}
// May be +inf for a cone whose solid angle underflows a float: its light then adds 0.
inline float uniformConePdfSin2(double sin2) { return float(1.0 / (2.0 * kPiD * coneOneMinusCos(sin2))); }

// Uniform random rotation (Shoemake 1992, "Uniform random rotations"): a unit quaternion
// uniform on S^3, returned as a rotation matrix.
inline Mat3 sampleUniformRotation(float u1, float u2, float u3) {
  float a = std::sqrt(1.0f - u1), b = std::sqrt(u1);
  float t1 = 2.0f * kPi * u2, t2 = 2.0f * kPi * u3;
  return quatToMat3(b * std::cos(t2), a * std::sin(t1), a * std::cos(t1), b * std::sin(t2));
}

// Veach's power heuristic with beta = 2.
inline float powerHeuristic(float pdfA, float pdfB) {
  // As a ratio: the squares of huge pdfs (a small light far away: 1e20 and beyond, or
  // +inf) overflowed to inf / inf = NaN.
  if (!(pdfA > 0)) return 0.0f;
  if (!(pdfB > 0)) return 1.0f;
  if (std::isinf(pdfA)) return std::isinf(pdfB) ? 0.5f : 1.0f;
  if (pdfA >= pdfB) {
    float r = pdfB / pdfA;
    return 1.0f / (1.0f + r * r);
  }
  float r = pdfA / pdfB;
  return r * r / (1.0f + r * r);
}

// Piecewise-constant density on [0, 1) with n bins. sampleContinuous returns x with
// pdf(x) = f(bin) / integral(f); sampleDiscrete returns bin i with probability f_i / sum f
// (never a bin of f_i = 0 while some f_i > 0).
class Distribution1D {
 public:
  Distribution1D() = default;
  explicit Distribution1D(const std::vector<float>& f);
  int size() const { return int(func_.size()); }
  float integral() const { return integral_; }
  float sampleContinuous(float u, float* pdf, int* bin = nullptr) const;
  int sampleDiscrete(float u, float* prob = nullptr) const;
  float pdfContinuous(float x) const;
  float discreteProb(int i) const { return integral_ > 0 ? func_[i] / (integral_ * size()) : 0.0f; }

 private:
  std::vector<float> func_, cdf_;
  float integral_ = 0;
};

// Piecewise-constant density on the unit square, sampled by marginal (v) then
// conditional (u). pdf is with respect to (u, v) area.
class Distribution2D {
 public:
  Distribution2D() = default;
  Distribution2D(const std::vector<float>& f, int nu, int nv);
  void sample(float u1, float u2, float& u, float& v, float* pdf) const;
  float pdf(float u, float v) const;

 private:
  std::vector<Distribution1D> conditional_;
  Distribution1D marginal_;
};

}  // namespace granular
