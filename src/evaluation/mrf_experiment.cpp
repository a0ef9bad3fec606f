#include "dynamic_occupancy_grid/evaluation/mrf_experiment.h"

#include "dynamic_occupancy_grid/core/common/parallel.h"

#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>

#include "dynamic_occupancy_grid/evaluation/evaluation.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

struct SquaredErrors {
  double p_occ_given_free = 0.0;
  double p_free_given_occ = 0.0;
  std::size_t cells = 0;

  TransitionRmse rmse() const {
    if (cells == 0) return TransitionRmse{};
    const auto n = static_cast<double>(cells);
    return TransitionRmse{std::sqrt(p_occ_given_free / n), std::sqrt(p_free_given_occ / n), cells};
  }
};

// The online learners' mappers of a run, fed the scans the recorder gets.
struct OnlineLearner {
  std::unique_ptr<core::Mapper> mapper;
  double seconds = 0.0;
};

// The online learners of the experiment, and where each one's outcome and map go: each
// cell's own online EM (what it was before kinds became the default), and kinds of cells.
struct OnlineLearnerSetup {
  core::TransitionLearner learner;
  MrfOnlineOutcome MrfRepetition::*outcome;
  std::vector<core::TransitionParams> MrfMaps::*map;
};
const std::array<OnlineLearnerSetup, 2> kOnlineLearners{{
    {core::TransitionLearner::kCellEm, &MrfRepetition::online, &MrfMaps::online},
    {core::TransitionLearner::kKinds, &MrfRepetition::online_kinds, &MrfMaps::online_kinds},
}};

// The observations of a whole run, recorded as offline EM reads them (as trainOffline does),
// and the same scans into each online learner.
core::ObservationSequences recordRun(Simulation& simulation, const core::MapperConfig& mapper_config,
                               std::vector<OnlineLearner>& learners) {
  core::MapperConfig config = mapper_config;
  config.learn_transitions = false;  // only the observations matter here
  core::Mapper mapper(config);
  core::SequenceBuilder recorder;
  mapper.recordObservations(&recorder);
  const auto integrate = [](core::Mapper& into, const core::Scan& scan) {
    const core::ScanResult result = into.integrate(scan);
    if (result.status != core::ScanStatus::kIntegrated) {
      throw std::runtime_error("runMrfExperiment: scan rejected: " + result.error);
    }
  };
  for (std::int64_t t = 0; t < simulation.config().steps; ++t) {
    for (int k = 0; k < simulation.config().scans_per_step; ++k) {
      const core::Scan scan = simulation.scan(k);
      integrate(mapper, scan);
      for (OnlineLearner& learner : learners) {
        const auto start = std::chrono::steady_clock::now();
        integrate(*learner.mapper, scan);
        learner.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      }
    }
    simulation.advance();
  }
  mapper.finishStep();
  for (OnlineLearner& learner : learners) {
    const auto start = std::chrono::steady_clock::now();
    learner.mapper->finishStep();
    learner.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  mapper.recordObservations(nullptr);
  return recorder.build();
}

// An online learner's transitions of the recorded cells (in their order), as its cells'
// filters use them, scored.
MrfOnlineOutcome scoreOnline(const OnlineLearner& learner, const core::ObservationSequences& sequences,
                             const World& world, std::size_t sparse_below,
                             std::vector<core::TransitionParams>* params) {
  params->clear();
  params->reserve(sequences.cellCount());
  for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
    const core::CellXY xy = sequences.cell(c);
    const std::optional<core::CellState> cell = learner.mapper->grid().cell(xy.x, xy.y);
    if (!cell || cell->last_step == core::kNeverObserved) {
      throw std::logic_error("runMrfExperiment: an online learner did not observe a recorded cell");
    }
    params->push_back(core::TransitionParams{cell->p_occ_given_free, cell->p_free_given_occ});
  }
  MrfOnlineOutcome outcome;
  outcome.rmse = transitionRmse(sequences, *params, world, sparse_below);
  outcome.rmse_by_kind = transitionRmseByKind(sequences, *params, world, sparse_below);
  outcome.rmse_changing_by_data = changingRmseBySeenStates(sequences, *params, world, sparse_below);
  if (learner.mapper->config().learner == core::TransitionLearner::kKinds) {
    const core::CellKinds& kinds = learner.mapper->kinds();
    for (int k = 0; k < core::kKindCount; ++k) {
      outcome.kinds.push_back(MrfLearnedKind{kinds.transitions(k), kinds.weight(k)});
    }
  }
  outcome.seconds = learner.seconds;
  return outcome;
}

