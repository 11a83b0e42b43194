// Grain density (core/grain_density.*): a simple cubic lattice of grains gives its packing
// rate inside, to the kernel's aliasing bound on the lattice (Poisson summation), nothing
// beyond the kernel's reach, half of it at the lattice's face; mixtures' number fractions
// sum to 1 and give the mix; volume is conserved; the build does not depend on threads.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <vector>

#include <tbb/task_arena.h>

#include "core/error.h"
#include "core/grain_density.h"
#include "core/rng.h"
#include "core/shapes.h"

using namespace granular;

namespace {

// The 1-D cubic B-spline (knot spacing 1) and the kernel W of width h, written here
// independently of core as the reference.
double b3(double x) {
  x = std::fabs(x);
  return x < 1 ? 2.0 / 3 - x * x + x * x * x / 2 : (x < 2 ? (2 - x) * (2 - x) * (2 - x) / 6 : 0.0);
}

double sinc4(double x) {
  const double s = x == 0 ? 1.0 : std::sin(x) / x;
  return s * s * s * s;
}

// Σ over the nonzero reciprocal-lattice vectors G of |Ŵ(G)|, Ŵ(ν) = Π_a sinc⁴(π ν_a h): how
// far a lattice's kernel sum can stray from its mean (Poisson summation). bcc: the
// reciprocal of a face-centred sublattice (all of h, k, l of one parity, in units 1/(2a)).
double aliasingBound(double h, double a, bool bcc) {
  double sum = 0;
  const int M = 24;
  for (int i = -M; i <= M; ++i)
    for (int j = -M; j <= M; ++j)
      for (int k = -M; k <= M; ++k) {
        if (i == 0 && j == 0 && k == 0) continue;
        double unit = 1 / a;
        if (bcc) {
          if (((i & 1) != (j & 1)) || ((j & 1) != (k & 1))) continue;
          unit = 1 / (2 * a);
        }
        sum += sinc4(kPiD * i * unit * h) * sinc4(kPiD * j * unit * h) * sinc4(kPiD * k * unit * h);
      }
  return sum;
}

struct Lattice {
  InstancedGrainsDesc desc;
  double spacing = 1, grainVolume[2] = {0, 0};
  int n = 12;
  Vec3 origin;
};

// n³ grains at origin + spacing (i, j, k); prototype 0 an icosphere of radius `radius`, and
// (mixed) prototype 1 a rock of the same scale on the sites of odd i + j + k.
Lattice lattice(int n, double spacing, float radius, const Vec3& origin, bool mixed) {
  Lattice L;
  L.n = n;
  L.spacing = spacing;
  L.origin = origin;
  L.desc.name = "/World/Lattice";
  GrainPrototypeDesc sphere;
  sphere.name = "/World/Lattice/Sphere";
  sphere.mesh = makeIcosphere(3);
  L.desc.prototypes.push_back(sphere);
  L.grainVolume[0] = std::fabs(sphere.mesh.signedVolume()) * radius * radius * radius;
  if (mixed) {
    GrainPrototypeDesc rock;
    rock.name = "/World/Lattice/Rock";
    rock.mesh = makeRock(2, 0.3f, 7);
    L.desc.prototypes.push_back(rock);
    L.grainVolume[1] = std::fabs(rock.mesh.signedVolume()) * radius * radius * radius;
  }
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      for (int k = 0; k < n; ++k) {
        L.desc.positions.push_back(origin + Vec3(float(i * spacing), float(j * spacing), float(k * spacing)));
        L.desc.scales.push_back(radius);
        L.desc.protoIndices.push_back(mixed ? (i + j + k) & 1 : 0);
      }
  return L;
}

// The reference: Σ_i V_i W(x − c_i) by brute force (sphere centroids are their centres).
double referenceDensity(const Lattice& L, double h, const Vec3& x) {
  double f = 0;
  for (size_t g = 0; g < L.desc.size(); ++g) {
    const Vec3 d = x - L.desc.positions[g];
    f += L.grainVolume[L.desc.protoIndices[g]] * b3(d.x / h) * b3(d.y / h) * b3(d.z / h) / (h * h * h);
  }
  return f;
}

}  // namespace

