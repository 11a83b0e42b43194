// test_helpers.h — brute-force references and scenes shared by the core tests.
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <functional>
#include <random>
#include <string>

#include <gtest/gtest.h>

#include <cmath>

#include "core/error.h"
#include "core/image_io.h"
#include "core/render.h"
#include "core/scene.h"

#include "core/material.h"
#include "core/math.h"
#include "core/mesh.h"
#include "core/scene_desc.h"
#include "core/shapes.h"

namespace granular::testing {

// The bit pattern of a float (Cryptomatte ids are hashes stored as float bits).
inline uint32_t bitsOf(float f) {
  uint32_t u;
  std::memcpy(&u, &f, 4);
  return u;
}

// Möller–Trumbore; returns t > 0 of the hit or +inf.
inline float rayTriangle(const Vec3& o, const Vec3& d, const Vec3& a, const Vec3& b, const Vec3& c) {
  Vec3 e1 = b - a, e2 = c - a, p = cross(d, e2);
  double det = dot(e1, p);
  if (std::fabs(det) < 1e-20) return kInf;
  double inv = 1.0 / det;
  Vec3 s = o - a;
  double u = dot(s, p) * inv;
  if (u < 0 || u > 1) return kInf;
  Vec3 q = cross(s, e1);
  double v = dot(d, q) * inv;
  if (v < 0 || u + v > 1) return kInf;
  double t = dot(e2, q) * inv;
  return t > 0 ? float(t) : kInf;
}

// Point in closed mesh by crossing parity along three directions (majority vote).
inline bool pointInMesh(const TriangleMesh& m, const Vec3& p) {
  const Vec3 dirs[3] = {normalize(Vec3(0.31f, 0.73f, 0.61f)), normalize(Vec3(-0.57f, 0.19f, 0.8f)),
                        normalize(Vec3(0.11f, -0.93f, 0.35f))};
  int votes = 0;
  for (const Vec3& d : dirs) {
    int crossings = 0;
    for (size_t t = 0; t < m.numTriangles(); ++t)
      if (std::isfinite(rayTriangle(p, d, m.points[m.indices[3 * t]], m.points[m.indices[3 * t + 1]],
                                    m.points[m.indices[3 * t + 2]])))
        ++crossings;
    votes += crossings & 1;
  }
  return votes >= 2;
}

// A uniformly random rotation: a normalised quaternion of four normal deviates.
inline Quat randomRotation(std::mt19937& rng) {
  std::normal_distribution<float> n(0.0f, 1.0f);
  Quat q{n(rng), n(rng), n(rng), n(rng)};
  const float l = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
  return Quat{q.w / l, q.x / l, q.y / l, q.z / l};
}

// The message of the InputError f throws, or "(no error)".
inline std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "(no error)";
}

// Images equal value for value, every channel (NaN never equals; +inf where nothing was
// hit equals +inf).
inline ::testing::AssertionResult sameImage(const Image& a, const Image& b) {
  if (a.width != b.width || a.height != b.height || a.channels != b.channels || a.pixels.size() != b.pixels.size())
    return ::testing::AssertionFailure() << "sizes or channels differ";
  for (size_t i = 0; i < a.pixels.size(); ++i)
    if (!(a.pixels[i] == b.pixels[i]))
      return ::testing::AssertionFailure() << "value " << i << ": " << a.pixels[i] << " vs " << b.pixels[i];
  return ::testing::AssertionSuccess();
}

// A small aggregate of rocks and boxes (3 : 1) in a squashed, moved icosphere: grain radius
// R, packing rate f; tile of 64 spheres.
inline AggregateDesc smallAggregate(float R = 0.08f, float f = 0.55f, uint64_t seed = 7,
                                    const std::string& name = "test_sand") {
  AggregateDesc a;
  a.name = name;
  a.boundary = makeIcosphere(2);
  a.xf = Transform::translate(Vec3(0.1f, -0.2f, 0.3f)) * Transform::scale(Vec3(1.0f, 0.7f, 0.9f));
  a.grainRadius = R;
  a.packingRate = f;
  a.seed = seed;
  a.tileSpheres = 64;
  a.prototypes = {GrainPrototypeDesc{"rock", makeRock(1, 0.25f, 3), 0},
                  GrainPrototypeDesc{"box", makeBox(Vec3(-0.5f, -0.3f, -0.4f), Vec3(0.5f, 0.3f, 0.4f)), 0}};
  a.weights = {3.0f, 1.0f};
  return a;
}

