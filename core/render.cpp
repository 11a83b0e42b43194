#include "render.h"

#include <chrono>

#include <tbb/blocked_range2d.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

namespace granular {

Renderer::Renderer(const Scene& scene)
    : scene_(scene), film_(scene.settings().width, scene.settings().height) {}

bool Renderer::renderPass(int samples, const std::atomic<bool>* cancel) {
  const RenderSettings& rs = scene_.settings();
  const Camera& cam = scene_.camera();
  std::atomic<bool> cancelled{false};
  auto body = [&](const tbb::blocked_range2d<int>& r) {
    for (int y = r.rows().begin(); y < r.rows().end(); ++y)
      for (int x = r.cols().begin(); x < r.cols().end(); ++x) {
        if (cancel && cancel->load(std::memory_order_relaxed)) { cancelled = true; return; }
        for (int s = 0; s < samples; ++s) {
          long index = done_ + s;
          Rng rng(hashInts(rs.seed, uint64_t(x), uint64_t(y), uint64_t(index)), 0);
          Ray ray = cam.generateRay(float(x) + rng.next1D(), float(y) + rng.next1D());
          PrimaryInfo info;
          PixelSample ps;
          ps.L = tracePath(scene_, ray, rng, &info);
          ps.hit = info.hit;
          ps.depth = info.depth;
          ps.normal = info.normal;
          film_.add(x, y, ps);
        }
      }
  };
  tbb::blocked_range2d<int> range(0, rs.height, 8, 0, rs.width, 8);
  if (rs.threads > 0) {
    tbb::task_arena arena(rs.threads);
    arena.execute([&] { tbb::parallel_for(range, body); });
  } else {
    tbb::parallel_for(range, body);
  }
  if (cancelled) return false;
  done_ += samples;
  return true;
}

bool Renderer::render(int passSamples, const std::function<void(const RenderProgress&)>& progress,
                      const std::atomic<bool>* cancel) {
  auto t0 = std::chrono::steady_clock::now();
  const long target = scene_.settings().spp;
  while (done_ < target) {
    int n = int(std::min<long>(passSamples, target - done_));
    if (!renderPass(n, cancel)) return false;
    if (progress) {
      RenderProgress p;
      p.samplesDone = done_;
      p.samplesTarget = target;
      p.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      progress(p);
    }
  }
  return true;
}

}  // namespace granular
