#pragma once
// What the bag tools (process_bag, offline_em, check_bag, simulate) share: the options they
// have in common (on command_line.h), the progress bar, and running offline EM on what a
// mapper recorded.
// Header-only: each tool stays one .cpp file.

#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <limits>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <boost/algorithm/string/classification.hpp>
#include <boost/algorithm/string/split.hpp>

#include "command_line.h"
#include "dynamic_occupancy_grid/core/pose/corrected_mapping.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/pose/motion_model.h"
#include "dynamic_occupancy_grid/core/cell/offline_em.h"
#include "dynamic_occupancy_grid/ros/bag_offline_em.h"
#include "dynamic_occupancy_grid/ros/bag_scan_source.h"
#include "dynamic_occupancy_grid/ros/parameters.h"

namespace dynamic_occupancy_grid {
namespace bag_tools {

/// The options the bag tools share.
struct SharedOptions {
  ros_layer::BagScanSourceOptions source;
  core::MapperConfig mapper;
  core::OfflineEmConfig em = [] {
    core::OfflineEmConfig config;
    config.prior_weight = ros_layer::kDefaultOfflinePriorWeight;
    return config;
  }();
};

/// "X,Y,YAW" as a pose; throws std::invalid_argument saying what was expected.
inline core::Pose2D toLaserPose(const std::string& text) {
  std::vector<std::string> parts;
  boost::split(parts, text, boost::is_any_of(","));
  const command_line::Range<double> any{};  // any finite number
  try {
    if (parts.size() == 3) {
      return core::Pose2D{command_line::toNumber(parts[0], any), command_line::toNumber(parts[1], any),
                          command_line::toNumber(parts[2], any)};
    }
  } catch (const std::invalid_argument&) {
  }
  throw std::invalid_argument("needs X,Y,YAW (three numbers), got '" + text + "'");
}

/// "A1,A2,A3,A4" as the odometry motion model's four alphas; throws std::invalid_argument
/// saying what was expected.
inline core::OdometryNoise toOdometryNoise(const std::string& text) {
  std::vector<std::string> parts;
  boost::split(parts, text, boost::is_any_of(","));
  if (parts.size() != 4) throw std::invalid_argument("needs four comma-separated numbers, got '" + text + "'");
  const command_line::Range<double> any{};  // any finite number
  const core::OdometryNoise noise{command_line::toNumber(parts[0], any), command_line::toNumber(parts[1], any),
                                  command_line::toNumber(parts[2], any), command_line::toNumber(parts[3], any)};
  noise.validate();
  return noise;
}

/// The name of a transition learner, as the node's ~learner.
inline core::TransitionLearner toLearner(const std::string& text) {
  if (text == "kinds") return core::TransitionLearner::kKinds;
  if (text == "cell_em") return core::TransitionLearner::kCellEm;
  throw std::invalid_argument("needs kinds or cell_em, got '" + text + "'");
}

/// Adds the options of the bag source and the mapper to `line`, read into `options`.
inline void addMappingOptions(command_line::CommandLine& line, SharedOptions* options) {
  namespace cl = command_line;
  ros_layer::BagScanSourceOptions& source = options->source;
  core::MapperConfig& mapper = options->mapper;
  line.options().add_options()
      ("topic", cl::nonEmpty(&source.scan_topic, "a topic")->value_name("NAME"),
       "LaserScan topic (default /scan)")
      ("fixed-frame", cl::nonEmpty(&source.fixed_frame, "a frame")->value_name("NAME"),
       "frame the map is built in (default odom)")
      ("laser-pose",
       cl::converted(toLaserPose, [&source](const core::Pose2D& pose) { source.static_laser_pose = pose; })
           ->value_name("X,Y,YAW"),
       "static laser pose in the fixed frame (m, m, rad); tf is not read (for bags recorded without tf)")
      ("start-time", cl::number(&source.start_time_s, cl::atLeast(0.0))->value_name("T"),
       "only scans stamped at or after T (ROS time, s; default: all)")
      ("end-time", cl::number(&source.end_time_s, cl::atLeast(0.0))->value_name("T"),
       "only scans stamped at or before T (ROS time, s; default: all)")
      ("resolution", cl::number(&mapper.resolution_m, cl::above(0.0))->value_name("M"),
       "cell size in metres (default 0.05)")
      ("time-step", cl::number(&mapper.time_step_s, cl::above(0.0))->value_name("S"),
       "HMM time step in seconds (default 1.0)")
      ("max-range", cl::number(&source.max_range_m, cl::above(0.0))->value_name("M"),
       "readings longer than M metres count as no return (default: the sensor's range_max)")
      ("max-free-range", cl::number(&mapper.max_free_range_m, cl::atLeast(0.0))->value_name("M"),
       "beams without return clear cells up to M metres (default 10; 0 ignores them)")
      ("p-hit-given-occ", cl::number(&mapper.p_hit_given_occ, cl::between(0.0, 1.0))->value_name("P"),
       "sensor model: p(hit | occupied) (default 0.7)")
      ("p-hit-given-free", cl::number(&mapper.p_hit_given_free, cl::between(0.0, 1.0))->value_name("P"),
       "sensor model: p(hit | free) (default 0.2)")
      ("mixed-step-probability",
       cl::number(&mapper.sensor_model_mixed_step_probability, cl::between(0.0, 0.5))->value_name("P"),
       "sensor model: the chance that a step whose beams disagree comes from a cell they only partly cover "
       "(default 0.001; 0 reads every step plainly), as the node's ~sensor_model/mixed_step_probability")
      ("prior-p-occ-given-free",
       cl::number(&mapper.prior_transitions.p_occ_given_free, cl::between(0.0, 1.0))->value_name("P"),
       "transition prior per step, free -> occupied (default 0.01)")
      ("prior-p-free-given-occ",
       cl::number(&mapper.prior_transitions.p_free_given_occ, cl::between(0.0, 1.0))->value_name("P"),
       "transition prior per step, occupied -> free (default 0.01)")
      ("learner", cl::converted(toLearner, [&mapper](core::TransitionLearner learner) { mapper.learner = learner; })
           ->value_name("NAME"),
       "how cells learn their transitions: kinds (kinds of cells learned from the whole map, the default) or "
       "cell_em (each cell's own online EM), as the node's ~learner");
}

/// --pose-correction and the filter's options (process_bag, check_bag).
struct PoseCorrectionOptions {
  std::string mode = "none";  ///< "none" or "rbpf", as given
  bool enabled = false;       ///< rbpf: the scans' poses are odometry, corrected by the pose filter
  core::PoseFilterConfig filter = [] {
    core::PoseFilterConfig config;
    const double alpha = ros_layer::kDefaultOdometryAlpha;  // as the node's ~rbpf/odom_alpha1..4
    config.motion_noise = {alpha, alpha, alpha, alpha};
    return config;
  }();
  std::uint32_t learned_min_observed_steps = 30;  ///< as the node's ~rbpf/learned_min_observed_steps
};

/// Adds --pose-correction and the pose filter's options to `line`, read into `options`.
inline void addPoseCorrectionOptions(command_line::CommandLine& line, PoseCorrectionOptions* options) {
  namespace cl = command_line;
  core::PoseFilterConfig& filter = options->filter;
  line.options().add_options()
      ("pose-correction", cl::nonEmpty(&options->mode, "none or rbpf")->value_name("MODE"),
       "none (the default: the scans' poses in --fixed-frame are the truth) or rbpf: they are odometry, "
       "corrected by the Rao-Blackwellised particle filter whose particle maps are cell HMMs (as the node's "
       "~pose_correction); the map frame then starts at odometry's first pose")
      ("particles", cl::number(&filter.particles, cl::between<std::size_t>(1, 100000))->value_name("N"),
       "pose correction: particles (default 30)")
      ("odometry-alphas",
       cl::converted(toOdometryNoise, [&filter](const core::OdometryNoise& noise) { filter.motion_noise = noise; })
           ->value_name("A1,A2,A3,A4"),
       "pose correction: the odometry's noise, amcl's odom_alpha1..4 (rotation from rotation, rotation from "
       "translation, translation from translation, translation from rotation; default 0.001 each)")
      ("update-distance", cl::number(&filter.update_distance_m, cl::above(0.0))->value_name("M"),
       "pose correction: a filter update once odometry moved M metres (default 0.5)")
      ("update-angle", cl::number(&filter.update_angle_rad, cl::above(0.0))->value_name("RAD"),
       "pose correction: ... or turned RAD radians (default 0.5)")
      ("filter-seed",
       cl::number(&filter.seed, cl::between<std::uint64_t>(0, std::numeric_limits<int>::max()))->value_name("N"),
       "pose correction: the particles' random seed (default 1)")
      ("resample-threshold", cl::number(&filter.resample_below, cl::between(0.0, 1.0))->value_name("R"),
       "pose correction: resample when N_eff < R x particles (default 0.5)")
      ("no-scan-matching", boost::program_options::bool_switch()->notifier([&filter](bool off) {
         if (off) filter.scan_matching = false;
       }),
       "pose correction: the proposal is the motion model alone")
      ("learned-min-observed-steps",
       cl::number(&options->learned_min_observed_steps, cl::between<std::uint32_t>(0, 1000000))->value_name("N"),
       "pose correction: the filter uses a cell's learned transitions once it was observed in N steps (default "
       "30)");
}

/// Checks the options addPoseCorrectionOptions read against the parsed `shared` ones (call
/// after validateSharedOptions) and completes the filter's config from the mapper's.
inline void validatePoseCorrectionOptions(const command_line::CommandLine& line, const SharedOptions& shared,
                                          PoseCorrectionOptions* options) {
  if (options->mode == "rbpf") {
    options->enabled = true;
  } else if (options->mode != "none") {
    line.fail("--pose-correction needs none or rbpf, got '" + options->mode + "'");
  }
  if (!options->enabled) return;
  if (shared.source.static_laser_pose) line.fail("--pose-correction rbpf needs odometry from tf, not --laser-pose");
  options->filter = core::poseFilterConfigFor(shared.mapper, options->filter);
  try {
    options->filter.validate();
  } catch (const std::invalid_argument& e) {
    line.fail(e.what());
  }
}

/// The names of the options addEmOptions adds.
inline const std::vector<std::string>& emOptionNames() {
  static const std::vector<std::string> names{"em-iterations", "em-tolerance", "em-prior-weight", "mrf-temperature",
                                              "em-learn-sensor-model", "threads"};
  return names;
}

/// Adds the options that tune offline EM to `line`, read into `options`.
inline void addEmOptions(command_line::CommandLine& line, SharedOptions* options) {
  namespace cl = command_line;
  core::OfflineEmConfig& em = options->em;
  line.options().add_options()
      ("em-iterations", cl::number(&em.max_iterations, cl::between(1, 65535))->value_name("N"),
       "offline EM: at most N iterations per cell (default 100)")
      ("em-tolerance", cl::number(&em.tolerance, cl::atLeast(0.0))->value_name("X"),
       "offline EM: a cell stops when an iteration gains less than X nats (default 1e-4; 0 always runs N "
       "iterations)")
      ("em-prior-weight", cl::number(&em.prior_weight, cl::atLeast(0.0))->value_name("W"),
       "offline EM: W pseudo-transitions per state drawn from the prior transitions (MAP; default 2; "
       "0 = maximum likelihood)")
      ("mrf-temperature", cl::number(&em.mrf_temperature, cl::atLeast(0.0))->value_name("T"),
       "offline EM: smooth the two transition maps with a pairwise MRF prior over 8-neighbour cells at "
       "temperature T (THEORY.md §7; the lower T, the smoother; default 0 = off, per-cell EM); all cells then "
       "iterate together and stop when an iteration gains less than X (--em-tolerance) times the number of "
       "cells")
      ("em-learn-sensor-model", boost::program_options::bool_switch(&em.learn_sensor_model),
       "offline EM: learn the sensor model too (an emission M-step after each round of per-cell EM; "
       "docs/online_learning.md); the map then uses the learned one. Not with --mrf-temperature")
      ("threads", cl::number(&em.threads, cl::between(0U, 1024U))->value_name("N"),
       "offline EM worker threads (default 0 = one per core)");
}

/// Checks the combination of values (the sensor model, the time range, ...) once all are
/// read; a bad one is a usage error naming it.
inline void validateSharedOptions(const command_line::CommandLine& line, SharedOptions* options) {
  const ros_layer::BagScanSourceOptions& source = options->source;
  if (source.end_time_s > 0.0 && source.end_time_s < source.start_time_s) {
    line.fail("--end-time must not be before --start-time");
  }
  // EM's chain starts where the mapper's cells start, and its MAP prior is the mapper's.
  options->em.initial_p_occ = options->mapper.initial_p_occ;
  options->em.prior = options->mapper.prior_transitions;
  try {
    options->mapper.validate();
    options->em.validate();
  } catch (const std::exception& e) {
    line.fail(e.what());
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
  if (config.learn_sensor_model) std::printf(", learning the sensor model");
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
  if (config.learn_sensor_model) {
    std::printf("offline EM sensor model: p_hit_given_occ %.4f, p_hit_given_free %.4f (%d rounds)\n",
                result.p_hit_given_occ, result.p_hit_given_free, result.sensor_model_rounds);
  }
  const core::OfflineEmApplied applied = mapper.applyOfflineEm(sequences, result, true);
  std::printf("offline EM applied to %zu cells (%zu not in the map)\n", applied.cells_applied,
              applied.cells_not_in_map);
  return result;
}

}  // namespace bag_tools
}  // namespace dynamic_occupancy_grid
