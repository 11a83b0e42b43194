#include "render.h"

#include <chrono>
#include <cmath>

#include <tbb/blocked_range2d.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include "arena.h"
#include "ept.h"
#include "error.h"

namespace granular {

Renderer::Renderer(const Scene& scene)
    : scene_(scene),
      width_(scene.settings().width),
      height_(scene.settings().height),
      window_(renderWindow(scene.settings())),
      film_(window_, scene.settings().width, scene.settings().height, scene.settings().cryptomatte) {
  const RenderSettings& rs = scene.settings();
  // Bundles matter only where paths can switch to the media.
  bool hybrid = rs.technique != Technique::Ept && scene.hasMedia();
  bundle_ = hybrid ? std::max(1, std::min(rs.bundleSize, rs.spp)) : 1;
  active_ = long(window_.width()) * window_.height();
}

void Renderer::setNoiseThreshold(float threshold) {
  if (!(threshold >= 0) || !std::isfinite(threshold))
    throw InputError("render", "noiseThreshold", str(threshold, " must be finite and >= 0"));
  // The pixels that stopped did so by the old threshold.
  if (done_ > 0 && threshold != threshold_)
    throw InputError("render", "noiseThreshold", "cannot change after the first pass: make a new renderer");
  threshold_ = threshold;
}

long Renderer::minAdaptiveSamples() const {
  return std::min<long>(scene_.settings().spp, std::max<long>(2L * bundle_, 16));
}

SampleCounts Renderer::sampleCounts() const {
  SampleCounts c;
  const long pixels = long(film_.width()) * film_.height();
  if (pixels == 0) return c;
  double sum = 0;
  c.min = film_.samples(0, 0);
  for (int y = 0; y < film_.height(); ++y)
    for (int x = 0; x < film_.width(); ++x) {
      const long n = film_.samples(x, y);
      sum += double(n);
      c.min = std::min(c.min, n);
      c.max = std::max(c.max, n);
    }
  c.mean = sum / double(pixels);
  return c;
}

void Renderer::prepare() {
  prepared_ = true;
  const RenderSettings& rs = scene_.settings();
  // Stand-ins: every path is in the media from its start, with nothing to tune.
  if (rs.technique == Technique::Ept || !scene_.hasMedia() || scene_.standIns()) return;
  if (rs.roulette > 0) roulette_.pa = rs.roulette;
  else roulette_ = tuneRoulette(scene_);
}

void Renderer::tracePixel(int x, int y, long first, int count, Film& film, int fx, int fy, bool counted,
                          bool adaptive) {
  const RenderSettings& rs = scene_.settings();
  const Camera& cam = scene_.camera();
  thread_local std::vector<PathState> paths;
  const long minSamples = adaptive ? minAdaptiveSamples() : 0;
  // The first light pick of each sample: a Kronecker sequence over the pixel's samples
  // (golden-ratio steps), rotated per pixel and seed; each one uniform.
  const double rotation = double(toUnitFloat(hashInts(rs.seed, uint64_t(x), uint64_t(y), 0x11647ULL)));
  for (int b = 0; b < count; b += bundle_) {
    if (adaptive && first + b >= minSamples && pixelConverged(fx, fy)) break;
    paths.clear();
    for (int s = b; s < std::min(b + bundle_, count); ++s) {
      long index = first + s;
      Rng rng(hashInts(rs.seed, uint64_t(x), uint64_t(y), uint64_t(index)), 0);
      Ray ray = cam.sampleRay(x, y, rng);
      PathState p = startPath(ray, 0, cam.coneSpread(), cam.coneWidth());
      p.rng = rng;
      const double k = rotation + double(index) * 0.6180339887498949;
      p.firstLightU = std::min(float(k - std::floor(k)), 0x1.fffffep-1f);
      if (scene_.standIns()) startInMedia(scene_, p);
      paths.push_back(p);
    }
    traceBundle(scene_, paths, roulette_.pa);
    long shortcuts = 0, nonFinite = 0, diffused = 0, lost = 0;
    for (const PathState& p : paths) {
      shortcuts += p.shortcut;
      diffused += p.credit == kDa;
      lost += p.lost;
      PixelSample ps;
      nonFinite += !toPixelSample(p, ps);
      film.add(fx, fy, ps);
    }
    if (!counted) continue;
    if (nonFinite) nonFinite_.fetch_add(nonFinite, std::memory_order_relaxed);
    shortcuts_ += shortcuts;
    diffused_ += diffused;
    if (lost) lost_.fetch_add(lost, std::memory_order_relaxed);
    paths_ += long(paths.size());
  }
}

// Runs body over 8×8 tiles of a width × height image on TBB (in an arena of
// settings().threads when that is set).
template <typename Body>
void Renderer::forTiles(int width, int height, const Body& body) const {
  tbb::blocked_range2d<int> range(0, height, 8, 0, width, 8);
  inArena(scene_.settings().threads, [&] { tbb::parallel_for(range, body); });
}

bool Renderer::renderPass(int samples, const std::atomic<bool>* cancel, const TileCallback& onTile) {
  const RenderSettings& rs = scene_.settings();
  const PixelWindow w = renderWindow(rs);
  // Scene::setView since construction may have changed the image or the crop.
  if (rs.width != width_ || rs.height != height_ || w != window_)
    throw InputError("render", "resolution", str(rs.width, "x", rs.height, " (pixels [", w.x0, ", ", w.x1, ") x [", w.y0,
                                                 ", ", w.y1, ")) is not this renderer's: make a new renderer after a "
                                                 "change of view"));
  if (!prepared_) prepare();
  // Each pixel continues from its own count (done_, or less where adaptive sampling
  // stopped it, or more after a cancelled pass) up to the pass's end.
  const long end = done_ + samples, minimum = minAdaptiveSamples();
  const bool vouch = threshold_ > 0 && guard_.empty() && end >= minimum;
  passPixels_ = 0;  // before the state names the new pass (progressSamples relies on it)
  passState_ = (uint64_t(done_) << 24) | uint64_t(vouch && done_ < minimum ? minimum - done_ : samples);
  if (vouch) {
    // Every pixel to the minimum first, so that its neighbours vouch for it (computeGuard).
    if (done_ < minimum) {
      if (!sweep(minimum, cancel, onTile)) return false;
      done_ = minimum;
      passPixels_ = 0;
      passState_ = (uint64_t(done_) << 24) | uint64_t(end - done_);
    }
    computeGuard();
  }
  if (!sweep(end, cancel, onTile)) return false;
  done_ = end;
  passState_ = uint64_t(done_) << 24;
  return true;
}

bool Renderer::sweep(long end, const std::atomic<bool>* cancel, const TileCallback& onTile) {
  std::atomic<bool> cancelled{false};
  const bool adaptive = threshold_ > 0;
  std::atomic<long> active{0};
  forTiles(window_.width(), window_.height(), [&](const tbb::blocked_range2d<int>& r) {
    long going = 0;
    for (int y = r.rows().begin(); y < r.rows().end(); ++y)
      for (int x = r.cols().begin(); x < r.cols().end(); ++x) {
        if (cancel && cancel->load(std::memory_order_relaxed)) { cancelled = true; return; }
        const long n = film_.samples(x, y);
        if (n < end) tracePixel(window_.x0 + x, window_.y0 + y, n, int(end - n), film_, x, y, true, adaptive);
        passPixels_.fetch_add(1, std::memory_order_relaxed);
        going += !adaptive ||
                 (film_.samples(x, y) >= end && !(end >= minAdaptiveSamples() && pixelConverged(x, y)));
      }
    active += going;
    if (onTile) onTile(r.cols().begin(), r.cols().end(), r.rows().begin(), r.rows().end());
  });
  if (cancelled) return false;
  active_ = active;
  return true;
}

void Renderer::computeGuard() {
  const int W = window_.width(), H = window_.height(), R = kVouchRadius, FW = W + 2 * R;
  const long minimum = minAdaptiveSamples();
  // The relative per-sample variance of a film pixel at the minimum (of one sample: none
  // known, so a value no count meets, finite so that box sums stay finite).
  auto relative = [](const Film& f, int x, int y) {
    const double se = f.stdError(x, y), scale = f.noiseScale(x, y);
    return std::isfinite(se) ? double(f.samples(x, y)) * se * se / (scale * scale) : 1e30;
  };
  // A crop's ring of neighbours, outside it but in the image: their first samples, as the
  // full film has them, in a film of one row. (i, j): in the window framed by R pixels.
  auto inWindow = [&](int i, int j) { return i >= R && i < W + R && j >= R && j < H + R; };
  auto inImage = [&](int i, int j) {
    const int x = window_.x0 + i - R, y = window_.y0 + j - R;
    return x >= 0 && y >= 0 && x < width_ && y < height_;
  };
  std::vector<std::pair<int, int>> ringAt;
  for (int j = 0; j < H + 2 * R; ++j)
    for (int i = 0; i < FW; ++i)
      if (!inWindow(i, j) && inImage(i, j)) ringAt.emplace_back(i, j);
  Film ring(std::max<int>(1, int(ringAt.size())), 1);
  forTiles(int(ringAt.size()), 1, [&](const tbb::blocked_range2d<int>& r) {
    for (int k = r.cols().begin(); k < r.cols().end(); ++k)
      tracePixel(window_.x0 + ringAt[k].first - R, window_.y0 + ringAt[k].second - R, 0, int(minimum), ring, k, 0,
                 false);
  });
  // The mean over each pixel's (2R+1)² box less itself, by box sums: rows, then columns.
  const int FH = H + 2 * R;
  std::vector<double> rel(size_t(FW) * FH, 0.0), in(size_t(FW) * FH, 0.0);  // 0 outside the image
  auto put = [&](int i, int j, double v) { rel[size_t(j) * FW + i] = v, in[size_t(j) * FW + i] = 1; };
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) put(x + R, y + R, relative(film_, x, y));
  for (size_t k = 0; k < ringAt.size(); ++k) put(ringAt[k].first, ringAt[k].second, relative(ring, int(k), 0));
  std::vector<double> rowRel(size_t(W) * FH), rowIn(size_t(W) * FH);  // each row's sums over 2R+1 columns
  for (int j = 0; j < FH; ++j)
    for (int x = 0; x < W; ++x) {
      double a = 0, b = 0;
      for (int i = x; i <= x + 2 * R; ++i) a += rel[size_t(j) * FW + i], b += in[size_t(j) * FW + i];
      rowRel[size_t(j) * W + x] = a, rowIn[size_t(j) * W + x] = b;
    }
  guard_.assign(size_t(W) * H, 0.0f);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      double a = -rel[size_t(y + R) * FW + x + R], b = -1;  // less the pixel itself
      for (int j = y; j <= y + 2 * R; ++j) a += rowRel[size_t(j) * W + x], b += rowIn[size_t(j) * W + x];
      guard_[size_t(y) * W + x] = b > 0 ? float(a / b) : 0.0f;
    }
}

