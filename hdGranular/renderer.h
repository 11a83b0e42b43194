// renderer.h — the progressive render loop of the delegate: core's Renderer on Hydra's
// render thread, writing the film into the bound AOV buffers after every pass.
//
// Contract: the render pass (main thread) stops the loop, changes scene, view, settings
// or AOV bindings, and starts it again; Stop() returns only when the loop has left (core
// checks the cancel flag between tiles, so that is quick). The loop ends when the sample
// count is reached or, with a noise threshold, when every covered pixel's standard error
// is below threshold × (its value + 0.01) — core's adaptive sampling, each pixel stopping
// there on its own and skipped by later passes (core/render.h); then, and also when the scene could not be
// built, the buffers are marked converged, so hosts never wait forever.
//
// What a viewport sees first: on images of 128×128 pixels or more, coarse previews (one
// bundle per 16×16, then per 4×4 block: core's renderPreview; per 32×32 block before them
// on images of 384×256 or more; the first one before the Russian roulette is tuned) fill
// the buffers within a fraction of a pass, then every full-resolution tile is written as soon as it is done.
// A render stopped by something else than the render pass (a render buffer being
// reallocated or freed: StopForEdit) is remembered, so that the next Execute restarts it.
// Stand-ins (core/scene.h): while the scene's full build runs (GetBuilder()), or the
// view's switch measurement (GetViewSwitch(), granular:switchForView), the render is
// provisional: it never marks the buffers converged nor writes render products, and the
// render that follows (the full scene's, the view's choice) keeps its image on screen
// until its own tiles replace it (no clearing; only previews finer than what is shown:
// none after a full pass, all of them when the build landed before the first).
// granular:denoise (SetDenoise): after every complete pass the color AOV shows the beauty
// denoised by core (core/denoise.h, guided by the film's albedo and normal), and keeps it
// while the next pass's raw tiles come (they would flicker over it); the film and every
// other AOV stay raw, and the next pass continues from the raw film. Without the denoiser,
// one warning and the raw beauty.
#ifndef HDGRANULAR_RENDERER_H
#define HDGRANULAR_RENDERER_H

#include <atomic>
#include <chrono>
#include <memory>
#include <mutex>
#include <string>

#include "pxr/base/gf/matrix4d.h"
#include "pxr/base/vt/dictionary.h"
#include "pxr/imaging/hd/renderPassState.h"
#include "pxr/imaging/hd/renderThread.h"
#include "pxr/pxr.h"
#include "core/render.h"
#include "core/scene.h"
#include "sceneBuilder.h"
#include "viewSwitch.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularRenderer {
 public:
  HdGranularRenderer();
  ~HdGranularRenderer();

  // With the loop stopped. A null scene (it could not be built) renders nothing.
  void SetScene(std::unique_ptr<granular::Scene> scene);
  granular::Scene* GetScene() { return _scene.get(); }
  std::shared_ptr<const granular::Scene> GetSharedScene() const { return _scene; }
  HdGranularSceneBuilder& GetBuilder() { return _builder; }
  HdGranularViewSwitch& GetViewSwitch() { return _viewSwitch; }
  void SetAovBindings(HdRenderPassAovBindingVector const& bindings) { _bindings = bindings; }
  HdRenderPassAovBindingVector const& GetAovBindings() const { return _bindings; }
  void SetProjection(GfMatrix4d const& projection) { _projection = projection; }
  void SetNoiseThreshold(float t) { _noiseThreshold = t; }
  void SetDenoise(bool on) { _denoise = on; }

  void SetPreview(bool enabled) { _preview = enabled; }
  // The scene's render stands in for one being built (above).
  void SetProvisional(bool provisional) { _provisional = provisional; }
  // The render pass has cleared the buffers: nothing is shown (see _shownStride).
  void BuffersCleared() { _shownStride = 0; }

  void Start();
  void Stop();
  // Stop() on behalf of a render buffer about to be reallocated or freed (any thread but
  // the render thread); WasInterrupted() is then true until the next Start().
  void StopForEdit();
  bool WasInterrupted() const { return _interrupted.load(); }
  bool IsConverged() const { return _converged.load(); }
  VtDictionary GetStats() const;

 private:
  void _Render();
  // Writes the film window [x0, x1) × [y0, y1) (image pixels less the crop's origin) into
  // the bound buffers from a film that holds every stride-th pixel (stride 1: the render's
  // own film).
  void _WriteRegion(granular::Film const& film, int stride, int x0, int x1, int y0, int y1);
  void _SetBuffersConverged(bool converged);
  // The film's beauty denoised into the color AOV; false when stopped meanwhile.
  bool _WriteDenoised(granular::Film const& film);
  double _SecondsSinceStart() const;
  void _MarkConverged();
  float _DepthToClip(float viewDepth) const;

  HdRenderThread _thread;
  std::shared_ptr<granular::Scene> _scene;  // shared with a full build that borrows from it
  HdGranularSceneBuilder _builder;
  HdGranularViewSwitch _viewSwitch;
  std::unique_ptr<granular::Renderer> _renderer;
  HdRenderPassAovBindingVector _bindings;
  GfMatrix4d _projection{1.0};
  float _noiseThreshold = 0;
  bool _denoise = false, _denoiseWarned = false;
  std::atomic<bool> _colorHeld{false};  // the color AOV holds a denoised image
  bool _preview = true, _provisional = false;
  std::atomic<bool> _cancel{false}, _converged{false}, _interrupted{false};
  // What the buffers show of this view since they were last cleared: 0 nothing, else the
  // finest preview stride written over the whole image (1: a full pass). A render that
  // keeps the image previews only finer than that.
  std::atomic<int> _shownStride{0};
  std::atomic<long> _nonFinite{0}, _lostPaths{0};
  // Since the delegate was made: core scenes built, aggregates voxelised in them or reused
  // from the scene before, equivalent media derived from TT (Scene::build's counts).
  int _sceneBuilds = 0, _aggregatesBuilt = 0, _aggregatesReused = 0, _mediaDerived = 0, _standInsBuilt = 0;
  // Seconds from Start() to the first image covering the viewport (the coarsest preview,
  // or the first pass) and to the first full-resolution pass; -1 until then.
  std::chrono::steady_clock::time_point _startTime;
  std::atomic<double> _firstImageSeconds{-1}, _firstPassSeconds{-1};
  std::atomic<long> _samplesDone{0}, _samplesTarget{1};
  std::atomic<double> _lodFraction{0};
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
