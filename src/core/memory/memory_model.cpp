#include "dynamic_occupancy_grid/core/memory/memory_model.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "dynamic_occupancy_grid/core/grid/scan_beams.h"

namespace dynamic_occupancy_grid {
namespace core {
namespace {

constexpr int kTileBits = 6;
constexpr std::int32_t kTileSize = 1 << kTileBits;
constexpr int kTileCells = kTileSize * kTileSize;
constexpr float kAbsent = std::numeric_limits<float>::quiet_NaN();

constexpr std::uint8_t kObserved = 1;
constexpr std::uint8_t kInView = 2;

void require(bool ok, const std::string& message) {
  if (!ok) throw std::invalid_argument(message);
}

bool finitePositive(double value) { return std::isfinite(value) && value > 0.0; }
bool probability(double p) { return std::isfinite(p) && p > 0.0 && p < 1.0; }
double logit(double p) { return std::log(p / (1.0 - p)); }
double sigmoid(double l) { return 1.0 / (1.0 + std::exp(-l)); }
std::int8_t percent(double p) { return static_cast<std::int8_t>(std::lround(100.0 * p)); }

void validateStore(const MemoryStoreParams& store, const std::string& name) {
  require(std::isfinite(store.l_min) && std::isfinite(store.l_max) && store.l_min < store.l_max,
          name + ": need finite l_min < l_max, got " + std::to_string(store.l_min) + ", " +
              std::to_string(store.l_max));
  require(probability(store.p_hit), name + ".p_hit must be in (0, 1), got " + std::to_string(store.p_hit));
  require(probability(store.p_miss), name + ".p_miss must be in (0, 1), got " + std::to_string(store.p_miss));
}

std::uint64_t tileKey(std::int32_t tile_x, std::int32_t tile_y) {
  return (std::uint64_t{static_cast<std::uint32_t>(tile_x)} << 32) | std::uint64_t{static_cast<std::uint32_t>(tile_y)};
}

int offsetOf(std::int32_t x, std::int32_t y) { return (y & (kTileSize - 1)) * kTileSize + (x & (kTileSize - 1)); }

bool contains(const std::vector<std::uint32_t>& sorted_ids, std::uint32_t id) {
  return std::binary_search(sorted_ids.begin(), sorted_ids.end(), id);
}

}  // namespace

struct MemoryModel::Tile {
  std::array<float, kTileCells> ltm;              ///< LTM log-odds, NaN = not in LTM
  std::array<float, kTileCells> stm;              ///< STM log-odds, NaN = not in STM
  std::array<std::uint32_t, kTileCells> configuration;
  std::array<float, kTileCells> view;             ///< summed log-odds of the current view
  std::array<std::uint32_t, kTileCells> scan_mark;  ///< scan id << 1 | hit
  std::array<std::uint8_t, kTileCells> flags;

