#include "dynamic_occupancy_grid/evaluation/learning_experiment.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <stdexcept>

#include "dynamic_occupancy_grid/core/common/parallel.h"
#include "dynamic_occupancy_grid/evaluation/evaluation.h"

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

void require(bool ok, const std::string& message) {
  if (!ok) throw std::invalid_argument("learning experiment: " + message);
}

constexpr core::LogOddsClamp kUnclamped{-1e6, 1e6};
// map_server's trinary thresholds (its defaults): what a planner sees.
constexpr double kFreeThreshold = 0.196;
constexpr double kOccupiedThreshold = 0.65;
constexpr double kChangingThreshold = 0.05;

int trinary(double p) {
  if (std::isnan(p)) return -1;
  if (p < kFreeThreshold) return 0;
  if (p > kOccupiedThreshold) return 1;
  return -1;
}

enum class Reading { kBelief, kStaticClamped, kStaticUnclamped };

struct MethodMapper {
  std::string name;
  std::unique_ptr<core::Mapper> mapper;
  Reading reading = Reading::kBelief;
  bool has_transitions = true;
};

double readCell(const MethodMapper& method, const core::CellState& cell, std::int64_t now) {
  switch (method.reading) {
    case Reading::kStaticClamped:
    case Reading::kStaticUnclamped:
      return core::logOddsToProbability(cell.log_odds);
    case Reading::kBelief:
      break;
  }
  const core::TransitionParams params{cell.p_occ_given_free, cell.p_free_given_occ};
  return core::predictOccupancy(cell.p_occ, params, now - cell.last_step);
}

std::string kindName(const core::TransitionParams& truth, bool occupied) {
  if (truth.isStatic()) return occupied ? "static occupied" : "static free";
  char text[64];
  std::snprintf(text, sizeof(text), "%.3g / %.3g", truth.p_occ_given_free, truth.p_free_given_occ);
  return text;
}

// Everything one repetition measures, per method.
struct KindSamples {
  core::TransitionParams truth;
  std::vector<double> p_of;
  std::vector<double> p_fo;
  std::array<double, core::kKindCount> most_probable_kind{};  // cells per most probable kind
};
struct MethodRun {
  double accuracy_all = 0.0;
  double accuracy_changing = 0.0;
  std::map<std::string, Accuracy> accuracy_by_kind;
  std::map<std::string, KindSamples> kinds;
  double dynamic_mae = 0.0;
  double retention = 0.0;
  double static_occupied_changing = 0.0;
  double static_free_changing = 0.0;
  double static_occupied_cells = 0.0;
  double static_free_cells = 0.0;
  double p_hit_given_occ = 0.0;
  double p_hit_given_free = 0.0;
  bool learns_kinds = false;
  std::array<core::TransitionParams, core::kKindCount> kind_transitions{};
  std::array<double, core::kKindCount> kind_weights{};
};
struct RepetitionRun {
  std::vector<MethodRun> methods;
  double laser_hits[2] = {0.0, 0.0};    // hits on occupied / free cells
  double laser_trials[2] = {0.0, 0.0};  // hits + misses
};

