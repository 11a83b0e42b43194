// DA: conservation properties of the diffusion profile, and DA against VPT on a thick
// bright slab (tests mirror core/diffusion.*).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "diffusion.h"
#include "render.h"
#include "scene.h"
#include "shapes.h"
#include "vpt.h"

using namespace granular;

TEST(Diffusion, NonAbsorbingHalfSpaceReemitsAllPower) {
  // With σ_a = 0 every photon of a point source eventually leaves a half space:
  // ∫ (φ/4 + D/2 ∂φ/∂z) dA = 2A/4 + 1/2 = 1 for the dipole (A = 1).
  MediumParams p = mediumFromRte(Vec3(10.0f), Vec3(1.0f), PhaseTable::isotropic());
  DiffusionProfile prof(p);
  for (float z : {0.05f, 0.3f, 2.0f}) {
    Vec3 total = prof.totalExitance(z, kInf, false);
    EXPECT_NEAR(total.x, 1.0f, 2e-3f) << "depth " << z;
  }
}

TEST(Diffusion, NonAbsorbingSlabSplitsPowerBetweenItsFaces) {
  MediumParams p = mediumFromRte(Vec3(10.0f), Vec3(1.0f), PhaseTable::isotropic());
  DiffusionProfile prof(p);
  const float d = 1.0f, zb = prof.zb.x;
  for (float z : {0.2f, 0.5f, 0.8f}) {
    float top = prof.totalExitance(z, d, false).x, bottom = prof.totalExitance(z, d, true).x;
    EXPECT_NEAR(top + bottom, 1.0f, 2e-3f) << "depth " << z;
    // Diffusion with extrapolated boundaries: the escape through the top is linear in depth.
    EXPECT_NEAR(top, (d - z + zb) / (d + 2 * zb), 2e-3f) << "depth " << z;
  }
}

TEST(Diffusion, AbsorptionLowersAndDepthLowersTheExitance) {
  MediumParams p = mediumFromRte(Vec3(10.0f), Vec3(0.95f, 0.99f, 1.0f), PhaseTable::isotropic());
  DiffusionProfile prof(p);
  Vec3 shallow = prof.totalExitance(0.2f, kInf, false), deep = prof.totalExitance(0.6f, kInf, false);
  EXPECT_LT(shallow.x, shallow.y);
  EXPECT_LT(shallow.y, shallow.z);
  EXPECT_LT(deep.x, shallow.x);
  EXPECT_GT(deep.x, 0.0f);
  // Exponential decay with σ_tr at depth (the dominant term of the dipole).
  float ratio = deep.x / shallow.x;
  EXPECT_NEAR(std::log(ratio), -p.sigmaTr.x * 0.4f, 0.15f * p.sigmaTr.x * 0.4f);
}

