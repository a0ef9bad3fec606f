#include "dynamic_occupancy_grid/core/grid/cell_grid.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>

namespace dynamic_occupancy_grid {
namespace core {
namespace {

// Floor division by the tile size (arithmetic shift floors for negative values too).
std::int32_t tileOf(std::int32_t cell) { return cell >> CellGrid::kTileBits; }

}  // namespace

void CellBox::include(std::int32_t x, std::int32_t y) {
  min_x = std::min(min_x, x);
  min_y = std::min(min_y, y);
  max_x = std::max(max_x, x);
  max_y = std::max(max_y, y);
}

void CellBox::include(const CellBox& other) {
  if (other.empty()) return;
  include(other.min_x, other.min_y);
  include(other.max_x, other.max_y);
}

CellGrid::CellGrid(double resolution_m, double anchor_x_m, double anchor_y_m,
                   std::optional<CellBox> fixed_cells, std::int32_t max_cells_per_side,
                   CellDefaults defaults)
    : resolution_m_(resolution_m),
      inverse_resolution_(1.0 / resolution_m),
      anchor_x_m_(anchor_x_m),
      anchor_y_m_(anchor_y_m),
      fixed_cells_(std::move(fixed_cells)),
      max_cells_per_side_(max_cells_per_side),
      defaults_(defaults) {
  if (!(resolution_m > 0.0) || !std::isfinite(resolution_m)) {
    throw std::invalid_argument("resolution must be a positive number of metres, got " +
                                std::to_string(resolution_m));
  }
  if (!std::isfinite(anchor_x_m) || !std::isfinite(anchor_y_m)) {
    throw std::invalid_argument("map origin must be finite");
  }
  if (max_cells_per_side < kTileSize) {
    throw std::invalid_argument("the map size limit must be at least " +
                                std::to_string(kTileSize) + " cells per side");
  }
  if (fixed_cells_) {
    if (fixed_cells_->empty()) throw std::invalid_argument("fixed map bounds are empty");
    if (fixed_cells_->width() > max_cells_per_side || fixed_cells_->height() > max_cells_per_side) {
      throw std::invalid_argument("fixed map bounds exceed the map size limit of " +
                                  std::to_string(max_cells_per_side) + " cells per side");
    }
    reserve(*fixed_cells_);
  }
}

CellGrid::CellGrid(const CellGrid& other)
    : resolution_m_(other.resolution_m_),
      inverse_resolution_(other.inverse_resolution_),
      anchor_x_m_(other.anchor_x_m_),
      anchor_y_m_(other.anchor_y_m_),
      fixed_cells_(other.fixed_cells_),
      max_cells_per_side_(other.max_cells_per_side_),
      defaults_(other.defaults_),
      tile_min_x_(other.tile_min_x_),
      tile_min_y_(other.tile_min_y_),
      tiles_w_(other.tiles_w_),
      tiles_h_(other.tiles_h_),
      allocated_tiles_(other.allocated_tiles_),
      allocated_cells_(other.allocated_cells_) {
  tiles_.reserve(other.tiles_.size());
  for (const std::unique_ptr<Tile>& tile : other.tiles_) {
    tiles_.push_back(tile ? std::make_unique<Tile>(*tile) : nullptr);
  }
}

CellGrid& CellGrid::operator=(const CellGrid& other) {
  if (this != &other) *this = CellGrid(other);
  return *this;
}

bool CellGrid::insideLimits(std::int32_t x, std::int32_t y) const {
  if (fixed_cells_) return fixed_cells_->contains(x, y);
  const std::int32_t half = max_cells_per_side_ / 2;
  return x >= -half && x < half && y >= -half && y < half;
}

CellBox CellGrid::bounds() const { return fixed_cells_ ? *fixed_cells_ : allocated_cells_; }

MapWindow CellGrid::window(const CellBox& cells) const {
  MapWindow window;
  window.resolution_m = resolution_m_;
  window.cells = cells;
  if (!cells.empty()) {
    window.origin_x_m = anchor_x_m_ + cells.min_x * resolution_m_;
    window.origin_y_m = anchor_y_m_ + cells.min_y * resolution_m_;
  }
  return window;
}

CellBox CellGrid::reserve(const CellBox& box) {
  if (box.empty()) return box;
  CellBox limited = box;
  if (fixed_cells_) {
    limited.min_x = std::max(box.min_x, fixed_cells_->min_x);
    limited.min_y = std::max(box.min_y, fixed_cells_->min_y);
    limited.max_x = std::min(box.max_x, fixed_cells_->max_x);
    limited.max_y = std::min(box.max_y, fixed_cells_->max_y);
  } else {
    const std::int32_t half = max_cells_per_side_ / 2;
    limited.min_x = std::max(box.min_x, -half);
    limited.min_y = std::max(box.min_y, -half);
    limited.max_x = std::min(box.max_x, half - 1);
    limited.max_y = std::min(box.max_y, half - 1);
  }
  if (limited.empty()) return limited;

  const std::int32_t want_min_x = tileOf(limited.min_x);
  const std::int32_t want_min_y = tileOf(limited.min_y);
  const std::int32_t want_max_x = tileOf(limited.max_x);
  const std::int32_t want_max_y = tileOf(limited.max_y);
  if (tiles_w_ > 0 && want_min_x >= tile_min_x_ && want_min_y >= tile_min_y_ &&
      want_max_x < tile_min_x_ + tiles_w_ && want_max_y < tile_min_y_ + tiles_h_) {
    return limited;
  }
  // Grow the index to the union, with slack so a robot exploring step by step does not
  // re-index on every scan; the slack never passes the limits.
  std::int32_t new_min_x = want_min_x;
  std::int32_t new_min_y = want_min_y;
  std::int32_t new_max_x = want_max_x;
  std::int32_t new_max_y = want_max_y;
  if (tiles_w_ > 0) {
    new_min_x = std::min(new_min_x, tile_min_x_);
    new_min_y = std::min(new_min_y, tile_min_y_);
    new_max_x = std::max(new_max_x, tile_min_x_ + tiles_w_ - 1);
    new_max_y = std::max(new_max_y, tile_min_y_ + tiles_h_ - 1);
  }
  if (!fixed_cells_) {
    const std::int32_t slack = 4;
    const std::int32_t half_tiles = (max_cells_per_side_ / 2) >> kTileBits;
    new_min_x = std::max(new_min_x - slack, -half_tiles - 1);
    new_min_y = std::max(new_min_y - slack, -half_tiles - 1);
    new_max_x = std::min(new_max_x + slack, half_tiles);
    new_max_y = std::min(new_max_y + slack, half_tiles);
  }
  const std::int32_t new_w = new_max_x - new_min_x + 1;
  const std::int32_t new_h = new_max_y - new_min_y + 1;
  std::vector<std::unique_ptr<Tile>> new_tiles(static_cast<std::size_t>(new_w) * new_h);
  for (std::int32_t ty = 0; ty < tiles_h_; ++ty) {
    for (std::int32_t tx = 0; tx < tiles_w_; ++tx) {
      auto& old_slot = tiles_[static_cast<std::size_t>(ty) * tiles_w_ + tx];
      if (!old_slot) continue;
      const std::int32_t nx = tile_min_x_ + tx - new_min_x;
      const std::int32_t ny = tile_min_y_ + ty - new_min_y;
      new_tiles[static_cast<std::size_t>(ny) * new_w + nx] = std::move(old_slot);
    }
  }
  tiles_ = std::move(new_tiles);
  tile_min_x_ = new_min_x;
  tile_min_y_ = new_min_y;
  tiles_w_ = new_w;
  tiles_h_ = new_h;
  return limited;
}

std::unique_ptr<CellGrid::Tile>* CellGrid::slot(std::int32_t tile_x, std::int32_t tile_y) {
  const std::int32_t tx = tile_x - tile_min_x_;
  const std::int32_t ty = tile_y - tile_min_y_;
  if (tx < 0 || ty < 0 || tx >= tiles_w_ || ty >= tiles_h_) return nullptr;
  return &tiles_[static_cast<std::size_t>(ty) * tiles_w_ + tx];
}

const std::unique_ptr<CellGrid::Tile>* CellGrid::slot(std::int32_t tile_x,
                                                      std::int32_t tile_y) const {
  return const_cast<CellGrid*>(this)->slot(tile_x, tile_y);
}

CellGrid::Tile* CellGrid::tileForWriting(std::int32_t x, std::int32_t y) {
  if (!insideLimits(x, y)) return nullptr;
  std::unique_ptr<Tile>* tile_slot = slot(tileOf(x), tileOf(y));
  if (tile_slot == nullptr) return nullptr;
  if (!*tile_slot) {
    auto tile = std::make_unique<Tile>();
    tile->p_occ.fill(0.5f);
    tile->last_step.fill(kNeverObserved);
    tile->log_odds.fill(0.0f);
    tile->p_occ_given_free.fill(defaults_.p_occ_given_free);
    tile->p_free_given_occ.fill(defaults_.p_free_given_occ);
    for (auto& stat : tile->em_stats) stat.fill(0.0f);
    tile->observed_steps.fill(0);
    tile->last_hits.fill(0);
    tile->last_misses.fill(0);
    tile->scan_record.fill(0);
    tile->tile_x = tileOf(x);
    tile->tile_y = tileOf(y);
    allocated_cells_.include(tile->tile_x * kTileSize, tile->tile_y * kTileSize);
    allocated_cells_.include((tile->tile_x * kTileSize) + kTileSize - 1,
                             (tile->tile_y * kTileSize) + kTileSize - 1);
    *tile_slot = std::move(tile);
    ++allocated_tiles_;
  }
  return tile_slot->get();
}

const CellGrid::Tile* CellGrid::findTile(std::int32_t x, std::int32_t y) const {
  // No limit check: a tile may straddle the limits, and its cells beyond them are simply
  // never written (they read as never observed).
  const std::unique_ptr<Tile>* tile_slot = slot(tileOf(x), tileOf(y));
  return tile_slot == nullptr ? nullptr : tile_slot->get();
}

std::optional<CellState> CellGrid::cell(std::int32_t x, std::int32_t y) const {
  const Tile* tile = findTile(x, y);
  if (tile == nullptr) return std::nullopt;
  const int i = offsetOf(x, y);
  if (tile->last_step[i] == kNeverObserved) return std::nullopt;
  CellState state{tile->p_occ[i], tile->last_step[i], tile->log_odds[i],
                  tile->p_occ_given_free[i], tile->p_free_given_occ[i], {}, tile->observed_steps[i],
                  tile->last_hits[i], tile->last_misses[i]};
  for (std::size_t k = 0; k < state.em_stats.size(); ++k) state.em_stats[k] = tile->em_stats[k][i];
  return state;
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
