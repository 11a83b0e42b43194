#include "renderer.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <thread>
#include <vector>

#include "core/denoise.h"
#include "core/image_io.h"
#include "pxr/imaging/hd/aov.h"
#include "pxr/imaging/hd/tokens.h"
#include "renderBuffer.h"
#include "renderProducts.h"

PXR_NAMESPACE_OPEN_SCOPE

HdGranularRenderer::HdGranularRenderer() {
  _thread.SetRenderCallback([this] { _Render(); });
  _thread.StartThread();
}

HdGranularRenderer::~HdGranularRenderer() {
  Stop();
  _thread.StopThread();
  _builder.Abandon();  // its destructor waits for the build still running
}

void HdGranularRenderer::SetScene(std::unique_ptr<granular::Scene> scene) {
  _renderer.reset();
  _scene = std::move(scene);
  if (_scene) {
    // A scene of stand-ins is counted by its stand-ins and the media it derived (its full
    // build borrows them); the full scene counts as the build.
    if (_scene->standIns()) {
      _standInsBuilt += _scene->standInsBuilt();
    } else {
      ++_sceneBuilds;
      _aggregatesBuilt += _scene->aggregatesBuilt();
      _aggregatesReused += _scene->aggregatesReused();
    }
    _mediaDerived += _scene->mediaDerived();
  }
}

void HdGranularRenderer::Start() {
  _cancel = false;
  _converged = false;
  _interrupted = false;
  _firstImageSeconds = _shownStride > 0 ? 0.0 : -1.0;  // an image kept on screen is there at once
  _firstPassSeconds = -1;
  _startTime = std::chrono::steady_clock::now();
  _SetBuffersConverged(false);
  _thread.StartRender();
}

void HdGranularRenderer::Stop() {
  _cancel = true;  // core leaves its pass at the next tile
  _thread.StopRender();
  _cancel = false;
}

void HdGranularRenderer::StopForEdit() {
  // Even a finished render must run again: a reallocated buffer has lost its pixels.
  Stop();
  _interrupted = true;
}

float HdGranularRenderer::_DepthToClip(float viewDepth) const {
  // Hydra's depth AOV: the projected z in [0, 1] (1 where nothing was hit).
  if (!std::isfinite(viewDepth)) return 1.0f;
  double z = -double(viewDepth);
  double clipZ = _projection[2][2] * z + _projection[3][2], clipW = _projection[2][3] * z + _projection[3][3];
  if (clipW == 0) return 1.0f;
  return float(std::clamp(0.5 * (clipZ / clipW) + 0.5, 0.0, 1.0));
}

double HdGranularRenderer::_SecondsSinceStart() const {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - _startTime).count();
}

void HdGranularRenderer::_SetBuffersConverged(bool converged) {
  for (auto const& b : _bindings)
    if (auto* rb = dynamic_cast<HdGranularRenderBuffer*>(b.renderBuffer)) rb->SetConverged(converged);
}

void HdGranularRenderer::_MarkConverged() {
  _converged = true;
  if (!_provisional) _SetBuffersConverged(true);
}

