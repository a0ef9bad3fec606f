#pragma once
// What the bag tools (process_bag, offline_em) share: command-line parsing of the options
// they have in common, the progress bar, and running offline EM on what a mapper recorded.
// Header-only: each tool stays one .cpp file.

#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <iostream>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/core/mapper.h"
#include "dynamic_occupancy_grid/core/offline_em.h"
#include "dynamic_occupancy_grid/ros/bag_offline_em.h"
#include "dynamic_occupancy_grid/ros/bag_scan_source.h"

namespace dynamic_occupancy_grid {
namespace bag_tools {

/// Help text of the options parseSharedOption understands.
inline const char* const kSharedUsage =
    "  --topic NAME          LaserScan topic (default /scan)\n"
    "  --fixed-frame NAME    frame the map is built in (default odom)\n"
    "  --laser-pose X,Y,YAW  static laser pose in the fixed frame (m, m, rad); tf is not\n"
    "                        read (for bags recorded without tf)\n"
    "  --start-time T        only scans stamped at or after T (ROS time, s; default: all)\n"
    "  --end-time T          only scans stamped at or before T (ROS time, s; default: all)\n"
    "  --resolution M        cell size in metres (default 0.05)\n"
    "  --time-step S         HMM time step in seconds (default 1.0)\n"
    "  --max-range M         readings longer than M metres count as no return (default:\n"
    "                        the sensor's range_max)\n"
    "  --max-free-range M    beams without return clear cells up to M metres (default 10;\n"
    "                        0 ignores them)\n"
    "  --p-hit-given-occ P   sensor model: p(hit | occupied) (default 0.7)\n"
    "  --p-hit-given-free P  sensor model: p(hit | free) (default 0.2)\n"
    "  --prior-p-occ-given-free P   transition prior per step, free -> occupied (default 0.01)\n"
    "  --prior-p-free-given-occ P   transition prior per step, occupied -> free (default 0.01)\n"
    "  --em-iterations N     offline EM: at most N iterations per cell (default 100)\n"
    "  --em-tolerance X      offline EM: a cell stops when an iteration gains less than X\n"
    "                        nats (default 1e-4; 0 always runs N iterations)\n"
    "  --em-prior-weight W   offline EM: W pseudo-transitions per state drawn from the\n"
    "                        prior transitions (MAP; default 2; 0 = maximum likelihood)\n"
    "  --mrf-temperature T   offline EM: smooth the two transition maps with a pairwise MRF\n"
    "                        prior over 8-neighbour cells at temperature T (THEORY.md §7;\n"
    "                        the lower T, the smoother; default 0 = off, per-cell EM); all\n"
    "                        cells then iterate together and stop when an iteration gains\n"
    "                        less than X (--em-tolerance) times the number of cells\n"
    "  --threads N           offline EM worker threads (default 0 = one per core)\n";

/// The options both tools understand.
struct SharedOptions {
  ros_layer::BagScanSourceOptions source;
  core::MapperConfig mapper;
  core::OfflineEmConfig em = [] {
    core::OfflineEmConfig config;
    config.prior_weight = ros_layer::kDefaultOfflinePriorWeight;
    return config;
  }();
};

/// Walks over argv; errors are usage errors: message, usage, exit status 2.
class Arguments {
 public:
  Arguments(int argc, char** argv, std::string tool, std::string usage)
      : args_(argv + 1, argv + argc), tool_(std::move(tool)), usage_(std::move(usage)) {}

