// VPT: free-flight sampling, transmittance and single scattering of a homogeneous slab
// against closed forms (tests mirror core/vpt.*).
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "core/ept.h"
#include "core/sampling.h"
#include "core/scene.h"
#include "core/shapes.h"
#include "core/vpt.h"
#include "test_helpers.h"

using namespace granular;

namespace {

constexpr float kSlab = 1.0f;  // thickness along z, top face at z = kSlab

// A wide slab aggregate [-10,10]^2 x [0,1]; its grains are never seen by VPT.
SceneDesc slabScene() {
  SceneDesc s;
  s.settings.technique = Technique::EptVpt;
  s.settings.width = s.settings.height = 4;
  MaterialDesc glass;
  glass.name = "glass";
  glass.type = MaterialType::Dielectric;
  s.materials.push_back(glass);
  AggregateDesc a;
  a.name = "slab";
  a.boundary = makeBox(Vec3(-10, -10, 0), Vec3(10, 10, kSlab));
  a.grainRadius = 0.1f;
  a.packingRate = 0.3f;
  a.tileSpheres = 64;
  a.prototypes = {GrainPrototypeDesc{"ball", makeIcosphere(1), 0}};
  a.weights = {1.0f};
  s.aggregates.push_back(a);
  return s;
}

// Mean and standard error of n independent estimates of the radiance along a ray that
// starts above the slab in the media (VPT) mode.
void estimate(const Scene& scene, const Ray& ray, int n, Vec3& mean, Vec3& se) {
  Vec3 s(0.0f), s2(0.0f);
  for (int i = 0; i < n; ++i) {
    PathState p = startPath(ray, hashInts(42, uint64_t(i)));
    p.mode = p.credit = kVpt;
    p.lastDelta = true;
    while (p.alive) vptStep(scene, p);
    Vec3 L = p.radiance();
    s += L;
    s2 += L * L;
  }
  mean = s / float(n);
  for (int c = 0; c < 3; ++c) se[c] = std::sqrt(std::max(0.0f, s2[c] / n - mean[c] * mean[c]) / (n - 1));
}

}  // namespace

TEST(Vpt, DistanceSamplingPdfIntegratesToOneAndMatchesHistogram) {
  HomogeneousMedium m(Vec3(0.5f, 1.0f, 3.0f), Vec3(1.0f), PhaseTable::isotropic());
  // ∫ p(t) dt over [0, 40] by the midpoint rule.
  double integral = 0;
  for (int i = 0; i < 400000; ++i) integral += m.distancePdf((i + 0.5f) * 1e-4f) * 1e-4;
  EXPECT_NEAR(integral, 1.0, 1e-3);
  // The fraction of samples below s is 1 − P(flight ≥ s).
  Rng rng(3);
  const int n = 200000;
  int below = 0;
  for (int i = 0; i < n; ++i) below += m.sampleDistance(rng.next1D(), rng.next1D()) < 0.7f;
  double p = 1.0 - m.survivalProbability(0.7f);
  EXPECT_NEAR(double(below) / n, p, 4 * std::sqrt(p * (1 - p) / n));
}

TEST(Vpt, SceneTransmittanceIsBeerLambertThroughTheSlab) {
  SceneDesc d = slabScene();
  auto scene = Scene::build(d);
  scene->setMedium(0, mediumFromRte(Vec3(0.5f, 1.0f, 2.0f), Vec3(0.3f), PhaseTable::isotropic()));
  Vec3 dir = normalize(Vec3(0.3f, 0.1f, -1.0f));
  float len = kSlab / -dir.z;  // path length inside
  Vec3 T = scene->transmittance(Vec3(0, 0, 3), dir, 10.0f);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(T[c], std::exp(-scene->medium(0).sigmaT()[c] * len), 1e-4f);
  // From inside: only the part to the boundary counts.
  Vec3 Tin = scene->transmittance(Vec3(0, 0, 0.25f), Vec3(0, 0, 1), 10.0f);
  EXPECT_NEAR(Tin.y, std::exp(-1.0f * 0.75f), 1e-4f);
  EXPECT_EQ(scene->mediumAt(Vec3(0, 0, 0.5f)), 0);
  EXPECT_EQ(scene->mediumAt(Vec3(0, 0, 1.5f)), -1);
}

