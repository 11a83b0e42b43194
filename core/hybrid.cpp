#include "hybrid.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <tbb/parallel_for.h>

#include "arena.h"
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
  p.pendingStraight = Vec3(0.0f);  // the media count those grains as scatterings (ppt.h)
  enterMedia(scene, p);
  continueIntoMedia(paths, i, pa, split);
}

// Adds the continuations after the first n paths into their paths and removes them.
void foldSplits(std::vector<PathState>& paths, size_t n) {
  for (size_t i = n; i < paths.size(); ++i) {
    PathState& p = paths[size_t(paths[i].splitFrom)];
    for (int t = 0; t < kTransports; ++t) p.L[t] += paths[i].L[t];
    p.cost[1] += paths[i].cost[1];
    if (paths[i].credit == kDa) p.credit = kDa;
    p.lost = p.lost || paths[i].lost;
  }
  paths.resize(n);
}

}  // namespace

void startInMedia(const Scene& scene, PathState& path) {
  path.mode = path.credit = kVpt;
  path.enteredMedia = true;  // from the camera: no roulette, nothing to share a split
  path.medium = scene.mediumAt(path.ray.o, path.ray.time);
}

BundleStats traceBundle(const Scene& scene, std::vector<PathState>& paths, float pa) {
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
      if (!p.alive) p.addPendingStraight();  // ended among proxies: theirs (ppt.h)
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
  foldSplits(paths, n);
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
      // L + H and H per path (H: what it carried after entering the media, 0 if it never did).
      double s = 0, s2 = 0, h2 = 0;
      PixelResult& pr = res[size_t(i)];
      for (const PathState& p : paths) {
        double all = luminance(p.radiance()), hi = p.enteredMedia ? luminance(p.L[kVpt] + p.L[kDa]) : 0.0;
        if (!std::isfinite(all) || !std::isfinite(hi)) all = hi = 0;
        s += all;
        s2 += all * all;
        h2 += hi * hi;
        pr.tL += p.enteredMedia ? p.cost[0] : p.cost[0] + p.cost[1];
        pr.tH += p.enteredMedia ? p.cost[1] : 0.0;
      }
      const double m = s / N;
      pr.VH = h2 / N;
      pr.VL = std::max(0.0, s2 / N - m * m) * N / (N - 1) - pr.VH;
      pr.tL /= N;
      pr.tH /= N;
    }
  };
  tbb::blocked_range<int64_t> range(0, count, 4);
  inArena(rs.threads, [&] { tbb::parallel_for(range, body); });
  for (const PixelResult& pr : res) {  // in order: deterministic sums
    out.VL += pr.VL; out.VH += pr.VH; out.tL += pr.tL; out.tH += pr.tH;
  }
  out.pixels = int(count);
  out.VL /= double(count); out.VH /= double(count); out.tL /= double(count); out.tH /= double(count);
  out.pa = bestContinuations(out);
  return out;
}

float bestContinuations(const RouletteTuning& t) {
  // No high-order work, or no low-order noise to weigh it against: nothing to gain.
  if (!(t.tH > 0) || !(t.VL > 0)) return 1.0f;
  return float(std::clamp(std::sqrt(t.VH * t.tL / (t.VL * t.tH)), 0.05, 1.0));
}

}  // namespace granular