// A sun of 5 degrees (intensity 3, from above and aside) and a blue sky: the light of the
// hybrid, LOD and explicit-grain tests.
inline std::vector<LightDesc> sunAndSky() {
  LightDesc sun;
  sun.name = "sun";
  sun.type = LightType::Distant;
  sun.angle = 5;
  sun.intensity = 3;
  sun.xf = Transform::lookAt(Vec3(0.0f), Vec3(-0.4f, -1.0f, -0.5f), Vec3(0, 0, 1));
  LightDesc sky;
  sky.name = "sky";
  sky.type = LightType::Dome;
  sky.color = Vec3(0.5f, 0.6f, 0.8f);
  return {sun, sky};
}

// A ball (radius 1) of bright sand grains of radius R under a sun and a sky, seen from
// eye towards target with square apertures (focal length 50): the scene of the hybrid
// and LOD tests.
inline SceneDesc sandBallScene(const Vec3& eye, float aperture, float R, uint64_t aggregateSeed,
                               const Vec3& target = Vec3(0.0f)) {
  SceneDesc s;
  s.camera.cameraToWorld = Transform::lookAt(eye, target, Vec3(0, 1, 0));
  s.camera.focalLength = 50;
  s.camera.horizontalAperture = s.camera.verticalAperture = aperture;
  MaterialDesc sand;
  sand.name = "sand";
  sand.type = MaterialType::Dielectric;
  sand.ior = 1.5f;
  sand.absorption = Vec3(0.02f, 0.04f, 0.1f);
  s.materials.push_back(sand);
  s.lights = sunAndSky();
  AggregateDesc a;
  a.name = "ball";
  a.boundary = makeIcosphere(3);
  a.grainRadius = R;
  a.packingRate = 0.6f;
  a.tileSpheres = 128;
  a.seed = aggregateSeed;
  a.prototypes = {GrainPrototypeDesc{"rock", makeRock(1, 0.2f, 2), 0}};
  a.weights = {1.0f};
  s.aggregates.push_back(a);
  return s;
}

// A white furnace: a ball (radius 1) of rock grains of one material under a white dome of
// radiance 1 and nothing else, seen head-on (24x24 pixels, EPT only, no path-length
// limit). What the grains return is all the image shows.
inline SceneDesc whiteFurnaceScene(const MaterialDesc& grain) {
  SceneDesc s;
  s.settings.width = 24;
  s.settings.height = 24;
  s.settings.spp = 4;
  s.settings.maxDepth = 1 << 20;
  s.settings.seed = 3;
  s.settings.technique = Technique::Ept;  // the explicit reference alone
  s.camera.cameraToWorld = Transform::lookAt(Vec3(0, 0, 4), Vec3(0, 0, 0), Vec3(0, 1, 0));
  s.camera.focalLength = 50;
  s.camera.horizontalAperture = 24;
  s.camera.verticalAperture = 24;
  s.materials.push_back(grain);
  LightDesc dome;
  dome.name = "dome";
  dome.type = LightType::Dome;
  dome.color = Vec3(1.0f);
  s.lights.push_back(dome);
  AggregateDesc a;
  a.name = "furnace_grains";
  a.boundary = makeIcosphere(2);
  a.grainRadius = 0.12f;
  a.packingRate = 0.5f;
  a.tileSpheres = 64;
  a.prototypes = {GrainPrototypeDesc{"rock", makeRock(1, 0.2f, 1), 0}};
  a.weights = {1.0f};
  s.aggregates.push_back(a);
  return s;
}

