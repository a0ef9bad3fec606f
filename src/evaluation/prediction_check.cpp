#include "dynamic_occupancy_grid/evaluation/prediction_check.h"

#include <algorithm>
#include <limits>
#include <optional>
#include <stdexcept>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/core/cell/offline_em.h"

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

double ratio(std::size_t numerator, std::size_t denominator) {
  return denominator == 0 ? kNaN : static_cast<double>(numerator) / static_cast<double>(denominator);
}

struct Label {
  std::int32_t step;
  std::int32_t x;
  std::int32_t y;
  bool occupied;
};

// What one replay did. Two replays of the same scans through the same configuration agree
// on all of it; a difference means the replay is not repeatable and the labels of the first
// pass do not belong to the maps of the second.
struct ReplayTally {
  std::size_t scans = 0;
  std::size_t integrated = 0;
  std::size_t rejected = 0;
  std::size_t beams_hit = 0;
  std::size_t beams_no_return = 0;
  std::size_t beams_ignored = 0;
  std::size_t cells_outside = 0;
  std::optional<std::int64_t> last_applied_step;
  std::string last_rejection;

  void add(const core::ScanResult& result) {
    ++scans;
    if (result.status != core::ScanStatus::kIntegrated) {
      ++rejected;
      last_rejection = result.error;
      return;
    }
    ++integrated;
    beams_hit += result.beams_hit;
    beams_no_return += result.beams_no_return;
    beams_ignored += result.beams_ignored;
    cells_outside += result.cells_outside;
  }
  bool sameAs(const ReplayTally& other) const {
    return scans == other.scans && integrated == other.integrated && rejected == other.rejected &&
           beams_hit == other.beams_hit && beams_no_return == other.beams_no_return &&
           beams_ignored == other.beams_ignored && cells_outside == other.cells_outside &&
           last_applied_step == other.last_applied_step;
  }
  std::string describe() const {
    return std::to_string(scans) + " scans (" + std::to_string(integrated) + " integrated, " +
           std::to_string(beams_hit) + " beams hit) up to step " +
           (last_applied_step ? std::to_string(*last_applied_step) : std::string("none"));
  }
};

void addPrediction(PredictionScore& score, double p_occ, bool occupied) {
  const double truth = occupied ? 1.0 : 0.0;
  score.brier_sum += (p_occ - truth) * (p_occ - truth);
  if (p_occ > 0.5) {
    ++(occupied ? score.occupied_predicted_occupied : score.free_predicted_occupied);
  } else if (p_occ < 0.5) {
    ++(occupied ? score.occupied_predicted_free : score.free_predicted_free);
  } else {
    ++score.unclassified;
  }
}

// `mapper` holds the map after the label's origin step.
void scoreLabel(const core::Mapper& mapper, const Label& label, HorizonScore& horizon) {
  ++horizon.labels;
  const std::optional<core::CellState> cell = mapper.grid().cell(label.x, label.y);
  if (!cell) {
    ++horizon.unseen;
    return;
  }
  if (label.occupied) ++horizon.occupied_labels;
  addPrediction(horizon.dynamic_model, mapper.beliefAt(label.x, label.y, label.step), label.occupied);
  addPrediction(horizon.static_model, core::logOddsToProbability(cell->log_odds), label.occupied);
}

}  // namespace

std::size_t PredictionScore::classified() const {
  return occupied_predicted_occupied + occupied_predicted_free + free_predicted_occupied + free_predicted_free;
}

double PredictionScore::accuracy() const {
  return ratio(occupied_predicted_occupied + free_predicted_free, classified());
}

double PredictionScore::occupiedAccuracy() const {
  return ratio(occupied_predicted_occupied, occupied_predicted_occupied + occupied_predicted_free);
}

double PredictionScore::freeAccuracy() const {
  return ratio(free_predicted_free, free_predicted_free + free_predicted_occupied);
}

double PredictionScore::brier() const {
  return scored() == 0 ? kNaN : brier_sum / static_cast<double>(scored());
}

