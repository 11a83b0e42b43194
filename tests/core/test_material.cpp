// Materials: the rough dielectric (GGX microfacets) against its own density and
// reciprocity, its smooth limit, and the directional albedo two independent ways; a white
// furnace of rough clear grains through the renderer (NEE + MIS) against a BSDF-only
// walk written here.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "core/material.h"
#include "core/microfacet.h"
#include "core/render.h"
#include "core/rng.h"
#include "core/sampling.h"
#include "core/scene.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;

namespace {

// The single-scattering BSDF (compensated = false) or the renderer's default.
Material rough(float ior, float roughness, bool compensated = false) {
  MaterialDesc d;
  d.type = MaterialType::Dielectric;
  d.ior = ior;
  d.roughness = roughness;
  d.energyCompensation = compensated;
  return Material::fromDesc(d);
}

Vec3 direction(float cosTheta, float phi) {
  const float s = std::sqrt(std::max(0.0f, 1.0f - cosTheta * cosTheta));
  return {s * std::cos(phi), s * std::sin(phi), cosTheta};
}

}  // namespace

TEST(Microfacet, RoughnessMapsToAlphaSquaredAndTinyRoughnessIsSmooth) {
  EXPECT_EQ(alphaFromRoughness(0.0f), 0.0f);
  EXPECT_EQ(alphaFromRoughness(0.03f), 0.0f);  // α 9e-4 < kMinAlpha: the delta interface
  EXPECT_FLOAT_EQ(alphaFromRoughness(0.5f), 0.25f);
  EXPECT_FLOAT_EQ(alphaFromRoughness(1.0f), 1.0f);
  EXPECT_TRUE(rough(1.5f, 0.0f).isDelta());
  EXPECT_FALSE(rough(1.5f, 0.3f).isDelta());
}

TEST(Microfacet, GgxNormalsAndVisibleNormalsIntegrateToOne) {
  // ∫ D(m) m.z dω = 1 and ∫ D_wo(m) dω = 1 (Heitz 2018, eq. 1), by uniform hemisphere
  // sampling with a standard error of the mean.
  for (float alpha : {0.1f, 0.5f, 1.0f}) {
    Rng rng(7);
    const Vec3 wo = direction(0.4f, 0.3f);
    const int n = 1 << 20;
    double s1 = 0, s1sq = 0, s2 = 0, s2sq = 0;
    for (int i = 0; i < n; ++i) {
      Vec3 m = sampleUniformSphere(rng.next1D(), rng.next1D());
      m.z = std::fabs(m.z);
      const double a = ggxD(m, alpha) * m.z / (2 * kUniformSpherePdf);
      const double b = ggxVisiblePdf(wo, m, alpha) / (2 * kUniformSpherePdf);
      s1 += a; s1sq += a * a; s2 += b; s2sq += b * b;
    }
    const double m1 = s1 / n, se1 = std::sqrt((s1sq / n - m1 * m1) / n);
    const double m2 = s2 / n, se2 = std::sqrt((s2sq / n - m2 * m2) / n);
    EXPECT_NEAR(m1, 1.0, 4 * se1 + 1e-4) << alpha;
    EXPECT_NEAR(m2, 1.0, 4 * se2 + 1e-4) << alpha;
  }
}

TEST(RoughDielectric, SamplesCarryTheirOwnPdfAndWeightEvalOverPdf) {
  Rng rng(11);
  for (float ior : {1.31f, 1.55f, 2.4f})
    for (float roughness : {0.1f, 0.3f, 0.7f, 1.0f}) {
      const Material m = rough(ior, roughness);
      int ok = 0;
      for (int i = 0; i < 4000; ++i) {
        Vec3 wo = sampleUniformSphere(rng.next1D(), rng.next1D());  // both sides
        BsdfSample s;
        if (!m.sample(wo, rng.next1D(), rng.next1D(), rng.next1D(), s)) continue;
        ++ok;
        ASSERT_FALSE(s.delta);
        EXPECT_EQ(s.transmitted, (wo.z > 0) != (s.wi.z > 0));
        const float pdf = m.pdf(wo, s.wi);
        EXPECT_NEAR(s.pdf, pdf, 1e-3f * pdf) << ior << " " << roughness;
        const Vec3 f = m.eval(wo, s.wi);
        EXPECT_NEAR(s.weight.x, f.x / pdf, 2e-3f * s.weight.x + 1e-6f);
        EXPECT_LE(s.weight.x, 1.0f + 1e-5f);  // G2 / G1 ≤ 1
      }
      EXPECT_GT(ok, 3000);
    }
}