TEST(Vpt, ChromaticTransmittanceOfAnAbsorbingSlab) {
  // Albedo 0: a path passes with weight T/P or is absorbed, so E[L] = exp(−σ_c d).
  SceneDesc d = slabScene();
  LightDesc dome;
  dome.name = "dome";
  dome.type = LightType::Dome;
  d.lights.push_back(dome);
  auto scene = Scene::build(d);
  Vec3 sigma(0.5f, 1.0f, 2.0f);
  scene->setMedium(0, mediumFromRte(sigma, Vec3(0.0f), PhaseTable::isotropic()));
  Ray ray{Vec3(0, 0, 3), Vec3(0, 0, -1)};
  Vec3 mean, se;
  estimate(*scene, ray, 40000, mean, se);
  for (int c = 0; c < 3; ++c) {
    EXPECT_GT(se[c], 0.0f);
    EXPECT_NEAR(mean[c], std::exp(-sigma[c] * kSlab), 4 * se[c]) << c;
  }
}

TEST(Vpt, SingleScatteringOfASlabUnderASun) {
  // One scattering (maxDepth 1), isotropic phase, a delta sun of irradiance E at cosine μ
  // above the slab, viewed straight down: L = α σ E/(4π) (1 − e^{−σd(1+1/μ)}) / (σ(1+1/μ)).
  SceneDesc d = slabScene();
  d.settings.maxDepth = 1;
  d.settings.physicalSun = false;  // a delta sun, as the closed form has it (else 0.53°: scene.h)
  LightDesc sun;
  sun.name = "sun";
  sun.type = LightType::Distant;
  sun.angle = 0;
  Vec3 toSun = normalize(Vec3(0.5f, 0.0f, 1.0f));
  sun.xf = Transform::lookAt(Vec3(0.0f), -toSun, Vec3(0, 1, 0));  // emits along local −Z
  sun.intensity = 2.0f;
  d.lights.push_back(sun);
  auto scene = Scene::build(d);
  LightSample ls;
  ASSERT_TRUE(scene->lights()[0].sampleLi(Vec3(0.0f), 0.5f, 0.5f, ls));
  ASSERT_TRUE(ls.delta);
  ASSERT_NEAR(dot(ls.wi, toSun), 1.0f, 1e-5f);
  const float sigma = 1.5f, albedo = 0.8f;
  scene->setMedium(0, mediumFromRte(Vec3(sigma), Vec3(albedo), PhaseTable::isotropic()));
  Ray ray{Vec3(0, 0, 3), Vec3(0, 0, -1)};
  Vec3 mean, se;
  estimate(*scene, ray, 40000, mean, se);
  float mu = toSun.z, k = sigma * (1.0f + 1.0f / mu);
  float expected = albedo * sigma * 2.0f / (4.0f * kPi) * (1.0f - std::exp(-k * kSlab)) / k;
  EXPECT_GT(se.x, 0.0f);
  EXPECT_NEAR(mean.x, expected, 4 * se.x) << "se " << se.x;
}