  Tile() {
    ltm.fill(kAbsent);
    stm.fill(kAbsent);
    configuration.fill(0);
    view.fill(0.0f);
    scan_mark.fill(0);
    flags.fill(0);
  }
};

void MemoryModelConfig::validate() const {
  require(finitePositive(resolution_m), "resolution must be > 0 m, got " + std::to_string(resolution_m));
  require(std::isfinite(origin_x_m) && std::isfinite(origin_y_m), "origin must be finite");
  validateStore(stm, "stm");
  validateStore(ltm, "ltm");
  require(stm.p_hit > 0.5, "stm.p_hit must be > 0.5 (a hit must rehearse), got " + std::to_string(stm.p_hit));
  require(ltm.p_hit > 0.5, "ltm.p_hit must be > 0.5 (a hit must count as one), got " + std::to_string(ltm.p_hit));
  require(ltm.p_miss < 0.5, "ltm.p_miss must be < 0.5 (a miss must decay), got " + std::to_string(ltm.p_miss));
  require(finitePositive(update_distance_m), "update_distance must be > 0 m, got " + std::to_string(update_distance_m));
  require(initial_mapping_updates >= 0,
          "initial_mapping_updates must be >= 0, got " + std::to_string(initial_mapping_updates));
  require(std::isfinite(ltm_occupied_log_odds), "ltm_occupied_log_odds must be finite");
  require(hypothesis_configurations >= 0 && hypothesis_configurations <= 10,
          "hypothesis_configurations must be in [0, 10], got " + std::to_string(hypothesis_configurations));
  require(std::isfinite(max_free_range_m) && max_free_range_m >= 0.0,
          "max_free_range must be >= 0 m, got " + std::to_string(max_free_range_m));
  require(finitePositive(max_map_size_m), "max_map_size must be > 0 m, got " + std::to_string(max_map_size_m));
  require(max_map_size_m / resolution_m < 1.0e8, "max_map_size / resolution must be below 1e8 cells");
}

MemoryModel::MemoryModel(const MemoryModelConfig& config) : config_(config) {
  config_.validate();
  hit_view_ = logit(config_.ltm.p_hit);
  miss_view_ = logit(config_.ltm.p_miss);
  limit_cells_ = static_cast<std::int32_t>(std::ceil(config_.max_map_size_m / (2.0 * config_.resolution_m)));
}

MemoryModel::~MemoryModel() = default;
MemoryModel::MemoryModel(MemoryModel&&) noexcept = default;
MemoryModel& MemoryModel::operator=(MemoryModel&&) noexcept = default;

MemoryModel::MemoryModel(const MemoryModel& other)
    : config_(other.config_),
      hit_view_(other.hit_view_),
      miss_view_(other.miss_view_),
      limit_cells_(other.limit_cells_),
      view_cells_(other.view_cells_),
      scan_id_(other.scan_id_),
      last_laser_pose_(other.last_laser_pose_),
      view_distance_m_(other.view_distance_m_),
      updates_(other.updates_),
      next_configuration_(other.next_configuration_),
      configurations_(other.configurations_),
      ltm_cells_(other.ltm_cells_),
      stm_cells_(other.stm_cells_),
      bounds_(other.bounds_),
      changed_(other.changed_) {
  tiles_.reserve(other.tiles_.size());
  for (const auto& [key, tile] : other.tiles_) tiles_.emplace(key, std::make_unique<Tile>(*tile));
}

MemoryModel& MemoryModel::operator=(const MemoryModel& other) {
  if (this != &other) {
    MemoryModel copy(other);
    *this = std::move(copy);
  }
  return *this;
}

MemoryModel::Tile* MemoryModel::tileForWriting(std::int32_t x, std::int32_t y) {
  if (x < -limit_cells_ || y < -limit_cells_ || x >= limit_cells_ || y >= limit_cells_) return nullptr;
  std::unique_ptr<Tile>& tile = tiles_[tileKey(x >> kTileBits, y >> kTileBits)];
  if (!tile) tile = std::make_unique<Tile>();
  return tile.get();
}

const MemoryModel::Tile* MemoryModel::tileAt(std::int32_t x, std::int32_t y) const {
  const auto found = tiles_.find(tileKey(x >> kTileBits, y >> kTileBits));
  return found == tiles_.end() ? nullptr : found->second.get();
}

void MemoryModel::observeCell(std::int32_t x, std::int32_t y, bool hit, std::size_t& cells_outside) {
  Tile* tile = tileForWriting(x, y);
  if (tile == nullptr) {
    ++cells_outside;
    return;
  }
  const int i = offsetOf(x, y);
  const std::uint32_t mark = tile->scan_mark[i];
  if ((mark >> 1) == scan_id_) {
    // Counted in this scan already: a hit wins over a miss.
    if (!hit || (mark & 1U) != 0) return;
    tile->scan_mark[i] = mark | 1U;
    tile->view[i] += static_cast<float>(hit_view_ - miss_view_);
    return;
  }
  tile->scan_mark[i] = (scan_id_ << 1) | (hit ? 1U : 0U);
  tile->view[i] += static_cast<float>(hit ? hit_view_ : miss_view_);
  if ((tile->flags[i] & kInView) == 0) {
    tile->flags[i] |= kInView;
    view_cells_.push_back(CellXY{x, y});
  }
}

MemoryScanResult MemoryModel::integrate(const Scan& scan) {
  MemoryScanResult result;
  const auto refuse = [&result](std::string error) {
    result.integrated = false;
    result.error = std::move(error);
    return result;
  };
  if (const auto error = scanFieldsError(scan)) return refuse(*error);
  const double u0 = (scan.laser_pose.x_m - config_.origin_x_m) / config_.resolution_m;
  const double v0 = (scan.laser_pose.y_m - config_.origin_y_m) / config_.resolution_m;
  if (std::abs(u0) > kMaxLatticeCoordinate || std::abs(v0) > kMaxLatticeCoordinate) {
    return refuse("laser pose is too far from the map origin");
  }
  BeamRules rules;
  rules.cells_per_m = 1.0 / config_.resolution_m;
  rules.max_free_range_m = config_.max_free_range_m;
  rules.max_beam_m = 1.5 * config_.max_map_size_m;
  std::vector<BeamEnd> beams;
  BeamCounts counts;
  CellBox box;
  if (const auto bad_beam = beamEnds(scan, u0, v0, rules, beams, counts, box)) {
    return refuse("beam " + std::to_string(*bad_beam) + " ends too far from the map origin");
  }
  result.beams_hit = counts.hit;
  result.beams_no_return = counts.no_return;
  result.beams_ignored = counts.ignored;

  // Marks hold the id in 31 bits; on wrap-around forget all marks (once in 2^31 scans).
  if (scan_id_ == (std::numeric_limits<std::uint32_t>::max() >> 1)) {
    for (auto& entry : tiles_) entry.second->scan_mark.fill(0);
    scan_id_ = 0;
  }
  ++scan_id_;
  for (const BeamEnd& beam : beams) {
    const CellXY end = traverseSegment(u0, v0, beam.u1, beam.v1, [&](std::int32_t x, std::int32_t y) {
      observeCell(x, y, false, result.cells_outside);
    });
    observeCell(end.x, end.y, beam.hit, result.cells_outside);
  }

  if (last_laser_pose_) {
    view_distance_m_ +=
        std::hypot(scan.laser_pose.x_m - last_laser_pose_->x_m, scan.laser_pose.y_m - last_laser_pose_->y_m);
  }
  last_laser_pose_ = scan.laser_pose;
  if (view_distance_m_ >= config_.update_distance_m) result.update = update();
  return result;
}

void MemoryModel::forget(Tile& tile, int offset) {
  tile.ltm[offset] = kAbsent;
  --ltm_cells_;
  const auto found = configurations_.find(tile.configuration[offset]);
  if (found != configurations_.end() && --found->second.alive == 0) configurations_.erase(found);
  tile.configuration[offset] = 0;
}

MemoryUpdate MemoryModel::update() {
  MemoryUpdate result;
  result.index = updates_;
  const double stm_hit = logit(config_.stm.p_hit);
  const double ltm_miss = logit(config_.ltm.p_miss);
  struct Migrating {
    Tile* tile;
    int offset;
    CellXY cell;
  };
  std::vector<Migrating> migrating;
  for (const CellXY& cell : view_cells_) {
    Tile& tile = *tileForWriting(cell.x, cell.y);
    const int i = offsetOf(cell.x, cell.y);
    const float evidence = tile.view[i];
    tile.view[i] = 0.0f;
    tile.flags[i] &= static_cast<std::uint8_t>(~kInView);
    if (evidence == 0.0f) continue;
    const bool hit = evidence > 0.0f;
    ++(hit ? result.view_hits : result.view_misses);
    tile.flags[i] |= kObserved;
    bounds_.include(cell.x, cell.y);
    changed_.include(cell.x, cell.y);
    if (!std::isnan(tile.ltm[i])) {
      // Recall, eq. (4): a hit refreshes the cell, a miss decays it; below l_min it is forgotten.
      if (hit) {
        tile.ltm[i] = static_cast<float>(config_.ltm.l_max);
      } else {
        const double decayed = tile.ltm[i] + ltm_miss;
        if (decayed < config_.ltm.l_min) {
          forget(tile, i);
          ++result.forgotten;
        } else {
          tile.ltm[i] = static_cast<float>(decayed);
        }
      }
      continue;
    }
    // Rehearsal, eq. (5), for what the LTM does not hold: a new point enters STM at l_min,
    // a hit adds logit(p_hit), a miss resets the cell to l_min (it stays in STM).
    if (hit) {
      if (std::isnan(tile.stm[i])) {
        tile.stm[i] = static_cast<float>(config_.stm.l_min);
        ++stm_cells_;
      } else {
        const double after = std::min(tile.stm[i] + stm_hit, config_.stm.l_max);
        tile.stm[i] = static_cast<float>(after);
        if (after >= config_.stm.l_max) migrating.push_back(Migrating{&tile, i, cell});
      }
    } else if (!std::isnan(tile.stm[i])) {
      tile.stm[i] = static_cast<float>(config_.stm.l_min);
    }
  }
  view_cells_.clear();

  if (!migrating.empty()) {
    const std::uint32_t id = updates_ < config_.initial_mapping_updates ? 0 : next_configuration_++;
    Configuration& configuration = configurations_[id];
    if (configuration.cells.empty()) configuration.created_update = updates_;
    for (const Migrating& m : migrating) {
      m.tile->stm[m.offset] = kAbsent;
      --stm_cells_;
      m.tile->ltm[m.offset] = static_cast<float>(config_.ltm.l_max);
      m.tile->configuration[m.offset] = id;
      ++ltm_cells_;
      configuration.cells.push_back(m.cell);
      configuration.bounds.include(m.cell.x, m.cell.y);
      result.migrated.push_back(m.cell);
    }
    configuration.alive += migrating.size();
    result.configuration = id;
  }
  ++updates_;
  view_distance_m_ = 0.0;
  return result;
}

std::optional<double> MemoryModel::ltmLogOdds(std::int32_t x, std::int32_t y) const {
  const Tile* tile = tileAt(x, y);
  if (tile == nullptr || std::isnan(tile->ltm[offsetOf(x, y)])) return std::nullopt;
  return tile->ltm[offsetOf(x, y)];
}

std::optional<double> MemoryModel::stmLogOdds(std::int32_t x, std::int32_t y) const {
  const Tile* tile = tileAt(x, y);
  if (tile == nullptr || std::isnan(tile->stm[offsetOf(x, y)])) return std::nullopt;
  return tile->stm[offsetOf(x, y)];
}

std::optional<std::uint32_t> MemoryModel::configurationOf(std::int32_t x, std::int32_t y) const {
  const Tile* tile = tileAt(x, y);
  if (tile == nullptr || std::isnan(tile->ltm[offsetOf(x, y)])) return std::nullopt;
  return tile->configuration[offsetOf(x, y)];
}

bool MemoryModel::observed(std::int32_t x, std::int32_t y) const {
  const Tile* tile = tileAt(x, y);
  return tile != nullptr && (tile->flags[offsetOf(x, y)] & kObserved) != 0;
}

std::vector<ConfigurationInfo> MemoryModel::configurations() const {
  std::vector<ConfigurationInfo> infos;
  infos.reserve(configurations_.size());
  for (const auto& [id, configuration] : configurations_) {
    ConfigurationInfo info;
    info.id = id;
    info.created_update = configuration.created_update;
    info.bounds = configuration.bounds;
    double presence_sum = 0.0;
    // A cell forgotten and migrated again later belongs to its new configuration.
    for (const CellXY& cell : configuration.cells) {
      const Tile* tile = tileAt(cell.x, cell.y);
      const int i = offsetOf(cell.x, cell.y);
      if (std::isnan(tile->ltm[i]) || tile->configuration[i] != id) continue;
      ++info.cells;
      presence_sum += sigmoid(tile->ltm[i]);
    }
    info.presence = info.cells > 0 ? presence_sum / static_cast<double>(info.cells) : 0.0;
    infos.push_back(info);
  }
  std::sort(infos.begin(), infos.end(),
            [](const ConfigurationInfo& a, const ConfigurationInfo& b) { return a.id < b.id; });
  return infos;
}

std::vector<MapHypothesis> MemoryModel::hypotheses() const {
  std::vector<ConfigurationInfo> enumerated;
  for (const ConfigurationInfo& info : configurations()) {
    if (info.id != 0) enumerated.push_back(info);
  }
  // The newest K (highest ids; configurations() is ascending).
  const std::size_t k = std::min<std::size_t>(enumerated.size(), static_cast<std::size_t>(config_.hypothesis_configurations));
  enumerated.erase(enumerated.begin(), enumerated.end() - static_cast<std::ptrdiff_t>(k));
  std::vector<MapHypothesis> hypotheses;
  hypotheses.reserve(std::size_t{1} << k);
  double total = 0.0;
  for (std::uint32_t mask = 0; mask < (std::uint32_t{1} << k); ++mask) {
    MapHypothesis hypothesis;
    hypothesis.weight = 1.0;
    for (std::size_t c = 0; c < k; ++c) {
      const bool present = ((mask >> c) & 1U) != 0;
      (present ? hypothesis.configurations : hypothesis.excluded).push_back(enumerated[c].id);
      hypothesis.weight *= present ? enumerated[c].presence : 1.0 - enumerated[c].presence;
    }
    total += hypothesis.weight;
    hypotheses.push_back(std::move(hypothesis));
  }
  for (MapHypothesis& hypothesis : hypotheses) {
    hypothesis.weight = total > 0.0 ? hypothesis.weight / total : 1.0 / static_cast<double>(hypotheses.size());
  }
  std::stable_sort(hypotheses.begin(), hypotheses.end(), [](const MapHypothesis& a, const MapHypothesis& b) {
    if (a.weight != b.weight) return a.weight > b.weight;
    if (a.excluded.size() != b.excluded.size()) return a.excluded.size() < b.excluded.size();
    return a.configurations < b.configurations;
  });
  return hypotheses;
}

MapWindow MemoryModel::window(const CellBox& cells) const {
  MapWindow window;
  window.resolution_m = config_.resolution_m;
  window.cells = cells;
  if (!cells.empty()) {
    window.origin_x_m = config_.origin_x_m + cells.min_x * config_.resolution_m;
    window.origin_y_m = config_.origin_y_m + cells.min_y * config_.resolution_m;
  }
  return window;
}

template <class CellValue>
std::vector<std::int8_t> MemoryModel::render(const CellBox& cells, CellValue&& value) const {
  std::vector<std::int8_t> grid(static_cast<std::size_t>(cells.width() * cells.height()), kGridUnknown);
  std::size_t index = 0;
  for (std::int32_t y = cells.min_y; !cells.empty() && y <= cells.max_y; ++y) {
    for (std::int32_t x = cells.min_x; x <= cells.max_x; ++x, ++index) {
      const Tile* tile = tileAt(x, y);
      if (tile == nullptr) continue;
      const int i = offsetOf(x, y);
      if ((tile->flags[i] & kObserved) == 0) continue;
      grid[index] = value(*tile, i);
    }
  }
  return grid;
}

std::vector<std::int8_t> MemoryModel::ltmGrid(const CellBox& cells) const {
  return render(cells, [](const Tile& tile, int i) {
    return std::isnan(tile.ltm[i]) ? kGridFree : percent(sigmoid(tile.ltm[i]));
  });
}

std::vector<std::int8_t> MemoryModel::stmGrid(const CellBox& cells) const {
  return render(cells, [](const Tile& tile, int i) {
    return std::isnan(tile.stm[i]) ? kGridFree : percent(sigmoid(tile.stm[i]));
  });
}

std::vector<std::int8_t> MemoryModel::hypothesisGrid(const MapHypothesis& hypothesis, const CellBox& cells) const {
  std::vector<std::uint32_t> present = hypothesis.configurations;
  std::vector<std::uint32_t> absent = hypothesis.excluded;
  std::sort(present.begin(), present.end());
  std::sort(absent.begin(), absent.end());
  const double threshold = config_.ltm_occupied_log_odds;
  return render(cells, [&](const Tile& tile, int i) {
    if (std::isnan(tile.ltm[i])) return kGridFree;
    const std::uint32_t id = tile.configuration[i];
    if (id != 0 && contains(present, id)) return kGridOccupied;
    if (id != 0 && contains(absent, id)) return kGridFree;
    return tile.ltm[i] > threshold ? kGridOccupied : kGridFree;
  });
}

CellBox MemoryModel::takeChangedCells() {
  const CellBox changed = changed_;
  changed_ = CellBox{};
  return changed;
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
