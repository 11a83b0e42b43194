// viewSwitch.h — the view's switch measurement (granular:switchForView) on a thread of its
// own, so that a camera move never waits for it (core/scene.h: setView's
// ViewSwitchTiming::Apart, pendingViewSwitch, applyViewSwitch).
//
// Contract: Update(scene) starts measuring what the scene's view left to measure, as a
// background job (backgroundJob.h) holding the scene alive, unless a measurement is under
// way or has ended untaken: one at a time, so that a moving camera never piles them up.
// Ready() says it has ended; Take() returns the work and its measurements (or rethrows
// what the measurement threw) for Scene::applyViewSwitch, which refuses them if the scene
// has taken another view meanwhile; the next Update then measures the view it has. Until
// its own measurement is taken the scene renders with the dome's and the sun's choices,
// and the render is provisional (renderer.h).
#ifndef HDGRANULAR_VIEW_SWITCH_H
#define HDGRANULAR_VIEW_SWITCH_H

#include <memory>
#include <vector>

#include "pxr/pxr.h"
#include "backgroundJob.h"
#include "core/scene.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularViewSwitch {
 public:
  struct Measured {
    granular::Scene::ViewSwitchWork work;
    std::vector<std::shared_ptr<const granular::SwitchMeasure>> measures;
  };
  void Update(std::shared_ptr<const granular::Scene> scene);
  bool Pending() const { return _job.Pending(); }
  bool Ready() const { return _job.Ready(); }
  Measured Take() { return _job.Take(); }
  void Abandon() { _job.Abandon(); }

 private:
  HdGranularBackgroundJob<Measured> _job;
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