// The ball of bench/accuracy_matrix.py: rock grains 100 across (f 0.6, absorption 0.05
// per radius, IOR ior) over a grey floor under a white dome, filling most of a 32 x 24
// image; amberFlint: amber rocks and flint flakes (0.6 / 0.4, f 0.55) instead. The
// aggregate's id is 1 (the primId AOV).
inline SceneDesc matrixBall(bool amberFlint, float ior = 2.4f) {
  SceneDesc s;
  s.settings.width = 32;
  s.settings.height = 24;
  s.settings.spp = 32;
  s.camera.cameraToWorld = Transform::lookAt(Vec3(0.3f, 0.7f, 2.6f), Vec3(0, -0.1f, 0), Vec3(0, 1, 0));
  s.camera.focalLength = 35;
  s.camera.horizontalAperture = 36;
  s.camera.verticalAperture = 27;
  MaterialDesc grain{"grain", MaterialType::Dielectric, Vec3(0.5f), amberFlint ? 1.55f : ior,
                     amberFlint ? Vec3(0.2f, 0.6f, 1.5f) : Vec3(0.05f)};
  MaterialDesc floor{"floor", MaterialType::Lambert, Vec3(0.5f)};
  MaterialDesc flint{"flint", MaterialType::Dielectric, Vec3(0.5f), 1.8f, Vec3(0.05f)};
  s.materials = {grain, floor, flint};
  MeshDesc f;
  f.name = "floor";
  f.mesh = makeBox(Vec3(-4, -1.3f, -4), Vec3(4, -1.0f, 4));
  f.material = 1;
  s.meshes.push_back(f);
  LightDesc sky;
  sky.name = "sky";
  sky.type = LightType::Dome;
  s.lights.push_back(sky);
  AggregateDesc a;
  a.name = "ball";
  a.boundary = makeIcosphere(3);
  a.grainRadius = 0.01f;
  a.packingRate = amberFlint ? 0.55f : 0.6f;
  a.seed = 3;
  a.tileSpheres = 512;
  a.id = 1;
  a.prototypes = {GrainPrototypeDesc{"rock", makeRock(2, 0.25f, 2), 0}};
  a.weights = {1};
  if (amberFlint) {
    a.prototypes.push_back(GrainPrototypeDesc{"flake", makeEllipsoid(Vec3(1.0f, 0.6f, 0.8f), 2), 2});
    a.weights = {0.6f, 0.4f};
  }
  s.aggregates.push_back(a);
  return s;
}

// A smooth dielectric grain material of this IOR and absorption per grain radius.
inline Material dielectric(float ior, Vec3 absorption = Vec3(0.0f)) {
  Material m;
  m.type = MaterialType::Dielectric;
  m.ior = ior;
  m.absorption = absorption;
  return m;
}

// Per channel: the image's mean and its standard error (pixels independent; each pixel's
// variance of the mean from the film's variance AOV).
struct ChannelEstimate {
  double mean[3] = {0, 0, 0}, se[3] = {0, 0, 0};
};

// An image's estimates over windows: each [x0, x1) x [y0, y1).
inline std::vector<ChannelEstimate> imageEstimates(const Image& img, const std::vector<std::array<int, 4>>& windows) {
  const auto& names = img.channels;
  auto channel = [&](const std::string& n) { return int(std::find(names.begin(), names.end(), n) - names.begin()); };
  const int var[3] = {channel("variance.R"), channel("variance.G"), channel("variance.B")};
  std::vector<ChannelEstimate> out;
  for (const auto& [x0, x1, y0, y1] : windows) {
    ChannelEstimate e;
    const double n = double(x1 - x0) * (y1 - y0);
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        const float* px = &img.pixels[(size_t(y) * img.width + x) * img.channels.size()];
        for (int c = 0; c < 3; ++c) {
          e.mean[c] += px[c] / n;
          e.se[c] += px[var[c]] / (n * n);
        }
      }
    for (int c = 0; c < 3; ++c) e.se[c] = std::sqrt(e.se[c]);
    out.push_back(e);
  }
  return out;
}

// Two images of one scene (or of two that should render alike) with the same seeds: the
// mean of their per-pixel differences a − b per channel and its standard error, from the
// differences' spread (pixels independent). Far tighter than two independent errors where
// the seeds correlate the images, and right where they do not.
struct PairedDifference {
  double diff[3] = {0, 0, 0}, se[3] = {0, 0, 0};
};

inline PairedDifference pairedDifference(const Image& a, const Image& b) {
  PairedDifference p;
  double s2[3] = {0, 0, 0};
  const double n = double(a.width) * a.height;
  for (int y = 0; y < a.height; ++y)
    for (int x = 0; x < a.width; ++x)
      for (int c = 0; c < 3; ++c) {
        const double d = double(a.at(x, y)[c]) - b.at(x, y)[c];
        p.diff[c] += d / n;
        s2[c] += d * d / n;
      }
  for (int c = 0; c < 3; ++c) p.se[c] = std::sqrt(std::max(0.0, s2[c] - p.diff[c] * p.diff[c]) / (n - 1));
  return p;
}

