// Heterogeneous medium (core/heterogeneous_medium.*): spectral tracking and ratio tracking
// against closed forms. A constant density is HomogeneousMedium's exp(−σ t) and mean free
// path; a linear gradient's transmittance is exp(−∫σ) and its collision density
// α σ(t) T(t). Fixed seeds; each tolerance is a number of the estimate's standard errors
// (estimated from the samples), 4.5 where one test makes tens of comparisons.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "core/grain_density.h"
#include "core/heterogeneous_medium.h"
#include "core/rng.h"
#include "core/shapes.h"
#include "core/vpt.h"

using namespace granular;

namespace {

// Mean and standard error of the mean, per channel.
struct Stat {
  double sum[3] = {0, 0, 0}, sq[3] = {0, 0, 0};
  int64_t n = 0;
  void add(const Vec3& v) {
    for (int c = 0; c < 3; ++c) {
      sum[c] += v[c];
      sq[c] += double(v[c]) * v[c];
    }
  }
  double mean(int c) const { return sum[c] / double(n); }
  double se(int c) const {
    const double m = mean(c), var = std::max(0.0, sq[c] / double(n) - m * m);
    return std::sqrt(var / double(n - 1));
  }
};

const Vec3 kSigma(1.0f, 2.0f, 0.5f), kAlbedo(0.9f, 0.8f, 0.7f);

HomogeneousMedium reference(const Vec3& sigma = kSigma) {
  return HomogeneousMedium(sigma, kAlbedo, PhaseTable::isotropic());
}

// density 0.5 = the reference everywhere in voxels [−r, r]³ of size dx.
HeterogeneousMedium constant(float dx, int64_t r) {
  VoxelLeaves v = VoxelLeaves::fromFunction(dx, {-r, -r, -r}, {r, r, r}, [](int64_t, int64_t, int64_t) { return 0.5; });
  return HeterogeneousMedium(std::move(v), 0.5f, reference(), "constant");
}

// f = 1 + b x (x = i Δ) over x in [−1.5, 1.5], |y|, |z| < 0.8; f_ref = 1.
constexpr float kDx = 0.05f, kGrad = 0.4f;
HeterogeneousMedium gradient(const Vec3& sigma) {
  VoxelLeaves v = VoxelLeaves::fromFunction(kDx, {-30, -16, -16}, {30, 16, 16},
                                            [](int64_t i, int64_t, int64_t) { return 1.0 + kGrad * (double(i) * kDx); });
  return HeterogeneousMedium(std::move(v), 1.0f, reference(sigma), "gradient");
}

// The gradient's optical depth along o + d t for t in [0, t] (closed form).
Vec3 gradientDepth(const Vec3& sigma, const Vec3& o, const Vec3& d, double t) {
  const double integral = (t + kGrad * (o.x * t + d.x * t * t / 2)) * length(d);
  return sigma * float(integral);
}

}  // namespace

TEST(HeterogeneousMedium, ConstantDensityTransmittanceIsTheHomogeneousMediums) {
  const HeterogeneousMedium med = constant(0.1f, 30);
  const HomogeneousMedium hom = reference();
  EXPECT_EQ(med.sigmaT(Vec3(0.3f, -1.0f, 2.0f)), kSigma);
  Ray ray;
  ray.o = Vec3(-0.7f, 0.2f, 0.1f);
  ray.d = normalize(Vec3(1.0f, 0.4f, -0.3f));
  const float t = 1.3f;
  const Vec3 expected = hom.transmittance(t);
  Stat ratio, ratioRR, delta;
  Rng rng(11);
  const int N = 40000;
  for (int i = 0; i < N; ++i) {
    ratio.add(med.transmittance(ray, t, rng, false));
    ratioRR.add(med.transmittance(ray, t, rng, true));
    delta.add(med.transmittanceDelta(ray, t, rng));
  }
  ratio.n = ratioRR.n = delta.n = N;
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(ratio.mean(c), expected[c], 4 * ratio.se(c) + 1e-6) << "ratio tracking, channel " << c;
    EXPECT_NEAR(ratioRR.mean(c), expected[c], 4 * ratioRR.se(c) + 1e-6) << "with roulette, channel " << c;
    EXPECT_NEAR(delta.mean(c), expected[c], 4 * delta.se(c) + 1e-6) << "delta tracking, channel " << c;
  }
  // Ratio tracking of the densest channel: every collision multiplies it by (1 − 1/(1+1e-5)).
  EXPECT_LT(ratio.se(1), delta.se(1));
}

