// DA in the heterogeneous medium of simulated grains (core/heterogeneous_diffusion.h): the
// level-set boundary against a block's known faces, the rule's decisions on uniform and
// graded slabs, and the hybrid with DA against the hybrid without it (VPT to the end).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>

#include "core/heterogeneous_diffusion.h"
#include "core/render.h"
#include "core/scene.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;
using granular::testing::randomRotation;

namespace {

// Bright sand (little absorption: paths scatter long enough for DA) under a sun and a sky.
SceneDesc baseScene(uint64_t seed) {
  SceneDesc s;
  s.settings.width = s.settings.height = 16;
  s.settings.spp = 256;
  s.settings.seed = seed;
  s.settings.technique = Technique::Hybrid;
  s.settings.explicitBounces = 0;  // the medium from the first grain on: DA's part is what differs
  s.settings.proxies = ProxyUse::Off;
  s.settings.roulette = 1.0f;
  s.settings.daInstanced = true;  // off by default
  MaterialDesc sand;
  sand.name = "sand";
  sand.type = MaterialType::Dielectric;
  sand.ior = 1.5f;
  sand.absorption = Vec3(0.02f, 0.04f, 0.1f);
  s.materials = {sand};
  s.lights = granular::testing::sunAndSky();
  return s;
}

// An instancer of no grains yet with one prototype: a unit icosphere of the sand.
InstancedGrainsDesc roundGrains(const char* name, const char* proto, int id) {
  InstancedGrainsDesc g;
  g.name = name;
  g.id = id;
  GrainPrototypeDesc round;
  round.name = proto;
  round.mesh = makeIcosphere(2);
  round.material = 0;
  g.prototypes = {round};
  return g;
}

// A block of N³ grains on a cubic lattice of spacing a (unit spheres, scale 1), centred on
// the origin: each grain fills its lattice cell's share, so the block's faces are at ±N a/2.
InstancedGrainsDesc latticeBlock(int n, float a) {
  InstancedGrainsDesc g = roundGrains("/World/Block", "/World/Block/Round", 1);
  for (int z = 0; z < n; ++z)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) {
        g.positions.push_back((Vec3(float(x), float(y), float(z)) + Vec3(0.5f - 0.5f * float(n))) * a);
        g.protoIndices.push_back(0);
      }
  return g;
}

// Unit spheres on the lattice of spacing a whose centres lie within radius R of the origin.
InstancedGrainsDesc latticeBall(float R, float a) {
  InstancedGrainsDesc g = roundGrains("/World/Block", "/World/Block/Round", 1);
  const int n = int(R / a) + 1;
  for (int z = -n; z <= n; ++z)
    for (int y = -n; y <= n; ++y)
      for (int x = -n; x <= n; ++x) {
        const Vec3 c = Vec3(float(x), float(y), float(z)) * a;
        if (length(c) > R) continue;
        g.positions.push_back(c);
        g.protoIndices.push_back(0);
      }
  return g;
}