// One render's estimates over windows of the image.
// The scene built and rendered at its settings' spp, as an image.
inline Image renderImage(const SceneDesc& d) {
  auto scene = Scene::build(d);
  Renderer r(*scene);
  EXPECT_TRUE(r.render(d.settings.spp));
  return r.film().toImage();
}

inline std::vector<ChannelEstimate> renderEstimates(const SceneDesc& d, const std::vector<std::array<int, 4>>& windows) {
  auto scene = Scene::build(d);
  Renderer r(*scene);
  EXPECT_TRUE(r.render(d.settings.spp));
  return imageEstimates(r.film().toImage(), windows);
}

inline ChannelEstimate renderEstimate(const SceneDesc& d, int x0 = 0, int x1 = -1, int y0 = 0, int y1 = -1) {
  return renderEstimates(d, {{x0, x1 < 0 ? d.settings.width : x1, y0, y1 < 0 ? d.settings.height : y1}})[0];
}

// A side x side grid of blocks over a square image of `size` pixels.
inline std::vector<std::array<int, 4>> blocks(int size, int side) {
  std::vector<std::array<int, 4>> w;
  for (int j = 0; j < side; ++j)
    for (int i = 0; i < side; ++i) w.push_back({i * size / side, (i + 1) * size / side, j * size / side, (j + 1) * size / side});
  return w;
}

// Motion blur against the shutter it spans. scene(blur, f, seed, spp): blurred over the
// shutter (f = 0.5), or still at fraction f of the motion. The blurred image against the
// average of 16 still ones at the middles of 16 equal slices of the shutter (each of
// spp / 16 samples), per block of a 4 x 4 grid and channel: within 4 standard errors.
// Returns the blurred image's largest difference from the still one at mid-shutter, in
// standard errors (the motion shows).
inline double expectBlurIsTheShuttersAverage(const std::function<SceneDesc(bool, float, uint64_t, int)>& scene,
                                             int spp, const char* label) {
  const SceneDesc blurredScene = scene(true, 0.5f, 3, spp);
  const auto windows = blocks(blurredScene.settings.width, 4);
  const auto blurred = renderEstimates(blurredScene, windows);
  constexpr int kSlices = 16;
  std::vector<ChannelEstimate> average(windows.size());
  for (int k = 0; k < kSlices; ++k) {
    const auto e = renderEstimates(scene(false, (float(k) + 0.5f) / kSlices, 50 + uint64_t(k), spp / kSlices), windows);
    for (size_t b = 0; b < windows.size(); ++b)
      for (int c = 0; c < 3; ++c) {
        average[b].mean[c] += e[b].mean[c] / kSlices;
        average[b].se[c] += e[b].se[c] * e[b].se[c] / (kSlices * kSlices);
      }
  }
  const auto still = renderEstimates(scene(false, 0.5f, 9, spp), windows);
  double worst = 0, stillWorst = 0;
  for (size_t b = 0; b < windows.size(); ++b)
    for (int c = 0; c < 3; ++c) {
      // Blocks of sky alone have no noise: float rounding is their tolerance.
      const double se = std::sqrt(average[b].se[c]), rounding = 1e-5 * std::fabs(average[b].mean[c]) + 1e-12;
      const double z = std::fabs(blurred[b].mean[c] - average[b].mean[c]) / (std::hypot(blurred[b].se[c], se) + rounding);
      worst = std::max(worst, z);
      stillWorst = std::max(stillWorst, std::fabs(blurred[b].mean[c] - still[b].mean[c]) /
                                            (std::hypot(blurred[b].se[c], still[b].se[c]) + rounding));
      // 48 comparisons: 4 standard errors, a chance of 0.3% that any one exceeds it by noise.
      EXPECT_LE(z, 4.0) << label << ": block " << b << " channel " << c;
    }
  std::printf("%s: worst block %.2f standard errors from the shutter's average; the still one at mid-shutter: %.1f\n",
              label, worst, stillWorst);
  return stillWorst;
}

}  // namespace granular::testing