RepetitionRun runRepetition(const ScenarioConfig& scenario, const LearningExperimentConfig& config, int repetition) {
  const std::uint64_t world_seed = mixSeed(config.seed * 1000003ULL + static_cast<std::uint64_t>(repetition) + 0x5041ULL);
  core::MapperConfig base = evaluationMapperConfig(scenario);
  base.learn_sensor_model = config.learn_sensor_model;

  ScenarioConfig training_scenario = scenario;
  training_scenario.redraw_at_step = -1;
  Simulation training(training_scenario, world_seed, mixSeed(world_seed ^ 0x7261696eULL));
  core::OfflineEmConfig offline_config = evaluationOfflineEmConfig(base);
  offline_config.learn_sensor_model = config.learn_sensor_model;
  const OfflineTraining offline = trainOffline(training, base, scenario.steps, offline_config);

  Simulation simulation(scenario, world_seed, mixSeed(world_seed ^ 0x6576616cULL));
  const World& world = simulation.world();

  std::vector<MethodMapper> methods;
  const auto add = [&](const std::string& name, core::MapperConfig mapper_config, Reading reading, bool transitions) {
    methods.push_back(MethodMapper{name, std::make_unique<core::Mapper>(mapper_config), reading, transitions});
  };
  core::MapperConfig fixed = base;
  fixed.learn_transitions = false;
  add("static", fixed, Reading::kStaticClamped, false);
  if (config.node_defaults) {
    // What a user gets who sets nothing about the sensor: the package's start (0.7 / 0.2),
    // learned by the default learner, against the static_map that start gives.
    core::MapperConfig node = base;
    node.p_hit_given_occ = core::MapperConfig{}.p_hit_given_occ;
    node.p_hit_given_free = core::MapperConfig{}.p_hit_given_free;
    node.learn_sensor_model = true;
    core::MapperConfig node_static = node;
    node_static.learn_transitions = false;
    add("node_static", node_static, Reading::kStaticClamped, false);
    add("node_default", node, Reading::kBelief, true);
  }
  core::MapperConfig unclamped = fixed;
  unclamped.static_clamp = kUnclamped;
  add("textbook", unclamped, Reading::kStaticUnclamped, false);
  add("learning_off", fixed, Reading::kBelief, true);
  for (const LearnerVariant& variant : config.variants) {
    core::MapperConfig learner = base;
    learner.learn_transitions = true;
    if (variant.configure) variant.configure(learner);
    add(variant.name, learner, Reading::kBelief, true);
  }
  // Offline EM's own sensor model, learned with its transitions (or the configured one).
  core::MapperConfig offline_fixed = fixed;
  offline_fixed.learn_sensor_model = false;
  offline_fixed.p_hit_given_occ = offline.result.p_hit_given_occ;
  offline_fixed.p_hit_given_free = offline.result.p_hit_given_free;
  add("offline", offline_fixed, Reading::kBelief, true);
  add("oracle", fixed, Reading::kBelief, true);
  core::Mapper& offline_mapper = *methods[methods.size() - 2].mapper;
  core::Mapper& oracle_mapper = *methods.back().mapper;
  for (std::size_t i = 0; i < offline.sequences.cellCount(); ++i) {
    const core::CellXY c = offline.sequences.cell(i);
    offline_mapper.setCellTransitions(c.x, c.y, offline.result.params[i]);
  }
  for (std::int32_t y = 0; y < world.height(); ++y) {
    for (std::int32_t x = 0; x < world.width(); ++x) oracle_mapper.setCellTransitions(x, y, world.truth(x, y));
  }
  // The static and textbook grids read the same log-odds in every mapper; two extra
  // mappers keep the code uniform at the price of their traversal.

  const std::vector<std::size_t> dynamic = [&] {
    std::vector<std::size_t> cells;
    for (std::size_t i = 0; i < world.occupancy().size(); ++i) {
      if (!world.truth(world.cellOf(i).x, world.cellOf(i).y).isStatic()) cells.push_back(i);
    }
    return cells;
  }();
  // The laser's hit rates per true state: each observed cell step of a recorder against the
  // state the cell had in that step (static cells keep theirs; dynamic ones are logged).
  core::SequenceBuilder recorder;
  methods[0].mapper->recordObservations(&recorder);
  std::vector<std::vector<std::uint8_t>> dynamic_history;
  dynamic_history.reserve(static_cast<std::size_t>(scenario.steps));

  const auto window_start = static_cast<std::int64_t>(std::floor((1.0 - config.window_fraction) * scenario.steps));
  std::vector<Accuracy> all(methods.size());
  std::vector<Accuracy> changing(methods.size());
  std::vector<std::map<std::string, Accuracy>> by_kind(methods.size());
  std::vector<std::string> kind_of(world.occupancy().size());
  for (std::size_t i = 0; i < kind_of.size(); ++i) {
    const core::CellXY c = world.cellOf(i);
    kind_of[i] = kindName(world.truth(c.x, c.y), world.occupancy()[i] != 0);
  }
  std::vector<std::uint8_t> is_dynamic(world.occupancy().size(), 0);
  for (const std::size_t i : dynamic) is_dynamic[i] = 1;

  for (std::int64_t t = 0; t < scenario.steps; ++t) {
    std::vector<std::uint8_t> states;
    states.reserve(dynamic.size());
    for (const std::size_t i : dynamic) states.push_back(world.occupancy()[i]);
    dynamic_history.push_back(std::move(states));
    for (int k = 0; k < scenario.scans_per_step; ++k) {
      const core::Scan scan = simulation.scan(k);
      for (MethodMapper& method : methods) {
        const core::ScanResult result = method.mapper->integrate(scan);
        if (result.status != core::ScanStatus::kIntegrated)
          throw std::runtime_error("learning experiment: scan rejected: " + result.error);
      }
    }
    for (MethodMapper& method : methods) method.mapper->finishStep();
    if (t >= window_start) {
      for (std::size_t m = 0; m < methods.size(); ++m) {
        const core::CellGrid& grid = methods[m].mapper->grid();
        for (std::size_t i = 0; i < world.occupancy().size(); ++i) {
          const core::CellXY c = world.cellOf(i);
          const std::optional<core::CellState> cell = grid.cell(c.x, c.y);
          if (!cell) continue;
          const double p = readCell(methods[m], *cell, t);
          if (p == 0.5) continue;
          const bool right = (p > 0.5) == (world.occupancy()[i] != 0);
          ++all[m].classified;
          all[m].correct += right ? 1 : 0;
          Accuracy& kind = by_kind[m][kind_of[i]];
          ++kind.classified;
          kind.correct += right ? 1 : 0;
          if (is_dynamic[i] != 0) {
            ++changing[m].classified;
            changing[m].correct += right ? 1 : 0;
          }
        }
      }
    }
    simulation.advance();
  }
  methods[0].mapper->recordObservations(nullptr);

  RepetitionRun run;
  {
    const core::ObservationSequences sequences = recorder.build();
    std::vector<std::int64_t> dynamic_slot(world.occupancy().size(), -1);
    for (std::size_t d = 0; d < dynamic.size(); ++d) dynamic_slot[dynamic[d]] = static_cast<std::int64_t>(d);
    for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
      const core::CellXY xy = sequences.cell(c);
      const std::size_t i = world.index(xy.x, xy.y);
      for (const core::StepObservation* o = sequences.begin(c); o != sequences.end(c); ++o) {
        const bool occupied = dynamic_slot[i] >= 0
                                  ? dynamic_history[static_cast<std::size_t>(o->step)][static_cast<std::size_t>(dynamic_slot[i])] != 0
                                  : world.occupancy()[i] != 0;
        const int state = occupied ? 0 : 1;
        run.laser_hits[state] += o->hits;
        run.laser_trials[state] += o->hits + o->misses;
      }
    }
  }

  const std::int64_t end = scenario.steps - 1;
  const core::Mapper& static_mapper = *methods[0].mapper;
  for (std::size_t m = 0; m < methods.size(); ++m) {
    MethodRun result;
    result.accuracy_all = all[m].value();
    result.accuracy_changing = changing[m].value();
    result.accuracy_by_kind = by_kind[m];
    result.p_hit_given_occ = methods[m].mapper->sensor().pHitGivenOcc();
    result.p_hit_given_free = methods[m].mapper->sensor().pHitGivenFree();
    const core::MapperConfig& mapper_config = methods[m].mapper->config();
    result.learns_kinds = mapper_config.learn_transitions && mapper_config.learner == core::TransitionLearner::kKinds;
    if (result.learns_kinds) {
      for (int k = 0; k < core::kKindCount; ++k) {
        result.kind_transitions[k] = methods[m].mapper->kinds().transitions(k);
        result.kind_weights[k] = methods[m].mapper->kinds().weight(k);
      }
    }
    double kept = 0.0;
    double classified = 0.0;
    double dynamic_error = 0.0;
    double dynamic_cells = 0.0;
    for (std::size_t i = 0; i < world.occupancy().size(); ++i) {
      const core::CellXY c = world.cellOf(i);
      const std::optional<core::CellState> cell = methods[m].mapper->grid().cell(c.x, c.y);
      if (!cell) continue;
      if (cell->last_step < end - config.left_for_steps) {
        const std::optional<core::CellState> reference = static_mapper.grid().cell(c.x, c.y);
        const int expected = trinary(core::logOddsToProbability(reference->log_odds));
        if (expected >= 0) {
          classified += 1.0;
          kept += trinary(readCell(methods[m], *cell, end)) == expected ? 1.0 : 0.0;
        }
      }
      if (!methods[m].has_transitions) continue;
      const core::TransitionParams truth = world.truth(c.x, c.y);
      const bool occupied = world.occupancy()[i] != 0;
      KindSamples& kind = result.kinds[kindName(truth, occupied)];
      kind.truth = truth;
      kind.p_of.push_back(cell->p_occ_given_free);
      kind.p_fo.push_back(cell->p_free_given_occ);
      if (result.learns_kinds) {
        int most_probable = 0;
        for (int k = 1; k < core::kKindCount; ++k) {
          const double p_k = cell->em_stats[2 * k] + cell->em_stats[2 * k + 1];
          const double p_best = cell->em_stats[2 * most_probable] + cell->em_stats[2 * most_probable + 1];
          if (p_k > p_best) most_probable = k;
        }
        kind.most_probable_kind[most_probable] += 1.0;
      }
      if (truth.isStatic()) {
        const double leave = occupied ? cell->p_free_given_occ : cell->p_occ_given_free;
        (occupied ? result.static_occupied_cells : result.static_free_cells) += 1.0;
        if (leave > kChangingThreshold) (occupied ? result.static_occupied_changing : result.static_free_changing) += 1.0;
      } else {
        dynamic_error += 0.5 * (std::abs(cell->p_occ_given_free - truth.p_occ_given_free) +
                                std::abs(cell->p_free_given_occ - truth.p_free_given_occ));
        dynamic_cells += 1.0;
      }
    }
    result.retention = classified > 0.0 ? kept / classified : 0.0;
    result.dynamic_mae = dynamic_cells > 0.0 ? dynamic_error / dynamic_cells : 0.0;
    run.methods.push_back(std::move(result));
  }
  return run;
}

