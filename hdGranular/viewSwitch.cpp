#include "viewSwitch.h"

#include <utility>

PXR_NAMESPACE_OPEN_SCOPE

void HdGranularViewSwitch::Update(std::shared_ptr<const granular::Scene> scene) {
  // One measurement at a time: a measurement cannot be interrupted, and a camera that keeps
  // moving would start one per frame, each running to its end on the cores the render
  // needs. The one under way ends (refused by applyViewSwitch if its view has gone), then
  // the view the scene has by then is measured.
  if (_job.Pending() || !scene || scene->pendingViewSwitch().empty()) return;
  // The work's views point at the scene's lights: the job keeps the scene alive.
  _job.Start([work = scene->pendingViewSwitch(), scene] { return Measured{work, work.measure()}; });
}

PXR_NAMESPACE_CLOSE_SCOPE
