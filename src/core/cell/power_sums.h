#pragma once
// Sums of powers behind the O(1) gap crossings of online and offline EM (THEORY.md §5–6):
// a run of k steps with fixed A = Pi + lambda^n (I - Pi) turns every per-step sum into
// geometric sums in lambda (and in the decay of online EM). Private to the core.

#include <cmath>
#include <cstdint>

namespace dynamic_occupancy_grid {
namespace core {
namespace detail {

/// sum_{l=0}^{k-1} x^l for x in [-1, 1] and k >= 0, given one_minus_x = 1 - x computed
/// without cancellation by the caller (x close to 1 is where rates live).
inline double geometricSum(double x, double one_minus_x, std::int64_t k) {
  if (k <= 0) return 0.0;
  if (one_minus_x == 0.0) return static_cast<double>(k);
  const double steps = static_cast<double>(k);
  // Near 1, 1 - x^k cancels: take it from expm1/log1p instead.
  if (std::abs(one_minus_x) < 1e-3) return -std::expm1(steps * std::log1p(-one_minus_x)) / one_minus_x;
  return (1.0 - std::pow(x, steps)) / one_minus_x;
}

/// sum_{l=0}^{k-1} a^l b^{k-1-l} for a, b in [-1, 1], k >= 0; a_minus_b = a - b computed
/// without cancellation by the caller.
inline double mixedPowerSum(double a, double b, double a_minus_b, std::int64_t k) {
  if (k <= 0) return 0.0;
  if (a_minus_b == 0.0) return static_cast<double>(k) * std::pow(a, static_cast<double>(k - 1));
  // Factor out the larger base: the ratio is then in [-1, 1] and the sum geometric.
  if (std::abs(a) >= std::abs(b)) {
    return std::pow(a, static_cast<double>(k - 1)) * geometricSum(b / a, a_minus_b / a, k);
  }
  return std::pow(b, static_cast<double>(k - 1)) * geometricSum(a / b, -a_minus_b / b, k);
}

}  // namespace detail
}  // namespace core
}  // namespace dynamic_occupancy_grid
