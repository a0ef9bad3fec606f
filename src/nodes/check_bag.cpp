// check_bag: a self-supervised check of the map on a bag without ground truth. For each
// horizon h, how well the map after each time step predicts the hits and misses of the scans
// h later: the dynamic model (beliefs predicted in closed form) against the static
// occupancy grid of the same mapper. Reads the bag twice (labels, then maps and scores;
// evaluation/prediction_check.h). At the end it also reports the map the second pass built:
// the sensor model in use (learned or fixed), the cells the static map classifies and how
// many of them the belief keeps (and the stationary and predicted layers), and the static walls
// learned as changing, edge cells apart. See docs/self_check.md.

#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <memory>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "bag_tools.h"
#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/core/pose/corrected_mapping.h"
#include "dynamic_occupancy_grid/core/layers/layers.h"
#include "dynamic_occupancy_grid/core/layers/map_export.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/evaluation/prediction_check.h"
#include "dynamic_occupancy_grid/ros/bag_offline_em.h"
#include "dynamic_occupancy_grid/ros/bag_scan_source.h"
#include "dynamic_occupancy_grid/ros/parameters.h"

namespace dog = dynamic_occupancy_grid;

namespace {

const std::vector<double> kDefaultHorizons_s{1.0, 5.0, 30.0, 60.0};
// The end-of-run report: map_server's trinary thresholds (its defaults, what a planner
// sees), and the change probability above which a cell counts as learned as changing
// (issue 17's 0.05).
constexpr double kFreeThreshold = 0.196;
constexpr double kOccupiedThreshold = 0.65;
constexpr double kChangingThreshold = 0.05;
constexpr double kDefaultRetentionAfter_s = 10.0;

struct Options {
  dog::bag_tools::SharedOptions shared;
  std::vector<double> horizons_s;
  std::vector<std::int64_t> horizons_steps;  ///< horizons_s in whole steps
  std::string csv_path;                      ///< empty: no CSV
  /// Retention is also reported on the cells last observed at least this long before the
  /// end (in whole steps).
  double retention_after_s = kDefaultRetentionAfter_s;
  std::int64_t retention_after_steps = 0;
  /// The end-of-run retention of the `predicted` layer looks this far ahead of the last step
  /// (the node's ~prediction_horizon by default; in whole steps).
  double prediction_horizon_s = dog::ros_layer::NodeParameters{}.prediction_horizon_s;
  std::int64_t prediction_horizon_steps = 0;
  /// --pose-correction rbpf: every pass corrects the scans' odometry poses the same way (its
  /// own filter and learner, deterministic) before the map being scored sees them.
  dog::bag_tools::PoseCorrectionOptions correction;
};

Options parseArguments(int argc, char** argv) {
  namespace cl = dog::command_line;
  namespace po = boost::program_options;
  Options options;
  dog::core::MapperConfig& mapper = options.shared.mapper;
  // The node's default: the sensor model is learned (~learn_sensor_model).
  mapper.learn_sensor_model = dog::ros_layer::kDefaultLearnSensorModel;
  bool no_learning = false;
  bool learn_sensor_model = false;
  bool no_learn_sensor_model = false;
  std::vector<std::string> bags;
  cl::CommandLine line("check_bag",
                       "usage: check_bag BAG [options]\n"
                       "How well the map after each time step predicts the scans of the bag h seconds later\n"
                       "(dynamic model and static map; accuracy and Brier score). See docs/self_check.md.\n");
  line.options().add_options()
      ("horizon", cl::numbers(&options.horizons_s, cl::between(0.0, 1.0e9))->value_name("S"),
       "prediction horizon in seconds, rounded to whole time steps; repeat for several (default 1, 5, 30, 60); "
       "0 scores the map on the scans it has just integrated")
      ("csv", cl::nonEmpty(&options.csv_path, "a file name")->value_name("FILE"), "also write the results as CSV")
      ("no-learning", po::bool_switch(&no_learning),
       "no online learning of the transitions: cells keep the prior transitions (the sensor model is still "
       "learned unless --no-learn-sensor-model)")
      ("learn-sensor-model", po::bool_switch(&learn_sensor_model),
       "learn p(hit | occupied) and p(hit | free) online, shared by all cells, from --p-hit-given-occ / "
       "--p-hit-given-free (default: on, as the node's ~learn_sensor_model)")
      ("no-learn-sensor-model", po::bool_switch(&no_learn_sensor_model),
       "keep the sensor model fixed at --p-hit-given-occ / --p-hit-given-free")
      ("retention-after", cl::number(&options.retention_after_s, cl::atLeast(0.0))->value_name("S"),
       "the end-of-run retention is also reported on the cells last observed at least S seconds before the "
       "end (default 10)")
      ("prediction-horizon", cl::number(&options.prediction_horizon_s, cl::between(0.0, 1.0e9))->value_name("S"),
       "the end-of-run retention of the 'predicted' layer looks S seconds ahead of the last step, rounded to "
       "whole steps (default 60, the node's ~prediction_horizon)");
  dog::bag_tools::addMappingOptions(line, &options.shared);
  dog::bag_tools::addPoseCorrectionOptions(line, &options.correction);
  // The options that tune offline EM are read (so that they are refused by name) but not
  // listed: check_bag runs no offline EM, which would learn the transitions from the very
  // scans the map is scored on.
  for (const std::string& name : dog::bag_tools::emOptionNames()) {
    line.hidden().add_options()(name.c_str(), po::value<std::string>());
  }
  line.hidden().add_options()("bag", po::value(&bags));
  line.positional("bag");
  const po::variables_map values = line.parse(argc, argv);
  for (const std::string& name : dog::bag_tools::emOptionNames()) {
    if (values.count(name) > 0) {
      line.fail("--" + name + " does not apply: check_bag runs no offline EM (it would learn from the scans it is "
                "scored on)");
    }
  }
  if (bags.empty()) line.fail("no bag given");
  if (bags.size() > 1) line.fail("more than one bag given");
  options.shared.source.bag_path = bags.front();
  if (learn_sensor_model && no_learn_sensor_model) {
    line.fail("--learn-sensor-model and --no-learn-sensor-model contradict each other");
  }
  if (learn_sensor_model) mapper.learn_sensor_model = true;
  if (no_learn_sensor_model) mapper.learn_sensor_model = false;
  if (no_learning) mapper.learn_transitions = false;
  dog::bag_tools::validateSharedOptions(line, &options.shared);
  dog::bag_tools::validatePoseCorrectionOptions(line, options.shared, &options.correction);
  if (options.horizons_s.empty()) options.horizons_s = kDefaultHorizons_s;
  const double time_step_s = options.shared.mapper.time_step_s;
  for (const double horizon_s : options.horizons_s) {
    const double steps = std::round(horizon_s / time_step_s);
    // Far beyond any recording (the mapper counts steps in 32 bits), and safe to convert.
    if (steps > 1.0e15) {
      std::ostringstream message;
      message << "--horizon " << horizon_s << " s is too many time steps of " << time_step_s << " s";
      line.fail(message.str());
    }
    if (horizon_s > 0.0 && steps == 0.0) {
      std::ostringstream message;
      message << "--horizon " << horizon_s << " s rounds to 0 steps of " << time_step_s
              << " s: that would score the map on its own scans (use 0 for that on purpose)";
      line.fail(message.str());
    }
    options.horizons_steps.push_back(static_cast<std::int64_t>(steps));
  }
  const double retention_steps = std::round(options.retention_after_s / time_step_s);
  if (retention_steps > 1.0e15) line.fail("--retention-after is too many time steps");
  options.retention_after_steps = static_cast<std::int64_t>(retention_steps);
  // As process_bag's --prediction-horizon (the node rounds ~prediction_horizon the same way).
  options.prediction_horizon_steps = std::llround(options.prediction_horizon_s / time_step_s);
  return options;
}

// A ratio for the table: fixed decimals, "-" when undefined (nothing to score).
std::string tableNumber(double value, int decimals) {
  if (std::isnan(value)) return "-";
  char text[32];
  std::snprintf(text, sizeof(text), "%.*f", decimals, value);
  return text;
}

// A ratio for the CSV: full precision, "nan" when undefined.
std::string csvNumber(double value) {
  if (std::isnan(value)) return "nan";
  char text[32];
  std::snprintf(text, sizeof(text), "%.10g", value);
  return text;
}

double fraction(std::size_t part, std::size_t whole) {
  return whole == 0 ? std::nan("") : static_cast<double>(part) / static_cast<double>(whole);
}

// The map the second pass built, at its last applied step.
struct EndOfRun {
  std::int64_t step = 0;               ///< last applied step
  double p_hit_given_occ = 0.0;        ///< the sensor model in use (learned or fixed)
  double p_hit_given_free = 0.0;
  dog::core::SensorModelStats sensor_stats;
  /// learner kinds: the kinds learned (transitions and shares).
  std::array<dog::core::TransitionParams, dog::core::kKindCount> kinds{};
  std::array<double, dog::core::kKindCount> kind_shares{};
  std::size_t observed_cells = 0;
  // The static map's classes (clamped log-odds; occupied > 0.65, free < 0.196), and of each
  // the cells the belief at the last step puts in the same class.
  std::size_t static_free = 0;
  std::size_t static_occupied = 0;
  std::size_t kept_free = 0;
  std::size_t kept_occupied = 0;
  // The same, on the cells last observed at least retention_after_steps before the end.
  std::size_t left_static_free = 0;
  std::size_t left_static_occupied = 0;
  std::size_t left_kept_free = 0;
  std::size_t left_kept_occupied = 0;
  // Of the static map's free / occupied cells, those the `stationary` layer (long-run p(occ))
  // and the `predicted` layer (prediction_horizon_steps after the last step) classify the
  // same way: the layers' own values (core::evaluateLayer), as the node publishes them.
  std::size_t stationary_kept_free = 0;
  std::size_t stationary_kept_occupied = 0;
  std::size_t predicted_kept_free = 0;
  std::size_t predicted_kept_occupied = 0;
  // Static-occupied cells with a static-free 8-neighbour (a wall's edge).
  std::size_t occupied_edge = 0;
  // Static-occupied cells with p_free_given_occ > 0.05 (walls learned as changing), and of
  // those the edge cells; static-free cells with p_occ_given_free > 0.05.
  std::size_t occupied_changing = 0;
  std::size_t occupied_changing_edge = 0;
  std::size_t free_changing = 0;
  // Of the walls learned as changing, those last observed at least retention_after_steps
  // before the end (of left_static_occupied).
  std::size_t left_occupied_changing = 0;
};

// map_server's trinary reading of a probability: 1 occupied, 0 free, -1 unknown (NaN too).
int trinary(double p) {
  if (p > kOccupiedThreshold) return 1;
  if (p < kFreeThreshold) return 0;
  return -1;
}

// The static map's class of cell (x, y); -1 for unknown or never observed.
int staticClass(const dog::core::CellGrid& grid, std::int32_t x, std::int32_t y) {
  const dog::core::CellGrid::Tile* tile = grid.findTile(x, y);
  if (tile == nullptr) return -1;
  const int i = dog::core::CellGrid::offsetOf(x, y);
  if (tile->last_step[i] == dog::core::kNeverObserved) return -1;
  return trinary(dog::core::logOddsToProbability(tile->log_odds[i]));
}

EndOfRun summarizeEnd(const dog::core::Mapper& mapper, std::int64_t retention_after_steps,
                      std::int64_t prediction_horizon_steps) {
  namespace core = dog::core;
  EndOfRun end;
  end.p_hit_given_occ = mapper.sensor().pHitGivenOcc();
  end.p_hit_given_free = mapper.sensor().pHitGivenFree();
  end.sensor_stats = mapper.sensorModelStats();
  for (int k = 0; k < core::kKindCount; ++k) {
    end.kinds[k] = mapper.kinds().transitions(k);
    end.kind_shares[k] = mapper.kinds().weight(k);
  }
  const std::optional<std::int64_t> last = mapper.lastAppliedStep();
  if (!last) return end;
  end.step = *last;
  const core::CellGrid& grid = mapper.grid();
  // The two layers over every cell that may hold data, row-major from box's lower-left cell.
  const core::CellBox box = grid.bounds();
  std::vector<float> stationary;
  std::vector<float> predicted;
  core::evaluateLayer(grid, core::Layer::kStationary, *last, 0, box, &stationary);
  core::evaluateLayer(grid, core::Layer::kPredicted, *last, prediction_horizon_steps, box, &predicted);
  const auto layer_class = [&box](const std::vector<float>& values, std::int32_t x, std::int32_t y) {
    const std::size_t index = static_cast<std::size_t>((std::int64_t{y} - box.min_y) * box.width() +
                                                       (std::int64_t{x} - box.min_x));
    return trinary(values[index]);  // NaN (never observed) is -1
  };
  grid.forEachTile([&](const core::CellGrid::Tile& tile) {
    for (int i = 0; i < core::CellGrid::kTileCells; ++i) {
      if (tile.last_step[i] == core::kNeverObserved) continue;
      ++end.observed_cells;
      const int expected = trinary(core::logOddsToProbability(tile.log_odds[i]));
      if (expected < 0) continue;
      const core::TransitionParams params{tile.p_occ_given_free[i], tile.p_free_given_occ[i]};
      // The belief layer at the last step: the cell's belief predicted over its gap.
      const double belief = core::predictOccupancy(tile.p_occ[i], params, *last - tile.last_step[i]);
      const bool kept = trinary(belief) == expected;
      const bool left = tile.last_step[i] <= *last - retention_after_steps;
      const std::int32_t x = tile.cellX(i);
      const std::int32_t y = tile.cellY(i);
      const bool stationary_kept = layer_class(stationary, x, y) == expected;
      const bool predicted_kept = layer_class(predicted, x, y) == expected;
      if (expected == 0) {
        ++end.static_free;
        end.kept_free += kept ? 1 : 0;
        end.stationary_kept_free += stationary_kept ? 1 : 0;
        end.predicted_kept_free += predicted_kept ? 1 : 0;
        if (left) {
          ++end.left_static_free;
          end.left_kept_free += kept ? 1 : 0;
        }
        if (params.p_occ_given_free > kChangingThreshold) ++end.free_changing;
        continue;
      }
      ++end.static_occupied;
      end.kept_occupied += kept ? 1 : 0;
      end.stationary_kept_occupied += stationary_kept ? 1 : 0;
      end.predicted_kept_occupied += predicted_kept ? 1 : 0;
      if (left) {
        ++end.left_static_occupied;
        end.left_kept_occupied += kept ? 1 : 0;
      }
      bool edge = false;
      for (int dy = -1; dy <= 1 && !edge; ++dy) {
        for (int dx = -1; dx <= 1 && !edge; ++dx) {
          if (dx != 0 || dy != 0) edge = staticClass(grid, x + dx, y + dy) == 0;
        }
      }
      end.occupied_edge += edge ? 1 : 0;
      if (params.p_free_given_occ > kChangingThreshold) {
        ++end.occupied_changing;
        end.occupied_changing_edge += edge ? 1 : 0;
        end.left_occupied_changing += left ? 1 : 0;
      }
    }
  });
  return end;
}

// "k of n (p%)".
std::string share(std::size_t part, std::size_t whole) {
  const double f = fraction(part, whole);
  return std::to_string(part) + " of " + std::to_string(whole) + " (" +
         (std::isnan(f) ? std::string("-") : tableNumber(100.0 * f, 1) + "%") + ")";
}

void printEnd(const EndOfRun& end, const Options& options) {
  const dog::core::MapperConfig& mapper = options.shared.mapper;
  std::printf("\nmap at the end (step %lld)\n", static_cast<long long>(end.step));
  if (mapper.learn_sensor_model) {
    std::printf("  sensor model: p_hit_given_occ %.4f, p_hit_given_free %.4f (learned from %.0f / %.0f beam ends "
                "in occupied / free cells, start %g / %g)\n",
                end.p_hit_given_occ, end.p_hit_given_free, end.sensor_stats.trials[0], end.sensor_stats.trials[1],
                mapper.p_hit_given_occ, mapper.p_hit_given_free);
  } else {
    std::printf("  sensor model: p_hit_given_occ %.4f, p_hit_given_free %.4f (fixed)\n", end.p_hit_given_occ,
                end.p_hit_given_free);
  }
  if (mapper.learn_transitions && mapper.learner == dog::core::TransitionLearner::kKinds) {
    std::printf("  kinds of cells (p_occ_given_free / p_free_given_occ per step, share of the cells):");
    for (int k = 0; k < dog::core::kKindCount; ++k) {
      std::printf("%s %.5f / %.5f, %.4f", k == 0 ? "" : ";", end.kinds[k].p_occ_given_free,
                  end.kinds[k].p_free_given_occ, end.kind_shares[k]);
    }
    std::printf("\n");
  }
  std::printf("  static map (clamped log-odds, occupied > %g, free < %g): %zu free, %zu occupied of %zu observed "
              "cells\n",
              kOccupiedThreshold, kFreeThreshold, end.static_free, end.static_occupied, end.observed_cells);
  std::printf("  retention (belief at the last step, same thresholds): free %s, occupied %s\n",
              share(end.kept_free, end.static_free).c_str(), share(end.kept_occupied, end.static_occupied).c_str());
  std::printf("  retention of the cells last observed >= %s before the end: free %s, occupied %s\n",
              dog::bag_tools::secondsName(static_cast<double>(options.retention_after_steps) * mapper.time_step_s)
                  .c_str(),
              share(end.left_kept_free, end.left_static_free).c_str(),
              share(end.left_kept_occupied, end.left_static_occupied).c_str());
  std::printf("  retention by the stationary layer (long-run p(occ), same thresholds): free %s, occupied %s\n",
              share(end.stationary_kept_free, end.static_free).c_str(),
              share(end.stationary_kept_occupied, end.static_occupied).c_str());
  std::printf("  retention by the predicted layer (%s ahead of the last step, same thresholds): free %s, occupied "
              "%s\n",
              dog::bag_tools::secondsName(static_cast<double>(options.prediction_horizon_steps) * mapper.time_step_s)
                  .c_str(),
              share(end.predicted_kept_free, end.static_free).c_str(),
              share(end.predicted_kept_occupied, end.static_occupied).c_str());
  std::printf("  walls learned as changing (static occupied, p_free_given_occ > %g): %zu of %zu, %zu of them edge "
              "cells (edge: a free 8-neighbour; %zu occupied cells are edge cells)\n",
              kChangingThreshold, end.occupied_changing, end.static_occupied, end.occupied_changing_edge,
              end.occupied_edge);
  std::printf("  walls last observed >= %s before the end learned as changing: %s\n",
              dog::bag_tools::secondsName(static_cast<double>(options.retention_after_steps) * mapper.time_step_s)
                  .c_str(),
              share(end.left_occupied_changing, end.left_static_occupied).c_str());
  std::printf("  free cells learned as changing (static free, p_occ_given_free > %g): %zu of %zu\n",
              kChangingThreshold, end.free_changing, end.static_free);
}

void printTable(const dog::evaluation::PredictionCheckResult& result, const Options& options) {
  std::printf("\nprediction check: the map after each step against the labels of the step h later\n"
              "  label: one cell in one step, occupied if hits > misses, free if misses > hits (tie: none)\n"
              "  unseen: labels on cells the map had not observed yet (not scored); occupied: share of the\n"
              "  scored labels; accuracy: p > 0.5 says occupied, p < 0.5 free; occ.acc: accuracy on the\n"
              "  occupied labels only; Brier: mean of (p - label)^2, label 1 occupied, 0 free\n");
  std::printf("%9s %7s %10s %9s %8s | %-26s | %s\n", "", "", "", "", "", "dynamic", "static");
  std::printf("%9s %7s %10s %9s %8s | %8s %8s %8s | %8s %8s %8s\n", "horizon", "steps", "labels", "unseen",
              "occupied", "accuracy", "occ.acc", "Brier", "accuracy", "occ.acc", "Brier");
  const double time_step_s = options.shared.mapper.time_step_s;
  for (const dog::evaluation::HorizonScore& score : result.horizons) {
    const dog::evaluation::PredictionScore& dynamic = score.dynamic_model;
    const dog::evaluation::PredictionScore& fixed = score.static_model;
    const double occupied = fraction(score.occupied_labels, score.scored());
    const std::string occupied_text = std::isnan(occupied) ? "-" : tableNumber(100.0 * occupied, 1) + "%";
    std::printf("%9s %7lld %10zu %9zu %8s | %8s %8s %8s | %8s %8s %8s\n",
                dog::bag_tools::secondsName(static_cast<double>(score.horizon_steps) * time_step_s).c_str(),
                static_cast<long long>(score.horizon_steps), score.labels, score.unseen,
                occupied_text.c_str(),
                tableNumber(dynamic.accuracy(), 4).c_str(), tableNumber(dynamic.occupiedAccuracy(), 4).c_str(),
                tableNumber(dynamic.brier(), 4).c_str(), tableNumber(fixed.accuracy(), 4).c_str(),
                tableNumber(fixed.occupiedAccuracy(), 4).c_str(), tableNumber(fixed.brier(), 4).c_str());
  }
}

void writeCsv(std::ostream& file, const dog::evaluation::PredictionCheckResult& result, const EndOfRun& end,
              const Options& options) {
  file << "horizon_s,horizon_steps,labels,unseen,occupied_labels";
  for (const char* model : {"dynamic", "static"}) {
    file << ',' << model << "_accuracy," << model << "_occupied_accuracy," << model << "_free_accuracy," << model
         << "_brier," << model << "_unclassified";
  }
  // The map at the end: the same on every row.
  file << ",end_step,end_p_hit_given_occ,end_p_hit_given_free,end_observed_cells,end_static_free,"
          "end_static_occupied,end_kept_free,end_kept_occupied,end_retention_after_s,end_left_static_free,"
          "end_left_static_occupied,end_left_kept_free,end_left_kept_occupied,end_occupied_edge,"
          "end_occupied_changing,end_occupied_changing_edge,end_free_changing,end_stationary_kept_free,"
          "end_stationary_kept_occupied,end_prediction_horizon_s,end_predicted_kept_free,end_predicted_kept_occupied,"
          "end_left_occupied_changing";
  file << '\n';
  std::ostringstream end_columns;
  end_columns << ',' << end.step << ',' << csvNumber(end.p_hit_given_occ) << ',' << csvNumber(end.p_hit_given_free)
              << ',' << end.observed_cells << ',' << end.static_free << ',' << end.static_occupied << ','
              << end.kept_free << ',' << end.kept_occupied << ','
              << csvNumber(static_cast<double>(options.retention_after_steps) * options.shared.mapper.time_step_s)
              << ',' << end.left_static_free << ',' << end.left_static_occupied << ',' << end.left_kept_free << ','
              << end.left_kept_occupied << ',' << end.occupied_edge << ',' << end.occupied_changing << ','
              << end.occupied_changing_edge << ',' << end.free_changing << ',' << end.stationary_kept_free << ','
              << end.stationary_kept_occupied << ','
              << csvNumber(static_cast<double>(options.prediction_horizon_steps) * options.shared.mapper.time_step_s)
              << ',' << end.predicted_kept_free << ',' << end.predicted_kept_occupied << ','
              << end.left_occupied_changing;
  for (const dog::evaluation::HorizonScore& score : result.horizons) {
    file << csvNumber(static_cast<double>(score.horizon_steps) * options.shared.mapper.time_step_s) << ','
         << score.horizon_steps << ',' << score.labels << ',' << score.unseen << ',' << score.occupied_labels;
    for (const dog::evaluation::PredictionScore* model : {&score.dynamic_model, &score.static_model}) {
      file << ',' << csvNumber(model->accuracy()) << ',' << csvNumber(model->occupiedAccuracy()) << ','
           << csvNumber(model->freeAccuracy()) << ',' << csvNumber(model->brier()) << ',' << model->unclassified;
    }
    file << end_columns.str() << '\n';
  }
}

// Maps, scores and reports; `csv` is open when a CSV is asked for.
void checkAndReport(dog::ros_layer::BagScanSource& source, const Options& options) {
  const dog::core::MapperConfig& mapper = options.shared.mapper;
  std::printf("mapper: resolution %g m, time step %g s, p_hit_given_occ %g, p_hit_given_free %g, "
              "prior p_occ_given_free %g, p_free_given_occ %g per step, online learning %s, "
              "sensor model learning %s, mixed step probability %g\n",
              mapper.resolution_m, mapper.time_step_s, mapper.p_hit_given_occ, mapper.p_hit_given_free,
              mapper.prior_transitions.p_occ_given_free, mapper.prior_transitions.p_free_given_occ,
              mapper.learn_transitions ? "on" : "off", mapper.learn_sensor_model ? "on" : "off",
              mapper.sensor_model_mixed_step_probability);
  if (mapper.learn_transitions && mapper.learner == dog::core::TransitionLearner::kKinds) {
    std::printf("online learning: kinds of cells (%d), switch probability %g, forgetting %g per step\n",
                dog::core::kKindCount, mapper.kinds.switch_probability, mapper.kinds.forgetting);
  } else if (mapper.learn_transitions) {
    std::printf("online learning: each cell's online EM\n");
  }
  std::fflush(stdout);

  dog::bag_tools::ProgressBar bar;
  int pass = 0;
  dog::ros_layer::BagScanStats first_pass;
  // Without pose correction, checkPredictions keeps the map it scores to itself: this
  // mapper, with the same configuration and fed the same scans in the second pass, ends as
  // the same map (the mapper is deterministic) for the end-of-run report.
  dog::core::Mapper final_map(mapper);
  // With it, the map scored and reported is the corrected mapping's own, as the node's: it
  // maps the last seconds' scans again when it takes a correction. A filter and its learner
  // made afresh for each pass: both passes see the same corrected poses.
  std::unique_ptr<dog::core::Mapper> learner;
  std::unique_ptr<dog::core::CorrectedMapping> correction;
  std::size_t correction_updates = 0;
  std::size_t correction_refused = 0;  // over both passes
  const dog::evaluation::ScanReplay replay = [&](const dog::evaluation::ScanConsumer& consumer) {
    ++pass;
    const std::string phase = "pass " + std::to_string(pass);
    const bool corrected_run = options.correction.enabled;
    const dog::evaluation::ScanConsumer both = [&consumer, &final_map](const dog::core::Scan& scan) {
      consumer(scan);
      final_map.integrate(scan);
    };
    const dog::evaluation::ScanConsumer& use = pass == 2 && !corrected_run ? both : consumer;
    correction.reset();
    learner.reset();
    if (corrected_run) {
      learner = std::make_unique<dog::core::Mapper>(mapper);
      correction = std::make_unique<dog::core::CorrectedMapping>(*learner, options.correction.filter,
                                                                 options.correction.learned_min_observed_steps);
    }
    const dog::evaluation::ScanConsumer corrected = [&use, &correction,
                                                     &correction_refused](const dog::core::Scan& scan) {
      dog::core::CorrectedScan result;
      try {
        result = correction->integrate(scan);
      } catch (const std::invalid_argument&) {
        ++correction_refused;  // no corrected pose: not scored either
        return;
      }
      use(result.corrected);
    };
    const dog::ros_layer::BagScanStats stats =
        source.forEachScan(corrected_run ? corrected : use, [&bar, &phase](double done) {
          bar.show(phase, done);
          return true;
        });
    if (correction) {
      correction->finish();  // the end of the data: the map scored last is the one mapped again
      correction_updates = correction->filter().updates();
    }
    if (pass > 1) return;
    first_pass = stats;
    // Said here, with what the bag reader knows (tf errors, time range), rather than as the
    // core's "no scan handed out".
    if (!stats.first_stamp_s) {
      dog::ros_layer::BagMappingStats mapping;
      mapping.source = stats;
      throw std::runtime_error(dog::ros_layer::describeUnusableBag(options.shared.source.bag_path, mapping));
    }
  };
  const dog::evaluation::ScoredMap scored_map = [&learner]() -> dog::core::Mapper& { return *learner; };
  const auto start = std::chrono::steady_clock::now();
  const dog::evaluation::PredictionCheckResult result =
      dog::evaluation::checkPredictions(mapper, replay, options.horizons_steps,
                                        options.correction.enabled ? scored_map : nullptr);
  final_map.finishStep();
  const EndOfRun end = summarizeEnd(learner ? *learner : final_map, options.retention_after_steps, options.prediction_horizon_steps);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  std::printf("scans read: %zu, integrated: %zu, rejected: %zu", first_pass.scans_read, result.scans_integrated,
              result.scans_rejected);
  if (options.shared.source.static_laser_pose) {
    std::printf(" (static laser pose given, tf not read)\n");
  } else {
    std::printf(", without a pose in '%s': %zu\n", source.options().fixed_frame.c_str(),
                first_pass.scans_without_pose);
  }
  if (first_pass.scans_outside_time_range > 0) {
    std::printf("  outside the time range: %zu\n", first_pass.scans_outside_time_range);
  }
  if (result.scans_rejected > 0) std::printf("  last rejection: %s\n", result.last_rejection.c_str());
  if (first_pass.scans_without_pose > 0) std::printf("  last tf error: %s\n", first_pass.last_pose_error.c_str());
  std::printf("time steps: %lld of %g s; %zu cells observed in %zu cell-steps, %zu of them tied (no label); "
              "bag %.1f s read twice in %.2f s\n",
              static_cast<long long>(result.steps), mapper.time_step_s, result.observed_cells,
              result.observed_cell_steps, result.tied_cell_steps, first_pass.bag_duration_s, seconds);
  if (options.correction.enabled) {
    std::printf("pose correction: %zu particles, %zu filter updates a pass (the map is scored at the corrected "
                "poses), %zu scans refused by the filter; map -> odom changed %zu times, %zu scans mapped again\n",
                options.correction.filter.particles, correction_updates, correction_refused / 2,
                correction->correctionsTaken(), correction->scansRemapped());
  }
  for (std::size_t k = 0; k < options.horizons_s.size(); ++k) {
    const double effective_s = static_cast<double>(options.horizons_steps[k]) * mapper.time_step_s;
    if (std::abs(effective_s - options.horizons_s[k]) > 1e-9 * std::max(1.0, options.horizons_s[k])) {
      std::printf("note: horizon %g s is not a whole number of %g s steps: %s used\n", options.horizons_s[k],
                  mapper.time_step_s, dog::bag_tools::secondsName(effective_s).c_str());
    }
  }
  printTable(result, options);
  printEnd(end, options);
  if (!options.csv_path.empty()) {
    std::ostringstream csv;
    writeCsv(csv, result, end, options);
    // Through a temporary file and a rename: a failure never leaves a partial file, nor
    // truncates one that was there.
    dog::core::writeFileAtomically(options.csv_path, csv.str());
    std::printf("csv -> %s\n", options.csv_path.c_str());
  }
}

int run(const Options& options) {
  // A CSV that could not be written is refused before the bag is read, not after.
  if (!options.csv_path.empty()) {
    const std::string::size_type slash = options.csv_path.rfind('/');
    const std::string directory = slash == std::string::npos ? "." : options.csv_path.substr(0, std::max<std::size_t>(slash, 1));
    if (::access(directory.c_str(), W_OK) != 0) {
      throw std::runtime_error("cannot write " + options.csv_path + ": " + std::strerror(errno));
    }
  }
  dog::ros_layer::BagScanSource source(options.shared.source);
  checkAndReport(source, options);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const Options options = parseArguments(argc, argv);
  try {
    return run(options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "check_bag: %s\n", e.what());
    return 1;
  }
}