TEST(Vpt, FlightsSearchedOnlyAsFarAsTheyGoDecideAsAnUnboundedSearch) {
  // vptStep draws a flight t first and searches the scene only to Scene::flightReach(o, t).
  // Every decision (scatter at t, or the hit before it) must be the unbounded search's,
  // also where the slab stands on a ground box whose top face is its bottom face: there a
  // crossing within the surface's offset of it is the surface's (intersectMedium).
  SceneDesc d = slabScene();
  MeshDesc ground;
  ground.name = "ground";
  ground.mesh = makeBox(Vec3(-20, -20, -1), Vec3(20, 20, 0));
  d.meshes.push_back(ground);
  auto scene = Scene::build(d);
  scene->setMedium(0, mediumFromRte(Vec3(4.0f), Vec3(0.9f), PhaseTable::isotropic()));
  Rng rng(11);
  int scattered = 0, stopped = 0, atGround = 0;
  for (int i = 0; i < 4000; ++i) {
    const Vec3 o(20 * rng.next1D() - 10, 20 * rng.next1D() - 10, kSlab * (0.02f + 0.96f * rng.next1D()));
    const Vec3 dir = sampleUniformSphere(rng.next1D(), rng.next1D());
    const Ray ray{o, dir};
    Hit full;
    const bool foundFull = scene->intersectMedium(ray, full);
    ASSERT_TRUE(foundFull);  // inside a closed boundary
    // Flights short of, about and past the first hit, and within rounding of it.
    std::vector<float> ts = {full.t * rng.next1D(), full.t * (1 + rng.next1D()), full.t};
    for (int k = 1; k <= 4; ++k) {
      ts.push_back(std::nextafter(full.t, 0.0f) * (1 - 1e-7f * float(k)));
      ts.push_back(full.t * (1 + 1e-7f * float(k)));
    }
    atGround += full.kind == Hit::Surface;
    for (float t : ts) {
      Ray query = ray;
      query.tmax = scene->flightReach(o, t);
      Hit hit;
      const bool found = scene->intersectMedium(query, hit);
      const bool scatters = !found || t < hit.t, scattersFull = t < full.t;
      ASSERT_EQ(scatters, scattersFull) << "o " << o.x << " " << o.y << " " << o.z << " t " << t;
      if (!scatters) {
        EXPECT_EQ(hit.kind, full.kind);
        EXPECT_EQ(hit.t, full.t);
      }
      (scatters ? scattered : stopped) += 1;
    }
  }
  EXPECT_GT(atGround, 500);  // flights toward the ground end on it, not at the crossing
  EXPECT_GT(scattered, 4000 * 4);  // both outcomes are exercised, near the hit too
  EXPECT_GT(stopped, 4000 * 4);
}

TEST(Vpt, DeepShadowRaysLeftByRouletteAddNoBias) {
  // mediumNee traces the shadow ray of a scattering deep in its aggregate with a chance
  // set by the distance field's depth (vpt.cpp) and divides by it. Under a delta sun each
  // traced estimate is exactly β f T L, so the mean of many calls must be it.
  SceneDesc d = slabScene();
  d.settings.physicalSun = false;
  LightDesc sun;
  sun.name = "sun";
  sun.type = LightType::Distant;
  sun.angle = 0;
  const Vec3 toSun = normalize(Vec3(0.5f, 0.0f, 1.0f));
  sun.xf = Transform::lookAt(Vec3(0.0f), -toSun, Vec3(0, 1, 0));
  sun.intensity = 2.0f;
  d.lights.push_back(sun);
  auto scene = Scene::build(d);
  scene->setMedium(0, mediumFromRte(Vec3(12.0f), Vec3(0.9f), PhaseTable::isotropic()));
  const HomogeneousMedium& med = scene->medium(0);
  const Vec3 wi = normalize(Vec3(0.2f, 0.3f, -1.0f));
  auto exact = [&](const Vec3& p) {
    LightSample ls;
    EXPECT_TRUE(scene->lights()[0].sampleLi(p, 0.5f, 0.5f, ls));
    return med.phase(wi, ls.wi) * scene->transmittance(p, ls.wi, kInf) * ls.Li;
  };
  auto nee = [&](const Vec3& p, uint64_t seed) {
    PathState path = startPath(Ray{p, wi}, seed);
    path.mode = path.credit = kVpt;
    path.medium = 0;
    mediumNee(*scene, path, med, p);
    return path.radiance();
  };
  // Near the top face every shadow ray is traced: each call gives the exact value.
  const Vec3 shallow(0.3f, -0.2f, kSlab - 0.02f);
  const Vec3 e0 = exact(shallow);
  ASSERT_GT(e0.x, 0.1f * med.phase(wi, toSun).x * 2.0f);
  for (uint64_t i = 0; i < 64; ++i) EXPECT_NEAR(nee(shallow, i).x, e0.x, 1e-5f * e0.x);
  // In the middle, 6 mean free paths from either face, most are left.
  const Vec3 deep(0.3f, -0.2f, 0.5f * kSlab);
  const float e = exact(deep).x;
  ASSERT_GT(e, 0.0f);
  const int n = 40000;
  double s = 0, s2 = 0;
  int traced = 0;
  for (int i = 0; i < n; ++i) {
    const double L = nee(deep, hashInts(7, uint64_t(i))).x;
    s += L;
    s2 += L * L;
    traced += L > 0;
  }
  const double mean = s / n, se = std::sqrt(std::max(0.0, s2 / n - mean * mean) / (n - 1));
  // Traced with a chance of about e^−6 / kShadowRouletteBelow (1/2): some 0.5%.
  EXPECT_GT(traced, n / 1000);
  EXPECT_LT(traced, n / 50);
  EXPECT_NEAR(mean, e, 4 * se) << "traced " << traced << " of " << n;
}