TEST(HeterogeneousMedium, ConstantDensityMeanFreePathIsTheHomogeneousMediums) {
  // Voxels ±40 of 0.5: the flight ends by 19.5, where e^{−σ L} is at most 6e-5.
  const HeterogeneousMedium med = constant(0.5f, 40);
  Ray ray;
  ray.o = Vec3(0.1f, 0.2f, 0.3f);
  ray.d = Vec3(0, 0, 1);
  const float L = 19.5f;
  // E[w_c t; scattered] = α_c ∫_0^L σ t e^{−σ t} dt; E[w_c; passed] = e^{−σ L}.
  Stat tw, passed;
  Rng rng(5);
  const int N = 60000;
  for (int i = 0; i < N; ++i) {
    const MediumFlight f = med.sampleFlight(ray, L, rng);
    tw.add(f.scattered ? f.weight * f.t : Vec3(0.0f));
    passed.add(f.scattered ? Vec3(0.0f) : f.weight);
    ASSERT_LE(maxComponent(f.weight), 3 * average(f.weight) * 1.0001f);  // bounded weights
  }
  tw.n = passed.n = N;
  for (int c = 0; c < 3; ++c) {
    const double s = kSigma[c], sL = s * L;
    const double mfp = (1 - std::exp(-sL) * (1 + sL)) / s;  // 1/σ but for the far end
    EXPECT_NEAR(tw.mean(c) / kAlbedo[c], mfp, 4 * tw.se(c) / kAlbedo[c]) << "channel " << c;
    // The homogeneous medium's mean free path, but for e^{−σL}(1 + σL) < 1e-3 of it.
    EXPECT_NEAR(mfp * kSigma[c], mediumFromRte(kSigma, kAlbedo, PhaseTable::isotropic()).meanFreePath()[c] * kSigma[c], 1e-3);
    EXPECT_NEAR(passed.mean(c), std::exp(-sL), 4 * passed.se(c) + 1e-6);
  }
}

TEST(HeterogeneousMedium, LinearGradientTransmittanceIsExpOfTheIntegral) {
  const Vec3 sigma(1.0f, 1.5f, 0.7f);
  const HeterogeneousMedium med = gradient(sigma);
  EXPECT_NEAR(med.density(Vec3(0.52f, 0.1f, -0.3f)), 1 + kGrad * 0.52f, 1e-5f);  // trilinear is exact on it
  Ray ray;
  ray.o = Vec3(-1.2f, 0.03f, 0.02f);
  ray.d = Vec3(1.0f, 0.2f, -0.1f) * 2.0f;  // not unit: t is the ray's parameter
  const float t = 1.1f;
  const Vec3 expected = vexp(-gradientDepth(sigma, ray.o, ray.d, t));
  Stat ratio, delta;
  Rng rng(3);
  const int N = 40000;
  int64_t lookupsRatio = 0, lookupsDelta = 0;
  for (int i = 0; i < N; ++i) {
    ratio.add(med.transmittance(ray, t, rng, false, &lookupsRatio));
    delta.add(med.transmittanceDelta(ray, t, rng, &lookupsDelta));
  }
  ratio.n = delta.n = N;
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(ratio.mean(c), expected[c], 4 * ratio.se(c)) << "ratio tracking, channel " << c;
    EXPECT_NEAR(delta.mean(c), expected[c], 4 * delta.se(c)) << "delta tracking, channel " << c;
    EXPECT_GT(ratio.se(c), 0.0);
  }
  EXPECT_GT(lookupsRatio, 0);
  // The same ray started inside, at tmin: the depth of the remaining part.
  Ray inside = ray;
  inside.tmin = 0.4f;
  const Vec3 rest = vexp(-(gradientDepth(sigma, ray.o, ray.d, t) - gradientDepth(sigma, ray.o, ray.d, 0.4)));
  Stat part;
  for (int i = 0; i < N; ++i) part.add(med.transmittance(inside, t, rng, true));
  part.n = N;
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(part.mean(c), rest[c], 4 * part.se(c));
}

