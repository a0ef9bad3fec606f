#include "dynamic_occupancy_grid/evaluation/evaluation.h"

#include "dynamic_occupancy_grid/core/common/parallel.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

// A clamp the textbook grid never reaches: log-odds of 1e6 is p = 1 in any float.
constexpr core::LogOddsClamp kUnclamped{-1e6, 1e6};

core::MapperConfig fixedTransitions(core::MapperConfig config) {
  config.learn_transitions = false;
  config.static_clamp = kUnclamped;
  return config;
}

}  // namespace

std::string methodName(Method method) {
  switch (method) {
    case Method::kStatic:
      return "static";
    case Method::kStaticUnclamped:
      return "static_unclamped";
    case Method::kOnline:
      return "online";
    case Method::kOffline:
      return "offline";
    case Method::kOracle:
      return "oracle";
  }
  return "unknown";
}

core::MapperConfig evaluationMapperConfig(const ScenarioConfig& scenario) {
  core::MapperConfig config;
  config.resolution_m = scenario.resolution_m;
  config.time_step_s = scenario.time_step_s;
  config.p_hit_given_occ = scenario.p_hit_given_occ;
  config.p_hit_given_free = scenario.p_hit_given_free;
  config.origin_x_m = 0.0;
  config.origin_y_m = 0.0;
  config.fixed_bounds = true;
  config.width_m = scenario.width_cells * scenario.resolution_m;
  config.height_m = scenario.height_cells * scenario.resolution_m;
  return config;
}

core::OfflineEmConfig evaluationOfflineEmConfig(const core::MapperConfig& mapper_config) {
  core::OfflineEmConfig config;
  config.initial_p_occ = mapper_config.initial_p_occ;
  config.prior = mapper_config.prior_transitions;
  // The tools' default (ros_layer::kDefaultOfflinePriorWeight): with maximum likelihood a
  // cell seen only free learns p_free_given_occ at the upper bound.
  config.prior_weight = 2.0;
  config.p_min = mapper_config.online_em.p_min;
  config.p_max = mapper_config.online_em.p_max;
  config.symmetric = mapper_config.online_em.symmetric;
  config.threads = 1;
  return config;
}

OfflineTraining trainOffline(Simulation& training, const core::MapperConfig& mapper_config, std::int64_t steps,
                             const core::OfflineEmConfig& em_config) {
  core::MapperConfig config = mapper_config;
  config.learn_transitions = false;  // only the observations matter here
  config.learn_sensor_model = false;  // offline EM starts from the configured sensor model
  core::Mapper mapper(config);
  core::SequenceBuilder recorder;
  mapper.recordObservations(&recorder);
  for (std::int64_t t = 0; t < steps; ++t) {
    for (int k = 0; k < training.config().scans_per_step; ++k) {
      const core::ScanResult result = mapper.integrate(training.scan(k));
      if (result.status != core::ScanStatus::kIntegrated)
        throw std::runtime_error("trainOffline: scan rejected: " + result.error);
    }
    training.advance();
  }
  mapper.finishStep();
  mapper.recordObservations(nullptr);
  OfflineTraining training_result;
  training_result.sequences = recorder.build();
  training_result.result = core::runOfflineEm(training_result.sequences, mapper.sensor(), em_config);
  return training_result;
}

MethodMappers::MethodMappers(const core::MapperConfig& base, const World& world)
    : online_([&] {
        core::MapperConfig config = base;
        config.learn_transitions = true;
        return config;
      }()),
      offline_(fixedTransitions(base)),
      oracle_(fixedTransitions(base)) {
  const auto fits = [&](const core::Mapper& mapper) {
    const core::MapperConfig& c = mapper.config();
    return c.fixed_bounds && c.origin_x_m == 0.0 && c.origin_y_m == 0.0 && c.resolution_m == world.resolution() &&
           std::llround(c.width_m / c.resolution_m) == world.width() &&
           std::llround(c.height_m / c.resolution_m) == world.height();
  };
  if (!fits(online_)) {
    throw std::invalid_argument("MethodMappers: the mapper must have fixed bounds on the world (origin 0, same "
                                "resolution and size; see evaluationMapperConfig)");
  }
}

void MethodMappers::setOffline(const OfflineTraining& training) {
  for (std::size_t i = 0; i < training.sequences.cellCount(); ++i) {
    const core::CellXY c = training.sequences.cell(i);
    offline_.setCellTransitions(c.x, c.y, training.result.params[i]);
  }
}

