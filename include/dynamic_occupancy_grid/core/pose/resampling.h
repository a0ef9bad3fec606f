#pragma once
// Resampling of weighted particles (the corridor's RBPF and the pose filter share it).
//
// ROS-free: standard library only.

#include <cstddef>
#include <functional>
#include <vector>

namespace dynamic_occupancy_grid {
namespace core {

/// Liu & Chen's residual resampling: particle i gets floor(N w_i) copies, and the
/// R = N - sum floor(N w_i) remaining draws are multinomial with probabilities proportional
/// to the residuals N w_i - floor(N w_i). Returns the copies per particle (summing to
/// `count`). `uniform01` draws from [0, 1). `weights` need not be normalised; throws
/// std::invalid_argument if one is negative or not finite, or all are zero.
std::vector<std::size_t> residualResample(const std::vector<double>& weights, std::size_t count,
                                          const std::function<double()>& uniform01);

/// exp(log_weights), normalised to sum 1: the largest is subtracted first, so that weights
/// far below 1 in linear terms do not all underflow. Requires a finite largest log weight.
std::vector<double> normalisedWeights(const std::vector<double>& log_weights);

/// Kish's effective sample size (sum w)^2 / sum w^2 of non-negative weights (0 if all are 0).
double effectiveSampleSize(const std::vector<double>& weights);

}  // namespace core
}  // namespace dynamic_occupancy_grid
