// sceneBuilder.h — the full build of a core scene on a thread of its own, while the
// viewport renders the scene's stand-ins (core/scene.h, SceneDetail::StandIns).
//
// Contract: Start() begins Scene::build(desc, previous) on a new thread; `previous` (the
// stand-in scene, which lends its media and every aggregate it holds fully built) is kept
// alive until the build ends. A build started while another is under way abandons that
// one: its result is dropped when it ends (a build cannot be interrupted). Ready() says
// that the latest build has ended; Take() returns its scene, or rethrows what the build
// threw, and the builder is then idle. All calls come from one thread (the render pass's);
// the destructor waits for every build still running.
#ifndef HDGRANULAR_SCENE_BUILDER_H
#define HDGRANULAR_SCENE_BUILDER_H

#include <atomic>
#include <exception>
#include <memory>
#include <thread>
#include <vector>

#include "pxr/pxr.h"
#include "core/scene.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularSceneBuilder {
 public:
  HdGranularSceneBuilder() = default;
  HdGranularSceneBuilder(HdGranularSceneBuilder const&) = delete;
  HdGranularSceneBuilder& operator=(HdGranularSceneBuilder const&) = delete;
  ~HdGranularSceneBuilder();

  void Start(granular::SceneDesc desc, std::shared_ptr<const granular::Scene> previous);
  // A build was started and its result not taken yet.
  bool Pending() const { return bool(_current); }
  bool Ready() const { return _current && _current->done.load(); }
  std::unique_ptr<granular::Scene> Take();
  void Abandon();

 private:
  struct Job {
    std::thread thread;
    std::atomic<bool> done{false};
    std::unique_ptr<granular::Scene> scene;
    std::exception_ptr error;
  };
  void _Reap(bool wait);  // joins the abandoned builds that have ended (all of them: wait)
  std::shared_ptr<Job> _current;
  std::vector<std::shared_ptr<Job>> _abandoned;
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