void MethodMappers::setOracle(const World& world) {
  for (std::int32_t y = 0; y < world.height(); ++y) {
    for (std::int32_t x = 0; x < world.width(); ++x) oracle_.setCellTransitions(x, y, world.truth(x, y));
  }
}

void MethodMappers::integrate(const core::Scan& scan) {
  for (core::Mapper* mapper : {&online_, &offline_, &oracle_}) {
    const core::ScanResult result = mapper->integrate(scan);
    if (result.status != core::ScanStatus::kIntegrated)
      throw std::runtime_error("MethodMappers: scan rejected: " + result.error);
  }
}

void MethodMappers::finishStep() {
  for (core::Mapper* mapper : {&online_, &offline_, &oracle_}) mapper->finishStep();
}

const core::Mapper& MethodMappers::mapper(Method method) const {
  switch (method) {
    case Method::kStatic:
    case Method::kOnline:
      return online_;
    case Method::kOffline:
      return offline_;
    case Method::kStaticUnclamped:
    case Method::kOracle:
      return oracle_;
  }
  throw std::invalid_argument("MethodMappers: unknown method");
}

double MethodMappers::belief(Method method, std::int32_t x, std::int32_t y) const {
  const core::Mapper& source = mapper(method);
  const std::optional<core::CellState> cell = source.grid().cell(x, y);
  if (!cell) return std::numeric_limits<double>::quiet_NaN();
  if (method == Method::kStatic || method == Method::kStaticUnclamped)
    return core::logOddsToProbability(cell->log_odds);
  const core::TransitionParams params{cell->p_occ_given_free, cell->p_free_given_occ};
  const std::int64_t now = source.lastAppliedStep().value_or(cell->last_step);
  return core::predictOccupancy(cell->p_occ, params, now - cell->last_step);
}

std::optional<core::TransitionParams> MethodMappers::transitions(Method method, std::int32_t x, std::int32_t y) const {
  if (method == Method::kStatic || method == Method::kStaticUnclamped) {
    throw std::invalid_argument("MethodMappers::transitions: " + methodName(method) + " has no transitions");
  }
  const std::optional<core::CellState> cell = mapper(method).grid().cell(x, y);
  if (!cell) return std::nullopt;
  return core::TransitionParams{cell->p_occ_given_free, cell->p_free_given_occ};
}

Accuracy accuracyOf(const MethodMappers& mappers, Method method, const World& world,
                    const std::vector<std::uint8_t>* defined) {
  if (defined != nullptr && defined->size() != world.occupancy().size()) {
    throw std::invalid_argument("accuracyOf: the mask must have one entry per cell of the world");
  }
  Accuracy accuracy;
  for (std::int32_t y = 0; y < world.height(); ++y) {
    for (std::int32_t x = 0; x < world.width(); ++x) {
      if (defined != nullptr && (*defined)[world.index(x, y)] == 0) continue;
      const double p = mappers.belief(method, x, y);
      if (std::isnan(p) || p == 0.5) continue;  // never observed, or exactly 0.5: not classified
      ++accuracy.classified;
      if ((p > 0.5) == world.occupied(x, y)) ++accuracy.correct;
    }
  }
  return accuracy;
}

ParameterError parameterErrorOf(const MethodMappers& mappers, Method method, const World& world) {
  ParameterError error;
  for (std::int32_t y = 0; y < world.height(); ++y) {
    for (std::int32_t x = 0; x < world.width(); ++x) {
      const std::optional<core::TransitionParams> learned = mappers.transitions(method, x, y);
      if (!learned) continue;
      const core::TransitionParams truth = world.truth(x, y);
      const double e_of = std::abs(learned->p_occ_given_free - truth.p_occ_given_free);
      const double e_fo = std::abs(learned->p_free_given_occ - truth.p_free_given_occ);
      if (truth.isStatic()) {
        error.static_p_occ_given_free += e_of;
        error.static_p_free_given_occ += e_fo;
        ++error.static_cells;
      } else {
        error.dynamic_p_occ_given_free += e_of;
        error.dynamic_p_free_given_occ += e_fo;
        ++error.dynamic_cells;
      }
    }
  }
  if (error.static_cells > 0) {
    error.static_p_occ_given_free /= static_cast<double>(error.static_cells);
    error.static_p_free_given_occ /= static_cast<double>(error.static_cells);
  }
  if (error.dynamic_cells > 0) {
    error.dynamic_p_occ_given_free /= static_cast<double>(error.dynamic_cells);
    error.dynamic_p_free_given_occ /= static_cast<double>(error.dynamic_cells);
  }
  return error;
}

