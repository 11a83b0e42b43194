// render.h — the progressive renderer: passes of samples over the film with TBB.
//
// Contract: renderPass(n) adds samples [k, k+n) to every pixel, where k is the count
// so far, as bundles (hybrid.h) of N = min(bundleSize, spp) paths of a pixel traced in
// lock-step, the last one partial if N does not divide n; render() makes passes of whole
// bundles, so that bundle b always holds sample indices [bN, bN+N). Sample
// s of pixel (x, y) draws all its randomness from a generator seeded by
// hash(seed, x, y, s), so an image depends on the seed and the sample count only —
// not on the thread count nor on how samples were split into passes. P_a comes from
// settings.roulette or, when that is negative and the scene has media, from the
// pre-render (tuneRoulette) run once before the first pass. A pass checks the cancel
// flag between tiles and returns false when it was set. A sample whose estimate is not
// finite is dropped as a whole (the pixel keeps its count) and counted.
//
// A crop (RenderSettings::cropX0.., renderWindow()) renders only its pixels, into a film
// of the window's size whose pixel (0, 0) is the window's first; everything else — each
// pixel's random streams, the pre-render over the whole image — is as without it, so the
// films of a tiling are the full film's pixels bit for bit.
//
// Adaptive sampling (setNoiseThreshold(T) > 0): each pixel stops on its own once it
// has at least minAdaptiveSamples() samples and Film::pixelBelowNoiseThreshold(T) holds,
// checked before each of its bundles from its own film statistics — so a pixel's
// samples stay whole bundles [bN, bN+N) of the same streams, and where it stops depends
// only on the seed, spp and T, not on threads or pass splits: the image is the one a
// render of those per-pixel sample counts draws. A pixel that stopped stays stopped (its
// statistics no longer change). After each pass the renderer counts the pixels still
// going; converged() is true when none is, and render() then ends before spp.
// The minimum is two bundles and at least 16 samples: the paths of a bundle share its
// switch to the media (hybrid.h), so one bundle's spread understates the pixel's
// variance, and a handful of samples that happen to agree (all missing a small light)
// would read as no noise at all. Samples that agree because an event of a few percent
// (a bounce onto a nearby object, an occluder of the sky) has not happened yet are
// common where the rest of the estimate is exact (a sky-lit floor), so the pixel's
// neighbours vouch for it: a pixel stops only once its own standard error meets the
// threshold and so would, with its own count, the mean relative per-sample variance of
// the 24 pixels around it (within kVouchRadius) at the minimum — an estimate of the
// region's spread from 24 times the samples, in which an event of a few percent shows.
// (Their largest instead would hold a whole region to the one neighbour whose 16 samples
// met a rare bright path, at 16 times its weight.) The first pass that reaches the minimum
// takes every pixel there before any goes on; a crop traces its ring of neighbours to the
// minimum as well, so tiles stay the full film's pixels.
//
// Interactive hosts: renderPass() calls onTile from the worker thread that finished a
// tile (its pixels then hold the pass's samples), so a host can show tiles as they come;
// renderPreview(stride) first renders one bundle of the centre pixel of every
// stride×stride block into a coarse film — the same random streams as those pixels' first
// bundle in renderPass — at about 1/stride² of a pass's cost, leaving the film and the
// counts (nonFiniteSamples, shortcutFraction) untouched.
#pragma once

#include <atomic>
#include <functional>

#include "path_state.h"
#include "film.h"
#include "hybrid.h"
#include "scene.h"