TEST(RoughDielectric, IsTheAdjointOfARadianceBtdf) {
  // f is the BTDF without the radiance scale 1/η² (material.h): reflection is symmetric,
  // and refraction obeys f(wo, wi) = η² f(wi, wo), η = n(wi's side) / n(wo's side).
  const float ior = 1.55f;
  const Material m = rough(ior, 0.5f);
  Rng rng(5);
  int checked = 0;
  for (int i = 0; i < 2000; ++i) {
    Vec3 wo = sampleUniformSphere(rng.next1D(), rng.next1D());
    Vec3 wi = sampleUniformSphere(rng.next1D(), rng.next1D());
    const float fo = m.eval(wo, wi).x / std::fabs(wi.z), fi = m.eval(wi, wo).x / std::fabs(wo.z);
    if (!(fo > 1e-4f) || !std::isfinite(fo)) continue;
    const bool transmitted = (wo.z > 0) != (wi.z > 0);
    const float eta = transmitted ? (wo.z > 0 ? ior : 1.0f / ior) : 1.0f;
    EXPECT_NEAR(fo, eta * eta * fi, 2e-3f * fo) << transmitted;
    ++checked;
  }
  EXPECT_GT(checked, 500);
}

TEST(RoughDielectric, DirectionalAlbedoBySamplingEqualsTheIntegralOfEval) {
  // Two independent estimates of ∫ f |cos wi| dω: the sampled weights (importance
  // sampling, failed samples count 0) and eval over uniform sphere directions; and the
  // fraction of successful samples equals ∫ pdf dω. Both ≤ 1: single-scattering
  // microfacets lose energy (more the rougher), never gain it.
  for (float ior : {1.31f, 2.4f})
    for (float roughness : {0.5f, 1.0f})
      for (float cosO : {0.9f, 0.3f, -0.6f}) {
        const Material m = rough(ior, roughness);
        const Vec3 wo = direction(cosO, 0.7f);
        Rng rng(17);
        const int n = 1 << 19;
        double a = 0, a2 = 0, succ = 0;
        for (int i = 0; i < n; ++i) {
          BsdfSample s;
          double w = m.sample(wo, rng.next1D(), rng.next1D(), rng.next1D(), s) ? s.weight.x : 0.0;
          a += w; a2 += w * w;
          succ += w > 0;
        }
        double b = 0, b2 = 0, p = 0, p2 = 0;
        for (int i = 0; i < n; ++i) {
          const Vec3 wi = sampleUniformSphere(rng.next1D(), rng.next1D());
          const double f = m.eval(wo, wi).x / kUniformSpherePdf, q = m.pdf(wo, wi) / kUniformSpherePdf;
          b += f; b2 += f * f; p += q; p2 += q * q;
        }
        const double ma = a / n, sea = std::sqrt((a2 / n - ma * ma) / n);
        const double mb = b / n, seb = std::sqrt((b2 / n - mb * mb) / n);
        const double ms = succ / n, ses = std::sqrt(ms * (1 - ms) / n);
        const double mp = p / n, sep = std::sqrt((p2 / n - mp * mp) / n);
        SCOPED_TRACE(::testing::Message() << "ior " << ior << " roughness " << roughness << " cos " << cosO);
        std::printf("ior %.2f roughness %.1f cos %+.1f: albedo %.4f (sampled) %.4f (integrated), success %.4f / %.4f\n",
                    ior, roughness, cosO, ma, mb, ms, mp);
        EXPECT_NEAR(ma, mb, 4 * std::hypot(sea, seb));
        EXPECT_NEAR(ms, mp, 4 * std::hypot(ses, sep));
        EXPECT_LE(ma, 1.0 + 4 * sea);
        EXPECT_GT(ma, 0.3);
      }
}

