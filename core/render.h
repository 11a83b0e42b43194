// render.h — the progressive renderer: passes of samples over the film with TBB.
//
// Contract: renderPass(n) adds samples [k, k+n) to every pixel, where k is the count
// so far; sample s of pixel (x, y) draws all its randomness from a generator seeded by
// hash(seed, x, y, s), so an image depends on the seed and the sample count only —
// not on the thread count nor on how samples were split into passes. A pass checks
// the cancel flag between tiles and returns false when it was set.
#pragma once

#include <atomic>
#include <functional>

#include "ept.h"
#include "film.h"
#include "scene.h"

namespace granular {

struct RenderProgress {
  long samplesDone = 0;       // per pixel
  long samplesTarget = 0;
  double seconds = 0;
};

class Renderer {
 public:
  explicit Renderer(const Scene& scene);
  bool renderPass(int samples, const std::atomic<bool>* cancel = nullptr);
  // Renders settings().spp samples in passes of passSamples; calls progress after each.
  bool render(int passSamples = 1, const std::function<void(const RenderProgress&)>& progress = nullptr,
              const std::atomic<bool>* cancel = nullptr);
  const Film& film() const { return film_; }
  long samplesPerPixel() const { return done_; }

 private:
  const Scene& scene_;
  Film film_;
  long done_ = 0;
};

}  // namespace granular
