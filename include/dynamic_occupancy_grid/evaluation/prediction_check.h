#pragma once
// Self-supervised check of a map's predictions on a recording without ground truth: how well
// the map after step t predicts what the scans of step t + h observe, for the dynamic model
// (each cell's HMM belief predicted to t + h in closed form, THEORY.md §3) and for the static
// baseline (the same mapper's log-odds grid), with the accuracy of THEORY.md §9 and the
// Brier score. Users tune parameters on their own bags with it (check_bag).
//
// Definitions (one "label" = one cell in one step):
//   - Label: the hits and misses the scans of step s put in cell c (the Mapper's fusion:
//     one reading per scan and cell, a hit wins over a miss of the same scan). Occupied if
//     hits > misses, free if misses > hits; a tie carries no majority and is not a label.
//     One label per cell and step, not one per reading, because the HMM's state is one per
//     step, and so that a cell swept by many scans of one step does not count more than a
//     cell seen once. Labels depend only on the geometry (resolution, time step, free range,
//     poses), not on the sensor model or the transitions: runs that differ only in those are
//     scored on the same labels.
//   - Horizon h >= 0 steps: the label of step s is scored against the map after step
//     u = s - h, i.e. the map that has integrated exactly the scans of steps <= u. Labels
//     with u < 0 (before the first step) are not scored at this horizon. Steps without scans
//     are origins too: the map after such a step is the map after the last step with scans,
//     so every label with s - h >= 0 is scored exactly once per horizon, gaps or not.
//     h = 0 scores the map on the very scans it has just integrated (a fit, not a forecast).
//   - Dynamic prediction: Mapper::beliefAt(x, y, s) on the map after step u. Static
//     prediction: logOddsToProbability(log_odds) of the same cell of the same map.
//   - Unseen: a label whose cell the map after step u has never observed. Both models know
//     nothing there (the same map, so the same cells): unseen labels are counted, and left
//     out of both models' scores.
//   - Accuracy (THEORY.md §9): p > 0.5 predicts occupied, p < 0.5 free, p == 0.5 is not
//     classified; correct / classified. Brier score: mean of (p - y)^2 over the scored
//     labels, y = 1 occupied, 0 free (0 is perfect, 0.25 is what p = 0.5 everywhere gets).
//
// Cost: two replays of the scans (the first records the labels, the second maps again and
// scores), one sort of the labels by step, then O(1) per label and horizon: nothing is done
// per map cell or per step.
//
// ROS-free: standard library only.

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/grid/scan.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

/// Receives the scans of a recording one by one, in order.
using ScanConsumer = std::function<void(const core::Scan&)>;
/// Hands every scan of a recording to the consumer, in recording order. checkPredictions
/// calls it twice; both calls must hand out the same scans.
using ScanReplay = std::function<void(const ScanConsumer&)>;

/// How one model (dynamic or static) did on the scored labels of one horizon.
struct PredictionScore {
  std::size_t occupied_predicted_occupied = 0;
  std::size_t occupied_predicted_free = 0;
  std::size_t free_predicted_occupied = 0;
  std::size_t free_predicted_free = 0;
  std::size_t unclassified = 0;  ///< p == 0.5 exactly: no class (THEORY.md §9)
  double brier_sum = 0.0;        ///< sum of (p - y)^2 over all scored labels

  /// Labels with a class (p != 0.5).
  std::size_t classified() const;
  /// Scored labels (classified or not).
  std::size_t scored() const { return classified() + unclassified; }
  /// Correct / classified; NaN when nothing was classified.
  double accuracy() const;
  /// Of the occupied labels: the fraction classified occupied; NaN if there is none.
  double occupiedAccuracy() const;
  /// Of the free labels: the fraction classified free; NaN if there is none.
  double freeAccuracy() const;
  /// brier_sum / scored(); NaN when nothing was scored.
  double brier() const;
};

/// The result of one horizon.
struct HorizonScore {
  std::int64_t horizon_steps = 0;
  std::size_t labels = 0;           ///< labels with s - h >= 0
  std::size_t unseen = 0;           ///< of those, on a cell the map after s - h never observed
  std::size_t occupied_labels = 0;  ///< of the scored (not unseen) labels, the occupied ones
  PredictionScore dynamic_model;    ///< Mapper::beliefAt predicted to the label's step
  PredictionScore static_model;     ///< the log-odds baseline of the same cell

  /// labels - unseen: the labels both models are scored on.
  std::size_t scored() const { return labels - unseen; }
};

struct PredictionCheckResult {
  /// One entry per requested horizon, in the order requested.
  std::vector<HorizonScore> horizons;
  std::int64_t steps = 0;                 ///< steps of the recording (last applied step + 1)
  std::size_t scans_integrated = 0;       ///< per replay
  std::size_t scans_rejected = 0;         ///< per replay (invalid, or time going backwards)
  std::string last_rejection;             ///< why the last rejected scan was rejected
  std::size_t observed_cell_steps = 0;    ///< cells with hits or misses, summed over steps
  std::size_t tied_cell_steps = 0;        ///< of those, hits == misses: no label
  std::size_t observed_cells = 0;         ///< distinct cells observed at least once
};

/// The map the replay keeps itself, to be scored in the second replay instead of one that
/// checkPredictions builds from the scans (check_bag --pose-correction: the corrected
/// mapping's Mapper, which maps the last seconds' scans again when it takes a correction).
/// Called after the consumer has seen each scan; the map returned must have integrated
/// that scan by then, and have `config`'s geometry.
using ScoredMap = std::function<core::Mapper&()>;

/// Replays the scans twice through Mappers built from `config`: the first time to record
/// every cell's hits and misses per step (the labels), the second time to map again and score
/// each horizon's labels against the map as it was h steps before them (definitions above),
/// as it was once that step was applied. With `scored_map`, the second replay scores that
/// map instead (see ScoredMap; checkPredictions applies its last step).
/// Throws std::invalid_argument for a bad config, an empty `replay` function, no horizon or a
/// negative one; std::runtime_error if no scan could be integrated (the message says how
/// many were handed out and why the last was rejected) or if the second replay handed out
/// other scans than the first. Exceptions of `replay` pass through.
PredictionCheckResult checkPredictions(const core::MapperConfig& config, const ScanReplay& replay,
                                       const std::vector<std::int64_t>& horizons_steps,
                                       const ScoredMap& scored_map = nullptr);

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