void HdGranularRenderer::_WriteRegion(granular::Film const& film, int stride, int x0, int x1, int y0, int y1) {
  // Film pixel (x, y) is image pixel (x, y) + the crop's origin (render.h).
  const granular::PixelWindow crop = granular::renderWindow(_scene->settings());
  const int width = _scene->settings().width, height = _scene->settings().height;
  // Channel offsets of Film::pixelChannels (film.h).
  constexpr int kColor = 0, kDepth = 4, kNormal = 5, kParts = 8, kPrimId = 20, kAlbedo = 21, kSampleCount = 24,
                kVariance = 25, kInstanceId = 28, kAggregateId = 29;
  std::vector<float> px(size_t(x1 - x0) * (y1 - y0) * granular::Film::kChannels);
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x)
      film.pixelChannels(x / stride, y / stride,
                         &px[(size_t(y - y0) * (x1 - x0) + (x - x0)) * granular::Film::kChannels]);
  auto lock = _thread.LockFramebuffer();
  for (auto const& b : _bindings) {
    auto* rb = dynamic_cast<HdGranularRenderBuffer*>(b.renderBuffer);
    // A buffer of another size belongs to a view this render is not for.
    if (!rb || int(rb->GetWidth()) != width || int(rb->GetHeight()) != height) continue;
    const TfToken& aov = b.aovName;
    if (aov == HdAovTokens->color && _colorHeld) continue;  // the denoised image stays (renderer.h)
    int c0 = -1, n = 0;
    if (aov == HdAovTokens->color) c0 = kColor, n = 4;
    else if (aov == HdAovTokens->normal) c0 = kNormal, n = 3;
    else if (aov == "ept") c0 = kParts, n = 3;
    else if (aov == "vpt") c0 = kParts + 3, n = 3;
    else if (aov == "da") c0 = kParts + 6, n = 3;
    else if (aov == "ppt") c0 = kParts + 9, n = 3;
    else if (aov == "albedo") c0 = kAlbedo, n = 3;
    else if (aov == "sampleCount") c0 = kSampleCount, n = 1;
    else if (aov == "variance") c0 = kVariance, n = 3;
    // A Cryptomatte layer (CryptoObject00, ...): its RGBA of the pixel's ranked ids.
    int cryptoLayer = -1;
    granular::CryptomatteType cryptoType = granular::CryptomatteType::Object;
    for (auto t : {granular::CryptomatteType::Object, granular::CryptomatteType::Material})
      for (int k = 0; k < granular::kCryptomatteLayers; ++k)
        if (aov == granular::cryptomatteLayerName(t, k)) cryptoLayer = k, cryptoType = t;
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) {
        const float* p = &px[(size_t(y - y0) * (x1 - x0) + (x - x0)) * granular::Film::kChannels];
        const int ix = crop.x0 + x, iy = crop.y0 + y;
        if (aov == HdAovTokens->depth) {
          float d = _DepthToClip(p[kDepth]);
          rb->Write(ix, iy, &d, 1);
        } else if (aov == HdAovTokens->cameraDepth) {
          float d = std::isfinite(p[kDepth]) ? p[kDepth] : 0.0f;
          rb->Write(ix, iy, &d, 1);
        } else if (aov == HdAovTokens->primId) {
          rb->WriteInt(ix, iy, int(p[kPrimId]));
        } else if (aov == HdAovTokens->instanceId) {
          rb->WriteInt(ix, iy, int(p[kInstanceId]));
        } else if (aov == "aggregateId") {
          rb->WriteInt(ix, iy, int(p[kAggregateId]));
        } else if (cryptoLayer >= 0) {
          float ranked[4 * granular::kCryptomatteLayers];
          film.cryptomatteChannels(x / stride, y / stride, cryptoType, ranked);
          rb->Write(ix, iy, ranked + 4 * cryptoLayer, 4);
        } else if (c0 >= 0) {
          rb->Write(ix, iy, p + c0, n);
        }
      }
  }
}

void HdGranularRenderer::_Render() {
  if (!_scene) {  // nothing (or nothing valid) to render
    _MarkConverged();
    return;
  }
  _renderer = std::make_unique<granular::Renderer>(*_scene);
  // A threshold that is not a positive number is off, as it always was here.
  _renderer->setNoiseThreshold(std::isfinite(_noiseThreshold) && _noiseThreshold > 0 ? _noiseThreshold : 0.0f);
  _colorHeld = false;
  const long target = _scene->settings().spp;
  const granular::PixelWindow crop = granular::renderWindow(_scene->settings());  // the film's pixels
  const int width = crop.width(), height = crop.height();
  _samplesTarget = target;
  _samplesDone = 0;
  _nonFinite = 0;
  // Coarse previews first on images large enough to wait for (see renderer.h); on a
  // viewport-sized image one bundle per 32×32 block comes first, a quarter of the 16×16
  // preview's cost, so that a camera move shows something at once.
  if (_preview && long(width) * height >= 128 * 128) {
    std::vector<int> strides = {16, 4};
    if (width >= 384 && height >= 256) strides.insert(strides.begin(), 32);
    for (int stride : strides) {
      if (_shownStride > 0 && stride >= _shownStride) continue;  // no coarser than the image kept
      granular::Film preview;
      // The first image does not wait for the roulette's pre-render (core/render.h).
      if (!_renderer->renderPreview(stride, preview, &_cancel, /*tuned=*/stride != strides.front())) return;
      _WriteRegion(preview, stride, 0, width, 0, height);
      _shownStride = stride;
      if (_firstImageSeconds < 0) _firstImageSeconds = _SecondsSinceStart();
      if (_thread.IsStopRequested()) return;
    }
  }
  const int bundle = _renderer->bundleSize();
  const granular::Film& film = _renderer->film();
  auto onTile = [&](int x0, int x1, int y0, int y1) { _WriteRegion(film, 1, x0, x1, y0, y1); };
  while (!_thread.IsStopRequested()) {
    if (_thread.IsPauseRequested()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
      continue;
    }
    long done = _renderer->samplesPerPixel();
    int pass = int(std::min<long>(bundle, target - done));
    bool finished = _renderer->renderPass(pass, &_cancel, onTile);
    _nonFinite = _renderer->nonFiniteSamples();
    _lostPaths = _renderer->lostPaths();
    if (!finished) return;  // stopped mid-pass
    done = _renderer->samplesPerPixel();
    _samplesDone = done;
    _shownStride = 1;
    if (_firstPassSeconds < 0) _firstPassSeconds = _SecondsSinceStart();
    if (_firstImageSeconds < 0) _firstImageSeconds = _firstPassSeconds.load();
    _lodFraction = _renderer->shortcutFraction();
    bool converged = done >= target;
    // Adaptive sampling (core's, as granular render --noise-threshold): every pixel stopped.
    converged = converged || _renderer->converged();
    if (_denoise && !_WriteDenoised(film)) return;  // stopped meanwhile
    if (converged) {
      if (!_provisional) HdGranularWriteRenderProducts(this, film, _scene.get());  // before a waiting host sees convergence
      _MarkConverged();
      return;
    }
  }
}

