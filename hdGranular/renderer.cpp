#include "renderer.h"

#include <chrono>
#include <cmath>
#include <thread>

#include "image_io.h"
#include "pxr/imaging/hd/aov.h"
#include "pxr/imaging/hd/tokens.h"
#include "renderBuffer.h"

PXR_NAMESPACE_OPEN_SCOPE

HdGranularRenderer::HdGranularRenderer() {
  _thread.SetRenderCallback([this] { _Render(); });
  _thread.StartThread();
}

HdGranularRenderer::~HdGranularRenderer() {
  Stop();
  _thread.StopThread();
}

void HdGranularRenderer::SetScene(std::unique_ptr<granular::Scene> scene) {
  _renderer.reset();
  _scene = std::move(scene);
}

void HdGranularRenderer::Start() {
  _cancel = false;
  _converged = false;
  for (auto const& b : _bindings)
    if (auto* rb = dynamic_cast<HdGranularRenderBuffer*>(b.renderBuffer)) rb->SetConverged(false);
  _thread.StartRender();
}

void HdGranularRenderer::Stop() {
  _cancel = true;  // core leaves its pass at the next tile
  _thread.StopRender();
  _cancel = false;
}

float HdGranularRenderer::_DepthToClip(float viewDepth) const {
  // Hydra's depth AOV: the projected z in [0, 1] (1 where nothing was hit).
  if (!std::isfinite(viewDepth)) return 1.0f;
  double z = -double(viewDepth);
  double clipZ = _projection[2][2] * z + _projection[3][2], clipW = _projection[2][3] * z + _projection[3][3];
  if (clipW == 0) return 1.0f;
  return float(std::clamp(0.5 * (clipZ / clipW) + 0.5, 0.0, 1.0));
}

void HdGranularRenderer::_MarkConverged() {
  _converged = true;
  for (auto const& b : _bindings)
    if (auto* rb = dynamic_cast<HdGranularRenderBuffer*>(b.renderBuffer)) rb->SetConverged(true);
}

void HdGranularRenderer::_WriteBuffers(bool converged) {
  granular::Image img = _renderer->film().toImage();
  auto lock = _thread.LockFramebuffer();
  for (auto const& b : _bindings) {
    auto* rb = dynamic_cast<HdGranularRenderBuffer*>(b.renderBuffer);
    if (!rb || int(rb->GetWidth()) != img.width || int(rb->GetHeight()) != img.height) continue;
    const TfToken& aov = b.aovName;
    int c0 = -1, n = 0;
    if (aov == HdAovTokens->color) c0 = img.channelIndex("R"), n = 4;
    else if (aov == HdAovTokens->normal) c0 = img.channelIndex("N.X"), n = 3;
    else if (aov == "ept" || aov == "vpt" || aov == "da") c0 = img.channelIndex(aov.GetString() + ".R"), n = 3;
    const int zc = img.channelIndex("Z"), idc = img.channelIndex("primId");
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x) {
        const float* px = img.at(x, y);
        if (aov == HdAovTokens->depth) {
          float d = _DepthToClip(px[zc]);
          rb->Write(x, y, &d, 1);
        } else if (aov == HdAovTokens->cameraDepth) {
          float d = std::isfinite(px[zc]) ? px[zc] : 0.0f;
          rb->Write(x, y, &d, 1);
        } else if (aov == HdAovTokens->primId) {
          rb->WriteInt(x, y, int(px[idc]));
        } else if (c0 >= 0) {
          rb->Write(x, y, px + c0, n);
        }
      }
    rb->SetConverged(converged);
  }
}

void HdGranularRenderer::_Render() {
  if (!_scene) {  // nothing (or nothing valid) to render
    _MarkConverged();
    return;
  }
  _renderer = std::make_unique<granular::Renderer>(*_scene);
  const long target = _scene->settings().spp;
  _samplesTarget = target;
  _samplesDone = 0;
  const int bundle = _renderer->bundleSize();
  while (!_thread.IsStopRequested()) {
    if (_thread.IsPauseRequested()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
      continue;
    }
    long done = _renderer->samplesPerPixel();
    int pass = int(std::min<long>(bundle, target - done));
    if (!_renderer->renderPass(pass, &_cancel)) return;  // stopped mid-pass
    done = _renderer->samplesPerPixel();
    _samplesDone = done;
    _lodFraction = _renderer->shortcutFraction();
    bool converged = done >= target;
    if (!converged && _noiseThreshold > 0 && done >= 2 * bundle) {
      // Noise threshold: every pixel's standard error below threshold × (value + 0.01).
      const granular::Film& film = _renderer->film();
      bool quiet = true;
      for (int y = 0; y < film.height() && quiet; ++y)
        for (int x = 0; x < film.width() && quiet; ++x)
          quiet = film.stdError(x, y) <= _noiseThreshold * (granular::luminance(film.mean(x, y)) + 0.01f);
      converged = quiet;
    }
    _WriteBuffers(converged);
    if (converged) {
      _MarkConverged();
      return;
    }
  }
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
  }
  return stats;
}

PXR_NAMESPACE_CLOSE_SCOPE