MrfEmOutcome runEm(const core::ObservationSequences& sequences, const core::ObservationModel& sensor,
                   const core::OfflineEmConfig& config, const World& world, std::size_t sparse_below,
                   std::vector<core::TransitionParams>* params) {
  const auto start = std::chrono::steady_clock::now();
  core::OfflineEmResult result = core::runOfflineEm(sequences, sensor, config);
  MrfEmOutcome outcome;
  outcome.em_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  outcome.rmse = transitionRmse(sequences, result.params, world, sparse_below);
  outcome.rmse_by_kind = transitionRmseByKind(sequences, result.params, world, sparse_below);
  outcome.rmse_changing_by_data = changingRmseBySeenStates(sequences, result.params, world, sparse_below);
  // objective holds the value before the first M-step and after each one.
  outcome.em_iterations = static_cast<int>(result.objective.size()) - 1;
  outcome.objective = std::move(result.objective);
  outcome.newton_iterations = std::move(result.mrf_newton_iterations);
  *params = std::move(result.params);
  return outcome;
}

struct Run {
  MrfRepetition repetition;
  MrfMaps maps;
};

Run runRepetition(const ScenarioConfig& scenario, const MrfExperimentConfig& config, int repetition) {
  Run run;
  // Derived as the accuracy experiment derives its seeds: nearby (seed, repetition) pairs
  // give unrelated runs.
  run.repetition.world_seed = mixSeed(config.seed * 1000003ULL + static_cast<std::uint64_t>(repetition));
  run.repetition.run_seed = mixSeed(run.repetition.world_seed ^ 0x6d7266ULL);  // "mrf": its own stream
  Simulation simulation(scenario, run.repetition.world_seed, run.repetition.run_seed);
  const core::MapperConfig mapper_config = evaluationMapperConfig(scenario);
  // The online learners: the package's defaults on the scenario's geometry and sensor
  // model, but the learner (kOnlineLearners).
  std::vector<OnlineLearner> learners(kOnlineLearners.size());
  for (std::size_t l = 0; l < learners.size(); ++l) {
    core::MapperConfig learner_config = mapper_config;
    learner_config.learn_transitions = true;
    learner_config.learner = kOnlineLearners[l].learner;
    learners[l].mapper = std::make_unique<core::Mapper>(learner_config);
  }
  const core::ObservationSequences sequences = recordRun(simulation, mapper_config, learners);
  run.repetition.cells_observed = sequences.cellCount();
  run.repetition.square_cells_both_states = squareCellsSeenInBothStates(sequences, simulation.mrfSquaresLayout());
  const core::ObservationModel sensor(mapper_config.p_hit_given_occ, mapper_config.p_hit_given_free,
                                mapper_config.sensor_model_mixed_step_probability);

  core::OfflineEmConfig em_config = evaluationOfflineEmConfig(mapper_config);
  em_config.initial_params = core::TransitionParams{0.5, 0.5};  // the paper's starting point
  em_config.max_iterations = config.max_iterations;
  std::vector<core::TransitionParams> plain;
  run.repetition.plain = runEm(sequences, sensor, em_config, simulation.world(), config.sparse_below, &plain);
  em_config.mrf_temperature = config.temperature;
  std::vector<core::TransitionParams> mrf;
  run.repetition.mrf = runEm(sequences, sensor, em_config, simulation.world(), config.sparse_below, &mrf);
  std::vector<std::vector<core::TransitionParams>> online(learners.size());
  for (std::size_t l = 0; l < learners.size(); ++l) {
    run.repetition.*kOnlineLearners[l].outcome =
        scoreOnline(learners[l], sequences, simulation.world(), config.sparse_below, &online[l]);
  }

  if (repetition == 0) {
    const World& world = simulation.world();
    MrfMaps& maps = run.maps;
    maps.width = world.width();
    maps.height = world.height();
    const std::size_t size = world.occupancy().size();
    constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
    maps.observed_steps.assign(size, 0);
    maps.plain.assign(size, core::TransitionParams{kNaN, kNaN});
    maps.mrf.assign(size, core::TransitionParams{kNaN, kNaN});
    for (const OnlineLearnerSetup& setup : kOnlineLearners) {
      (maps.*setup.map).assign(size, core::TransitionParams{kNaN, kNaN});
    }
    maps.truth.resize(size);
    for (std::size_t i = 0; i < size; ++i) {
      const core::CellXY c = world.cellOf(i);
      maps.truth[i] = world.truth(c.x, c.y);
    }
    for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
      const core::CellXY xy = sequences.cell(c);
      const std::size_t i = world.index(xy.x, xy.y);
      maps.observed_steps[i] = static_cast<std::uint32_t>(sequences.end(c) - sequences.begin(c));
      maps.plain[i] = plain[c];
      maps.mrf[i] = mrf[c];
      for (std::size_t l = 0; l < kOnlineLearners.size(); ++l) (maps.*kOnlineLearners[l].map)[i] = online[l][c];
    }
  }
  return run;
}

