#include "sceneBuilder.h"

#include <utility>

PXR_NAMESPACE_OPEN_SCOPE

HdGranularSceneBuilder::~HdGranularSceneBuilder() {
  Abandon();
  _Reap(true);
}

void HdGranularSceneBuilder::Start(granular::SceneDesc desc, std::shared_ptr<const granular::Scene> previous) {
  Abandon();
  auto job = std::make_shared<Job>();
  // The thread holds the job and the lending scene: either may outlive the builder's
  // interest in them.
  job->thread = std::thread([job = job.get(), desc = std::move(desc), previous = std::move(previous)] {
    try {
      job->scene = granular::Scene::build(desc, previous.get());
    } catch (...) {
      job->error = std::current_exception();
    }
    job->done = true;
  });
  _current = std::move(job);
}

std::unique_ptr<granular::Scene> HdGranularSceneBuilder::Take() {
  if (!_current) return nullptr;
  std::shared_ptr<Job> job = std::move(_current);
  job->thread.join();
  if (job->error) std::rethrow_exception(job->error);
  return std::move(job->scene);
}

void HdGranularSceneBuilder::Abandon() {
  if (_current) _abandoned.push_back(std::move(_current));
  _Reap(false);
}

void HdGranularSceneBuilder::_Reap(bool wait) {
  for (auto it = _abandoned.begin(); it != _abandoned.end();) {
    if (wait || (*it)->done.load()) {
      (*it)->thread.join();
      it = _abandoned.erase(it);
    } else {
      ++it;
    }
  }
}

PXR_NAMESPACE_CLOSE_SCOPE
