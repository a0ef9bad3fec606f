#pragma once
// The mapping pipeline of the core: scans in, per-cell HMM beliefs, online-learned
// transition probabilities and the static log-odds baseline out. Scans are grouped into time steps (THEORY.md §4); within a step each
// touched cell gathers hit and miss counts; when a scan of a later step arrives the step is
// applied to the touched cells only (THEORY.md §3: untouched cells cost nothing).

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/cell/cell_kinds.h"
#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/core/layers/layers.h"
#include "dynamic_occupancy_grid/core/cell/offline_em.h"
#include "dynamic_occupancy_grid/core/cell/online_em.h"
#include "dynamic_occupancy_grid/core/grid/scan.h"
#include "dynamic_occupancy_grid/core/grid/step_clock.h"

namespace dynamic_occupancy_grid {
namespace core {

/// How cells learn their transitions (docs/online_learning.md).
enum class TransitionLearner {
  /// Each cell by itself: online EM of its own two probabilities (THEORY.md §6, online_em.h).
  kCellEm,
  /// A few kinds of cells learned from the whole map, each cell's kind a hidden variable
  /// of its filter (cell_kinds.h).
  kKinds,
};

struct MapperConfig {
  double resolution_m = 0.05;         ///< cell side, metres
  double time_step_s = 1.0;           ///< one HMM step, seconds of sensor time
  double p_hit_given_occ = 0.7;       ///< sensor model: a beam ends in an occupied cell
  double p_hit_given_free = 0.2;      ///< sensor model: a beam ends in a free cell
  /// Learn the sensor model online, shared by all cells (docs/online_learning.md, "The
  /// sensor model"): p_hit_given_occ / p_hit_given_free above are the start, worth
  /// sensor_model_prior_weight beam ends per state; every cell step then adds its hits and
  /// misses, weighed by the cell's state one observation later (fixed-lag smoothing). The
  /// model in use is always the one the start and the sums give (Mapper::sensor()); the
  /// flag says whether steps add to the sums. The static baseline (static_map) always
  /// weighs steps with the configured model: its clamp is chosen for it, and a learned
  /// near-perfect laser would make one miss clear a wall there. The
  /// node turns it on by default (~learn_sensor_model); off here, so the core's default is
  /// the fixed model of THEORY.md §1.
  bool learn_sensor_model = false;
  double sensor_model_prior_weight = 1000.0;
  /// The learned p_hit_given_occ and p_hit_given_free stay in [sensor_model_p_min,
  /// 1 - sensor_model_p_min], p_hit_given_occ at least 0.05 above p_hit_given_free.
  double sensor_model_p_min = 0.01;
  /// The chance that a step whose beams disagree (hits and misses in one step) comes from a
  /// cell they only partly cover, a wall's edge under the laser's range noise, rather than
  /// from the cell's state (ObservationModel; docs/online_learning.md, "Steps whose beams
  /// disagree"). 0 reads every step with the plain likelihoods of THEORY.md §1. The static
  /// baseline always reads them plainly. In [0, 0.5].
  double sensor_model_mixed_step_probability = 1e-3;
  /// Transition probabilities every cell starts with (per step); also the prior guess of
  /// online learning.
  TransitionParams prior_transitions{0.01, 0.01};
  /// Learn each cell's transitions online (THEORY.md §6); false keeps prior_transitions.
  bool learn_transitions = true;
  TransitionLearner learner = TransitionLearner::kKinds;
  /// learner kKinds: the kinds and how they are learned.
  KindsConfig kinds;
  OnlineEmConfig online_em;
  double initial_p_occ = 0.5;         ///< belief of a cell before its first observation
  LogOddsClamp static_clamp;          ///< clamping of the static baseline
  /// Beams without return (range >= range_max or +inf) clear cells up to this distance
  /// (and never beyond the scan's range_max); 0 ignores such beams.
  double max_free_range_m = 10.0;
  double origin_x_m = 0.0;            ///< world position of the lattice's cell (0, 0) corner
  double origin_y_m = 0.0;
  /// Fixed bounds: only [origin, origin + size) is mapped and nothing grows.
  bool fixed_bounds = false;
  double width_m = 0.0;               ///< fixed bounds only
  double height_m = 0.0;              ///< fixed bounds only
  /// A growing map stays inside origin +- max_map_size_m / 2 along each axis.
  double max_map_size_m = 1000.0;

  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

enum class ScanStatus {
  kIntegrated,
  kRejectedInvalid,        ///< malformed scan (see ScanResult::error)
  kRejectedTimeBackwards,  ///< stamp in a step before the one being gathered
};

struct ScanResult {
  ScanStatus status = ScanStatus::kIntegrated;
  std::string error;                 ///< why a scan was rejected
  std::size_t beams_hit = 0;         ///< finite range in [range_min, range_max)
  std::size_t beams_no_return = 0;   ///< range >= range_max or +inf: free space only
  std::size_t beams_ignored = 0;     ///< NaN, -inf, < range_min
  std::size_t cells_outside = 0;     ///< beam cells beyond the map's bounds, dropped
};

/// The running sums of online sensor-model learning (MapperConfig::learn_sensor_model):
/// per state (0 = occ, 1 = free), the expected number of beam ends (hits + misses) and of
/// hits in cells of that state, without the prior's pseudo-counts.
struct SensorModelStats {
  double trials[2] = {0.0, 0.0};
  double hits[2] = {0.0, 0.0};
};

/// What Mapper::applyOfflineEm did.
struct OfflineEmApplied {
  std::size_t cells_applied = 0;
  std::size_t cells_not_in_map = 0;  ///< in the result, never observed by this map: skipped
};

class Mapper {
 public:
  /// Throws std::invalid_argument for a bad configuration.
  explicit Mapper(const MapperConfig& config);
  /// A checkpoint: the whole state, except that the copy records nothing
  /// (recordObservations).
  Mapper(const Mapper& other);
  Mapper(Mapper&&) = default;
  Mapper& operator=(const Mapper&) = delete;
  Mapper& operator=(Mapper&&) = default;
  ~Mapper() = default;

