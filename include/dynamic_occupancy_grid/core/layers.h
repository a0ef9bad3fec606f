#pragma once
// The map layers the package publishes, evaluated lazily from the cell state at a given
// step (THEORY.md §3): nothing is stored per layer, unobserved cells are brought to the
// requested step in closed form when read.

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/cell_grid.h"

namespace dynamic_occupancy_grid {
namespace core {

enum class Layer {
  kBelief,          ///< p(occ) at the requested step
  kPredicted,       ///< p(occ) at the requested step + horizon
  kStationary,      ///< long-run p(occ); a static cell keeps its belief
  kOccGivenFree,    ///< p_of per step
  kFreeGivenOcc,    ///< p_fo per step
  kStatic,          ///< standard occupancy grid baseline, p(occ) of the clamped log-odds
};

/// Name used for topics and files ("belief", "predicted", ...).
std::string layerName(Layer layer);

/// Values of `layer` over `box` (row-major, row = y from box.min_y, like
/// nav_msgs/OccupancyGrid), NaN for cells never observed. `step` is "now";
/// `horizon_steps` is used by kPredicted only.
void evaluateLayer(const CellGrid& grid, Layer layer, std::int64_t step,
                   std::int64_t horizon_steps, const CellBox& box, std::vector<float>* values);

/// The one scaling to nav_msgs/OccupancyGrid values: NaN -> -1 (unknown), otherwise
/// round(100 * value / full_scale) clamped to 0..100. Probabilities use full_scale = 1.
void toOccupancyValues(const std::vector<float>& values, float full_scale,
                       std::vector<std::int8_t>* occupancy);

/// How probabilities become OccupancyGrid values for map consumers, as map_server reads an
/// image (its `mode`): p > occupied_thresh -> 100, p < free_thresh -> 0, otherwise -1
/// (kTrinary) or 1 + 98 (p - free_thresh) / (occupied_thresh - free_thresh) truncated
/// (kScale); kRaw is toOccupancyValues' round(100 p). NaN (never observed) is -1 in all.
enum class ThresholdMode { kTrinary, kScale, kRaw };

struct OccupancyThresholds {
  ThresholdMode mode = ThresholdMode::kTrinary;
  double occupied_thresh = 0.65;  ///< map_server's default
  double free_thresh = 0.196;     ///< map_server's default
  /// Throws std::invalid_argument unless 0 <= free_thresh < occupied_thresh <= 1.
  void validate() const;
};

/// Probabilities (NaN = unknown) to OccupancyGrid values by `thresholds`.
void toThresholdedOccupancyValues(const std::vector<float>& values, const OccupancyThresholds& thresholds,
                                  std::vector<std::int8_t>* occupancy);

/// One value of toOccupancyValues / toThresholdedOccupancyValues (they call these).
std::int8_t occupancyValue(float value, float full_scale);
std::int8_t thresholdedOccupancyValue(float value, const OccupancyThresholds& thresholds);

/// How layer values become OccupancyGrid values: toOccupancyValues with `full_scale`, or
/// toThresholdedOccupancyValues with `thresholds` when set (full_scale is then unused).
struct OccupancyScaling {
  float full_scale = 1.0f;
  std::optional<OccupancyThresholds> thresholds;
};

/// `layer` over `box` straight to OccupancyGrid values (row-major like evaluateLayer), in one
/// pass per row without a float buffer, rows split over `threads` threads (0: one per core;
/// boxes under 512 x 512 cells use the calling thread only). The values are exactly those of
/// evaluateLayer followed by toOccupancyValues / toThresholdedOccupancyValues, for every cell
/// state: a cell is decided by a fast path only when that path proves the reference's value
/// (exact integer thresholds of the scaling, an error bound on the prediction); the rest is
/// computed the reference's way. Never-observed and unallocated cells are -1.
void layerOccupancy(const CellGrid& grid, Layer layer, std::int64_t step, std::int64_t horizon_steps,
                    const CellBox& box, const OccupancyScaling& scaling, std::vector<std::int8_t>* occupancy,
                    unsigned threads = 0);

/// The loop layerOccupancy runs, process-wide (for tests and benchmarks: all give the same
/// values): kAuto the best the CPU has (AVX-512 for the prediction, else AVX2), kAvx2 at most
/// AVX2, kReference every cell the reference's way. Without AVX2 it is always kReference.
enum class LayerKernel { kAuto, kAvx2, kReference };
void setLayerKernel(LayerKernel kernel);

}  // namespace core
}  // namespace dynamic_occupancy_grid