PredictionCheckResult checkPredictions(const core::MapperConfig& config, const ScanReplay& replay,
                                       const std::vector<std::int64_t>& horizons_steps,
                                       const ScoredMap& scored_map) {
  config.validate();
  if (!replay) throw std::invalid_argument("checkPredictions: no scan replay given");
  if (horizons_steps.empty()) throw std::invalid_argument("checkPredictions: no horizon given");
  for (const std::int64_t horizon : horizons_steps) {
    if (horizon < 0) {
      throw std::invalid_argument("checkPredictions: horizons must be >= 0 steps, got " + std::to_string(horizon));
    }
  }

  // Pass 1: the labels. Which cells a scan hits or misses does not depend on the
  // transitions, so this mapper skips learning, which would only cost time.
  core::MapperConfig labelling_config = config;
  labelling_config.learn_transitions = false;
  core::Mapper labelling(labelling_config);
  core::SequenceBuilder recorder;
  labelling.recordObservations(&recorder);
  ReplayTally first;
  replay([&](const core::Scan& scan) { first.add(labelling.integrate(scan)); });
  labelling.finishStep();
  labelling.recordObservations(nullptr);
  first.last_applied_step = labelling.lastAppliedStep();
  if (first.integrated == 0) {
    std::string message = "checkPredictions: no scan could be integrated (" + std::to_string(first.scans) +
                          " handed out";
    if (first.rejected > 0) message += ", all rejected; the last because: " + first.last_rejection;
    throw std::runtime_error(message + ")");
  }

  PredictionCheckResult result;
  result.steps = *first.last_applied_step + 1;
  result.scans_integrated = first.integrated;
  result.scans_rejected = first.rejected;
  result.last_rejection = first.last_rejection;
  const core::ObservationSequences sequences = recorder.build();
  result.observed_cells = sequences.cellCount();
  result.observed_cell_steps = sequences.observationCount();
  std::vector<Label> labels;
  labels.reserve(sequences.observationCount());
  for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
    const core::CellXY xy = sequences.cell(c);
    for (const core::StepObservation* o = sequences.begin(c); o != sequences.end(c); ++o) {
      if (o->hits == o->misses) {
        ++result.tied_cell_steps;
        continue;
      }
      labels.push_back(Label{o->step, xy.x, xy.y, o->hits > o->misses});
    }
  }
  // Pass 2 walks the labels in step order; stable keeps the order reproducible.
  std::stable_sort(labels.begin(), labels.end(), [](const Label& a, const Label& b) { return a.step < b.step; });

  // Pass 2: map again and score. cursor[k]: the first label of horizon k not scored yet;
  // labels before step h have no origin in the data and are never scored at horizon h.
  result.horizons.resize(horizons_steps.size());
  std::vector<std::size_t> cursor(horizons_steps.size());
  for (std::size_t k = 0; k < horizons_steps.size(); ++k) {
    const std::int64_t horizon = horizons_steps[k];
    result.horizons[k].horizon_steps = horizon;
    cursor[k] = static_cast<std::size_t>(
        std::lower_bound(labels.begin(), labels.end(), horizon,
                         [](const Label& label, std::int64_t step) { return label.step < step; }) -
        labels.begin());
  }
  core::Mapper own(config);
  // Scores, with `mapper` as it is now, every label not scored yet whose origin step s - h
  // is before `end_origin` (all of them without one). The caller guarantees that the map is
  // the map after each of those origins.
  const auto score_until = [&](const core::Mapper& mapper, std::optional<std::int64_t> end_origin) {
    for (std::size_t k = 0; k < horizons_steps.size(); ++k) {
      const std::int64_t horizon = horizons_steps[k];
      while (cursor[k] < labels.size() &&
             (!end_origin || labels[cursor[k]].step - horizon < *end_origin)) {
        scoreLabel(mapper, labels[cursor[k]], result.horizons[k]);
        ++cursor[k];
      }
    }
  };
  ReplayTally second;
  replay([&](const core::Scan& scan) {
    if (scored_map) {
      ++second.scans;  // the replay's map: its results are the replay's
    } else {
      second.add(own.integrate(scan));
    }
    // The map changes only when the step being gathered is applied, i.e. within the
    // integrate() of a scan of a later step. After it the map is the map after every step
    // before the gathering one (the steps since the last applied step had no scans), so the
    // labels of all those origins are scored now. Checking after every scan costs
    // O(horizons) when there is nothing to score.
    const core::Mapper& mapper = scored_map ? scored_map() : own;
    if (const std::optional<std::int64_t> gathering = mapper.gatheringStep()) score_until(mapper, *gathering);
  });
  core::Mapper& mapper = scored_map ? scored_map() : own;
  mapper.finishStep();
  second.last_applied_step = mapper.lastAppliedStep();
  const bool same = scored_map ? second.scans == first.scans && second.last_applied_step == first.last_applied_step
                               : second.sameAs(first);
  if (!same) {
    throw std::runtime_error("checkPredictions: the scan replay is not repeatable: the first pass saw " +
                             first.describe() + ", the second " + second.describe());
  }
  // The final map is the map after its last step and after every later origin.
  score_until(mapper, std::nullopt);
  return result;
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