TEST(GrainDensity, LatticeGivesItsPackingRateInsideNothingOutsideAndHalfAtItsFace) {
  const double a = 1.0, h = 1.35;
  const float delta = float(h / 2);
  const int n = 12;
  // Shift the lattice so that its face (the last plane + a/2) lies on a voxel centre.
  const float o = 17 * delta - float((n - 0.5) * a);
  Lattice L = lattice(n, a, 0.45f, Vec3(o), false);
  GrainDensityOptions opt;
  opt.kernelWidth = float(h);
  GrainDensity g = buildGrainDensity(L.desc, opt);
  ASSERT_FLOAT_EQ(g.packing.voxelSize, delta);
  EXPECT_EQ(g.stats.grains, n * n * n);
  EXPECT_NEAR(g.stats.meanRadius, 0.45f, 1e-3f);  // the icosphere's bounding radius × scale
  const double fRef = L.grainVolume[0] / (a * a * a);
  // Every voxel centre whose kernel support holds only existing planes sees the infinite
  // lattice: within the aliasing bound of fRef, plus float rounding.
  const double bound = aliasingBound(h, a, false) + 1e-5;
  ASSERT_LT(bound, 0.02);
  auto interior = [&](double x) { return x - o > 2 * h - a && x - o < n * a - 2 * h; };
  int checked = 0;
  double worst = 0;
  for (int i = -10; i < 40; ++i)
    for (int j = -10; j < 40; ++j)
      for (int k = -10; k < 40; ++k) {
        const Vec3 x(i * delta, j * delta, k * delta);
        const float f = g.packing.voxel(i, j, k);
        if (interior(x.x) && interior(x.y) && interior(x.z)) {
          worst = std::max(worst, std::fabs(f / fRef - 1));
          ++checked;
        }
        // Beyond 2h of every centre along some axis: exactly 0, and not active.
        // (Trilinear sampling reaches a voxel further.)
        auto outside = [&](float c, double margin) {
          return c - o <= -2 * h - margin || c - o >= (n - 1) * a + 2 * h + margin;
        };
        if (outside(x.x, 0) || outside(x.y, 0) || outside(x.z, 0)) ASSERT_EQ(f, 0.0f) << i << " " << j << " " << k;
        if (outside(x.x, delta) || outside(x.y, delta) || outside(x.z, delta)) ASSERT_EQ(g.packing.sample(x), 0.0f);
      }
  EXPECT_GT(checked, 1000);
  EXPECT_LE(worst, bound) << "interior voxels stray by " << worst << " of the packing rate " << fRef;
  // The soft edge: the profile across the face is the kernel's (the brute-force sum),
  // full inside, 0 beyond 2h past the last plane, and at the face about half.
  // At voxel centres the field is the kernel sum itself (between them, trilinear).
  const float mid = std::round((o + float(n / 2) * float(a) + 0.3f * float(a)) / delta) * delta;
  for (int k = 0; k < 30; ++k) {
    const Vec3 x(mid, mid, k * delta);
    const double ref = referenceDensity(L, h, x);
    EXPECT_NEAR(g.packingRate(x), ref, 2e-5 * fRef) << "z " << x.z;
  }
  const float face = 17 * delta;
  const double half = g.packingRate(Vec3(mid, mid, face)) / fRef;
  // The 1-D midpoint sum of the kernel over the planes behind the face, against 1/2: the
  // lattice's own discreteness; the other two axes add the interior bound.
  double oneAxis = 0;
  for (int k = 0; k < 8; ++k) oneAxis += a / h * b3((k + 0.5) * a / h);
  EXPECT_NEAR(half, 0.5, std::fabs(oneAxis - 0.5) + bound);
  EXPECT_GT(g.packingRate(Vec3(mid, mid, face - float(2 * h))), (1 - bound) * fRef);
  EXPECT_EQ(g.packingRate(Vec3(mid, mid, face - float(a / 2) + float(2 * h) + delta)), 0.0f);
}

