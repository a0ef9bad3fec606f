#pragma once
// The map layers the package publishes, evaluated lazily from the cell state at a given
// step (THEORY.md §3): nothing is stored per layer, unobserved cells are brought to the
// requested step in closed form when read.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"

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

/// Versions of tiles for LayerTileCache: whoever writes cells bumps their tiles (the mapper
/// would, wherever it marks changed cells; see BENCHMARKS.md, issue 18). Cheap per bump (a
/// hash map entry per tile), so a writer bumps once per run of cells in one tile.
class TileVersions {
 public:
  /// A cell of tile (tile_x, tile_y) (the tile of cell (x, y) is (x >> 6, y >> 6)) changed.
  void bump(std::int32_t tile_x, std::int32_t tile_y);
  /// Cells anywhere may have changed (a model loaded, offline EM applied, ...).
  void bumpAll() { epoch_ = ++counter_; }
  std::uint64_t version(std::int32_t tile_x, std::int32_t tile_y) const;

 private:
  std::uint64_t counter_ = 0;
  std::uint64_t epoch_ = 0;
  std::unordered_map<std::uint64_t, std::uint64_t> versions_;
};

/// int8 values of one layer that does not change with the step (stationary, p_occ_given_free,
/// p_free_given_occ, static_map) kept per 64 x 64 tile, so that a full message is a copy of
/// one byte per cell plus the tiles written since the last one. Values are exactly
/// layerOccupancy's, provided every write of a cell of the grid bumped its tile in the
/// TileVersions given (a tile reallocated by the grid is recomputed in any case).
class LayerTileCache {
 public:
  /// Throws std::invalid_argument for kBelief and kPredicted (they change with the step).
  LayerTileCache(Layer layer, const OccupancyScaling& scaling);
  ~LayerTileCache();
  LayerTileCache(LayerTileCache&&) noexcept;
  LayerTileCache& operator=(LayerTileCache&&) noexcept;

  Layer layer() const { return layer_; }
  const OccupancyScaling& scaling() const { return scaling_; }
  /// layerOccupancy(grid, layer, any step, 0, box, scaling, occupancy, threads): tiles at the
  /// version they were cached at are copied, the others computed (whole) first.
  void occupancy(const CellGrid& grid, const TileVersions& versions, const CellBox& box,
                 std::vector<std::int8_t>* occupancy, unsigned threads = 0);
  /// Tiles held, and tiles computed by the last occupancy() call.
  std::size_t tiles() const { return entries_.size(); }
  std::size_t lastComputed() const { return last_computed_; }

 private:
  struct Entry;
  Layer layer_;
  OccupancyScaling scaling_;
  std::unordered_map<std::uint64_t, std::unique_ptr<Entry>> entries_;
  std::size_t last_computed_ = 0;
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
