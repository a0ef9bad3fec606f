#pragma once
// Short-term / long-term memory and map hypotheses (Morris et al., "Multiple map hypotheses
// for planning and navigating in non-stationary environments"; THEORY.md §8), in 2D.
//
// Two log-odds stores over one cell lattice:
//   LTM  what the robot believes is there. A hit sets a cell to ltm.l_max, a miss adds
//        logit(ltm.p_miss) (eq. 4): LTM decays slowly and is refreshed at once. A cell
//        below ltm.l_min is forgotten (removed from LTM).
//   STM  novelty being rehearsed: occupied cells the LTM does not hold. A miss resets a cell
//        to stm.l_min, a hit adds logit(stm.p_hit) (eq. 5), clamped to stm.l_max. A cell
//        that reaches stm.l_max migrates to LTM (at ltm.l_max).
// As in the paper, a new STM point is "initialised with l_min" by the hit that adds it, and
// later hits rehearse it; a miss resets it to l_min, where it stays in STM. With Table I's
// values (0.40 + 0.85 = 1.25 < 1.28) a new cell migrates when it is hit in three
// consecutive updates, a reset one in two, with no update in between that saw it free: a
// person must stand in the same cell over two or three views to reach LTM.
//
// Updates. Scans are not applied one by one: their observations are gathered into a *view*
// until the laser has travelled update_distance_m, and the view updates the stores
// (the paper's guard against a robot that turns on the spot or stands still rehearsing
// STM many times over). Within a scan a cell counts once (a hit wins over a miss); over
// the view a cell's hits and misses are summed as log-odds (eq. 2 with the sensor model of
// the LTM row, logit(ltm.p_hit) per hit and logit(ltm.p_miss) per miss: the view's own
// occupancy grid); a positive sum is a hit of this
// update, a negative one a miss, zero leaves the cell alone. The order of one update is the
// paper's: recall (eq. 4 on the LTM cells of the view), rehearsal (eq. 5 on the others),
// migration, forgetting.
//
// Configurations. The cells that migrate in one update form one configuration with a new
// id (1, 2, ...); they keep it while they stay in LTM and decay like the rest of LTM. The
// cells that migrate during the first initial_mapping_updates updates form the base map
// (configuration 0), which the paper builds in a separate mapping run: every hypothesis
// contains it.
//
// Hypotheses. A hypothesis is a set of configurations assumed present; the configurations
// not in it are assumed absent. Its map: a base cell or a cell of a configuration that is
// neither new enough to be enumerated nor in the set is occupied if its LTM log-odds is
// above ltm_occupied_log_odds; a cell of an included configuration is occupied; a cell of
// an excluded one is free; any other observed cell is free; the rest unknown. The newest
// hypothesis_configurations configurations are enumerated (2^K hypotheses, K <= 10; the
// paper's office gave 4 configurations and 16 hypotheses). Each has a prior weight from
// the memory itself: configuration c is present with probability presence(c), the mean of
// sigma(L) over its cells (near 1 while the configuration is refreshed, falling as its
// cells are seen free), independently of the others; weights are normalised to sum to 1.
// The evaluation's hypothesis planner re-weights them by what navigation finds
// (memory_experiment.h).
//
// ROS-free: standard library only.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/grid/scan.h"
#include "dynamic_occupancy_grid/core/grid/traversal.h"

