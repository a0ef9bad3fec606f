#include "dynamic_occupancy_grid/core/layers.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "dynamic_occupancy_grid/core/cell_model.h"

namespace dynamic_occupancy_grid {
namespace core {
namespace {

float cellValue(const CellGrid::Tile& tile, int i, Layer layer, std::int64_t step,
                std::int64_t horizon_steps) {
  const TransitionParams params{tile.p_occ_given_free[i], tile.p_free_given_occ[i]};
  switch (layer) {
    case Layer::kBelief:
      return static_cast<float>(predictOccupancy(tile.p_occ[i], params, step - tile.last_step[i]));
    case Layer::kPredicted:
      return static_cast<float>(
          predictOccupancy(tile.p_occ[i], params, step + horizon_steps - tile.last_step[i]));
    case Layer::kStationary: {
      const std::optional<double> pi_occ = stationaryOccupancy(params);
      return pi_occ ? static_cast<float>(*pi_occ) : tile.p_occ[i];
    }
    case Layer::kOccGivenFree:
      return tile.p_occ_given_free[i];
    case Layer::kFreeGivenOcc:
      return tile.p_free_given_occ[i];
    case Layer::kStatic:
      return static_cast<float>(logOddsToProbability(tile.log_odds[i]));
  }
  return std::numeric_limits<float>::quiet_NaN();
}

}  // namespace

std::string layerName(Layer layer) {
  switch (layer) {
    case Layer::kBelief:
      return "belief";
    case Layer::kPredicted:
      return "predicted";
    case Layer::kStationary:
      return "stationary";
    case Layer::kOccGivenFree:
      return "p_occ_given_free";
    case Layer::kFreeGivenOcc:
      return "p_free_given_occ";
    case Layer::kStatic:
      return "static_map";
  }
  return "unknown";
}

void evaluateLayer(const CellGrid& grid, Layer layer, std::int64_t step,
                   std::int64_t horizon_steps, const CellBox& box, std::vector<float>* values) {
  constexpr float kUnknown = std::numeric_limits<float>::quiet_NaN();
  values->assign(static_cast<std::size_t>(box.width() * box.height()), kUnknown);
  if (box.empty()) return;
  const std::int64_t width = box.width();
  for (std::int32_t y = box.min_y; y <= box.max_y; ++y) {
    float* row = values->data() + static_cast<std::size_t>((std::int64_t{y} - box.min_y) * width);
    // One tile lookup per run of cells sharing a tile.
    for (std::int32_t x = box.min_x; x <= box.max_x;) {
      const std::int32_t run_end =
          std::min<std::int32_t>(box.max_x, (x | (CellGrid::kTileSize - 1)));
      if (const CellGrid::Tile* tile = grid.findTile(x, y)) {
        for (std::int32_t cx = x; cx <= run_end; ++cx) {
          const int i = CellGrid::offsetOf(cx, y);
          if (tile->last_step[i] == kNeverObserved) continue;
          row[cx - box.min_x] = cellValue(*tile, i, layer, step, horizon_steps);
        }
      }
      if (run_end == std::numeric_limits<std::int32_t>::max()) break;
      x = run_end + 1;
    }
  }
}

void toOccupancyValues(const std::vector<float>& values, float full_scale,
                       std::vector<std::int8_t>* occupancy) {
  occupancy->resize(values.size());
  const float scale = 100.0f / full_scale;
  for (std::size_t i = 0; i < values.size(); ++i) {
    const float value = values[i];
    occupancy->at(i) = std::isnan(value)
                           ? std::int8_t{-1}
                           : static_cast<std::int8_t>(std::lround(std::clamp(value * scale, 0.0f, 100.0f)));
  }
}

void OccupancyThresholds::validate() const {
  if (!(std::isfinite(free_thresh) && std::isfinite(occupied_thresh) && free_thresh >= 0.0 &&
        free_thresh < occupied_thresh && occupied_thresh <= 1.0)) {
    throw std::invalid_argument("occupancy thresholds need 0 <= free_thresh < occupied_thresh <= 1, got free_thresh " +
                                std::to_string(free_thresh) + ", occupied_thresh " + std::to_string(occupied_thresh));
  }
}

void toThresholdedOccupancyValues(const std::vector<float>& values, const OccupancyThresholds& thresholds,
                                  std::vector<std::int8_t>* occupancy) {
  if (thresholds.mode == ThresholdMode::kRaw) {
    toOccupancyValues(values, 1.0f, occupancy);
    return;
  }
  occupancy->resize(values.size());
  const double span = thresholds.occupied_thresh - thresholds.free_thresh;
  for (std::size_t i = 0; i < values.size(); ++i) {
    const double p = values[i];
    std::int8_t value = -1;
    if (std::isnan(p)) {
      value = -1;
    } else if (p > thresholds.occupied_thresh) {
      value = 100;
    } else if (p < thresholds.free_thresh) {
      value = 0;
    } else if (thresholds.mode == ThresholdMode::kScale) {
      // map_server's image_loader: value = 1 + 98 * ratio, assigned to an int (truncated).
      value = static_cast<std::int8_t>(1.0 + 98.0 * (p - thresholds.free_thresh) / span);
    }
    (*occupancy)[i] = value;
  }
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
