#include "hybrid.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "ept.h"
#include "ppt.h"
#include "vpt.h"

namespace granular {

namespace {


// Russian roulette (pa < 1) or splitting (pa > 1) of path i where it enters the media:
// ⌊pa⌋ or ⌈pa⌉ continuations, pa on average, each weighted 1/pa; the path is the first,
// the others go to `split` with empty radiance and costs.
void continueIntoMedia(std::vector<PathState>& paths, size_t i, float pa, std::vector<PathState>& split) {
  PathState& p = paths[i];
  p.enteredMedia = true;
  if (pa == 1.0f) return;
  const float whole = std::floor(pa);
  const int n = int(whole) + (p.rng.next1D() < pa - whole);
  if (n == 0) {
    p.alive = false;
    return;
  }
  p.beta /= pa;
  p.rrScale = pa;
  for (int j = 1; j < n; ++j) {
    PathState c = p;
    const uint64_t a = p.rng.nextU32(), b = p.rng.nextU32();
    c.rng = Rng(hashInts(a, b, uint64_t(j)), 0);
    for (Vec3& l : c.L) l = Vec3(0.0f);
    c.cost[0] = c.cost[1] = 0;
    c.splitFrom = int(i);
    split.push_back(c);
  }
}

// The bundle's switch of path i to the media (Meng et al. 2015).
void switchToMedia(const Scene& scene, std::vector<PathState>& paths, size_t i, float pa,
                   std::vector<PathState>& split) {
  PathState& p = paths[i];
  p.switchPending = false;
  p.mode = kVpt;
  p.credit = kVpt;
  p.medium = scene.mediumAt(p.ray.o, p.ray.time);
  continueIntoMedia(paths, i, pa, split);
}

// Adds the continuations after the first n paths into their paths and removes them.
void foldSplits(std::vector<PathState>& paths, size_t n) {
  for (size_t i = n; i < paths.size(); ++i) {
    PathState& p = paths[size_t(paths[i].splitFrom)];
    for (int t = 0; t < kTransports; ++t) p.L[t] += paths[i].L[t];
    p.cost[1] += paths[i].cost[1];
    if (paths[i].credit == kDa) p.credit = kDa;
  }
  paths.resize(n);
}

}  // namespace

void startInMedia(const Scene& scene, PathState& path) {
  path.mode = path.credit = kVpt;
  path.enteredMedia = true;  // from the camera: no roulette, nothing to share a split
  path.medium = scene.mediumAt(path.ray.o, path.ray.time);
}

BundleStats traceBundle(const Scene& scene, std::vector<PathState>& paths, float pa, bool fold) {
  const RenderSettings& rs = scene.settings();
  const size_t n = paths.size();
  const int N = int(n);
  const double tau = double(rs.tau) * scene.maxGrainRadius();
  bool decided = rs.technique == Technique::Ept || !scene.hasMedia() || N < 2;
  BundleStats stats;
  std::vector<PathState> split;
  for (int k = 0;; ++k) {
    int alive = 0;
    bool lowOrders = true;  // every live path out of the media has done its low orders
    Vec3 centroid(0.0f);
    for (size_t i = 0; i < paths.size(); ++i) {
      PathState& p = paths[i];
      if (!p.alive) continue;
      if (p.mode == kEpt) eptStep(scene, p);
      else if (p.mode == kPpt) pptStep(scene, p);
      else vptStep(scene, p);
      if (p.alive && p.switchPending && !p.inGrain) switchToMedia(scene, paths, i, pa, split);
      // In the media by the level-of-detail shortcut (ept.h, ppt.h): the same roulette.
      else if (p.alive && p.mode == kVpt && !p.enteredMedia) continueIntoMedia(paths, i, pa, split);
      if (p.alive) {
        ++alive;
        centroid += p.ray.o;
        if (p.mode != kVpt && lowOrders && !decided) lowOrders = lowOrdersDone(scene, p);
      }
    }
    paths.insert(paths.end(), split.begin(), split.end());
    split.clear();
    if (alive == 0) break;
    // Not before every live path still out of the media has done its low orders (ppt.h).
    if (decided || alive < 2 || !lowOrders) continue;
    // σ_k: RMS distance of the live vertices to their centroid.
    centroid /= float(alive);
    double s2 = 0;
    for (const PathState& p : paths)
      if (p.alive) s2 += length2(p.ray.o - centroid);
    double sigma = std::sqrt(s2 / alive);
    if (sigma > tau * alive / N) {
      decided = true;
      stats.switchedAtBounce = k;
      for (size_t i = 0; i < n; ++i) {
        PathState& p = paths[i];
        if (!p.alive || p.mode == kVpt) continue;
        if (p.inGrain) p.switchPending = true;
        else switchToMedia(scene, paths, i, pa, split);
      }
      paths.insert(paths.end(), split.begin(), split.end());
      split.clear();
    }
  }
  if (fold) foldSplits(paths, n);
  return stats;
}

double RouletteTuning::variance(double p) const {
  if (p <= 1.0) return V0 + V1 + H2 * (1.0 / p - 1.0);
  const double f = p - std::floor(p);
  return V0 + V1 / p + H12 * f * (1.0 - f) / (p * p);
}

RouletteTuning tuneRoulette(const Scene& scene) {
  const RenderSettings& rs = scene.settings();
  RouletteTuning out;
  const int64_t total = int64_t(rs.width) * rs.height;
  const int64_t count = std::min<int64_t>(total, std::max<int64_t>(64, total / 100));
  const int N = std::max(2, std::min(rs.bundleSize, rs.spp));
  struct PixelResult { double V01 = 0, V1 = 0, H2 = 0, H12 = 0, tL = 0, tH = 0; };
  std::vector<PixelResult> res(static_cast<size_t>(count), PixelResult());
  const Camera& cam = scene.camera();
  auto body = [&](const tbb::blocked_range<int64_t>& r) {
    std::vector<PathState> paths;
    std::vector<double> lo, h1, h2;
    for (int64_t i = r.begin(); i < r.end(); ++i) {
      // Pixels spread evenly over the image (a stride through the raster order).
      int64_t idx = (i * total) / count + (total / count) / 2;
      int x = int(idx % rs.width), y = int(idx / rs.width);
      paths.clear();
      for (int s = 0; s < N; ++s) {
        Rng rng(hashInts(rs.seed, uint64_t(x), uint64_t(y), uint64_t(s), 0x9a11ULL), 0);
        Ray ray = cam.sampleRay(x, y, rng);
        PathState p = startPath(ray, 0, cam.coneSpread(), cam.coneWidth());
        p.rng = rng;
        paths.push_back(p);
      }
      // Two continuations of weight 1/2 per path entering the media: H_1 and H_2 are
      // twice their radiance. A path with none (it never entered them) is all low order:
      // no P_a changes it.
      traceBundle(scene, paths, 2.0f, false);
      lo.assign(size_t(N), 0.0);
      h1.assign(size_t(N), 0.0);
      h2.assign(size_t(N), 0.0);
      std::vector<char> switched(size_t(N), 0);
      PixelResult& pr = res[size_t(i)];
      for (size_t j = size_t(N); j < paths.size(); ++j) {
        const PathState& c = paths[j];
        const size_t k = size_t(c.splitFrom);
        switched[k] = 1;
        h2[k] = 2.0 * luminance(c.L[kVpt] + c.L[kDa]);
        pr.tH += 0.5 * c.cost[1];
      }
      for (size_t k = 0; k < size_t(N); ++k) {
        const PathState& p = paths[k];
        if (switched[k]) {
          lo[k] = luminance(p.L[kEpt] + p.L[kPpt]);
          h1[k] = 2.0 * luminance(p.L[kVpt] + p.L[kDa]);
          pr.tL += p.cost[0];
          pr.tH += 0.5 * p.cost[1];
        } else {
          lo[k] = luminance(p.radiance());
          pr.tL += p.cost[0] + p.cost[1];
        }
        if (!std::isfinite(lo[k]) || !std::isfinite(h1[k]) || !std::isfinite(h2[k])) lo[k] = h1[k] = h2[k] = 0;
      }
      double s = 0, s2 = 0;
      for (size_t k = 0; k < size_t(N); ++k) {
        const double v = lo[k] + h1[k];
        s += v;
        s2 += v * v;
        pr.V1 += 0.5 * (h1[k] - h2[k]) * (h1[k] - h2[k]);
        pr.H2 += 0.5 * (h1[k] * h1[k] + h2[k] * h2[k]);
        pr.H12 += h1[k] * h2[k];
      }
      const double m = s / N;
      pr.V01 = std::max(0.0, s2 / N - m * m) * N / (N - 1);
      pr.V1 /= N;
      pr.H2 /= N;
      pr.H12 /= N;
      pr.tL /= N;
      pr.tH /= N;
    }
  };
  tbb::blocked_range<int64_t> range(0, count, 4);
  if (rs.threads > 0) {
    tbb::task_arena arena(rs.threads);
    arena.execute([&] { tbb::parallel_for(range, body); });
  } else {
    tbb::parallel_for(range, body);
  }
  double V01 = 0;
  for (const PixelResult& pr : res) {  // in order: deterministic sums
    V01 += pr.V01; out.V1 += pr.V1; out.H2 += pr.H2; out.H12 += pr.H12; out.tL += pr.tL; out.tH += pr.tH;
  }
  out.pixels = int(count);
  const double c = double(count);
  V01 /= c; out.V1 /= c; out.H2 /= c; out.H12 /= c; out.tL /= c; out.tH /= c;
  out.V0 = std::max(0.0, V01 - out.V1);
  out.pa = bestContinuations(out);
  return out;
}

float bestContinuations(const RouletteTuning& t) {
  // No high-order work or no noise: nothing to gain from roulette.
  if (!(t.tH > 0) || !(t.variance(1.0) > 0)) return 1.0f;
  // The least variance × cost on a grid of P_a in [0.05, 1]. Not above: splitting's
  // predicted gains did not carry over to the images' error × time (hybrid.h).
  float pa = 1.0f;
  double best = t.variance(1.0) * t.cost(1.0);
  for (int k = 5; k < 100; ++k) {
    const double p = 0.01 * k, v = t.variance(p) * t.cost(p);
    if (v < best * (1.0 - 1e-9)) {
      best = v;
      pa = float(p);
    }
  }
  return pa;
}

}  // namespace granular
