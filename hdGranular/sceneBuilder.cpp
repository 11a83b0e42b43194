#include "sceneBuilder.h"

#include <utility>

PXR_NAMESPACE_OPEN_SCOPE

void HdGranularSceneBuilder::Start(granular::SceneDesc desc, std::shared_ptr<const granular::Scene> previous) {
  _job.Start([desc = std::move(desc), previous = std::move(previous)] {
    return granular::Scene::build(desc, previous.get());
  });
}

PXR_NAMESPACE_CLOSE_SCOPE
