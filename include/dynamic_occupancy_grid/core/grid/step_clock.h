#pragma once
// Groups sensor time into HMM time steps of time_step_s seconds (THEORY.md §4). Step 0
// starts at the first stamp the clock is given.

#include <cstdint>
#include <optional>

namespace dynamic_occupancy_grid {
namespace core {

class StepClock {
 public:
  /// Throws std::invalid_argument unless time_step_s is finite and > 0.
  explicit StepClock(double time_step_s);

  double timeStep() const { return time_step_s_; }
  /// Sensor time of the start of step 0, once started.
  std::optional<double> origin() const { return origin_s_; }
  /// Anchors step 0 at `stamp_s` if no stamp was seen yet.
  void startAt(double stamp_s);
  /// Puts the origin where `stamp_s` is the start of `step` (restarted time, restored models).
  void anchor(double stamp_s, std::int64_t step);
  /// Sets the origin exactly (a restored model).
  void restoreOrigin(double origin_s) { origin_s_ = origin_s; }
  /// The step holding `stamp_s` (negative before the origin). Requires origin().
  std::int64_t stepOf(double stamp_s) const;
  /// Sensor time at which `step` starts.
  double stepStart(std::int64_t step) const;

 private:
  double time_step_s_;
  std::optional<double> origin_s_;
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