TEST(RoughDielectric, StaysFiniteAtGrazingAnglesAndTheSmallestAlpha) {
  // Directions within 1e-6 of the macro surface, on both sides, normal incidence and the
  // narrowest lobe (α = kMinAlpha): eval, pdf and samples finite, never NaN.
  const float cosines[] = {1.0f, 0.5f, 1e-3f, 1e-6f, -1e-6f, -1e-3f, -0.5f, -1.0f};
  for (float roughness : {std::sqrt(kMinAlpha) * 1.001f, 0.3f, 1.0f})
    for (bool compensated : {false, true}) {
      const Material m = rough(2.4f, roughness, compensated);
      ASSERT_GT(m.alpha, 0.0f);
      Rng rng(31);
      for (float co : cosines)
        for (float ci : cosines) {
          const Vec3 wo = direction(co, 0.2f), wi = direction(ci, 2.9f);
          float p;
          const float f = m.eval(wo, wi, &p).x;
          EXPECT_TRUE(std::isfinite(f) && std::isfinite(p) && f >= 0 && p >= 0) << co << " " << ci << " " << roughness;
          for (int k = 0; k < 64; ++k) {
            BsdfSample s;
            if (!m.sample(wo, rng.next1D(), rng.next1D(), rng.next1D(), s)) continue;
            EXPECT_TRUE(isFinite(s.wi) && isFinite(s.weight) && std::isfinite(s.pdf) && s.pdf > 0) << co;
          }
        }
    }
}

TEST(SmoothDielectric, AnyChoiceOfBranchKeepsTheExpectation) {
  // sampleSmooth with reflection chosen with probability p: weight F / p for the mirror,
  // (1 − F) / (1 − p) for the refraction, the directions those of sample(). Over a uniform
  // grid of uLobe each branch's mean weight is its Fresnel share, whatever p; at p = F the
  // samples are sample()'s, bit for bit.
  const float ior = 1.5f;
  const Material smooth = rough(ior, 0.0f);
  ASSERT_TRUE(smooth.isDelta());
  for (float cosO : {0.95f, 0.3f, -0.9f, -0.75f}) {  // outside, grazing, inside, inside near TIR
    const Vec3 wo = direction(cosO, 0.7f);
    const Material::SmoothBranches b = smooth.smoothBranches(wo);
    const float F = b.F;
    const Vec3 &reflected = b.reflected, &refracted = b.refracted;
    ASSERT_NEAR(F, fresnelDielectric(cosO, ior), 1e-7f);
    ASSERT_GT(F, 0.0f);
    ASSERT_LT(F, 1.0f);
    EXPECT_NEAR(dot(reflected, Vec3(-wo.x, -wo.y, wo.z)), 1.0f, 1e-6f);
    EXPECT_LT(refracted.z * wo.z, 0.0f);  // through the interface
    for (float p : {F, 0.5f, 0.9f, 0.05f}) {
      const int n = 10000;
      double r = 0, t = 0;
      for (int i = 0; i < n; ++i) {
        const float u = (float(i) + 0.5f) / float(n);
        BsdfSample s, ref;
        ASSERT_TRUE(Material::sampleSmooth(b, p, u, s));
        ASSERT_TRUE(s.delta);
        (s.transmitted ? t : r) += s.weight.x;
        const Vec3& expected = s.transmitted ? refracted : reflected;
        ASSERT_NEAR(dot(s.wi, expected), 1.0f, 1e-6f);
        if (p == F) {
          ASSERT_TRUE(smooth.sample(wo, u, 0.5f, 0.5f, ref));
          EXPECT_EQ(granular::testing::bitsOf(s.wi.x), granular::testing::bitsOf(ref.wi.x));
          EXPECT_EQ(granular::testing::bitsOf(s.wi.z), granular::testing::bitsOf(ref.wi.z));
          EXPECT_EQ(s.weight.x, 1.0f);
        }
      }
      // The grid puts round(p n) samples on the mirror: the means are within 1/n of exact.
      EXPECT_NEAR(r / n, F, 2.0 / n * std::max(1.0, double(F) / p)) << cosO << " " << p;
      EXPECT_NEAR(t / n, 1.0 - F, 2.0 / n * std::max(1.0, (1.0 - F) / (1.0 - double(p)))) << cosO << " " << p;
    }
  }
}