  /// The next argument, false at the end.
  bool next(std::string* arg) {
    if (index_ >= args_.size()) return false;
    current_ = args_[index_++];
    *arg = current_;
    return true;
  }
  /// The value of the option just read.
  std::string value() {
    if (index_ >= args_.size()) fail(current_ + " needs a value");
    return args_[index_++];
  }
  double number() { return parseNumber(current_, value()); }
  /// A number in [min, max].
  double number(double min, double max) {
    const double result = number();
    if (result < min || result > max) {
      std::ostringstream message;
      message << current_ << " must be in [" << min << ", " << max << "], got " << result;
      fail(message.str());
    }
    return result;
  }
  /// A number > 0.
  double positiveNumber() {
    const double result = number();
    if (!(result > 0.0)) {
      std::ostringstream message;
      message << current_ << " must be > 0, got " << result;
      fail(message.str());
    }
    return result;
  }
  /// A number >= 0.
  double nonNegativeNumber() {
    const double result = number();
    if (result < 0.0) {
      std::ostringstream message;
      message << current_ << " must be >= 0, got " << result;
      fail(message.str());
    }
    return result;
  }
  /// A whole number in [min, max].
  long integer(long min, long max) {
    const std::string text = value();
    std::size_t used = 0;
    long result = 0;
    try {
      result = std::stol(text, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != text.size() || text.empty()) fail(current_ + " expects a whole number, got '" + text + "'");
    if (result < min || result > max) {
      fail(current_ + " must be in [" + std::to_string(min) + ", " + std::to_string(max) + "], got " + text);
    }
    return result;
  }
  double parseNumber(const std::string& option, const std::string& text) {
    std::size_t used = 0;
    double result = 0.0;
    try {
      result = std::stod(text, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != text.size() || text.empty() || !std::isfinite(result)) {
      fail(option + " expects a number, got '" + text + "'");
    }
    return result;
  }

  [[noreturn]] void fail(const std::string& message) const {
    std::cerr << tool_ << ": " << message << "\n" << usage_;
    std::exit(2);
  }
  [[noreturn]] void help() const {
    std::cout << usage_;
    std::exit(0);
  }

 private:
  std::vector<std::string> args_;
  std::size_t index_ = 0;
  std::string current_;
  std::string tool_;
  std::string usage_;
};

/// Reads `arg` (and its value) if it is one of kSharedUsage's options; false otherwise.
inline bool parseSharedOption(const std::string& arg, Arguments& args, SharedOptions* options) {
  if (arg == "--topic") {
    options->source.scan_topic = args.value();
  } else if (arg == "--fixed-frame") {
    options->source.fixed_frame = args.value();
  } else if (arg == "--laser-pose") {
    std::stringstream parts(args.value());
    std::string item;
    std::vector<double> numbers;
    while (std::getline(parts, item, ',')) numbers.push_back(args.parseNumber(arg, item));
    if (numbers.size() != 3) args.fail("--laser-pose expects X,Y,YAW");
    options->source.static_laser_pose = core::Pose2D{numbers[0], numbers[1], numbers[2]};
  } else if (arg == "--start-time") {
    options->source.start_time_s = args.nonNegativeNumber();
  } else if (arg == "--end-time") {
    options->source.end_time_s = args.nonNegativeNumber();
  } else if (arg == "--resolution") {
    options->mapper.resolution_m = args.positiveNumber();
  } else if (arg == "--time-step") {
    options->mapper.time_step_s = args.positiveNumber();
  } else if (arg == "--max-range") {
    options->source.max_range_m = args.positiveNumber();
  } else if (arg == "--max-free-range") {
    options->mapper.max_free_range_m = args.nonNegativeNumber();
  } else if (arg == "--p-hit-given-occ") {
    options->mapper.p_hit_given_occ = args.number(0.0, 1.0);
  } else if (arg == "--p-hit-given-free") {
    options->mapper.p_hit_given_free = args.number(0.0, 1.0);
  } else if (arg == "--prior-p-occ-given-free") {
    options->mapper.prior_transitions.p_occ_given_free = args.number(0.0, 1.0);
  } else if (arg == "--prior-p-free-given-occ") {
    options->mapper.prior_transitions.p_free_given_occ = args.number(0.0, 1.0);
  } else if (arg == "--em-iterations") {
    options->em.max_iterations = static_cast<int>(args.integer(1, 65535));
  } else if (arg == "--em-tolerance") {
    options->em.tolerance = args.nonNegativeNumber();
  } else if (arg == "--em-prior-weight") {
    options->em.prior_weight = args.nonNegativeNumber();
  } else if (arg == "--mrf-temperature") {
    options->em.mrf_temperature = args.nonNegativeNumber();
  } else if (arg == "--threads") {
    options->em.threads = static_cast<unsigned>(args.integer(0, 1024));
  } else {
    return false;
  }
  return true;
}

/// Checks the combination of values (the sensor model, the time range, ...) once all are
/// read; a bad one is a usage error naming it.
inline void validateSharedOptions(Arguments& args, SharedOptions* options) {
  const ros_layer::BagScanSourceOptions& source = options->source;
  if (source.end_time_s > 0.0 && source.end_time_s < source.start_time_s) {
    args.fail("--end-time must not be before --start-time");
  }
  // EM's chain starts where the mapper's cells start, and its MAP prior is the mapper's.
  options->em.initial_p_occ = options->mapper.initial_p_occ;
  options->em.prior = options->mapper.prior_transitions;
  try {
    options->mapper.validate();
    options->em.validate();
  } catch (const std::exception& e) {
    args.fail(e.what());
  }
}

/// A one-line progress bar on stderr, drawn only when stderr is a terminal (scripts and
/// tests see clean output), redrawn only when the shown percentage or phase changes.
class ProgressBar {
 public:
  ProgressBar() : enabled_(isatty(STDERR_FILENO) != 0) {}

  void show(const std::string& phase, double fraction) {
    if (!enabled_) return;
    const int percent = static_cast<int>(std::lround(std::clamp(fraction, 0.0, 1.0) * 100.0));
    if (percent == percent_ && phase == phase_) return;
    if (phase != phase_ && !phase_.empty() && percent_ < 100) std::fputc('\n', stderr);
    percent_ = percent;
    phase_ = phase;
    const int width = 40;
    const int filled = percent * width / 100;
    std::fprintf(stderr, "\r%-8s [%s%s] %3d%%", phase.c_str(), std::string(filled, '#').c_str(),
                 std::string(width - filled, ' ').c_str(), percent);
    if (percent == 100) std::fputc('\n', stderr);
    std::fflush(stderr);
  }

 private:
  bool enabled_;
  int percent_ = -1;
  std::string phase_;
};

/// Seconds as a short name: "10s", "2.5s".
inline std::string secondsName(double seconds) {
  char text[64];
  std::snprintf(text, sizeof(text), "%.3f", seconds);
  std::string name(text);
  name.erase(name.find_last_not_of('0') + 1);
  if (name.back() == '.') name.pop_back();
  return name + "s";
}

/// Runs offline EM on the observations `recorder` gathered while `mapper` mapped (with the
/// mapper's sensor model), applies the result to the mapper with the offline filter's
/// final beliefs (the sequences are the mapper's own history), and prints what it did.
/// Returns the EM result; throws as runOfflineEm.
inline core::OfflineEmResult runOfflineEmAndApply(core::Mapper& mapper, core::SequenceBuilder& recorder,
                                                  const core::OfflineEmConfig& config, ProgressBar& bar) {
  mapper.recordObservations(nullptr);
  const core::ObservationSequences sequences = recorder.build();
  const unsigned threads = config.threads > 0 ? config.threads : std::max(1U, std::thread::hardware_concurrency());
  std::printf("offline EM: %zu cells, %zu observed cell steps (%.1f MB), %u threads", sequences.cellCount(),
              sequences.observationCount(), static_cast<double>(sequences.bytes()) / 1.0e6, threads);
  if (config.mrf_temperature > 0.0) std::printf(", MRF temperature %g", config.mrf_temperature);
  std::printf("\n");
  std::fflush(stdout);
  const auto start = std::chrono::steady_clock::now();
  const core::OfflineEmResult result =
      core::runOfflineEm(sequences, mapper.sensor(), config, [&bar](std::size_t done, std::size_t total) {
        bar.show("EM", total > 0 ? static_cast<double>(done) / static_cast<double>(total) : 1.0);
        return true;
      });
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  bar.show("EM", 1.0);
  const std::size_t iterations = result.objective.empty() ? 0 : result.objective.size() - 1;
  // With the MRF all cells iterate together; without it each cell stops on its own.
  std::printf("offline EM: %zu iterations (%s), %zu of %zu cells converged, objective %.6f -> %.6f, %.3f s\n",
              iterations, config.mrf_temperature > 0.0 ? "all cells together" : "the most any cell used",
              result.cells_converged, sequences.cellCount(),
              result.objective.empty() ? 0.0 : result.objective.front(),
              result.objective.empty() ? 0.0 : result.objective.back(), seconds);
  std::printf("offline EM objective per iteration:");
  for (const double value : result.objective) std::printf(" %.6f", value);
  std::printf("\n");
  // The MRF's M-step is a Newton solve per map (THEORY.md §7): its iterations are what T costs.
  if (!result.mrf_newton_iterations.empty()) {
    std::printf("offline EM MRF Newton iterations per M-step (p(occ->occ)/p(free->free)):");
    for (const std::array<int, 2>& newton : result.mrf_newton_iterations) {
      std::printf(" %d/%d", newton[0], newton[1]);
    }
    std::printf("\n");
  }
  const core::OfflineEmApplied applied = mapper.applyOfflineEm(sequences, result, true);
  std::printf("offline EM applied to %zu cells (%zu not in the map)\n", applied.cells_applied,
              applied.cells_not_in_map);
  return result;
}

}  // namespace bag_tools
}  // namespace dynamic_occupancy_grid
