// backgroundJob.h — one piece of work on a thread of its own, whose result the render pass
// takes when it is ready: the full build behind stand-ins (sceneBuilder.h), the view's
// switch measurement (viewSwitch.h).
//
// Contract: Start() runs work() on a new thread; a job started while another is under way
// abandons that one: its result is dropped when it ends (work cannot be interrupted).
// Ready() says that the latest job has ended; Take() returns its result, or rethrows what
// it threw, and the job is then idle (with none started, a default Result). All calls come from one thread (the render pass's);
// the destructor waits for every job still running. Whatever work needs must be captured
// by it (by value or shared ownership): it may outlive the caller's interest in it.
#ifndef HDGRANULAR_BACKGROUND_JOB_H
#define HDGRANULAR_BACKGROUND_JOB_H

#include <atomic>
#include <exception>
#include <functional>
#include <memory>
#include <thread>
#include <utility>
#include <vector>

#include "pxr/pxr.h"

PXR_NAMESPACE_OPEN_SCOPE

template <class Result>
class HdGranularBackgroundJob {
 public:
  HdGranularBackgroundJob() = default;
  HdGranularBackgroundJob(HdGranularBackgroundJob const&) = delete;
  HdGranularBackgroundJob& operator=(HdGranularBackgroundJob const&) = delete;
  ~HdGranularBackgroundJob() {
    Abandon();
    _Reap(true);
  }

  void Start(std::function<Result()> work) {
    Abandon();
    auto job = std::make_shared<Job>();
    // The thread holds the job: it may outlive the caller's interest in it.
    job->thread = std::thread([job = job.get(), work = std::move(work)] {
      try {
        job->result = work();
      } catch (...) {
        job->error = std::current_exception();
      }
      job->done = true;
    });
    _current = std::move(job);
  }
  // A job was started and its result not taken yet.
  bool Pending() const { return bool(_current); }
  bool Ready() const { return _current && _current->done.load(); }
  Result Take() {
    if (!_current) return Result{};
    std::shared_ptr<Job> job = std::move(_current);
    job->thread.join();
    if (job->error) std::rethrow_exception(job->error);
    return std::move(job->result);
  }
  void Abandon() {
    if (_current) _abandoned.push_back(std::move(_current));
    _Reap(false);
  }

 private:
  struct Job {
    std::thread thread;
    std::atomic<bool> done{false};
    Result result{};
    std::exception_ptr error;
  };
  // Joins the abandoned jobs that have ended (all of them: wait).
  void _Reap(bool wait) {
    for (auto it = _abandoned.begin(); it != _abandoned.end();) {
      if (wait || (*it)->done.load()) {
        (*it)->thread.join();
        it = _abandoned.erase(it);
      } else {
        ++it;
      }
    }
  }
  std::shared_ptr<Job> _current;
  std::vector<std::shared_ptr<Job>> _abandoned;
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
