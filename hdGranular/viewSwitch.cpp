#include "viewSwitch.h"

#include <utility>

PXR_NAMESPACE_OPEN_SCOPE

void HdGranularViewSwitch::Update(std::shared_ptr<const granular::Scene> scene) {
  if (!scene || scene->pendingViewSwitch().empty()) {
    Abandon();
    return;
  }
  const granular::Scene::ViewSwitchWork& work = scene->pendingViewSwitch();
  if (_job.Pending() && _view == work.view) return;
  _view = work.view;
  // The work's views point at the scene's lights: the job keeps the scene alive.
  auto shared = std::make_shared<const granular::Scene::ViewSwitchWork>(work);
  _job.Start([shared, scene = std::move(scene)] { return Measured{*shared, shared->measure()}; });
}

PXR_NAMESPACE_CLOSE_SCOPE