// The exits model (vpt.h): flights of kExitFlight λ_β to the next grain met, and each
// scattering's light moved by the grain's move for the angle it turned (tt.h, ExitMoves),
// never further than a grain's diameter and never through a surface. TT's medium, and a
// medium given directly, move nothing.
TEST(Vpt, TheExitsModelFliesToTheNextGrainMetAndMovesLightAsTheGrainLetsItOut) {
  SceneDesc d = slabScene();
  MeshDesc floor;  // just under the slab: a wall the moves must not pass
  floor.name = "floor";
  floor.mesh = makeBox(Vec3(-10, -10, -0.5f), Vec3(10, 10, -0.01f));
  floor.material = 0;
  d.meshes.push_back(floor);
  auto tt = Scene::build(d);
  d.settings.mediumModel = MediumModel::Exits;
  auto exits = Scene::build(d);
  const MediumParams& p = exits->mediumParams(0);
  EXPECT_FALSE(tt->medium(0).movesLight());
  EXPECT_EQ(tt->medium(0).sigmaT().x, p.sigmaT.x);
  const HomogeneousMedium& m = exits->medium(0);
  ASSERT_TRUE(m.movesLight());
  EXPECT_EQ(m.moveRadius(), 0.1f);
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(m.sigmaT()[c], 1.0f / (kExitFlight * p.lambdaBeta[c]), 1e-6f * m.sigmaT()[c]);
    EXPECT_GT(m.sigmaT()[c], p.sigmaT[c]);  // λ_β < λ_t = λ_β + α_s λ_s
    EXPECT_EQ(m.albedo()[c], p.albedo[c]);
  }
  EXPECT_NE(exits->lowOrdersText(0).find("the medium (exits)"), std::string::npos) << exits->lowOrdersText(0);
  EXPECT_EQ(tt->lowOrdersText(0).find("exits"), std::string::npos);
  // Moves: at most a diameter; light sent on moves further along ω_i than light sent back.
  Rng rng(5);
  const Vec3 wi = normalize(Vec3(0.1f, 0.2f, -1.0f));
  double on = 0, back = 0;
  int nOn = 0, nBack = 0;
  for (int i = 0; i < 16384; ++i) {
    const Vec3 wo = sampleUniformSphere(rng.next1D(), rng.next1D());
    const Vec3 move = m.exitMove(wi, wo, rng.next1D(), rng.next1D());
    ASSERT_LE(length(move), 2.0f * 0.1f * (1.0f + 1e-4f));
    if (dot(wi, wo) > 0.9f) on += dot(move, wi), ++nOn;
    if (dot(wi, wo) < -0.9f) back += dot(move, wi), ++nBack;
  }
  ASSERT_GT(nOn, 100);
  ASSERT_GT(nBack, 100);
  // Clear spheres (IOR 1.5) of radius 0.1: light sent on crosses about a diameter, light
  // sent back (reflected near where it came in) about a tenth of one.
  EXPECT_GT(on / nOn, 0.1);
  EXPECT_LT(back / nBack, 0.5 * on / nOn);
  // Never through a surface: from just above the floor, a move across it stays put.
  const Vec3 above(0, 0, 0.05f);
  EXPECT_EQ(exits->movedLight(above, Vec3(0, 0, -0.15f), 0.0f).z, above.z);
  EXPECT_NEAR(exits->movedLight(above, Vec3(0, 0, 0.15f), 0.0f).z, 0.2f, 1e-6f);
  EXPECT_EQ(exits->mediumAfterMove(0, Vec3(0, 0, 0.5f), 0.0f), 0);
  EXPECT_EQ(exits->mediumAfterMove(0, Vec3(0, 0, 1.05f), 0.0f), -1);
  // A medium given directly has no moves: TT's transport, whatever the model.
  exits->setMedium(0, mediumFromRte(Vec3(1.0f), Vec3(0.9f), PhaseTable::isotropic()));
  EXPECT_FALSE(exits->medium(0).movesLight());
  EXPECT_EQ(exits->medium(0).sigmaT().x, 1.0f);
}

