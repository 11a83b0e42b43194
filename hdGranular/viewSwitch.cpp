#include "viewSwitch.h"

#include <utility>

PXR_NAMESPACE_OPEN_SCOPE

void HdGranularViewSwitch::Update(std::shared_ptr<const granular::Scene> scene) {
  // One measurement at a time: a measurement cannot be interrupted, and a camera that keeps
  // moving would start one per frame, each running to its end on the cores the render
  // needs. The one under way ends (refused by applyViewSwitch if its view has gone), then
  // the view the scene has by then is measured.
  if (_job.Pending() || !scene || scene->pendingViewSwitch().empty()) return;
  const granular::Scene::ViewSwitchWork& work = scene->pendingViewSwitch();
  // The work's views point at the scene's lights: the job keeps the scene alive.
  auto shared = std::make_shared<const granular::Scene::ViewSwitchWork>(work);
  _job.Start([shared, scene = std::move(scene)] { return Measured{*shared, shared->measure()}; });
}

PXR_NAMESPACE_CLOSE_SCOPE
