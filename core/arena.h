// arena.h — work run on as many threads as RenderSettings::threads asks.
//
// Contract: inArena(threads, f) returns f(), run inside a TBB arena of `threads` threads
// when threads > 0, else on TBB's default pool; f's parallel loops then use that many.
#pragma once

#include <tbb/task_arena.h>

namespace granular {

template <typename F>
auto inArena(int threads, const F& f) {
  if (threads <= 0) return f();
  tbb::task_arena arena(threads);
  return arena.execute(f);
}

}  // namespace granular
