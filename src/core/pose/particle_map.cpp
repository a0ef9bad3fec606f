#include "dynamic_occupancy_grid/core/pose/particle_map.h"

#include <atomic>
#include <cmath>
#include <stdexcept>
#include <unordered_set>

#include "dynamic_occupancy_grid/core/grid/mapper.h"

namespace dynamic_occupancy_grid {
namespace core {

namespace {
std::size_t offsetOf(std::int32_t x, std::int32_t y) {
  constexpr std::int32_t kMask = ParticleMap::kTileSize - 1;
  return static_cast<std::size_t>((y & kMask) * ParticleMap::kTileSize + (x & kMask));
}
}  // namespace

UniformTransitions::UniformTransitions(const TransitionParams& params) : params_(params) {
  if (!params.isValid()) throw std::invalid_argument("UniformTransitions: invalid transition probabilities");
}

MapperTransitions::MapperTransitions(const Mapper& mapper, double resolution_m, std::uint32_t min_observed_steps)
    : mapper_(mapper), resolution_m_(resolution_m), min_observed_steps_(min_observed_steps) {
  if (!(resolution_m > 0.0) || !std::isfinite(resolution_m)) {
    throw std::invalid_argument("MapperTransitions: resolution must be finite and > 0");
  }
}

TransitionParams MapperTransitions::at(std::int32_t x, std::int32_t y) const {
  const CellGrid& grid = mapper_.grid();
  const double u = std::floor(grid.toLatticeX((x + 0.5) * resolution_m_));
  const double v = std::floor(grid.toLatticeY((y + 0.5) * resolution_m_));
  constexpr double kLimit = 2147483647.0;
  if (!(std::abs(u) < kLimit && std::abs(v) < kLimit)) return TransitionParams{0.0, 0.0};  // beyond any Mapper
  const auto cx = static_cast<std::int32_t>(u);
  const auto cy = static_cast<std::int32_t>(v);
  // The two fields straight from the tile: the whole CellState is 80 bytes.
  const CellGrid::Tile* tile = grid.findTile(cx, cy);
  const int offset = CellGrid::offsetOf(cx, cy);
  if (tile == nullptr || tile->last_step[offset] == kNeverObserved ||
      tile->observed_steps[offset] < min_observed_steps_) {
    return TransitionParams{0.0, 0.0};
  }
  return TransitionParams{tile->p_occ_given_free[offset], tile->p_free_given_occ[offset]};
}

std::uint64_t ParticleMap::keyOf(std::int32_t x, std::int32_t y) {
  const auto tile_x = static_cast<std::uint32_t>(x >> kTileBits);
  const auto tile_y = static_cast<std::uint32_t>(y >> kTileBits);
  return (std::uint64_t{tile_x} << 32) | tile_y;
}

const ParticleMap::Tile* ParticleMap::find(std::int32_t x, std::int32_t y) const {
  const auto it = tiles_.find(keyOf(x, y));
  return it == tiles_.end() ? nullptr : it->second.get();
}

ParticleMap::Tile& ParticleMap::writable(std::int32_t x, std::int32_t y) {
  std::shared_ptr<Tile>& tile = tiles_[keyOf(x, y)];
  if (!tile) {
    tile = std::make_shared<Tile>();
    tile->p_occ.fill(0.0f);
    tile->last_step.fill(kNeverObserved);
  } else if (tile.use_count() > 1) {
    // Shared since a copy of the map: this map gets its own. Copies are made only while no
    // map writes (resampling), so a count of 1 means no other map holds the tile.
    tile = std::make_shared<Tile>(*tile);
  } else {
    // The other holder may have let go of it on another thread just now (its copy made):
    // its reads of the tile happen before these writes.
    std::atomic_thread_fence(std::memory_order_acquire);
  }
  return *tile;
}

double ParticleMap::predictedIn(const Tile* tile, std::int32_t x, std::int32_t y, std::int64_t step,
                                const TransitionSource& transitions, double unknown_p_occ) {
  const std::size_t offset = offsetOf(x, y);
  const std::int32_t last = tile == nullptr ? kNeverObserved : tile->last_step[offset];
  // A new cell: the prior is its belief just before the step's transition (as the Mapper's).
  if (last == kNeverObserved) return predictOneStep(unknown_p_occ, transitions.at(x, y));
  return predictOccupancy(tile->p_occ[offset], transitions.at(x, y), step - last);
}

void ParticleMap::updateIn(Tile& tile, std::int32_t x, std::int32_t y, std::int64_t step, double log_likelihood_ratio,
                           const TransitionSource& transitions, double unknown_p_occ) {
  const std::size_t offset = offsetOf(x, y);
  const std::int32_t last = tile.last_step[offset];
  const TransitionParams params = transitions.at(x, y);
  const double prior = last == kNeverObserved ? predictOneStep(unknown_p_occ, params)
                                               : predictOccupancy(tile.p_occ[offset], params, step - last);
  tile.p_occ[offset] = static_cast<float>(bayesUpdate(prior, log_likelihood_ratio));
  tile.last_step[offset] = static_cast<std::int32_t>(step);
}

double ParticleMap::predicted(std::int32_t x, std::int32_t y, std::int64_t step, const TransitionSource& transitions,
                              double unknown_p_occ) const {
  return predictedIn(find(x, y), x, y, step, transitions, unknown_p_occ);
}

std::int32_t ParticleMap::lastStep(std::int32_t x, std::int32_t y) const {
  const Tile* tile = find(x, y);
  return tile == nullptr ? kNeverObserved : tile->last_step[offsetOf(x, y)];
}

void ParticleMap::update(std::int32_t x, std::int32_t y, std::int64_t step, double log_likelihood_ratio,
                         const TransitionSource& transitions, double unknown_p_occ) {
  updateIn(writable(x, y), x, y, step, log_likelihood_ratio, transitions, unknown_p_occ);
}

const ParticleMap::Tile* ParticleMap::Reader::tile(std::int32_t x, std::int32_t y) {
  const std::uint64_t key = keyOf(x, y);
  if (key_ != key) {
    key_ = key;
    tile_ = map_.find(x, y);
  }
  return tile_;
}

double ParticleMap::Reader::predicted(std::int32_t x, std::int32_t y, std::int64_t step,
                                      const TransitionSource& transitions, double unknown_p_occ) {
  return predictedIn(tile(x, y), x, y, step, transitions, unknown_p_occ);
}

std::int32_t ParticleMap::Reader::lastStep(std::int32_t x, std::int32_t y) {
  const Tile* cell_tile = tile(x, y);
  return cell_tile == nullptr ? kNeverObserved : cell_tile->last_step[offsetOf(x, y)];
}

void ParticleMap::Writer::update(std::int32_t x, std::int32_t y, std::int64_t step, double log_likelihood_ratio,
                                 const TransitionSource& transitions, double unknown_p_occ) {
  const std::uint64_t key = keyOf(x, y);
  if (key_ != key) {
    key_ = key;
    tile_ = &map_.writable(x, y);
  }
  updateIn(*tile_, x, y, step, log_likelihood_ratio, transitions, unknown_p_occ);
}

std::size_t ParticleMap::sharedTileCount() const {
  std::size_t shared = 0;
  for (const auto& entry : tiles_) shared += entry.second.use_count() > 1 ? 1 : 0;
  return shared;
}

bool ParticleMap::sharesTileWith(const ParticleMap& other, std::int32_t x, std::int32_t y) const {
  const Tile* mine = find(x, y);
  return mine != nullptr && mine == other.find(x, y);
}

CellBox ParticleMap::bounds() const {
  CellBox box;
  for (const auto& entry : tiles_) {
    const auto tile_x = static_cast<std::int32_t>(static_cast<std::uint32_t>(entry.first >> 32));
    const auto tile_y = static_cast<std::int32_t>(static_cast<std::uint32_t>(entry.first & 0xffffffffU));
    box.include(tile_x * kTileSize, tile_y * kTileSize);
    box.include(tile_x * kTileSize + kTileSize - 1, tile_y * kTileSize + kTileSize - 1);
  }
  return box;
}

std::size_t ParticleMap::distinctTileBytes(const std::vector<const ParticleMap*>& maps) {
  std::unordered_set<const Tile*> distinct;
  for (const ParticleMap* map : maps) {
    for (const auto& entry : map->tiles_) distinct.insert(entry.second.get());
  }
  return distinct.size() * sizeof(Tile);
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
