#include "dynamic_occupancy_grid/core/pose/resampling.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace dynamic_occupancy_grid {
namespace core {

std::vector<std::size_t> residualResample(const std::vector<double>& weights, std::size_t count,
                                          const std::function<double()>& uniform01) {
  double total = 0.0;
  for (const double w : weights) {
    if (!(w >= 0.0) || !std::isfinite(w)) throw std::invalid_argument("residualResample: a weight is negative or not finite");
    total += w;
  }
  if (!(total > 0.0)) throw std::invalid_argument("residualResample: all weights are zero");
  const std::size_t size = weights.size();
  std::vector<std::size_t> copies(size);
  std::vector<double> residual(size);
  std::size_t assigned = 0;
  for (std::size_t i = 0; i < size; ++i) {
    const double expected = static_cast<double>(count) * weights[i] / total;
    copies[i] = static_cast<std::size_t>(std::floor(expected));
    residual[i] = expected - static_cast<double>(copies[i]);
    assigned += copies[i];
  }
  // Rounding can put the floors one above count (weights summing to 1 + 1e-16): take back.
  for (std::size_t i = 0; assigned > count && i < size; ++i) {
    if (copies[i] > 0) {
      --copies[i];
      residual[i] += 1.0;
      --assigned;
    }
  }
  double residual_total = 0.0;
  for (const double r : residual) residual_total += r;
  const std::vector<double>& draw_from = residual_total > 0.0 ? residual : weights;
  const double draw_total = residual_total > 0.0 ? residual_total : total;
  for (std::size_t k = assigned; k < count; ++k) {
    const double u = uniform01() * draw_total;
    double cumulative = 0.0;
    std::size_t pick = size - 1;
    for (std::size_t i = 0; i < size; ++i) {
      cumulative += draw_from[i];
      if (u < cumulative) {
        pick = i;
        break;
      }
    }
    while (draw_from[pick] == 0.0 && pick > 0) --pick;  // u at the very top: the last with mass
    ++copies[pick];
  }
  return copies;
}

std::vector<double> normalisedWeights(const std::vector<double>& log_weights) {
  double top = -std::numeric_limits<double>::infinity();
  for (const double w : log_weights) top = std::max(top, w);
  std::vector<double> weights(log_weights.size());
  double total = 0.0;
  for (std::size_t i = 0; i < weights.size(); ++i) {
    weights[i] = std::exp(log_weights[i] - top);
    total += weights[i];
  }
  for (double& w : weights) w /= total;
  return weights;
}

double effectiveSampleSize(const std::vector<double>& weights) {
  double total = 0.0;
  double sum_squares = 0.0;
  for (const double w : weights) {
    total += w;
    sum_squares += w * w;
  }
  return sum_squares > 0.0 ? total * total / sum_squares : 0.0;
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