namespace dynamic_occupancy_grid {
namespace core {

/// One store's update policy (a row of the paper's Table I; log-odds and probabilities).
struct MemoryStoreParams {
  double l_min = 0.0;
  double l_max = 0.0;
  double p_hit = 0.7;   ///< a hit adds logit(p_hit)
  double p_miss = 0.4;  ///< a miss adds logit(p_miss)
};

struct MemoryModelConfig {
  double resolution_m = 0.05;
  double origin_x_m = 0.0;  ///< world position of the lattice's cell (0, 0) corner
  double origin_y_m = 0.0;
  MemoryStoreParams stm{0.40, 1.28, 0.7, 0.4};  ///< Table I
  MemoryStoreParams ltm{-2.9, 4.59, 0.7, 0.4};  ///< Table I
  /// Travel of the laser (m) over which scans are gathered into one view before an update.
  double update_distance_m = 1.0;
  /// Updates whose migrations build the base map (configuration 0) instead of configurations.
  int initial_mapping_updates = 10;
  /// An LTM cell is occupied (in ~ltm thresholding and in hypotheses) above this log-odds.
  double ltm_occupied_log_odds = 0.0;
  /// The newest configurations enumerated into hypotheses (2^K of them), 0..10.
  int hypothesis_configurations = 4;
  /// Beams without return clear cells up to this distance (and never beyond range_max);
  /// 0 ignores such beams (as MapperConfig::max_free_range_m).
  double max_free_range_m = 10.0;
  /// The map stays inside origin +- max_map_size_m / 2 along each axis; cells beyond are dropped.
  double max_map_size_m = 1000.0;

  /// Throws std::invalid_argument naming the first bad field: resolution, distances and
  /// sizes finite and > 0 (max_free_range >= 0), probabilities in (0, 1), each store's
  /// l_min < l_max, stm.p_hit and ltm.p_hit > 1/2 (a hit must rehearse, and count as a hit
  /// in the view), ltm.p_miss < 1/2 (a miss must decay, and count as a miss),
  /// initial_mapping_updates >= 0, hypothesis_configurations in [0, 10].
  void validate() const;
};

/// What one update of the stores did.
struct MemoryUpdate {
  std::int64_t index = 0;          ///< 0 for the first update
  std::size_t view_hits = 0;       ///< view cells whose summed evidence was a hit
  std::size_t view_misses = 0;     ///< ... a miss
  std::vector<CellXY> migrated;    ///< cells that moved from STM to LTM
  /// The id the migrated cells got (0: the base map); nullopt when none migrated.
  std::optional<std::uint32_t> configuration;
  std::size_t forgotten = 0;       ///< LTM cells forgotten
};

struct MemoryScanResult {
  bool integrated = true;
  std::string error;  ///< why the scan was refused (nothing of it was kept)
  std::size_t beams_hit = 0;
  std::size_t beams_no_return = 0;
  std::size_t beams_ignored = 0;
  std::size_t cells_outside = 0;  ///< beam cells beyond max_map_size, dropped
  /// The update this scan completed (its view reached update_distance_m), if any.
  std::optional<MemoryUpdate> update;
};

struct ConfigurationInfo {
  std::uint32_t id = 0;
  std::int64_t created_update = 0;  ///< the update its cells migrated in
  std::size_t cells = 0;            ///< cells still in LTM with this id
  double presence = 0.0;            ///< mean sigma(L) over them
  CellBox bounds;                   ///< of the cells it was created with
};

struct MapHypothesis {
  std::vector<std::uint32_t> configurations;  ///< assumed present, ascending ids
  std::vector<std::uint32_t> excluded;        ///< enumerated but assumed absent, ascending
  double weight = 0.0;                        ///< prior weight, the hypotheses' sum is 1
};

/// Occupancy values as in nav_msgs/OccupancyGrid.
constexpr std::int8_t kGridUnknown = -1;
constexpr std::int8_t kGridFree = 0;
constexpr std::int8_t kGridOccupied = 100;

class MemoryModel {
 public:
  /// Throws std::invalid_argument for a bad config.
  explicit MemoryModel(const MemoryModelConfig& config);
  ~MemoryModel();
  MemoryModel(const MemoryModel& other);
  MemoryModel& operator=(const MemoryModel& other);
  MemoryModel(MemoryModel&&) noexcept;
  MemoryModel& operator=(MemoryModel&&) noexcept;

  const MemoryModelConfig& config() const { return config_; }