namespace {

struct Repetition {
  std::array<std::vector<double>, kAllMethods.size()> accuracy;
  ParameterError online_error;
  ParameterError offline_error;
};

Repetition runRepetition(const ScenarioConfig& scenario, std::uint64_t seed, int repetition) {
  const std::uint64_t world_seed = mixSeed(seed * 1000003ULL + static_cast<std::uint64_t>(repetition));
  const core::MapperConfig mapper_config = evaluationMapperConfig(scenario);

  // The offline method's a-priori training run: the same place (world seed) on another
  // day (run seed), as it was at the start (no re-draw), as long as the evaluation run.
  ScenarioConfig training_scenario = scenario;
  training_scenario.redraw_at_step = -1;
  Simulation training(training_scenario, world_seed, mixSeed(world_seed ^ 0x7261696eULL));
  const OfflineTraining offline =
      trainOffline(training, mapper_config, scenario.steps, evaluationOfflineEmConfig(mapper_config));

  Simulation simulation(scenario, world_seed, mixSeed(world_seed ^ 0x6576616cULL));
  MethodMappers mappers(mapper_config, simulation.world());
  mappers.setOffline(offline);
  mappers.setOracle(simulation.world());

  Repetition result;
  for (auto& series : result.accuracy) series.reserve(static_cast<std::size_t>(scenario.steps));
  const bool per_hour = scenario.kind == ScenarioKind::kParkingLot;
  std::vector<std::uint8_t> seen_this_hour(simulation.world().occupancy().size(), 0);
  const core::Mapper& observer = mappers.mapper(Method::kOracle);  // all mappers see the same cells
  for (std::int64_t t = 0; t < scenario.steps; ++t) {
    for (int k = 0; k < scenario.scans_per_step; ++k) mappers.integrate(simulation.scan(k));
    mappers.finishStep();
    if (per_hour) {
      if (t % scenario.steps_per_hour == 0) std::fill(seen_this_hour.begin(), seen_this_hour.end(), 0);
      for (std::size_t i = 0; i < seen_this_hour.size(); ++i) {
        const core::CellXY c = simulation.world().cellOf(i);
        const std::optional<core::CellState> cell = observer.grid().cell(c.x, c.y);
        if (cell && cell->last_step == t) seen_this_hour[i] = 1;
      }
    }
    for (std::size_t m = 0; m < kAllMethods.size(); ++m) {
      result.accuracy[m].push_back(
          accuracyOf(mappers, kAllMethods[m], simulation.world(), per_hour ? &seen_this_hour : nullptr).value());
    }
    simulation.advance();
    // The oracle knows the truth at all times, also after a re-draw.
    if (simulation.step() == scenario.redraw_at_step) mappers.setOracle(simulation.world());
  }
  result.online_error = parameterErrorOf(mappers, Method::kOnline, simulation.world());
  result.offline_error = parameterErrorOf(mappers, Method::kOffline, simulation.world());
  return result;
}

}  // namespace

AccuracyExperimentResult runAccuracyExperiment(const ScenarioConfig& scenario, const AccuracyExperimentConfig& config,
                                               const std::function<void(int done)>& progress) {
  scenario.validate();
  if (config.repetitions <= 0) throw std::invalid_argument("runAccuracyExperiment: repetitions must be positive");
  const auto start = std::chrono::steady_clock::now();
  const auto repetitions = static_cast<std::size_t>(config.repetitions);
  std::vector<Repetition> runs(repetitions);
  core::runRepetitions(
      repetitions, config.threads,
      [&](std::size_t r) { runs[r] = runRepetition(scenario, config.seed, static_cast<int>(r)); }, progress);

  AccuracyExperimentResult result;
  result.scenario = scenario.name;
  for (std::size_t m = 0; m < kAllMethods.size(); ++m) {
    for (Repetition& run : runs) result.accuracy[m].push_back(std::move(run.accuracy[m]));
  }
  for (const Repetition& run : runs) {
    result.online_error.push_back(run.online_error);
    result.offline_error.push_back(run.offline_error);
  }
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