  /// Takes `rebuilt`'s whole state: a checkpoint of this mapper that has mapped the scans
  /// since again (CorrectedMapping's re-mapping when it takes a correction). This mapper's
  /// recorder stays (what it recorded stays too), every tile counts as written
  /// (tileVersions), and takeChangedCells() covers both maps.
  void adopt(Mapper&& rebuilt);
  /// Bumped by every change made other than by integrate() and finishStep() (the setters,
  /// restoring, offline EM, a clock restart): a checkpoint with another revision does not
  /// hold the mapper's settings.
  std::uint64_t settingsRevision() const { return settings_revision_; }

  const MapperConfig& config() const { return config_; }
  /// The sensor model in use: the configured one, or with learn_sensor_model the one
  /// learned up to the last applied step.
  const ObservationModel& sensor() const { return sensor_; }
  /// learn_sensor_model's running sums (all zero while it is off).
  const SensorModelStats& sensorModelStats() const { return sensor_stats_; }
  const StepClock& clock() const { return clock_; }
  const CellGrid& grid() const { return grid_; }
  /// learner kKinds: the kinds learned so far.
  const CellKinds& kinds() const { return kinds_; }
  /// A bump for every tile whose cells this mapper wrote (steps, restored cells, set
  /// transitions; every tile for applyOfflineEm): what LayerTileCache needs to stay exact.
  const TileVersions& tileVersions() const { return tile_versions_; }

  /// Adds a scan's evidence to the step its stamp falls in; applies the previous step first
  /// when the scan starts a new one. A rejected scan changes nothing.
  ScanResult integrate(const Scan& scan);
  /// Applies the step being gathered now (end of the data; nothing to do if none).
  void finishStep();

  /// The last step applied to the grid: maps show the state at the end of this step.
  std::optional<std::int64_t> lastAppliedStep() const { return last_applied_step_; }
  /// The step scans are being gathered into.
  std::optional<std::int64_t> gatheringStep() const { return gathering_step_; }
  /// p(occ) of cell (x, y) at `step` (>= its last update: predicted in closed form), NaN if
  /// the cell was never observed.
  double beliefAt(std::int32_t x, std::int32_t y, std::int64_t step) const;
  /// Cells changed by steps applied since the last call.
  CellBox takeChangedCells();
  /// From now on, every applied cell step is also added to `recorder` (offline EM input);
  /// nullptr stops. The recorder must outlive its use here.
  void recordObservations(SequenceBuilder* recorder) { recorder_ = recorder; }
  /// The recorder in use (recordObservations), nullptr if none.
  SequenceBuilder* recorder() const { return recorder_; }

  /// Time restarted (a bag played again, a simulator reset): applies the step being
  /// gathered, then re-anchors the clock so that `stamp_s` falls in the step after the last
  /// applied one. The map is kept; unobserved time between the two is not counted.
  void restartClockAt(double stamp_s);