  /// Gathers the scan into the current view (a refused scan changes nothing); when the
  /// laser has travelled update_distance_m since the view began, updates the stores.
  MemoryScanResult integrate(const Scan& scan);
  /// Updates the stores with the current view now, whatever the distance (a view without
  /// observations still counts as an update). Then starts a new view.
  MemoryUpdate update();
  /// Updates done so far.
  std::int64_t updates() const { return updates_; }
  /// Laser travel gathered in the current view (m).
  double viewDistanceM() const { return view_distance_m_; }

  /// LTM / STM log-odds of a cell; nullopt when the store does not hold it.
  std::optional<double> ltmLogOdds(std::int32_t x, std::int32_t y) const;
  std::optional<double> stmLogOdds(std::int32_t x, std::int32_t y) const;
  /// Configuration of an LTM cell (0: base map); nullopt when not in LTM.
  std::optional<std::uint32_t> configurationOf(std::int32_t x, std::int32_t y) const;
  /// Whether an update ever saw the cell (hit or miss).
  bool observed(std::int32_t x, std::int32_t y) const;
  std::size_t ltmCells() const { return ltm_cells_; }
  std::size_t stmCells() const { return stm_cells_; }

  /// Configurations with cells in LTM (the base map 0 included if it has any), ascending id.
  std::vector<ConfigurationInfo> configurations() const;
  /// All hypotheses over the newest hypothesis_configurations configurations, by weight
  /// (descending; ties by fewer excluded configurations, then by the ids).
  std::vector<MapHypothesis> hypotheses() const;

  /// Cells any update observed (empty box before the first).
  CellBox bounds() const { return bounds_; }
  /// The placement of `cells` in the world (for messages).
  MapWindow window(const CellBox& cells) const;
  /// Row-major grids over `cells` (index (y - min_y) * width + (x - min_x)), OccupancyGrid
  /// values: unknown -1 where no update observed the cell.
  ///   ltm: round(100 sigma(L)) for LTM cells, 0 for other observed cells;
  ///   stm: round(100 sigma(S)) for STM cells, 0 for other observed cells;
  ///   hypothesis: 100 / 0 as described at the top of this file.
  std::vector<std::int8_t> ltmGrid(const CellBox& cells) const;
  std::vector<std::int8_t> stmGrid(const CellBox& cells) const;
  std::vector<std::int8_t> hypothesisGrid(const MapHypothesis& hypothesis, const CellBox& cells) const;
  /// Cells whose values in the grids above may have changed since the last call (grows
  /// with each update); empty if none.
  CellBox takeChangedCells();

 private:
  struct Tile;
  struct Configuration {
    std::int64_t created_update = 0;
    std::vector<CellXY> cells;  ///< as migrated; some may since be forgotten
    std::size_t alive = 0;
    CellBox bounds;
  };
  Tile* tileForWriting(std::int32_t x, std::int32_t y);
  const Tile* tileAt(std::int32_t x, std::int32_t y) const;
  void observeCell(std::int32_t x, std::int32_t y, bool hit, std::size_t& cells_outside);
  void forget(Tile& tile, int offset);
  template <class CellValue>
  std::vector<std::int8_t> render(const CellBox& cells, CellValue&& value) const;

  MemoryModelConfig config_;
  double hit_view_ = 0.0;   ///< logit(view hit): the view's eq. (2) increments
  double miss_view_ = 0.0;
  std::int32_t limit_cells_ = 0;  ///< cells from the origin to the edge of the map, per axis
  std::unordered_map<std::uint64_t, std::unique_ptr<Tile>> tiles_;
  std::vector<CellXY> view_cells_;  ///< cells with evidence in the current view
  std::uint32_t scan_id_ = 0;
  std::optional<Pose2D> last_laser_pose_;
  double view_distance_m_ = 0.0;
  std::int64_t updates_ = 0;
  std::uint32_t next_configuration_ = 1;
  std::unordered_map<std::uint32_t, Configuration> configurations_;
  std::size_t ltm_cells_ = 0;
  std::size_t stm_cells_ = 0;
  CellBox bounds_;
  CellBox changed_;
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