TEST(RoughDielectric, ApproachesTheSmoothInterfaceAsRoughnessVanishes) {
  // At α 1.6e-3 nearly all sampled directions lie within 0.05 rad of the smooth
  // interface's (GGX's tail, P(tan θ_m > t) ≈ α² / t², leaves ~0.4% beyond), and
  // reflection is chosen with the smooth Fresnel probability.
  const float ior = 1.5f;
  const Material r = rough(ior, 0.04f), smooth = rough(ior, 0.0f);
  for (float cosO : {0.95f, 0.5f, -0.8f}) {
    const Vec3 wo = direction(cosO, 1.1f);
    Rng rng(3);
    const int n = 20000;
    int reflected = 0, close = 0;
    for (int i = 0; i < n; ++i) {
      BsdfSample s, ref;
      const float uLobe = rng.next1D();
      ASSERT_TRUE(r.sample(wo, uLobe, rng.next1D(), rng.next1D(), s));
      ASSERT_TRUE(smooth.sample(wo, s.transmitted ? 0.9999f : 0.0f, 0.5f, 0.5f, ref));
      reflected += !s.transmitted;
      close += dot(s.wi, ref.wi) > std::cos(0.05f);
    }
    EXPECT_GT(close, 0.98 * n) << cosO;
    const double F = fresnelDielectric(cosO, ior);
    EXPECT_NEAR(double(reflected) / n, F, 4 * std::sqrt(F * (1 - F) / n) + 2e-3) << cosO;
  }
}

namespace {

SceneDesc roughFurnace(float roughness, bool compensated) {
  MaterialDesc m;
  m.name = "frosted";
  m.type = MaterialType::Dielectric;
  m.ior = 1.5f;
  m.roughness = roughness;
  m.energyCompensation = compensated;
  SceneDesc s = granular::testing::whiteFurnaceScene(m);
  s.settings.width = 16;
  s.settings.height = 16;
  s.settings.spp = 64;
  s.settings.seed = 5;
  s.aggregates[0].name = "frosted_grains";
  s.aggregates[0].grainRadius = 0.15f;
  return s;
}

// The mean of each pixel of d rendered (channel R: the furnaces are grey), raster order.
std::vector<double> renderedPixels(const SceneDesc& d, std::unique_ptr<Scene>* built = nullptr) {
  auto scene = Scene::build(d);
  Renderer r(*scene);
  EXPECT_TRUE(r.render(4));
  std::vector<double> pixels;
  for (int y = 0; y < d.settings.height; ++y)
    for (int x = 0; x < d.settings.width; ++x) pixels.push_back(r.film().mean(x, y).x);
  if (built) *built = std::move(scene);
  return pixels;
}

// Mean and standard error of a list of per-path values.
void meanSe(const std::vector<double>& v, double& mean, double& se) {
  double s = 0, s2 = 0;
  for (double x : v) { s += x; s2 += x * x; }
  mean = s / v.size();
  se = std::sqrt(std::max(0.0, s2 / v.size() - mean * mean) / (v.size() - 1));
}

}  // namespace

TEST(RoughDielectric, AWhiteFurnaceOfRoughGrainsMatchesABsdfOnlyWalk) {
  // The renderer (NEE to the dome from both sides of rough interfaces, MIS with the BSDF
  // hits) against a walk that only samples the BSDF and counts escapes (dome radiance 1):
  // equal within noise. Both are below 1 by the microfacet model's energy loss.
  const SceneDesc d = roughFurnace(0.5f, false);
  std::unique_ptr<Scene> scene;
  const std::vector<double> pixels = renderedPixels(d, &scene);
  double rendered, renderedSe;
  meanSe(pixels, rendered, renderedSe);

  std::vector<double> walk;
  const int kWalks = 256;
  const Camera& cam = scene->camera();
  for (int y = 0; y < d.settings.height; ++y)
    for (int x = 0; x < d.settings.width; ++x)
      for (int k = 0; k < kWalks; ++k) {
        Rng rng(hashInts(99, uint64_t(x), uint64_t(y), uint64_t(k)), 0);
        Ray ray = cam.sampleRay(x, y, rng);
        double beta = 1;
        for (int depth = 0; depth < 100000; ++depth) {
          Hit hit;
          if (!scene->intersect(ray, hit)) break;  // escaped: dome radiance 1
          const Material& m = scene->material(hit.material);
          Frame frame(hit.ng);
          BsdfSample s;
          if (!m.sample(frame.toLocal(-ray.d), rng.next1D(), rng.next1D(), rng.next1D(), s)) { beta = 0; break; }
          beta *= s.weight.x;
          const Vec3 wi = frame.toWorld(s.wi);
          ray = Ray{offsetRayOrigin(hit.p, hit.ng, wi, hit.eps), wi};
        }
        walk.push_back(beta / kWalks);
      }
  // Per pixel, the renderer's mean minus the walk's (kWalks paths): the image's structure
  // cancels, and the differences' spread gives the standard error of their mean.
  std::vector<double> diffs;
  double walked = 0;
  for (size_t p = 0; p < pixels.size(); ++p) {
    double s = 0;
    for (int k = 0; k < kWalks; ++k) s += walk[p * kWalks + k];
    walked += s / pixels.size();
    diffs.push_back(pixels[p] - s);
  }
  double diff, diffSe;
  meanSe(diffs, diff, diffSe);
  std::printf("furnace of rough grains (roughness 0.5): renderer %.4f ± %.4f, BSDF walk %.4f; difference %+.5f ± %.5f\n",
              rendered, renderedSe, walked, diff, diffSe);
  EXPECT_GT(diffSe, 0.0);
  EXPECT_NEAR(diff, 0.0, 4 * diffSe);
  EXPECT_LT(rendered, 1.0);
  EXPECT_GT(rendered, 0.5);
}