bool HdGranularRenderer::_WriteDenoised(granular::Film const& film) {
  if (!granular::denoiserAvailable()) {
    if (!_denoiseWarned)
      TF_WARN("hdGranular: granular:denoise: %s; the viewport shows the beauty undenoised",
              granular::denoiserUnavailableReason().c_str());
    _denoiseWarned = true;
    return true;
  }
  // Channel offsets of Film::pixelChannels (film.h).
  constexpr int kColor = 0, kAlpha = 3, kNormal = 5, kAlbedo = 21;
  const int w = film.width(), h = film.height();
  const size_t n = size_t(w) * h;
  std::vector<float> color(3 * n), albedo(3 * n), normal(3 * n), alpha(n), out(3 * n);
  std::vector<float> px(granular::Film::kChannels);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      film.pixelChannels(x, y, px.data());
      const size_t i = size_t(y) * w + x;
      for (int c = 0; c < 3; ++c) {
        color[3 * i + c] = px[kColor + c];
        albedo[3 * i + c] = px[kAlbedo + c];
        normal[3 * i + c] = px[kNormal + c];
      }
      alpha[i] = px[kAlpha];
    }
  try {
    if (!granular::denoise(color.data(), albedo.data(), normal.data(), w, h, out.data(), &_cancel)) return false;
  } catch (std::exception const& e) {  // the raw beauty stays, said once
    if (!_denoiseWarned) TF_WARN("hdGranular: granular:denoise: %s", e.what());
    _denoiseWarned = true;
    return true;
  }
  const granular::PixelWindow crop = granular::renderWindow(_scene->settings());
  const int width = _scene->settings().width, height = _scene->settings().height;
  auto lock = _thread.LockFramebuffer();
  for (auto const& b : _bindings) {
    auto* rb = dynamic_cast<HdGranularRenderBuffer*>(b.renderBuffer);
    if (!rb || b.aovName != HdAovTokens->color || int(rb->GetWidth()) != width || int(rb->GetHeight()) != height)
      continue;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const size_t i = size_t(y) * w + x;
        const float rgba[4] = {out[3 * i], out[3 * i + 1], out[3 * i + 2], alpha[i]};
        rb->Write(crop.x0 + x, crop.y0 + y, rgba, 4);
      }
  }
  _colorHeld = true;
  return true;
}

