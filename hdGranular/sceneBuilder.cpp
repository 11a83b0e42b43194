#include "sceneBuilder.h"

#include <utility>

PXR_NAMESPACE_OPEN_SCOPE

void HdGranularSceneBuilder::Start(granular::SceneDesc desc, std::shared_ptr<const granular::Scene> previous) {
  // std::function copies what it holds: the description is shared, not copied per call.
  auto shared = std::make_shared<const granular::SceneDesc>(std::move(desc));
  _job.Start([shared, previous = std::move(previous)] { return granular::Scene::build(*shared, previous.get()); });
}

PXR_NAMESPACE_CLOSE_SCOPE
