#include "dynamic_occupancy_grid/core/grid/step_clock.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace dynamic_occupancy_grid {
namespace core {

StepClock::StepClock(double time_step_s) : time_step_s_(time_step_s) {
  if (!(time_step_s > 0.0) || !std::isfinite(time_step_s)) {
    throw std::invalid_argument("time_step must be a positive number of seconds, got " +
                                std::to_string(time_step_s));
  }
}

void StepClock::startAt(double stamp_s) {
  if (!origin_s_) origin_s_ = stamp_s;
}

void StepClock::anchor(double stamp_s, std::int64_t step) {
  // A millionth of a step of margin keeps rounding from putting stamp_s into step - 1.
  origin_s_ = stamp_s - (static_cast<double>(step) + 1e-6) * time_step_s_;
}

std::int64_t StepClock::stepOf(double stamp_s) const {
  // Saturate instead of overflowing the cast for absurd stamps; callers reject those.
  constexpr double kLimit = 4.0e18;
  const double step = std::floor((stamp_s - *origin_s_) / time_step_s_);
  return static_cast<std::int64_t>(std::clamp(step, -kLimit, kLimit));
}

double StepClock::stepStart(std::int64_t step) const {
  return *origin_s_ + static_cast<double>(step) * time_step_s_;
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