  /// Applies recorded evidence (sequences recorded by recordObservations with this mapper's
  /// configuration, steps in this mapper's time) as if the scans behind it were integrated
  /// again: each cell's observations, in order, through the step the scans went through, and
  /// the mapper's last applied step becomes the newest step among them (at least the old
  /// one). Cells are independent here, so a map's cells can be rebuilt in separate mappers
  /// (sharded offline EM, scripts/dask_offline_em.py) and merged bit for bit. Needs a mapper
  /// that gathers no step and learns nothing online (learn_transitions and
  /// learn_sensor_model off: those couple the cells); throws std::logic_error otherwise,
  /// std::invalid_argument (the map unchanged) for an observation in a step already
  /// applied or a cell outside the map's limits.
  void replayObservations(const ObservationSequences& sequences);

  /// Uses an offline EM result (sequences recorded with this mapper's geometry) for the
  /// cells it covers that this map has observed: their transitions become the learned ones,
  /// and the online statistics restart from them with the weight of the steps the result
  /// saw (capped at the online memory 1 / learning_rate_floor), so online learning goes on
  /// from there. With `use_final_beliefs` (the sequences are this map's own history, as in
  /// process_bag) each cell's belief also becomes the offline filter's at its last step. A
  /// sensor model the result learned (OfflineEmConfig::learn_sensor_model) becomes the
  /// mapper's: its sums replace the online ones (sensorModelStats), the configured start and
  /// the static baseline stay. With learner kKinds a cell keeps its kind posterior (its
  /// state follows the final belief) and shows the offline transitions until its next
  /// observed step, when its kinds' summary takes over again.
  OfflineEmApplied applyOfflineEm(const ObservationSequences& sequences, const OfflineEmResult& result,
                                  bool use_final_beliefs);

  /// Fixes the transitions cell (x, y) uses from now on, observed yet or not (the true
  /// parameters of a simulated world, or offline EM results learned on another recording):
  /// an observed cell's belief is first carried to the last applied step with the old ones.
  /// Meant for learn_transitions = false; with learning on, the online M-step replaces them
  /// at the cell's next observed step (and they also predict the gap before it). Throws std::invalid_argument for invalid parameters
  /// or a cell outside the map's limits.
  void setCellTransitions(std::int32_t x, std::int32_t y, const TransitionParams& params);

  /// A new sensor model while mapping (dynamic_reconfigure): every step applied from now on,
  /// the one being gathered included, weighs its hit and miss counts with it; cells keep
  /// their beliefs. Throws std::invalid_argument (and changes nothing) unless both are in
  /// (0, 1) with p_hit_given_occ > p_hit_given_free. With learn_sensor_model they are the
  /// new start: the sums learned so far are dropped.
  void setSensorModel(double p_hit_given_occ, double p_hit_given_free);
  /// How steps whose beams disagree are read from now on (MapperConfig::
  /// sensor_model_mixed_step_probability). Model files do not hold it: whoever loads one
  /// sets the reader's own. Throws std::invalid_argument (and changes nothing) outside [0, 0.5].
  void setMixedStepProbability(double mixed_step_probability);
  /// How much a cell's reading changes with the view from now on
  /// (KindsConfig::view_switch_probability; model files do not hold it: whoever loads one
  /// sets the reader's own). Throws std::invalid_argument (and changes nothing) outside
  /// [0, 0.5).
  void setViewSwitchProbability(double view_switch_probability);
  /// Turns online learning of the sensor model on or off while mapping. Off: the model
  /// learned so far stays in use, fixed; on again: learning goes on from its sums.
  void setLearnSensorModel(bool learn_sensor_model) {
    config_.learn_sensor_model = learn_sensor_model;
    ++settings_revision_;
  }
  /// Turns online learning of the transitions on or off while mapping. Off: each cell goes
  /// on with the transitions it has learned so far (fixed from now on); on again: learning
  /// resumes from the cell's statistics as they were when it was turned off.
  void setLearnTransitions(bool learn_transitions) {
    config_.learn_transitions = learn_transitions;
    ++settings_revision_;
  }

