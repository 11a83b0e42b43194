// sceneBuilder.h — the full build of a core scene on a thread of its own, while the
// viewport renders the scene's stand-ins (core/scene.h, SceneDetail::StandIns).
//
// Contract: Start() begins Scene::build(desc, previous) as a background job
// (backgroundJob.h); `previous` (the stand-in scene, which lends its media and every
// aggregate it holds fully built) is kept alive until the build ends. A build started
// while another is under way abandons that one. Ready() says that the latest build has
// ended; Take() returns its scene (null when none was started), or rethrows what the build
// threw, and the builder is then idle.
#ifndef HDGRANULAR_SCENE_BUILDER_H
#define HDGRANULAR_SCENE_BUILDER_H

#include <memory>

#include "pxr/pxr.h"
#include "backgroundJob.h"
#include "core/scene.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularSceneBuilder {
 public:
  void Start(granular::SceneDesc desc, std::shared_ptr<const granular::Scene> previous);
  // A build was started and its result not taken yet.
  bool Pending() const { return _job.Pending(); }
  bool Ready() const { return _job.Ready(); }
  std::unique_ptr<granular::Scene> Take() { return _job.Take(); }
  void Abandon() { _job.Abandon(); }

 private:
  HdGranularBackgroundJob<std::unique_ptr<granular::Scene>> _job;
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