// A slab |x|, |z| < X, −H < y < 0 of round grains (bounding radius 1 × scale, scales in
// [0.85, 0.95]) placed by random sequential addition up to `attempts` candidates (a random
// packing, as the slab of test_instanced_grains.cpp), in grain units scaled by 0.05.
// graded: then thinned, a grain at x > 0 kept with probability 1 − 0.5 x / X (half the
// packing at the edge x = X, the half x < 0 uniform).
InstancedGrainsDesc rsaSlab(bool graded, float X, float H, int attempts) {
  std::mt19937 rng(31);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  InstancedGrainsDesc g = roundGrains("/World/Grains", "/World/Grains/Round", 3);
  const float cell = 2.0f;
  const int nc[3] = {int(2 * X / cell) + 1, int(H / cell) + 1, int(2 * X / cell) + 1};
  std::vector<std::vector<int>> grid(size_t(nc[0]) * nc[1] * nc[2]);
  std::vector<Vec3> centres;
  std::vector<float> scales;
  for (int attempt = 0; attempt < attempts; ++attempt) {
    const Vec3 c(X * (2 * u(rng) - 1), -H * u(rng), X * (2 * u(rng) - 1));
    const float scale = 0.85f + 0.1f * u(rng);
    const int ci[3] = {int((c.x + X) / cell), int(-c.y / cell), int((c.z + X) / cell)};
    bool free = true;
    for (int dz = -1; dz <= 1 && free; ++dz)
      for (int dy = -1; dy <= 1 && free; ++dy)
        for (int dx = -1; dx <= 1 && free; ++dx) {
          const int x = ci[0] + dx, y = ci[1] + dy, z = ci[2] + dz;
          if (x < 0 || y < 0 || z < 0 || x >= nc[0] || y >= nc[1] || z >= nc[2]) continue;
          for (int k : grid[(size_t(z) * nc[1] + y) * nc[0] + x])
            if (length(centres[size_t(k)] - c) < scale + scales[size_t(k)]) free = false;
        }
    if (!free) continue;
    grid[(size_t(ci[2]) * nc[1] + ci[1]) * nc[0] + ci[0]].push_back(int(centres.size()));
    centres.push_back(c);
    scales.push_back(scale);
  }
  for (size_t i = 0; i < centres.size(); ++i) {
    if (graded && centres[i].x > 0 && u(rng) >= 1.0f - 0.5f * centres[i].x / X) continue;
    g.positions.push_back(centres[i]);
    g.orientations.push_back(randomRotation(rng));
    g.scales.push_back(scales[i]);
    g.protoIndices.push_back(0);
  }
  g.xf = Transform::scale(Vec3(0.05f));
  return g;
}

SceneDesc slabScene(bool graded, uint64_t seed, bool da) {
  SceneDesc s = baseScene(seed);
  s.settings.daInstanced = da;
  s.camera.cameraToWorld = Transform::lookAt(Vec3(0.0f, 3.0f, 1.5f), Vec3(0.0f, -0.3f, 0.0f), Vec3(0, 1, 0));
  s.camera.focalLength = 50;
  s.camera.horizontalAperture = s.camera.verticalAperture = 16;
  s.instancedGrains.push_back(rsaSlab(graded, 110.0f, 50.0f, 5000000));
  // The ground card it lies on, through its lowest grains (as a heap stands on its ground):
  // DA's exits through the bottom stop at it (SurfaceCutBoundary), not below it under the
  // sky's lower half (the image +10.7% in red, +5.3% in green without that).
  MeshDesc ground;
  ground.name = "ground";
  ground.mesh.points = {Vec3(-8.0f, -2.5f, -8.0f), Vec3(8.0f, -2.5f, -8.0f), Vec3(8.0f, -2.5f, 8.0f),
                        Vec3(-8.0f, -2.5f, 8.0f)};
  ground.mesh.indices = {0, 2, 1, 0, 3, 2};
  s.meshes.push_back(ground);
  return s;
}

Vec3 renderSpace(const Scene& scene, const Vec3& world) {
  const Vec3d& o = scene.renderOrigin();
  return world - Vec3(float(o.x), float(o.y), float(o.z));
}


// Renders scene (settings daInstanced on) with DA and then, by a new view of the same
// scene, without it (VPT to the end in the instancer's medium), the same seed: paired
// per-pixel differences, DA − VPT, per channel: their mean, its standard error (pixels
// independent), the mean of the VPT image, the mean of the light DA carried (the da AOV),
// DA's share of the light and of the paths.
struct Paired {
  double diff[3] = {0, 0, 0}, se[3] = {0, 0, 0}, base[3] = {0, 0, 0}, daLight[3] = {0, 0, 0};
  double daShare = 0, daPaths = 0;
};

Paired compareWithoutDa(Scene& scene, const SceneDesc& desc) {
  Renderer ra(scene);
  EXPECT_TRUE(ra.render(desc.settings.spp));
  const Image a = ra.film().toImage();
  RenderSettings off = desc.settings;
  off.daInstanced = false;
  scene.setView(desc.camera, off);
  EXPECT_EQ(scene.instancedDiffusion(0), nullptr);
  Renderer rb(scene);
  EXPECT_TRUE(rb.render(desc.settings.spp));
  const Image b = rb.film().toImage();
  scene.setView(desc.camera, desc.settings);
  const int da = a.channelIndex("da.R");
  Paired p;
  const auto d = granular::testing::pairedDifference(a, b);
  for (int c = 0; c < 3; ++c) {
    p.diff[c] = d.diff[c];
    p.se[c] = d.se[c];
  }
  double total = 0, daSum = 0;
  const double n = double(a.width) * a.height;
  for (int y = 0; y < a.height; ++y)
    for (int x = 0; x < a.width; ++x)
      for (int c = 0; c < 3; ++c) {
        p.base[c] += b.at(x, y)[c] / n;
        p.daLight[c] += a.at(x, y)[da + c] / n;
        total += a.at(x, y)[c];
        daSum += a.at(x, y)[da + c];
      }
  p.daShare = total > 0 ? daSum / total : 0;
  p.daPaths = ra.diffusionFraction();
  return p;
}