bool Renderer::pixelConverged(int fx, int fy) const {
  if (!film_.pixelBelowNoiseThreshold(fx, fy, threshold_)) return false;
  if (guard_.empty()) return true;
  const double n = double(film_.samples(fx, fy));
  return double(guard_[size_t(fy) * window_.width() + fx]) <= double(threshold_) * threshold_ * n;
}

bool Renderer::renderPreview(int stride, Film& preview, const std::atomic<bool>* cancel, bool tuned) {
  const RenderSettings& rs = scene_.settings();
  stride = std::max(1, stride);
  if (!prepared_ && tuned) prepare();
  if (!prepared_) roulette_.pa = rs.roulette > 0 ? rs.roulette : 1.0f;  // what prepare() leaves untuned
  const int W = window_.width(), H = window_.height();
  const int w = (W + stride - 1) / stride, h = (H + stride - 1) / stride;
  preview = Film(w, h);
  std::atomic<bool> cancelled{false};
  forTiles(w, h, [&](const tbb::blocked_range2d<int>& r) {
    for (int j = r.rows().begin(); j < r.rows().end(); ++j)
      for (int i = r.cols().begin(); i < r.cols().end(); ++i) {
        if (cancel && cancel->load(std::memory_order_relaxed)) { cancelled = true; return; }
        int x = window_.x0 + std::min(i * stride + stride / 2, W - 1);
        int y = window_.y0 + std::min(j * stride + stride / 2, H - 1);
        tracePixel(x, y, 0, std::min(bundle_, rs.spp), preview, i, j, false);
      }
  });
  return !cancelled;
}