TEST(Vpt, TheExitsModelTakesOverAtAGrainWhoseWayBackOutThePackingKeeps) {
  // Rays from above into the accuracy matrix's ball of grains meet a first grain by the
  // packing's flight (Aggregate::flightToGrain, as the exits model's first flight after a
  // grain walks it: vpt.h, enterMedia). Sent straight back from where it met that grain, a
  // ray crosses the spheres it came through again: the packing leaves it out far more often
  // than a memoryless flight of λ_β from that depth would, and never meets a grain beyond
  // where it started (outside every sphere).
  SceneDesc d = granular::testing::matrixBall(false, 1.55f);
  d.settings.technique = Technique::EptVpt;
  d.settings.proxies = ProxyUse::On;
  d.settings.explicitBounces = 0;
  EXPECT_FALSE(Scene::build(d)->takesOverAtGrains(0));  // TT's medium: a flight of its own
  d.settings.mediumModel = MediumModel::Exits;
  auto scene = Scene::build(d);
  ASSERT_TRUE(scene->takesOverAtGrains(0));
  const Aggregate& agg = *scene->aggregates()[0];
  const ProxyTables& tables = scene->proxyTables(0);
  const float lambdaBeta = scene->mediumParams(0).lambdaBeta[0];
  Rng rng(11);
  const int n = 4096;
  int out = 0;
  double memoryless = 0;
  for (int i = 0; i < n; ++i) {
    const float r = 0.5f * std::sqrt(rng.next1D()), phi = 2.0f * kPi * rng.next1D();
    const Vec3 o(r * std::cos(phi), r * std::sin(phi), 3.0f), down(0, 0, -1);
    const GrainFlight in = agg.flightToGrain(o, down, tables, nullptr, rng);
    ASSERT_TRUE(in.met());
    const float depth = std::max(0.0f, in.t - (3.0f - std::sqrt(1.0f - r * r)));
    memoryless += std::exp(-depth / lambdaBeta);
    const GrainFlight back = agg.flightToGrain(in.entry, -down, tables, &in.grain, rng);
    ASSERT_TRUE(!back.met() || back.t <= in.t) << back.t << " " << in.t;
    if (!back.met()) ++out;
  }
  const double pOut = double(out) / n, pMemoryless = memoryless / n;
  const double se = std::sqrt(pOut * (1 - pOut) / n);
  std::printf("way back out: the packing %.3f ± %.3f, a memoryless flight %.3f (λ_β %.4f)\n", pOut, se, pMemoryless,
              lambdaBeta);
  EXPECT_GT(pOut, pMemoryless + 0.1);
  EXPECT_GT(pOut - 4 * se, pMemoryless);
}