TEST(HeterogeneousMedium, CollisionDensityIsSigmaTimesTransmittance) {
  const Vec3 sigma(1.0f, 1.5f, 0.7f);
  const HeterogeneousMedium med = gradient(sigma);
  Ray ray;
  ray.o = Vec3(-1.3f, -0.2f, 0.1f);
  ray.d = normalize(Vec3(1.0f, 0.15f, 0.05f));
  const float tmax = 2.5f;
  const int bins = 20, N = 100000;
  std::vector<Stat> hist(bins);
  Stat passed;
  Rng rng(17);
  for (int i = 0; i < N; ++i) {
    const MediumFlight f = med.sampleFlight(ray, tmax, rng);
    for (int b = 0; b < bins; ++b) {
      const bool in = f.scattered && int(f.t / tmax * bins) == b;
      hist[size_t(b)].add(in ? f.weight : Vec3(0.0f));
    }
    passed.add(f.scattered ? Vec3(0.0f) : f.weight);
  }
  passed.n = N;
  for (int b = 0; b < bins; ++b) {
    Stat& s = hist[size_t(b)];
    s.n = N;
    const double ta = double(b) * tmax / bins, tb = double(b + 1) * tmax / bins;
    // ∫_bin α σ(t) T(t) dt = α (T(ta) − T(tb)).
    const Vec3 Ta = vexp(-gradientDepth(sigma, ray.o, ray.d, ta)), Tb = vexp(-gradientDepth(sigma, ray.o, ray.d, tb));
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(s.mean(c), kAlbedo[c] * (Ta[c] - Tb[c]), 4.5 * s.se(c)) << "bin " << b << ", channel " << c;
  }
  const Vec3 T = vexp(-gradientDepth(sigma, ray.o, ray.d, tmax));
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(passed.mean(c), T[c], 4.5 * passed.se(c));
}

TEST(HeterogeneousMedium, VacuumOutsideTheVoxelsAndInEmptyBlocks) {
  // Two slabs |x| in [0.8, 1.5] with nothing between them but zeros.
  VoxelLeaves v = VoxelLeaves::fromFunction(0.05f, {-30, -16, -16}, {30, 16, 16}, [](int64_t i, int64_t, int64_t) {
    return std::abs(i) >= 16 ? 1.0 : 0.0;
  });
  const HeterogeneousMedium med(std::move(v), 1.0f, reference(), "slabs");
  Rng rng(1);
  Ray miss;
  miss.o = Vec3(0.0f, 5.0f, 0.0f);
  miss.d = Vec3(1.0f, 0.0f, 0.0f);
  int64_t lookups = 0;
  EXPECT_EQ(med.transmittance(miss, 100.0f, rng, true, &lookups), Vec3(1.0f));
  const MediumFlight f = med.sampleFlight(miss, 100.0f, rng);
  EXPECT_FALSE(f.scattered);
  EXPECT_EQ(f.weight, Vec3(1.0f));
  EXPECT_EQ(f.lookups, 0);
  // Along y in the gap (x = 0): blocks of majorant 0, not a single lookup.
  Ray gap;
  gap.o = Vec3(0.01f, -2.0f, 0.01f);
  gap.d = Vec3(0.0f, 1.0f, 0.0f);
  EXPECT_EQ(med.transmittance(gap, 4.0f, rng, true, &lookups), Vec3(1.0f));
  EXPECT_EQ(lookups, 0);
  EXPECT_EQ(med.majorant(Vec3(0.01f, 0.0f, 0.01f)), 0.0f);
  EXPECT_EQ(med.sigmaT(Vec3(9.0f, 0.0f, 0.0f)), Vec3(0.0f));
  EXPECT_GT(med.majorant(Vec3(1.0f, 0.0f, 0.0f)), 0.0f);
}