SceneDesc blockScene() {
  SceneDesc s = baseScene(1);
  s.camera.cameraToWorld = Transform::lookAt(Vec3(60.0f, 80.0f, 100.0f), Vec3(0.0f), Vec3(0, 1, 0));
  s.camera.focalLength = 50;
  s.camera.horizontalAperture = s.camera.verticalAperture = 30;
  s.instancedGrains.push_back(latticeBlock(20, 2.3f));
  return s;
}

}  // namespace

// The known case: a block of 20³ unit spheres on a lattice of spacing 2.3 fills exactly the
// cube |x|, |y|, |z| < 23 (each grain its cell's share). Its level set lies on the cube's
// faces: the packing-rate field is the block smoothed by the symmetric kernel, so it passes
// half its bulk value on each face; the voxels (Δ = h = 3, the kernel's width) sample that
// ramp, whose trilinear interpolant and the binomial filter move a planar face's half
// level by a small fraction of Δ. Bounds: Δ/20 (0.15) for the distance along a face's
// normal, within a kernel's reach (2h) of the face; the same for rays leaving through a
// face's middle; normals within 1°; the exit point beyond the field's reach (f = 0).
TEST(HeterogeneousDiffusion, TheLevelSetOfAUniformBlockLiesOnItsFaces) {
  auto scene = Scene::build(blockScene());
  const HeterogeneousDiffusion* da = scene->instancedDiffusion(0);
  ASSERT_NE(da, nullptr);
  const LevelSetBoundary& b = da->boundary();
  const HeterogeneousMedium& med = *scene->instancedMedium(0);
  const float face = 23.0f, voxel = med.voxels().voxelSize, tol = 0.05f * voxel;
  ASSERT_NEAR(voxel, 3.0f, 0.1f);  // h = 3 mean radii of unit spheres
  // Along the normals of three faces, from 2h inside to 2h outside.
  for (int axis = 0; axis < 3; ++axis)
    for (float sign : {-1.0f, 1.0f})
      for (float s = -2 * da->skin(); s <= 2 * da->skin(); s += 0.7f) {
        Vec3 w(0.3f, -0.4f, 0.5f);
        w[axis] = sign * (face + s);
        const Vec3 p = renderSpace(*scene, w);
        EXPECT_NEAR(b.distance(p), s, tol) << "axis " << axis << " sign " << sign << " offset " << s;
        Vec3 n(0.0f);
        n[axis] = sign;
        EXPECT_GT(dot(b.normal(p), n), std::cos(1.0f * kPi / 180)) << "axis " << axis << " offset " << s;
      }
  // The closest point of a point 5 below the top face's middle.
  Vec3 c;
  const float z = b.closestPoint(renderSpace(*scene, Vec3(1.0f, face - 5.0f, -2.0f)), c);
  EXPECT_NEAR(z, 5.0f, tol);
  const Vec3 cw = c - renderSpace(*scene, Vec3(0.0f));
  EXPECT_NEAR(cw.x, 1.0f, tol);
  EXPECT_NEAR(cw.y, face, tol);
  EXPECT_NEAR(cw.z, -2.0f, tol);
  // Rays from inside leaving through a face at least 6 (2h) from its edges: the cube's exit.
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  int tested = 0;
  for (int k = 0; k < 400 && tested < 40; ++k) {
    const Vec3 d = normalize(Vec3(u(rng), u(rng), u(rng))), o = Vec3(u(rng), u(rng), u(rng)) * 10.0f;
    float ta = kInf;
    int exitAxis = 0;
    for (int a = 0; a < 3; ++a) {
      const float t = ((d[a] > 0 ? face : -face) - o[a]) / d[a];
      if (t < ta) ta = t, exitAxis = a;
    }
    const Vec3 q = o + d * ta;
    bool middle = true;
    for (int a = 0; a < 3; ++a) middle = middle && (a == exitAxis || std::fabs(q[a]) < face - 2 * da->skin());
    if (!middle) continue;
    ++tested;
    float t;
    Vec3 ng;
    ASSERT_TRUE(b.intersect(renderSpace(*scene, o), d, kInf, t, ng));
    EXPECT_NEAR(t, ta, tol / std::fabs(d[exitAxis])) << "ray " << k;
    EXPECT_GT(std::fabs(ng[exitAxis]), std::cos(1.0f * kPi / 180)) << "ray " << k;
    // Where the light is out of the medium: f = 0 there, within the field's reach.
    const Vec3 e = b.exitPoint(renderSpace(*scene, q), ng);
    EXPECT_EQ(med.density(e), 0.0f) << "ray " << k;
    EXPECT_LE(length(e - renderSpace(*scene, q)), da->skin() + 2 * voxel + 1e-3f);
  }
  EXPECT_EQ(tested, 40);
  // The bulk is the block's packing: 20³ spheres of the icosphere's volume in 46³.
  double volume = 0;
  Vec3 centroid;
  meshVolumeCentroid(makeIcosphere(2), volume, centroid);
  EXPECT_NEAR(da->bulk(), volume / (2.3 * 2.3 * 2.3), 0.01 * da->bulk());
}