namespace {

// A thick bright slab of index-matched grains under a sun at normal incidence, seen from
// above. τ is tiny so every bundle switches to the medium after its first grain contact.
SceneDesc brightSlab(Technique t) {
  SceneDesc s;
  s.settings.technique = t;
  s.settings.width = s.settings.height = 12;
  s.settings.spp = 64;
  s.settings.seed = 5;
  s.settings.tau = 1e-6f;
  s.settings.roulette = 1.0f;
  s.camera.cameraToWorld = Transform::lookAt(Vec3(0, 0, 6), Vec3(0, 0, 0), Vec3(0, 1, 0));
  s.camera.focalLength = 50;
  s.camera.horizontalAperture = s.camera.verticalAperture = 4;
  MaterialDesc matched;
  matched.name = "matched";
  matched.type = MaterialType::Dielectric;
  matched.ior = 1.0f;
  s.materials.push_back(matched);
  LightDesc sun;
  sun.name = "sun";
  sun.type = LightType::Distant;
  sun.angle = 0;
  sun.xf = Transform::lookAt(Vec3(0.0f), Vec3(0, 0, -1), Vec3(0, 1, 0));
  s.lights.push_back(sun);
  AggregateDesc a;
  a.name = "slab";
  a.boundary = makeBox(Vec3(-4, -4, -4), Vec3(4, 4, 0));
  a.grainRadius = 0.02f;
  a.packingRate = 0.3f;
  a.tileSpheres = 64;
  a.prototypes = {GrainPrototypeDesc{"ball", makeIcosphere(1), 0}};
  a.weights = {1.0f};
  s.aggregates.push_back(a);
  return s;
}

void renderMean(Technique t, double& mean, double& se, double& daShare) {
  SceneDesc d = brightSlab(t);
  auto scene = Scene::build(d);
  // σ_t = 20, α = 0.99: mean free path 0.05, DA from depth 2 min(1/σ'_t, 0.5/σ_tr) = 0.1.
  scene->setMedium(0, mediumFromRte(Vec3(20.0f), Vec3(0.99f), PhaseTable::isotropic()));
  Renderer r(*scene);
  ASSERT_TRUE(r.render(64));
  Image img = r.film().toImage();
  int da = img.channelIndex("da.G");
  double s = 0, s2 = 0, sda = 0;
  int n = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      double v = img.at(x, y)[1];
      s += v; s2 += v * v; sda += img.at(x, y)[da]; ++n;
    }
  mean = s / n;
  se = std::sqrt(std::max(0.0, s2 / n - mean * mean) / (n - 1));
  daShare = sda / s;
}

}  // namespace

TEST(Diffusion, BrightSlabReflectanceMatchesVptWithinFivePercent) {
  double mv, sv, dv, mh, sh, dh;
  renderMean(Technique::EptVpt, mv, sv, dv);
  renderMean(Technique::Hybrid, mh, sh, dh);
  std::printf("bright slab: VPT %.4f ± %.4f, VPT+DA %.4f ± %.4f (DA share %.2f)\n", mv, sv, mh, sh, dh);
  EXPECT_EQ(dv, 0.0);
  EXPECT_GT(dh, 0.3) << "DA should carry much of a bright slab's light";
  // The criterion of the issue (5%), widened by the two estimates' noise.
  EXPECT_NEAR(mh, mv, 0.05 * mv + 3 * std::sqrt(sv * sv + sh * sh)) << "VPT " << mv << " DA " << mh;
}

TEST(Diffusion, ExitanceStaysFiniteManyDiffusionLengthsDeep) {
  // Fine grains make σ_tr large: a source 2 units deep is then ~10^3 diffusion lengths
  // from a face, where both the dipole and the slab's 1-D totals underflow. The exitance
  // must be 0 there, not 0/0 (bench/stress.py found NaN samples with R = 0.001).
  MediumParams p = mediumFromRte(Vec3(2000.0f), Vec3(0.9f), PhaseTable::isotropic());
  DiffusionProfile prof(p);
  ASSERT_GT(prof.sigmaTr.x * 2.0f, 800.0f);
  for (float z : {0.01f, 0.5f, 2.0f})
    for (float rho : {0.0f, 0.3f, 5.0f})
      for (bool far : {false, true}) {
        Vec3 J = prof.exitance(z, rho, 4.0f, far);
        // Only the shallowest source right above it reaches the near face in float.
        if (z == 0.01f && rho == 0.0f && !far) EXPECT_GT(J.x, 0.0f);
        else EXPECT_TRUE(J.x == 0 && J.y == 0 && J.z == 0) << z << " " << rho << " " << far << ": " << J.x;
      }
  // Where it does not underflow, the finite slab is still scaled to its exact total.
  Vec3 near = prof.totalExitance(0.01f, 4.0f, false), half = prof.totalExitance(0.01f, kInf, false);
  ASSERT_GT(half.x, 0.0f);
  EXPECT_NEAR(near.x, half.x, 1e-3f * half.x);  // the far face is 4 units away: no difference
}
