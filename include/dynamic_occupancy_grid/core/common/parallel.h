#pragma once
// Work on several threads: runOnThreads (offline EM's workers) and independent
// repetitions of an experiment (the evaluation library), where each repetition writes only
// its own slot, so results do not depend on the number of threads.

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace dynamic_occupancy_grid {
namespace core {

/// Runs worker() on this thread and on threads - 1 more (fewer if the system has no more to
/// give), and returns when all have finished. The worker must not throw: it keeps its own
/// first failure.
inline void runOnThreads(std::size_t threads, const std::function<void()>& worker) {
  std::vector<std::thread> pool;
  try {
    for (std::size_t i = 1; i < threads; ++i) pool.emplace_back(worker);
  } catch (...) {
    // No more threads to be had: the ones started and this one do the work.
  }
  worker();
  for (std::thread& thread : pool) thread.join();
}

/// Runs job(r) for every r in [0, count) on `threads` threads (0 = one per core), calling
/// progress(done) (optional) after each finished repetition, never concurrently. The first
/// exception (from a job or from progress) stops handing out repetitions and is rethrown
/// once every thread has finished.
inline void runRepetitions(std::size_t count, unsigned threads, const std::function<void(std::size_t)>& job,
                           const std::function<void(int done)>& progress) {
  std::atomic<std::size_t> next{0};
  std::atomic<bool> failed{false};
  std::mutex mutex;  // guards done, first_error and the progress callback
  int done = 0;
  std::exception_ptr first_error;
  const auto worker = [&] {
    for (std::size_t r = next++; r < count && !failed; r = next++) {
      try {
        job(r);
        const std::lock_guard<std::mutex> lock(mutex);
        ++done;
        if (progress) progress(done);
      } catch (...) {
        const std::lock_guard<std::mutex> lock(mutex);
        if (!first_error) first_error = std::current_exception();
        failed = true;
      }
    }
  };
  if (threads == 0) threads = std::max(1U, std::thread::hardware_concurrency());
  threads = static_cast<unsigned>(std::min<std::size_t>(threads, count));
  runOnThreads(threads, worker);
  if (first_error) std::rethrow_exception(first_error);
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