TEST(GrainDensity, VolumeIsConservedAndTheBuildDoesNotDependOnThreads) {
  Lattice L = lattice(9, 1.0, 0.45f, Vec3(0.31f, -2.2f, 5.05f), true);
  // Jitter the grains so that nothing is symmetric.
  for (size_t i = 0; i < L.desc.size(); ++i) {
    const uint64_t hsh = hashInts(9, i);
    L.desc.positions[i] += Vec3(toUnitFloat(hsh) - 0.5f, toUnitFloat(hsh << 20) - 0.5f, toUnitFloat(hsh << 40) - 0.5f) * 0.2f;
    L.desc.scales[i] *= 0.8f + 0.2f * toUnitFloat(mix64(hsh));
  }
  GrainDensity one, two;
  tbb::task_arena(1).execute([&] { one = buildGrainDensity(L.desc); });
  tbb::task_arena(2).execute([&] { two = buildGrainDensity(L.desc); });
  ASSERT_EQ(one.packing.origins, two.packing.origins);
  ASSERT_EQ(one.packing.values.size(), two.packing.values.size());
  EXPECT_EQ(std::memcmp(one.packing.values.data(), two.packing.values.data(), one.packing.values.size() * 4), 0);
  ASSERT_EQ(one.fractions.size(), 2u);
  EXPECT_EQ(std::memcmp(one.fractions[1].values.data(), two.fractions[1].values.data(),
                        one.fractions[1].values.size() * 4), 0);
  // Σ f Δ³ over the voxels = Σ V_i (the kernel's weights sum to 1 over the voxels).
  double volume = 0, voxels = 0;
  for (size_t g = 0; g < L.desc.size(); ++g) {
    const double s = L.desc.scales[g];
    volume += std::fabs(L.desc.prototypes[size_t(L.desc.protoIndices[g])].mesh.signedVolume()) * s * s * s;
  }
  for (float f : one.packing.values) voxels += f;
  const double d3 = std::pow(double(one.packing.voxelSize), 3);
  EXPECT_NEAR(voxels * d3 / volume, 1.0, 1e-5);
  EXPECT_NEAR(one.stats.totalVolume / volume, 1.0, 1e-6);
  EXPECT_EQ(one.stats.bytes, 3 * one.packing.bytes());
}