// Whether cell `c` of `sequences` has a step with more hits than misses and one with more
// misses than hits.
bool seenInBothStates(const core::ObservationSequences& sequences, std::size_t c) {
  bool hits = false;
  bool misses = false;
  for (const core::StepObservation* o = sequences.begin(c); o != sequences.end(c); ++o) {
    hits = hits || o->hits > o->misses;
    misses = misses || o->misses > o->hits;
  }
  return hits && misses;
}

// The RMSE over the cells for which `include(index, cell)` holds, split by observed steps;
// a parameter not scored is NaN.
template <typename Include>
SplitRmse splitRmse(const core::ObservationSequences& sequences, const std::vector<core::TransitionParams>& learned,
                    const World& world, std::size_t sparse_below, const Include& include,
                    bool score_occ_given_free = true, bool score_free_given_occ = true) {
  if (learned.size() != sequences.cellCount()) {
    throw std::invalid_argument("transitionRmse: " + std::to_string(learned.size()) + " learned parameters for " +
                                std::to_string(sequences.cellCount()) + " cells");
  }
  SquaredErrors sparse;
  SquaredErrors well_observed;
  for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
    const core::CellXY xy = sequences.cell(c);
    if (!world.inside(xy.x, xy.y)) {
      throw std::invalid_argument("transitionRmse: cell (" + std::to_string(xy.x) + ", " + std::to_string(xy.y) +
                                  ") is outside the world");
    }
    if (!include(c, xy)) continue;
    const core::TransitionParams truth = world.truth(xy.x, xy.y);
    const auto observed = static_cast<std::size_t>(sequences.end(c) - sequences.begin(c));
    SquaredErrors& errors = observed < sparse_below ? sparse : well_observed;
    const double e_of = learned[c].p_occ_given_free - truth.p_occ_given_free;
    const double e_fo = learned[c].p_free_given_occ - truth.p_free_given_occ;
    errors.p_occ_given_free += e_of * e_of;
    errors.p_free_given_occ += e_fo * e_fo;
    ++errors.cells;
  }
  SplitRmse split{sparse.rmse(), well_observed.rmse()};
  constexpr double kNotScored = std::numeric_limits<double>::quiet_NaN();
  for (TransitionRmse* e : {&split.sparse, &split.well_observed}) {
    if (!score_occ_given_free) e->p_occ_given_free = kNotScored;
    if (!score_free_given_occ) e->p_free_given_occ = kNotScored;
  }
  return split;
}

}  // namespace

SplitRmse transitionRmse(const core::ObservationSequences& sequences,
                         const std::vector<core::TransitionParams>& learned, const World& world,
                         std::size_t sparse_below) {
  return splitRmse(sequences, learned, world, sparse_below, [](std::size_t, const core::CellXY&) { return true; });
}

CellKind cellKind(const World& world, std::int32_t x, std::int32_t y) {
  if (!world.inside(x, y)) {
    throw std::invalid_argument("cellKind: cell (" + std::to_string(x) + ", " + std::to_string(y) +
                                ") is outside the world");
  }
  const core::TransitionParams truth = world.truth(x, y);
  if (truth.p_occ_given_free != 0.0 || truth.p_free_given_occ != 0.0) return CellKind::kChanging;
  return world.occupied(x, y) ? CellKind::kStaticOccupied : CellKind::kStaticFree;
}