  /// Model loading (model_io.h): the saved time, on a mapper that has integrated nothing.
  /// Throws std::logic_error otherwise, std::invalid_argument for inconsistent values.
  void restoreTime(std::optional<double> clock_origin_s, std::optional<std::int64_t> last_applied_step);
  /// Model loading: the whole saved state of cell (x, y) (last_step at or before the last
  /// applied step). Throws std::invalid_argument for a cell outside the map or bad values.
  void restoreCell(std::int32_t x, std::int32_t y, const CellState& state);
  /// Model loading: learn_sensor_model's saved sums; the sensor model becomes the one they
  /// give. Throws std::invalid_argument for negative or non-finite sums, or hits above trials.
  void restoreSensorModelStats(const SensorModelStats& stats);
  /// Model loading: the kinds' saved sums and the transitions learned from them. Throws
  /// std::invalid_argument for negative or non-finite sums or transitions out of bounds.
  void restoreKinds(const CellKinds::Sums& sums, const std::array<TransitionParams, kKindCount>& transitions) {
    kinds_.restore(sums, transitions);
    ++settings_revision_;
  }

 private:
  void applyGatheredStep();
  void learnStep(CellGrid::Tile& tile, int offset, std::int32_t step, double evidence);
  /// learner kKinds: the cell's joint posterior over (kind, state), stored in em_stats.
  void learnKindsStep(CellGrid::Tile& tile, int offset, std::int32_t step, const KindEvidence& evidence,
                      double view_change);
  void addKindsSensorEvidence(const CellGrid::Tile& tile, int offset, std::int32_t step,
                              const KindEvidence& evidence, double view_change);
  /// How much the laser's view changed between a cell's last observed step and the step
  /// being applied, in [0, 1] (KindsConfig::view_switch_probability): the laser's motion
  /// between the two, in cells, at most 1; 1 when the last step is no longer remembered.
  double viewChangeSince(std::int32_t last_step) const;
  /// Writes a cell's statistics (as floats).
  void storeStats(CellGrid::Tile& tile, int offset, const TransitionStats& stats);
  /// learn_sensor_model: adds the previous observed step of a cell to the sums, weighed by
  /// its state given this step's evidence too.
  void addSensorEvidence(const CellGrid::Tile& tile, int offset, std::int32_t step, double evidence);
  void updateSensorModel();
  /// A beam's visit: one load and one store of the cell's Tile::scan_record.
  void markMiss(CellGrid::Tile& tile, int offset);
  void markHit(CellGrid::Tile& tile, int offset);
  void nextScanId();

  /// Cells touched in the step being gathered: per tile (in the order first touched) one
  /// bit per cell, so that the step visits each tile's cells in memory order, one tile after
  /// the other (beams cross the same tiles again and again; their order is not the cells').
  struct TouchedTile {
    CellGrid::Tile* tile;
    std::array<std::uint64_t, CellGrid::kTileCells / 64> cells;
  };
  void addTouched(CellGrid::Tile& tile, int offset);
  /// One touched cell's step: its gathered counts to applyCellEvidence.
  void applyCellStep(CellGrid::Tile& tile, int i, std::int32_t step);
  /// One cell's step with `hits` and `misses`: the filter or the learner, the static
  /// baseline, the record.
  void applyCellEvidence(CellGrid::Tile& tile, int i, std::int32_t step, std::uint32_t hits, std::uint32_t misses);

  MapperConfig config_;
  ObservationModel sensor_;
  /// The configured sensor model (p_hit_given_* of the config), which the static baseline
  /// (log_odds) always uses: a learned model does not change what static_map means.
  ObservationModel static_sensor_;
  StepClock clock_;
  CellGrid grid_;
  std::optional<std::int64_t> gathering_step_;
  std::optional<std::int64_t> last_applied_step_;
  std::vector<TouchedTile> touched_tiles_;
  std::uint32_t scan_id_ = 0;
  CellBox changed_cells_;
  TileVersions tile_versions_;
  SequenceBuilder* recorder_ = nullptr;
  CellKinds kinds_;
  SensorModelStats sensor_stats_;
  /// The laser's motion since the first scan, in cells: its path plus kViewRadiusM times its
  /// turns (viewChangeSince), and at which step it was, for the last kMotionSteps steps.
  double motion_cells_ = 0.0;
  std::optional<Pose2D> last_laser_pose_;
  static constexpr std::int32_t kMotionSteps = 4096;
  /// The slot of `step` in the two arrays below; a model file may hold steps before its
  /// clock's origin (negative), which have a slot too.
  static std::size_t motionSlot(std::int32_t step) {
    return static_cast<std::size_t>(((step % kMotionSteps) + kMotionSteps) % kMotionSteps);
  }
  std::vector<double> motion_at_step_ = std::vector<double>(kMotionSteps, 0.0);
  std::vector<std::int32_t> motion_step_ = std::vector<std::int32_t>(kMotionSteps, kNeverObserved);
  std::uint64_t settings_revision_ = 0;
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