TEST(GrainDensity, EveryVoxelIsTheSumOverItsGrainsAcrossSlabsAndGaps) {
  // Jittered grains in two clusters along x with a gap of empty leaves between them: the
  // build fills leaves one slab (constant x) at a time from its neighbours' grains, so
  // every voxel near a slab's face, and on both sides of the gap, is compared with the
  // sum over all grains written here (each axis's weights normalised over the support).
  Lattice L = lattice(7, 1.0, 0.45f, Vec3(0.13f, 0.4f, -0.27f), false);
  Lattice far = lattice(5, 1.0, 0.45f, Vec3(31.2f, 1.1f, 0.5f), false);
  L.desc.positions.insert(L.desc.positions.end(), far.desc.positions.begin(), far.desc.positions.end());
  L.desc.scales.insert(L.desc.scales.end(), far.desc.scales.begin(), far.desc.scales.end());
  L.desc.protoIndices.insert(L.desc.protoIndices.end(), far.desc.protoIndices.begin(), far.desc.protoIndices.end());
  for (size_t i = 0; i < L.desc.size(); ++i) {
    const uint64_t hsh = hashInts(17, i);
    L.desc.positions[i] += Vec3(toUnitFloat(hsh) - 0.5f, toUnitFloat(hsh << 20) - 0.5f, toUnitFloat(hsh << 40) - 0.5f) * 0.3f;
  }
  const double h = 0.9;
  // Voxels whose kernel reach 2h/Δ is a whole number and not (7.997, 2.86): a home leaf's
  // grains then reach ⌈2h/Δ⌉ voxels past it on one side.
  for (const double voxelOverH : {0.25, 0.2501, 0.5, 0.7, 1.0}) {
    GrainDensityOptions opt;
    opt.kernelWidth = float(h);
    opt.voxelSize = float(voxelOverH * h);
    const GrainDensity g = buildGrainDensity(L.desc, opt);
    const double delta = g.packing.voxelSize, reach = 2 * h / delta;
    auto weights = [&](double u, int64_t& s0, std::vector<double>& w) {  // one axis, voxel units
      s0 = int64_t(std::ceil(u - reach));
      const int64_t s1 = int64_t(std::floor(u + reach));
      double norm = 0;
      w.clear();
      for (int64_t j = s0; j <= s1; ++j) w.push_back(b3((double(j) - u) * delta / h));
      for (double x : w) norm += x;
      for (double& x : w) x /= norm;
    };
    // The reference on a dense box of voxels around both clusters.
    const int64_t lo[3] = {int64_t(std::floor(-3 / delta)), int64_t(std::floor(-3 / delta)), int64_t(std::floor(-3 / delta))};
    const int64_t hi[3] = {int64_t(std::ceil(40 / delta)), int64_t(std::ceil(10 / delta)), int64_t(std::ceil(10 / delta))};
    const int64_t nx = hi[0] - lo[0] + 1, ny = hi[1] - lo[1] + 1, nz = hi[2] - lo[2] + 1;
    std::vector<double> ref(size_t(nx * ny * nz), 0.0);
    const double volume = L.grainVolume[0] / (0.45 * 0.45 * 0.45);
    for (size_t i = 0; i < L.desc.size(); ++i) {
      const double s = L.desc.scales[i], v = volume * s * s * s / (delta * delta * delta);
      int64_t s0[3];
      std::vector<double> w[3];
      for (int a = 0; a < 3; ++a) weights(double(L.desc.positions[i][a]) / delta, s0[a], w[a]);
      for (size_t x = 0; x < w[0].size(); ++x)
        for (size_t y = 0; y < w[1].size(); ++y)
          for (size_t z = 0; z < w[2].size(); ++z)
            ref[size_t(((s0[0] + int64_t(x) - lo[0]) * ny + s0[1] + int64_t(y) - lo[1]) * nz + s0[2] + int64_t(z) - lo[2])] +=
                v * w[0][x] * w[1][y] * w[2][z];
    }
    double worst = 0, peak = 0;
    int64_t nonzero = 0;
    for (int64_t x = lo[0]; x <= hi[0]; ++x)
      for (int64_t y = lo[1]; y <= hi[1]; ++y)
        for (int64_t z = lo[2]; z <= hi[2]; ++z) {
          const double r = ref[size_t(((x - lo[0]) * ny + y - lo[1]) * nz + z - lo[2])];
          const float f = g.packing.voxel(x, y, z);
          peak = std::max(peak, r);
          worst = std::max(worst, std::fabs(double(f) - r));
          nonzero += f > 0;
        }
    // Float storage and a different order of summation: a few float roundings of the peak.
    EXPECT_LE(worst, 1e-6 * peak) << "voxel " << voxelOverH << " h";
    EXPECT_EQ(nonzero, g.stats.activeVoxels) << "voxel " << voxelOverH << " h";  // nothing outside the box
    EXPECT_GT(nonzero, 0);
  }
}