VtDictionary HdGranularRenderer::GetStats() const {
  VtDictionary stats;
  long target = std::max<long>(1, _samplesTarget.load());
  stats["percentDone"] = VtValue(_converged ? 100.0 : 100.0 * double(_samplesDone.load()) / double(target));
  stats["numCompletedSamples"] = VtValue(int(_samplesDone.load()));
  if (_scene) {
    double grains = 0, sigmaT = 0;
    for (size_t a = 0; a < _scene->aggregates().size(); ++a) {
      grains += _scene->aggregates()[a]->stats().approxGrains;
      if (_scene->hasMedia()) sigmaT = std::max(sigmaT, double(granular::average(_scene->mediumParams(int(a)).sigmaT)));
    }
    stats["granular:grains"] = VtValue(grains);
    stats["granular:sigmaT"] = VtValue(sigmaT);
    stats["granular:lodFraction"] = VtValue(_lodFraction.load());
    stats["granular:defaultLight"] = VtValue(_scene->defaultLightAdded());
    stats["granular:widenedSuns"] = VtValue(int(_scene->widenedSuns().size()));
    // Each light's chance in light sampling, in granular render's words ("" with one light).
    stats["granular:lightPicks"] = VtValue(_scene->lightPicksText());
    // Light linking: each linked light and how many objects it lights ("" when none is linked).
    stats["granular:lightLinks"] = VtValue(_scene->lightLinksText());
    stats["granular:iesProfiles"] = VtValue(_scene->iesProfilesText());
    // Shadow linking: each shadow-linked light and how many objects cast its shadows.
    stats["granular:shadowLinks"] = VtValue(_scene->shadowLinksText());
    // What carries the low orders: proxies (granular:proxies), and how many bounces before
    // the medium.
    stats["granular:proxies"] = VtValue(_scene->useProxies());
    stats["granular:explicitBounces"] = VtValue(_scene->explicitBounces());
    // Per aggregate, in granular render's words (core/switching.h): what carries the low
    // orders after the first grain and the measured bias of the medium there.
    std::string switching;
    int proxyVisits = 0;
    for (size_t a = 0; a < _scene->aggregates().size(); ++a) {
      const int ai = int(a);
      if (_scene->useProxies(ai)) proxyVisits = std::max(proxyVisits, _scene->proxyVisits(ai));
      switching += (switching.empty() ? "" : "\n") + _scene->aggregates()[a]->name() + ": " + _scene->lowOrdersText(ai);
    }
    for (size_t i = 0; i < _scene->instancedGrains().size(); ++i) {
      const int ii = int(i);
      if (_scene->instancedProxies(ii)) proxyVisits = std::max(proxyVisits, _scene->instancedProxyVisits(ii));
      const std::string& name = _scene->instancedGrains()[i]->desc().name;
      switching += (switching.empty() ? "" : "\n") + name + ": " + _scene->instancedLowOrdersText(ii) + "\n" + name +
                   ": " + _scene->instancedDiffusionText(ii);
    }
    stats["granular:proxyVisits"] = VtValue(proxyVisits);
    stats["granular:switching"] = VtValue(switching);
    // The image is of stand-ins (the media alone) while the full build runs.
    stats["granular:standIns"] = VtValue(_scene->standIns());
  }
  // Explicit grains (PointInstancers of a simulation's grains) in the scene: 0 without one.
  int64_t instancedGrains = 0;
  if (_scene)
    for (auto const& g : _scene->instancedGrains()) instancedGrains += g->stats().grains;
  stats["granular:instancedGrains"] = VtValue(instancedGrains);
  stats["granular:fullBuildPending"] = VtValue(_builder.Pending());
  // granular:switchForView: the view's measurement runs (the image is the dome's choice's meanwhile).
  stats["granular:viewSwitchPending"] = VtValue(_viewSwitch.Pending());
  stats["granular:nonFiniteSamples"] = VtValue(int(_nonFinite.load()));
  // Paths ended by a numerical failure (core/render.h, lostPaths): 0 unless something is wrong.
  stats["granular:lostPaths"] = VtValue(int(_lostPaths.load()));
  // Whether granular:denoise can denoise in this build (core/denoise.h).
  stats["granular:denoiserAvailable"] = VtValue(granular::denoiserAvailable());
  stats["granular:sceneBuilds"] = VtValue(_sceneBuilds);
  stats["granular:aggregatesBuilt"] = VtValue(_aggregatesBuilt);
  stats["granular:standInsBuilt"] = VtValue(_standInsBuilt);
  stats["granular:aggregatesReused"] = VtValue(_aggregatesReused);
  stats["granular:mediaDerived"] = VtValue(_mediaDerived);
  stats["granular:firstImageSeconds"] = VtValue(_firstImageSeconds.load());
  stats["granular:firstPassSeconds"] = VtValue(_firstPassSeconds.load());
  return stats;
}

PXR_NAMESPACE_CLOSE_SCOPE
