// check_bag: a self-supervised check of the map on a bag without ground truth. For each
// horizon h, how well the map after each time step predicts the hits and misses of the scans
// h later: the dynamic model (beliefs predicted in closed form) against the static
// occupancy grid of the same mapper. Reads the bag twice (labels, then maps and scores;
// evaluation/prediction_check.h). See docs/self_check.md.

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "bag_tools.h"
#include "dynamic_occupancy_grid/core/map_export.h"
#include "dynamic_occupancy_grid/core/mapper.h"
#include "dynamic_occupancy_grid/evaluation/prediction_check.h"
#include "dynamic_occupancy_grid/ros/bag_offline_em.h"
#include "dynamic_occupancy_grid/ros/bag_scan_source.h"

namespace dog = dynamic_occupancy_grid;

namespace {

const std::vector<double> kDefaultHorizons_s{1.0, 5.0, 30.0, 60.0};

struct Options {
  dog::bag_tools::SharedOptions shared;
  std::vector<double> horizons_s;
  std::vector<std::int64_t> horizons_steps;  ///< horizons_s in whole steps
  std::string csv_path;                      ///< empty: no CSV
};

Options parseArguments(int argc, char** argv) {
  namespace cl = dog::command_line;
  namespace po = boost::program_options;
  Options options;
  bool no_learning = false;
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
      ("no-learning", po::bool_switch(&no_learning), "no online learning: cells keep the prior transitions");
  dog::bag_tools::addMappingOptions(line, &options.shared);
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
  if (no_learning) options.shared.mapper.learn_transitions = false;
  dog::bag_tools::validateSharedOptions(line, &options.shared);
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

void printTable(const dog::core::PredictionCheckResult& result, const Options& options) {
  std::printf("\nprediction check: the map after each step against the labels of the step h later\n"
              "  label: one cell in one step, occupied if hits > misses, free if misses > hits (tie: none)\n"
              "  unseen: labels on cells the map had not observed yet (not scored); occupied: share of the\n"
              "  scored labels; accuracy: p > 0.5 says occupied, p < 0.5 free; occ.acc: accuracy on the\n"
              "  occupied labels only; Brier: mean of (p - label)^2, label 1 occupied, 0 free\n");
  std::printf("%9s %7s %10s %9s %8s | %-26s | %s\n", "", "", "", "", "", "dynamic", "static");
  std::printf("%9s %7s %10s %9s %8s | %8s %8s %8s | %8s %8s %8s\n", "horizon", "steps", "labels", "unseen",
              "occupied", "accuracy", "occ.acc", "Brier", "accuracy", "occ.acc", "Brier");
  const double time_step_s = options.shared.mapper.time_step_s;
  for (const dog::core::HorizonScore& score : result.horizons) {
    const dog::core::PredictionScore& dynamic = score.dynamic_model;
    const dog::core::PredictionScore& fixed = score.static_model;
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

void writeCsv(std::ostream& file, const dog::core::PredictionCheckResult& result, const Options& options) {
  file << "horizon_s,horizon_steps,labels,unseen,occupied_labels";
  for (const char* model : {"dynamic", "static"}) {
    file << ',' << model << "_accuracy," << model << "_occupied_accuracy," << model << "_free_accuracy," << model
         << "_brier," << model << "_unclassified";
  }
  file << '\n';
  for (const dog::core::HorizonScore& score : result.horizons) {
    file << csvNumber(static_cast<double>(score.horizon_steps) * options.shared.mapper.time_step_s) << ','
         << score.horizon_steps << ',' << score.labels << ',' << score.unseen << ',' << score.occupied_labels;
    for (const dog::core::PredictionScore* model : {&score.dynamic_model, &score.static_model}) {
      file << ',' << csvNumber(model->accuracy()) << ',' << csvNumber(model->occupiedAccuracy()) << ','
           << csvNumber(model->freeAccuracy()) << ',' << csvNumber(model->brier()) << ',' << model->unclassified;
    }
    file << '\n';
  }
}

// Maps, scores and reports; `csv` is open when a CSV is asked for.
void checkAndReport(dog::ros_layer::BagScanSource& source, const Options& options) {
  const dog::core::MapperConfig& mapper = options.shared.mapper;
  std::printf("mapper: resolution %g m, time step %g s, p_hit_given_occ %g, p_hit_given_free %g, "
              "prior p_occ_given_free %g, p_free_given_occ %g per step, online learning %s\n",
              mapper.resolution_m, mapper.time_step_s, mapper.p_hit_given_occ, mapper.p_hit_given_free,
              mapper.prior_transitions.p_occ_given_free, mapper.prior_transitions.p_free_given_occ,
              mapper.learn_transitions ? "on" : "off");
  std::fflush(stdout);

  dog::bag_tools::ProgressBar bar;
  int pass = 0;
  dog::ros_layer::BagScanStats first_pass;
  const dog::core::ScanReplay replay = [&](const dog::core::ScanConsumer& consumer) {
    ++pass;
    const std::string phase = "pass " + std::to_string(pass);
    const dog::ros_layer::BagScanStats stats = source.forEachScan(consumer, [&bar, &phase](double done) {
      bar.show(phase, done);
      return true;
    });
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
  const auto start = std::chrono::steady_clock::now();
  const dog::core::PredictionCheckResult result = dog::core::checkPredictions(mapper, replay, options.horizons_steps);
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
  for (std::size_t k = 0; k < options.horizons_s.size(); ++k) {
    const double effective_s = static_cast<double>(options.horizons_steps[k]) * mapper.time_step_s;
    if (std::abs(effective_s - options.horizons_s[k]) > 1e-9 * std::max(1.0, options.horizons_s[k])) {
      std::printf("note: horizon %g s is not a whole number of %g s steps: %s used\n", options.horizons_s[k],
                  mapper.time_step_s, dog::bag_tools::secondsName(effective_s).c_str());
    }
  }
  printTable(result, options);
  if (!options.csv_path.empty()) {
    std::ostringstream csv;
    writeCsv(csv, result, options);
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