// The rule (heterogeneous_diffusion.h) on the two slabs, at points between the DA depth
// and the slab's middle, away from its sides: on the uniform slab the packing never varies
// beyond the tolerance; on the graded one it does wherever the region reaches into the
// graded half, by at least the thinning's own ratio over the region, and not where the
// region stays in the uniform half. Then the hybrid with DA against the hybrid without it
// (VPT to the end), pixel-paired, same seed: within 3% of the light DA carries (DA's own
// error on homogeneous media) plus three standard errors per channel, with
// DA carrying a good part of the uniform slab's paths and fewer of the graded slab's (its
// graded half refuses DA; the camera looks at the step between its halves).
TEST(HeterogeneousDiffusion, TheRuleTakesAUniformSlabAndRefusesWherePackingVaries) {
  double uniformPaths = 0;
  for (bool graded : {false, true}) {
    const SceneDesc desc = slabScene(graded, 5, true);
    auto scene = Scene::build(desc);
    const HeterogeneousDiffusion* da = scene->instancedDiffusion(0);
    ASSERT_NE(da, nullptr);
    EXPECT_EQ(scene->instancedDiffusionText(0),
              "DA where the medium is deep and its packing uniform within ±10% over the diffusion's reach");
    const float X = 110 * 0.05f;
    int counts[4] = {0, 0, 0, 0}, gradedVaries = 0, gradedPoints = 0, uniformVaries = 0, uniformPoints = 0;
    for (float y = -0.7f; y >= -1.2f; y -= 0.25f)
      for (float x = -4.5f; x <= 4.5f; x += 0.5f)
        for (float z = -3.0f; z <= 3.0f; z += 1.0f) {
          const HeterogeneousDecision d = da->decide(renderSpace(*scene, Vec3(x, y, z)), desc.settings.daDepthFactor);
          if (d.outcome == DiffusionOutcome::Shallow) continue;  // not below the DA depth
          ++counts[int(d.outcome)];
          const float r = HeterogeneousDiffusion::kRegionDepths * d.depth;
          if (graded && x - r > 0) {
            // f ∝ 1 − 0.5 x / X across the region: at least this ratio between its ends.
            ++gradedPoints;
            gradedVaries += d.outcome == DiffusionOutcome::Varies;
            if (x + r < X - 1.0f)  // the region within the slab, clear of its side's skin
              EXPECT_GE(d.spread, 0.97f * (1 - 0.5f * (x - r) / X) / (1 - 0.5f * (x + r) / X)) << x << " " << y << " " << z;
          } else if (graded && x + r >= 2.5f) {
            // Reaching 2 or more into the graded half, past the tolerance's ratio
            // 1 / (1 − 0.5 · 2 / X) = 1.22, and more as cells round the region out.
            ++gradedPoints;
            gradedVaries += d.outcome == DiffusionOutcome::Varies;
          } else if (!graded || x + r < -0.2f) {
            ++uniformPoints;
            uniformVaries += d.outcome == DiffusionOutcome::Varies;
          }
        }
    std::printf("%s slab: %zu grains, bulk packing %.3f; below the DA depth: %d take DA, %d vary, %d curved; "
                "uniform region %d of %d vary, graded %d of %d\n",
                graded ? "graded" : "uniform", desc.instancedGrains[0].size(), da->bulk(), counts[3], counts[1],
                counts[2], uniformVaries, uniformPoints, gradedVaries, gradedPoints);
    EXPECT_GT(uniformPoints, 20);
    EXPECT_EQ(uniformVaries, 0);
    if (graded) {
      EXPECT_GT(gradedPoints, 20);
      EXPECT_EQ(gradedVaries, gradedPoints);
    } else {
      EXPECT_GT(counts[3], counts[2]) << "the uniform slab mostly takes DA";
    }

    const Paired p = compareWithoutDa(*scene, desc);
    std::printf("  DA on %.1f%% of the paths, %.1f%% of the light\n", 100 * p.daPaths, 100 * p.daShare);
    for (int c = 0; c < 3; ++c) {
      std::printf("  channel %d: VPT to the end %.5f, with DA %+.2f%% ± %.2f%%\n", c, p.base[c],
                  100 * p.diff[c] / p.base[c], 100 * p.se[c] / p.base[c]);
      // DA's own error: 1–2% of its light on homogeneous media (bench/README.md, "Diffusion").
      EXPECT_LE(std::fabs(p.diff[c]), 0.03 * p.daLight[c] + 3 * p.se[c]) << (graded ? "graded" : "uniform") << " " << c;
    }
    if (!graded) {
      uniformPaths = p.daPaths;
      EXPECT_GT(p.daPaths, 0.1);
      EXPECT_GT(p.daShare, 0.05);
    } else {
      EXPECT_LT(p.daPaths, uniformPaths);  // its graded half refuses DA
    }
  }
}