TEST(HeterogeneousMedium, MajorantsBoundSigmaEverywhere) {
  // A rough field: each voxel its own hash.
  VoxelLeaves v = VoxelLeaves::fromFunction(0.1f, {-20, -20, -20}, {19, 19, 19}, [](int64_t i, int64_t j, int64_t k) {
    return toUnitFloat(hashInts(4, uint64_t(i), uint64_t(j), uint64_t(k)));
  });
  const HeterogeneousMedium med(std::move(v), 0.6f, reference(), "rough");
  Rng rng(2);
  for (int n = 0; n < 200000; ++n) {
    const Vec3 p = Vec3(rng.next1D(), rng.next1D(), rng.next1D()) * 5.0f - Vec3(2.5f);
    ASSERT_LE(maxComponent(med.sigmaT(p)), med.majorant(p)) << p.x << " " << p.y << " " << p.z;
  }
}

TEST(HeterogeneousMedium, DeterministicGivenTheRng) {
  const HeterogeneousMedium med = gradient(Vec3(1.0f, 1.5f, 0.7f));
  Ray ray;
  ray.o = Vec3(-1.3f, 0.0f, 0.0f);
  ray.d = Vec3(1.0f, 0.0f, 0.0f);
  for (uint64_t s = 0; s < 50; ++s) {
    Rng a(s, 3), b(s, 3);
    const MediumFlight fa = med.sampleFlight(ray, 2.5f, a), fb = med.sampleFlight(ray, 2.5f, b);
    EXPECT_EQ(fa.t, fb.t);
    EXPECT_EQ(fa.weight, fb.weight);
    EXPECT_EQ(med.transmittance(ray, 2.5f, a), med.transmittance(ray, 2.5f, b));
  }
}

TEST(HeterogeneousMedium, FollowsTheGrainsPackingRate) {
  // A simple cubic lattice: σ_t inside is σ_t,ref at the lattice's packing rate.
  InstancedGrainsDesc desc;
  desc.name = "/World/Grains";
  GrainPrototypeDesc sphere;
  sphere.name = "/World/Grains/Sphere";
  sphere.mesh = makeIcosphere(2);
  desc.prototypes.push_back(sphere);
  for (int i = 0; i < 10; ++i)
    for (int j = 0; j < 10; ++j)
      for (int k = 0; k < 10; ++k) {
        desc.positions.push_back(Vec3(float(i), float(j), float(k)));
        desc.scales.push_back(0.45f);
        desc.protoIndices.push_back(0);
      }
  GrainDensityOptions opt;
  opt.kernelWidth = 1.35f;
  const GrainDensity g = buildGrainDensity(desc, opt);
  const float fRef = float(std::fabs(sphere.mesh.signedVolume()) * 0.45 * 0.45 * 0.45);
  MediumParams ref = mediumFromRte(kSigma, kAlbedo, PhaseTable::isotropic());
  ref.packingRate = fRef;
  const HeterogeneousMedium med(g, ref, desc.name);
  const Vec3 s = med.sigmaT(Vec3(4.6f, 4.3f, 4.4f));
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(s[c] / kSigma[c], 1.0f, 0.02f);  // the lattice's aliasing, about 1%
  EXPECT_EQ(med.sigmaT(Vec3(-4.0f, 4.0f, 4.0f)), Vec3(0.0f));
  EXPECT_GT(med.bytes(), g.packing.bytes());
}
