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

// The switch of one path to the media, with Russian roulette P_a (Meng et al. 2015).
void switchToMedia(const Scene& scene, PathState& p, float pa) {
  p.switchPending = false;
  if (pa < 1.0f) {
    if (p.rng.next1D() >= pa) {
      p.alive = false;
      return;
    }
    p.beta /= pa;
  }
  p.mode = kVpt;
  p.credit = kVpt;
  p.medium = scene.mediumAt(p.ray.o, p.ray.time);
}

}  // namespace

void startInMedia(const Scene& scene, PathState& path) {
  path.mode = path.credit = kVpt;
  path.medium = scene.mediumAt(path.ray.o, path.ray.time);
}

BundleStats traceBundle(const Scene& scene, std::vector<PathState>& paths, float pa) {
  const RenderSettings& rs = scene.settings();
  const int N = int(paths.size());
  const double tau = double(rs.tau) * scene.maxGrainRadius();
  bool decided = rs.technique == Technique::Ept || !scene.hasMedia() || N < 2;
  BundleStats stats;
  for (int k = 0;; ++k) {
    int alive = 0;
    bool lowOrders = true;  // every live path out of the media has done its low orders
    Vec3 centroid(0.0f);
    for (PathState& p : paths) {
      if (!p.alive) continue;
      if (p.mode == kEpt) eptStep(scene, p);
      else if (p.mode == kPpt) pptStep(scene, p);
      else vptStep(scene, p);
      if (p.alive && p.switchPending && !p.inGrain) switchToMedia(scene, p, pa);
      if (p.alive) {
        ++alive;
        centroid += p.ray.o;
        if (p.mode != kVpt && lowOrders && !decided) lowOrders = lowOrdersDone(scene, p);
      }
    }
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
      for (PathState& p : paths) {
        if (!p.alive || p.mode == kVpt) continue;
        if (p.inGrain) p.switchPending = true;
        else switchToMedia(scene, p, pa);
      }
    }
  }
  return stats;
}

RouletteTuning tuneRoulette(const Scene& scene) {
  const RenderSettings& rs = scene.settings();
  RouletteTuning out;
  const int64_t total = int64_t(rs.width) * rs.height;
  const int64_t count = std::min<int64_t>(total, std::max<int64_t>(64, total / 100));
  const int N = std::max(2, std::min(rs.bundleSize, rs.spp));
  struct PixelResult { double VL = 0, VH = 0, tL = 0, tH = 0; };
  std::vector<PixelResult> res(static_cast<size_t>(count), PixelResult());
  const Camera& cam = scene.camera();
  auto body = [&](const tbb::blocked_range<int64_t>& r) {
    std::vector<PathState> paths;
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
      traceBundle(scene, paths, 1.0f);
      double sl = 0, sl2 = 0, sh2 = 0, cl = 0, ch = 0;
      for (const PathState& p : paths) {
        double lo = luminance(p.L[kEpt] + p.L[kPpt]), hi = luminance(p.L[kVpt] + p.L[kDa]);
        if (!std::isfinite(lo) || !std::isfinite(hi)) continue;
        sl += lo; sl2 += lo * lo; sh2 += hi * hi;
        cl += p.cost[0]; ch += p.cost[1];
      }
      PixelResult& pr = res[size_t(i)];
      double m = sl / N;
      pr.VL = std::max(0.0, sl2 / N - m * m) * N / (N - 1);
      pr.VH = sh2 / N;
      pr.tL = cl / N;
      pr.tH = ch / N;
    }
  };
  tbb::blocked_range<int64_t> range(0, count, 4);
  if (rs.threads > 0) {
    tbb::task_arena arena(rs.threads);
    arena.execute([&] { tbb::parallel_for(range, body); });
  } else {
    tbb::parallel_for(range, body);
  }
  for (const PixelResult& pr : res) {  // in order: deterministic sums
    out.VL += pr.VL; out.VH += pr.VH; out.tL += pr.tL; out.tH += pr.tH;
  }
  out.pixels = int(count);
  out.VL /= double(count); out.VH /= double(count); out.tL /= double(count); out.tH /= double(count);
  // P_a = sqrt(V_H t_L / (V_L t_H)), the least cost (V_L + V_H/P_a)(t_L + P_a t_H); no high-order work or no low-order
  // noise: nothing to gain from roulette.
  if (out.tH <= 0 || out.VL <= 0) out.pa = 1.0f;
  else out.pa = float(std::clamp(std::sqrt(out.VH * out.tL / (out.VL * out.tH)), 0.05, 1.0));
  return out;
}

}  // namespace granular