namespace granular {

struct RenderProgress {
  long samplesDone = 0;       // per pixel
  long samplesTarget = 0;
  double seconds = 0;
};

// Samples per pixel of the film (differ between pixels with adaptive sampling).
struct SampleCounts {
  double mean = 0;
  long min = 0, max = 0;
};

// A finished path as a film sample; false when its estimate is not finite (a numerical
// failure), and then the sample carries no radiance: it is dropped as a whole.
inline bool toPixelSample(const PathState& p, PixelSample& ps) {
  bool finite = true;
  for (int t = 0; t < kTransports; ++t) finite = finite && isFinite(p.L[t]);
  ps.L = Vec3(0.0f);
  for (int t = 0; t < kTransports; ++t) {
    ps.byTechnique[t] = finite ? p.L[t] : Vec3(0.0f);
    ps.L += ps.byTechnique[t];
  }
  ps.hit = p.primary.hit;
  ps.depth = p.primary.depth;
  ps.normal = p.primary.normal;
  ps.primId = p.primary.primId;
  ps.albedo = p.primary.albedo;
  ps.instanceId = p.primary.instanceId;
  ps.aggregateId = p.primary.aggregateId;
  ps.cryptomatte[0] = p.primary.cryptomatte[0];
  ps.cryptomatte[1] = p.primary.cryptomatte[1];
  return finite;
}

class Renderer {
 public:
  explicit Renderer(const Scene& scene);
  // Film pixel window [x0, x1) × [y0, y1) of a finished tile (image pixels less the
  // crop's origin).
  using TileCallback = std::function<void(int x0, int x1, int y0, int y1)>;
  // Adds samples up to k + samples to every pixel that has not stopped (adaptive sampling).
  bool renderPass(int samples, const std::atomic<bool>* cancel = nullptr, const TileCallback& onTile = nullptr);
  // Adaptive sampling's threshold (0: off, every pixel gets spp); before the first pass.
  // InputError when negative or not finite, or when changed after the first pass.
  void setNoiseThreshold(float threshold);
  float noiseThreshold() const { return threshold_; }
  long minAdaptiveSamples() const;
  // With a threshold, after a pass: no pixel needs more samples.
  bool converged() const { return threshold_ > 0 && done_ > 0 && active_ == 0; }
  // Pixels still taking samples after the last pass (all of them without a threshold).
  long activePixels() const { return active_; }
  SampleCounts sampleCounts() const;
  // A film of ceil(W/stride) × ceil(H/stride) pixels, W × H the crop's size: pixel (i, j)
  // holds the first bundle of crop pixel (min(i·stride + stride/2, W−1), likewise j);
  // false when cancelled. tuned false: before the Russian roulette is tuned (its
  // pre-render traces about ten times the paths of a 32-pixel preview), the preview runs
  // with the settings' fixed P_a, else none (P_a 1): unbiased, but its values are not the
  // pass's; for a host's first image after a new view.
  bool renderPreview(int stride, Film& preview, const std::atomic<bool>* cancel = nullptr, bool tuned = true);
  // Renders settings().spp samples in passes of passSamples (or until converged()); calls
  // progress after each.
  bool render(int passSamples = 1, const std::function<void(const RenderProgress&)>& progress = nullptr,
              const std::atomic<bool>* cancel = nullptr);
  const Film& film() const { return film_; }
  // film().toImage() with the header a file of it needs: with Cryptomatte, each type's
  // metadata and manifest (cryptomatte.h) from the scene's names.
  Image image() const;
  // Samples so far of the pixels still going (the most any pixel has).
  long samplesPerPixel() const { return done_; }
  int bundleSize() const { return bundle_; }
  // Samples per pixel done so far, counting the finished pixels of the pass under way as
  // fractions of it (passes of whole bundles can be long); safe to read from any thread
  // while render() runs, for progress bars.
  double progressSamples() const;
  // The roulette used (after the first pass): P_a and, when tuned, the pre-render's numbers.
  const RouletteTuning& roulette() const { return roulette_; }
  // Samples whose estimate was not finite (NaN or Inf in some AOV) and were dropped from
  // the film: a numerical failure somewhere, never expected (the stress suite checks it).
  long nonFiniteSamples() const { return nonFinite_.load(); }
  // Paths ended by a numerical failure (a leak through a medium's boundary, crossings
  // without end: PathState::lost), their light lost: never expected, reported.
  long lostPaths() const { return lost_.load(); }
  long paths() const { return paths_.load(); }
  // Fraction of the paths so far that took the level-of-detail shortcut.
  double shortcutFraction() const { return paths_ ? double(shortcuts_) / double(paths_) : 0.0; }
  // Fraction of the paths so far that went on by DA (diffusion.h; aggregates' and instancers' media).
  double diffusionFraction() const { return paths_ ? double(diffused_) / double(paths_) : 0.0; }

 private:
  void prepare();
  // Traces samples [first, first + count) of image pixel (x, y) as bundles into film
  // pixel (fx, fy); counted (non-finite samples, shortcuts) only for the image's own film
  // (a preview repeats samples the passes trace again).
  // adaptive: stop before a bundle once the pixel is below the noise threshold.
  void tracePixel(int x, int y, long first, int count, Film& film, int fx, int fy, bool counted,
                  bool adaptive = false);
  template <typename Body>
  void forTiles(int width, int height, const Body& body) const;
  // Traces every pixel that has not stopped up to `end` samples (renderPass); false when
  // cancelled. Counts the pixels still going after it into active_.
  bool sweep(long end, const std::atomic<bool>* cancel, const TileCallback& onTile);
  static constexpr int kVouchRadius = 2;
  // The neighbours' vouching (see the top): guard_ from the film at the minimum, and
  // whether pixel (fx, fy) of the film has met the threshold.
  void computeGuard();
  bool pixelConverged(int fx, int fy) const;
  const Scene& scene_;
  int width_, height_;  // of the image
  PixelWindow window_;  // the image pixels this renderer covers
  Film film_;
  long done_ = 0;
  int bundle_ = 1;
  float threshold_ = 0;
  long active_ = 0;
  bool prepared_ = false;
  // Per film pixel: the mean relative per-sample variance (variance / Film::noiseScale²) of
  // its neighbours in the image at the minimum;
  // empty until every pixel has it.
  std::vector<float> guard_;
  // Progress of the pass under way: (samples done before it << 24 | its samples), and
  // its finished pixels; the pair is read consistently (see progressSamples()).
  std::atomic<uint64_t> passState_{0};
  std::atomic<long> passPixels_{0};
  RouletteTuning roulette_;
  std::atomic<long> nonFinite_{0}, lost_{0};
  std::atomic<long> shortcuts_{0}, paths_{0}, diffused_{0};
};

}  // namespace granular