const char* cellKindName(CellKind kind) {
  switch (kind) {
    case CellKind::kStaticFree:
      return "static_free";
    case CellKind::kStaticOccupied:
      return "static_occupied";
    case CellKind::kChanging:
      return "changing";
  }
  return "unknown";
}

bool isScored(CellKind kind, bool occ_given_free) {
  switch (kind) {
    case CellKind::kChanging:
      return true;
    case CellKind::kStaticFree:
      return occ_given_free;
    case CellKind::kStaticOccupied:
      return !occ_given_free;
  }
  return false;
}

std::array<SplitRmse, kCellKinds> transitionRmseByKind(const core::ObservationSequences& sequences,
                                                        const std::vector<core::TransitionParams>& learned,
                                                        const World& world, std::size_t sparse_below) {
  std::array<SplitRmse, kCellKinds> by_kind;
  for (std::size_t k = 0; k < kCellKinds; ++k) {
    const auto kind = static_cast<CellKind>(k);
    by_kind[k] = splitRmse(
        sequences, learned, world, sparse_below,
        [&](std::size_t, const core::CellXY& xy) { return cellKind(world, xy.x, xy.y) == kind; }, isScored(kind, true),
        isScored(kind, false));
  }
  return by_kind;
}

std::array<SplitRmse, 2> changingRmseBySeenStates(const core::ObservationSequences& sequences,
                                                  const std::vector<core::TransitionParams>& learned,
                                                  const World& world, std::size_t sparse_below) {
  std::array<SplitRmse, 2> by_data;
  for (const bool both : {true, false}) {
    by_data[both ? 0 : 1] =
        splitRmse(sequences, learned, world, sparse_below, [&](std::size_t c, const core::CellXY& xy) {
          return cellKind(world, xy.x, xy.y) == CellKind::kChanging && seenInBothStates(sequences, c) == both;
        });
  }
  return by_data;
}

std::array<std::size_t, 4> squareCellsSeenInBothStates(const core::ObservationSequences& sequences,
                                                       const MrfSquaresLayout& layout) {
  std::array<std::size_t, 4> both{};
  for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
    const core::CellXY xy = sequences.cell(c);
    for (std::size_t k = 0; k < layout.square_corner.size(); ++k) {
      const core::CellXY corner = layout.square_corner[k];
      if (xy.x < corner.x || xy.y < corner.y || xy.x >= corner.x + layout.square_side_cells ||
          xy.y >= corner.y + layout.square_side_cells) {
        continue;
      }
      if (seenInBothStates(sequences, c)) ++both[k];
    }
  }
  return both;
}

void MrfExperimentConfig::validate() const {
  if (repetitions <= 0) throw std::invalid_argument("runMrfExperiment: repetitions must be positive");
  if (!(temperature >= core::kMinMrfTemperature) || !std::isfinite(temperature)) {
    throw std::invalid_argument("runMrfExperiment: temperature must be finite and >= 1e-9 (as offline EM's)");
  }
  if (sparse_below == 0) throw std::invalid_argument("runMrfExperiment: sparse_below must be positive");
  if (max_iterations <= 0 || max_iterations > std::numeric_limits<std::uint16_t>::max()) {
    throw std::invalid_argument("runMrfExperiment: max_iterations must be in [1, 65535]");
  }
}

MrfExperimentResult runMrfExperiment(const ScenarioConfig& scenario, const MrfExperimentConfig& config,
                                     const std::function<void(int done)>& progress) {
  scenario.validate();
  config.validate();
  const auto start = std::chrono::steady_clock::now();
  std::vector<Run> runs(static_cast<std::size_t>(config.repetitions));
  core::runRepetitions(
      runs.size(), config.threads,
      [&](std::size_t r) { runs[r] = runRepetition(scenario, config, static_cast<int>(r)); }, progress);
  MrfExperimentResult result;
  result.first_maps = std::move(runs.front().maps);
  for (Run& run : runs) result.repetitions.push_back(std::move(run.repetition));
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
