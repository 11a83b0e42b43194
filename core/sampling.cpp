#include "sampling.h"

#include <algorithm>

namespace granular {

void cdfGuide(const float* cdf, int n, int g, uint32_t* guide) {
  for (int j = 0; j <= g; ++j) {
    const float u = float(j) / float(g) * cdf[n];
    const int i = int(std::upper_bound(cdf, cdf + n + 1, u) - cdf) - 1;
    guide[j] = uint32_t(std::clamp(i, 0, n));
  }
}

int guidedBin(const float* cdf, int n, const uint32_t* guide, int g, float u) {
  const int j = std::clamp(int(u / cdf[n] * float(g)), 0, g);
  int i = int(guide[j]);
  while (i > 0 && cdf[i] > u) --i;  // u · g rounded up to the next step
  while (i < n && cdf[i + 1] <= u) ++i;
  i = std::clamp(i, 0, n - 1);
  while (i > 0 && !(cdf[i + 1] > cdf[i])) --i;
  return i;
}

Distribution1D::Distribution1D(const std::vector<float>& f) : func_(f), cdf_(f.size() + 1) {
  int n = int(f.size());
  cdf_[0] = 0;
  double acc = 0;
  for (int i = 0; i < n; ++i) {
    float v = std::isfinite(func_[i]) && func_[i] > 0 ? func_[i] : 0.0f;  // never sample NaN
    func_[i] = v;
    acc += double(v) / n;
    cdf_[i + 1] = float(acc);
  }
  integral_ = float(acc);
  if (integral_ <= 0) {
    for (int i = 1; i <= n; ++i) cdf_[i] = float(i) / n;
  } else {
    for (int i = 1; i <= n; ++i) cdf_[i] /= integral_;
  }
  cdf_[n] = 1.0f;
}

static int findInterval(const std::vector<float>& cdf, float u) {
  // Largest i with cdf[i] <= u, clamped to [0, n-1].
  int lo = 0, hi = int(cdf.size()) - 2;
  while (lo < hi) {
    int mid = (lo + hi + 1) / 2;
    if (cdf[mid] <= u) lo = mid; else hi = mid - 1;
  }
  return lo;
}

float Distribution1D::sampleContinuous(float u, float* pdf, int* bin) const {
  int i = findInterval(cdf_, u);
  if (bin) *bin = i;
  float width = cdf_[i + 1] - cdf_[i];
  float du = width > 0 ? (u - cdf_[i]) / width : 0.5f;
  if (pdf) *pdf = integral_ > 0 ? func_[i] / integral_ : 1.0f;
  float x = (float(i) + std::min(std::max(du, 0.0f), 1.0f)) / size();
  return std::min(x, 0x1.fffffep-1f);
}

int Distribution1D::sampleDiscrete(float u, float* prob) const {
  int i = findInterval(cdf_, u);
  if (prob) *prob = integral_ > 0 ? discreteProb(i) : 1.0f / size();
  return i;
}

float Distribution1D::pdfContinuous(float x) const {
  int i = std::min(std::max(int(x * size()), 0), size() - 1);
  return integral_ > 0 ? func_[i] / integral_ : 1.0f;
}

Distribution2D::Distribution2D(const std::vector<float>& f, int nu, int nv) {
  conditional_.reserve(nv);
  std::vector<float> marg(nv);
  for (int v = 0; v < nv; ++v) {
    conditional_.emplace_back(std::vector<float>(f.begin() + size_t(v) * nu, f.begin() + size_t(v + 1) * nu));
    marg[v] = conditional_.back().integral();
  }
  marginal_ = Distribution1D(marg);
}

void Distribution2D::sample(float u1, float u2, float& u, float& v, float* pdf) const {
  float pv, pu;
  int row;
  v = marginal_.sampleContinuous(u2, &pv, &row);
  u = conditional_[row].sampleContinuous(u1, &pu);
  if (pdf) *pdf = pu * pv;
}

float Distribution2D::pdf(float u, float v) const {
  int nv = int(conditional_.size());
  int row = std::min(std::max(int(v * nv), 0), nv - 1);
  return conditional_[row].pdfContinuous(u) * marginal_.pdfContinuous(v);
}

}  // namespace granular