double Renderer::progressSamples() const {
  // The state before and after reading the pixel count must agree, so that the count
  // belongs to the pass the state names; this keeps the result non-decreasing.
  const double pixels = double(film_.width()) * film_.height();
  for (;;) {
    const uint64_t s1 = passState_.load();
    const long done = passPixels_.load();
    if (passState_.load() != s1) continue;
    const double base = double(s1 >> 24), n = double(s1 & 0xFFFFFF);
    if (n == 0 || pixels <= 0) return base;
    return base + n * std::min(1.0, double(done) / pixels);
  }
}

bool Renderer::render(int passSamples, const std::function<void(const RenderProgress&)>& progress,
                      const std::atomic<bool>* cancel) {
  auto t0 = std::chrono::steady_clock::now();
  const long target = scene_.settings().spp;
  while (done_ < target && !converged()) {
    int pass = ((std::max(passSamples, 1) + bundle_ - 1) / bundle_) * bundle_;  // whole bundles
    int n = int(std::min<long>(pass, target - done_));
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

Image Renderer::image() const {
  Image img = film_.toImage();
  if (film_.hasCryptomatte())
    for (CryptomatteType t : {CryptomatteType::Object, CryptomatteType::Material})
      for (auto& kv : cryptomatteMetadata(t, scene_.cryptomatteNames(t))) img.attributes.push_back(std::move(kv));
  return img;
}

}  // namespace granular