TEST(RoughDielectric, EnergyCompensationKeepsEveryDirectionsEnergy) {
  // Compensated (the default): f |cos wi| is the sampling density renormalised over the
  // valid directions, so every sample weighs exactly 1 and sampling (with its retries)
  // does not fail; eval over uniform directions — independent of sampling — integrates to
  // 1 up to the P_valid table's accuracy, from every direction on both sides.
  for (float ior : {1.31f, 2.4f})
    for (float roughness : {0.3f, 0.7f, 1.0f}) {
      const Material m = rough(ior, roughness, true);
      ASSERT_EQ(m.validTable.size(), size_t(2 * Material::kValidNodes));
      for (float cosO : {0.95f, 0.6f, 0.2f, -0.3f, -0.8f}) {
        SCOPED_TRACE(::testing::Message() << "ior " << ior << " roughness " << roughness << " cos " << cosO);
        const Vec3 wo = direction(cosO, 0.4f);
        Rng rng(23);
        int failed = 0;
        for (int i = 0; i < 4000; ++i) {
          BsdfSample s;
          if (!m.sample(wo, rng.next1D(), rng.next1D(), rng.next1D(), s)) { ++failed; continue; }
          EXPECT_EQ(s.weight.x, 1.0f);
          EXPECT_NEAR(s.pdf, m.pdf(wo, s.wi), 1e-3f * s.pdf);
          EXPECT_NEAR(m.eval(wo, s.wi).x, s.pdf, 1e-3f * s.pdf);
        }
        EXPECT_LE(failed, 1);
        const int n = 1 << 18;
        double b = 0, b2 = 0;
        for (int i = 0; i < n; ++i) {
          const double f = m.eval(wo, sampleUniformSphere(rng.next1D(), rng.next1D())).x / kUniformSpherePdf;
          b += f; b2 += f * f;
        }
        const double mean = b / n, se = std::sqrt((b2 / n - mean * mean) / n);
        EXPECT_NEAR(mean, 1.0, 4 * se + 5e-3);
      }
    }
  EXPECT_TRUE(rough(1.5f, 0.5f, false).validTable.empty());
  EXPECT_TRUE(rough(1.5f, 0.0f, true).validTable.empty());  // smooth: nothing lost
}

TEST(RoughDielectric, AWhiteFurnaceOfCompensatedRoughGrainsReturnsTheEnvironment) {
  // Clear grains of roughness 0.5 lose 37% without compensation (above); with it, every
  // path keeps throughput 1 through every interaction, as through smooth grains.
  double mean, se;
  meanSe(renderedPixels(roughFurnace(0.5f, true)), mean, se);
  std::printf("compensated furnace (roughness 0.5): %.4f ± %.4f\n", mean, se);
  // Escapes carry weight 1 exactly; next-event estimates evaluate f through the P_valid
  // table, whose accuracy (5e-3, EnergyCompensationKeepsEveryDirectionsEnergy) bounds
  // their bias.
  EXPECT_NEAR(mean, 1.0, 4 * se + 5e-3);
}