// Rule 3 on known shapes: the radius of curvature seen from 6 (the skin) below the surface
// of a ball of grains of radius 30 is the ball's (its level set's radius along the same
// direction) within 30%: at δ = 6 the depths drop by δ²/(2(R − z)) ≈ 0.8 and the lattice's
// stair steps and the first-order distance field move depths by ~0.15. Under the middle of
// a block's face it reads flat (beyond 20 such depths: the guard's 20 DA depths), beside
// an edge curved (below 20, where the ball's 30 passes).
TEST(HeterogeneousDiffusion, CurvatureOfTheLevelSetIsTheShapes) {
  SceneDesc d = blockScene();
  d.instancedGrains = {latticeBall(30.0f, 2.3f)};
  auto ball = Scene::build(d);
  const HeterogeneousDiffusion* da = ball->instancedDiffusion(0);
  ASSERT_NE(da, nullptr);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  for (int k = 0; k < 12; ++k) {
    const Vec3 dir = normalize(Vec3(u(rng), u(rng), u(rng)));
    float surface = 0;  // where the level set is along dir
    Vec3 ng;
    ASSERT_TRUE(da->boundary().intersect(renderSpace(*ball, Vec3(0.0f)), dir, kInf, surface, ng));
    const Vec3 x = renderSpace(*ball, dir * (surface - da->skin()));
    const float r = da->boundary().curvatureRadius(x, da->skin());
    std::printf("ball: level set at %.2f along (%.2f, %.2f, %.2f), curvature radius %.2f\n", surface, dir.x, dir.y,
                dir.z, r);
    EXPECT_NEAR(r, surface, 0.3f * surface) << k;
  }
  auto block = Scene::build(blockScene());
  const LevelSetBoundary& b = block->instancedDiffusion(0)->boundary();
  EXPECT_GT(b.curvatureRadius(renderSpace(*block, Vec3(1.0f, 17.0f, -2.0f)), 6.0f), 20 * 6.0f);
  EXPECT_LT(b.curvatureRadius(renderSpace(*block, Vec3(18.0f, 17.0f, -2.0f)), 6.0f), 20.0f);
}