double median(std::vector<double> values) {
  if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
  const auto middle = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), middle, values.end());
  return *middle;
}

}  // namespace

std::vector<LearnerVariant> defaultLearnerVariants() {
  const auto cell_em = [](core::MapperConfig& c) { c.learner = core::TransitionLearner::kCellEm; };
  return {
      {"default", {}},
      {"cell_em", cell_em},
  };
}

const MethodScore& LearningExperimentResult::method(const std::string& name) const {
  for (const MethodScore& score : methods) {
    if (score.method == name) return score;
  }
  throw std::invalid_argument("learning experiment: no method " + name);
}

LearningExperimentResult runLearningExperiment(const ScenarioConfig& scenario, const LearningExperimentConfig& config,
                                               const std::function<void(int done)>& progress) {
  scenario.validate();
  require(config.repetitions > 0, "repetitions must be positive");
  require(config.window_fraction > 0.0 && config.window_fraction <= 1.0, "window_fraction must be in (0, 1]");
  require(config.left_for_steps >= 0, "left_for_steps must be >= 0");
  for (const LearnerVariant& variant : config.variants) {
    require(!variant.name.empty(), "a learner variant needs a name");
  }
  const auto start = std::chrono::steady_clock::now();
  const auto repetitions = static_cast<std::size_t>(config.repetitions);
  std::vector<RepetitionRun> runs(repetitions);
  core::runRepetitions(
      repetitions, config.threads, [&](std::size_t r) { runs[r] = runRepetition(scenario, config, static_cast<int>(r)); },
      progress);

  LearningExperimentResult result;
  result.scenario = scenario.name;
  std::vector<std::string> names{"static"};
  if (config.node_defaults) {
    names.push_back("node_static");
    names.push_back("node_default");
  }
  names.push_back("textbook");
  names.push_back("learning_off");
  for (const LearnerVariant& variant : config.variants) names.push_back(variant.name);
  names.push_back("offline");
  names.push_back("oracle");
  double hits[2] = {0.0, 0.0};
  double trials[2] = {0.0, 0.0};
  for (const RepetitionRun& run : runs) {
    for (int s = 0; s < 2; ++s) {
      hits[s] += run.laser_hits[s];
      trials[s] += run.laser_trials[s];
    }
  }
  result.laser_hit_rate_occ = trials[0] > 0.0 ? hits[0] / trials[0] : 0.0;
  result.laser_hit_rate_free = trials[1] > 0.0 ? hits[1] / trials[1] : 0.0;
  const double n = static_cast<double>(runs.size());
  for (std::size_t m = 0; m < names.size(); ++m) {
    MethodScore score;
    score.method = names[m];
    std::map<std::string, KindSamples> pooled;
    std::map<std::string, Accuracy> pooled_accuracy;
    for (const RepetitionRun& run : runs) {
      const MethodRun& r = run.methods[m];
      for (const auto& [kind, accuracy] : r.accuracy_by_kind) {
        pooled_accuracy[kind].correct += accuracy.correct;
        pooled_accuracy[kind].classified += accuracy.classified;
      }
      score.accuracy_all.push_back(r.accuracy_all);
      score.accuracy_changing.push_back(r.accuracy_changing);
      score.dynamic_mae.push_back(r.dynamic_mae);
      score.retention.push_back(r.retention);
      score.static_occupied_changing += r.static_occupied_changing / n;
      score.static_free_changing += r.static_free_changing / n;
      score.static_occupied_cells += r.static_occupied_cells / n;
      score.static_free_cells += r.static_free_cells / n;
      score.p_hit_given_occ += r.p_hit_given_occ / n;
      score.p_hit_given_free += r.p_hit_given_free / n;
      if (r.learns_kinds) {
        score.kind_transitions.push_back(r.kind_transitions);
        score.kind_weights.push_back(r.kind_weights);
      }
      for (const auto& [kind, samples] : r.kinds) {
        KindSamples& into = pooled[kind];
        into.truth = samples.truth;
        into.p_of.insert(into.p_of.end(), samples.p_of.begin(), samples.p_of.end());
        into.p_fo.insert(into.p_fo.end(), samples.p_fo.begin(), samples.p_fo.end());
        for (int k = 0; k < core::kKindCount; ++k) into.most_probable_kind[k] += samples.most_probable_kind[k];
      }
    }
    for (const auto& [kind, accuracy] : pooled_accuracy) score.accuracy_by_kind[kind] = accuracy.value();
    for (const auto& [kind, samples] : pooled) {
      KindScore k;
      k.kind = kind;
      k.truth = samples.truth;
      k.cells = static_cast<double>(samples.p_of.size()) / n;
      for (std::size_t i = 0; i < samples.p_of.size(); ++i) {
        k.mae_p_occ_given_free += std::abs(samples.p_of[i] - samples.truth.p_occ_given_free);
        k.mae_p_free_given_occ += std::abs(samples.p_fo[i] - samples.truth.p_free_given_occ);
      }
      if (!samples.p_of.empty()) {
        k.mae_p_occ_given_free /= static_cast<double>(samples.p_of.size());
        k.mae_p_free_given_occ /= static_cast<double>(samples.p_of.size());
      }
      k.median_p_occ_given_free = median(samples.p_of);
      k.median_p_free_given_occ = median(samples.p_fo);
      for (int kind = 0; kind < core::kKindCount; ++kind) {
        k.most_probable_kind[kind] =
            samples.p_of.empty() ? 0.0 : samples.most_probable_kind[kind] / static_cast<double>(samples.p_of.size());
      }
      score.kinds.push_back(k);
    }
    result.methods.push_back(std::move(score));
  }
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