TEST(GrainDensity, FractionsOfAMixSumToOneAndGiveTheMix) {
  const double a = 1.0, h = 1.35;
  const int n = 12;
  Lattice L = lattice(n, a, 0.45f, Vec3(0.0f), true);
  GrainDensityOptions opt;
  opt.kernelWidth = float(h);
  GrainDensity g = buildGrainDensity(L.desc, opt);
  ASSERT_EQ(g.fractions.size(), 2u);
  EXPECT_EQ(g.prototypeNames[1], "/World/Lattice/Rock");
  // Every active voxel: the fractions sum to 1; inactive ones hold 0.
  int64_t active = 0;
  for (size_t v = 0; v < g.packing.values.size(); ++v) {
    const float s = g.fractions[0].values[v] + g.fractions[1].values[v];
    if (g.packing.values[v] > 0) {
      ++active;
      ASSERT_NEAR(s, 1.0f, 1e-5f);
    } else {
      ASSERT_EQ(s, 0.0f);
    }
  }
  EXPECT_EQ(active, g.stats.activeVoxels);
  // Inside, each prototype's number fraction is 1/2 to the aliasing of its face-centred
  // sublattice (and 0 beyond reach).
  const double bound = aliasingBound(h, a, true) + 1e-5;
  ASSERT_LT(bound, 0.05);
  double worst = 0;
  const float delta = g.packing.voxelSize;
  for (int i = 0; i < 20; ++i)
    for (int j = 0; j < 20; ++j)
      for (int k = 0; k < 20; ++k) {
        const Vec3 x(i * delta, j * delta, k * delta);
        auto interior = [&](double c) { return c > 2 * h - a && c < n * a - 2 * h; };
        if (!interior(x.x) || !interior(x.y) || !interior(x.z)) continue;
        worst = std::max(worst, double(std::fabs(g.numberFraction(1, x) - 0.5f)));
      }
  EXPECT_LE(worst, bound);
  EXPECT_EQ(g.numberFraction(0, Vec3(-10.0f)), 0.0f);
  // The packing rate inside is the two grains' mean volume per cell.
  const double fRef = 0.5 * (L.grainVolume[0] + L.grainVolume[1]) / (a * a * a);
  const Vec3 centre(float(n / 2) * float(a) + 0.2f);
  EXPECT_NEAR(g.packingRate(centre) / fRef, 1.0, aliasingBound(h, a, true) * 2 + 1e-4);
}

TEST(GrainDensity, FollowsTheInstancersTransform) {
  Lattice L = lattice(8, 1.0, 0.45f, Vec3(0.0f), false);
  GrainDensityOptions opt;
  opt.kernelWidth = 1.35f;
  GrainDensity g = buildGrainDensity(L.desc, opt);
  // Twice as large and moved by 3 (new) voxels: the same packing rate at the moved points.
  L.desc.xf = Transform::translate(3 * 1.35, 0, 0) * Transform::scale(Vec3(2.0f));
  opt.kernelWidth = 2.7f;
  GrainDensity moved = buildGrainDensity(L.desc, opt);
  EXPECT_NEAR(moved.stats.meanRadius, 0.9f, 2e-3f);
  for (int i = 0; i < 24; i += 3)
    for (int k = -4; k < 24; k += 5) {
      const Vec3 x(i * g.packing.voxelSize, 4 * g.packing.voxelSize, k * g.packing.voxelSize);
      EXPECT_NEAR(moved.packingRate(x * 2.0f + Vec3(3 * 1.35f, 0, 0)), g.packingRate(x), 1e-5f);
    }
}

TEST(GrainDensity, BadOptionsNameTheInstancerAndTheSetting) {
  Lattice L = lattice(2, 1.0, 0.45f, Vec3(0.0f), false);
  GrainDensityOptions opt;
  opt.kernelWidth = -1;
  try {
    buildGrainDensity(L.desc, opt);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.object(), "/World/Lattice");
    EXPECT_EQ(e.attribute(), "kernelWidth");
  }
  opt.kernelWidth = 1;
  opt.voxelSize = 0.1f;  // below h/4: a kernel would reach beyond its neighbouring leaves
  try {
    buildGrainDensity(L.desc, opt);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.attribute(), "voxelSize");
  }
  opt.voxelSize = 0;
  L.desc.scales[1] = -1;
  try {
    buildGrainDensity(L.desc, opt);
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.attribute(), "scales");
  }
}
