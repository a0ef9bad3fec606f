// process_bag: runs the mapping pipeline over the laser scans of a bag, faster than real
// time, optionally offline EM over the whole recording, and writes the map layers as
// map_server files and the model file. See README.md, "process_bag".

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "bag_tools.h"
#include "dynamic_occupancy_grid/core/pose/corrected_mapping.h"
#include "dynamic_occupancy_grid/core/layers/file_io.h"
#include "dynamic_occupancy_grid/core/layers/layers.h"
#include "dynamic_occupancy_grid/core/layers/map_export.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "dynamic_occupancy_grid/ros/bag_offline_em.h"
#include "dynamic_occupancy_grid/ros/bag_scan_source.h"
#include "dynamic_occupancy_grid/ros/conversions.h"
#include "dynamic_occupancy_grid/ros/parameters.h"

namespace dog = dynamic_occupancy_grid;

namespace {

struct Options {
  dog::bag_tools::SharedOptions shared;
  std::string out_dir = "dynamic_occupancy_grid_output";
  std::string model_path;  ///< empty: out_dir/model.dogm
  bool offline_em = false;
  double snapshot_every_s = 0.0;  ///< 0: no snapshots
  double prediction_horizon_s = 60.0;
  double transition_scale = 0.1;
  dog::bag_tools::PoseCorrectionOptions correction;
  std::string trajectory_path;  ///< empty: out_dir/trajectory.tum (with pose correction)
};

Options parseArguments(int argc, char** argv) {
  namespace cl = dog::command_line;
  Options options;
  bool no_learning = false;
  bool no_learn_sensor_model = false;
  // As the node: the sensor model is learned (~learn_sensor_model).
  options.shared.mapper.learn_sensor_model = dog::ros_layer::kDefaultLearnSensorModel;
  std::vector<std::string> bags;
  cl::CommandLine line("process_bag", "usage: process_bag BAG [options]\n");
  line.options().add_options()
      ("out", cl::nonEmpty(&options.out_dir, "a directory")->value_name("DIR"),
       "output directory (default ./dynamic_occupancy_grid_output)")
      ("model", cl::nonEmpty(&options.model_path, "a file name")->value_name("FILE"),
       "model file to write (default DIR/model.dogm)")
      ("offline-em", boost::program_options::bool_switch(&options.offline_em),
       "after mapping, learn every cell's transitions by offline EM over the whole bag and use them (and its "
       "final beliefs)")
      ("no-learning", boost::program_options::bool_switch(&no_learning),
       "no online learning: cells keep the prior transitions")
      ("no-learn-sensor-model", boost::program_options::bool_switch(&no_learn_sensor_model),
       "keep the sensor model fixed at --p-hit-given-occ / --p-hit-given-free (default: learned online from "
       "them, as the node's ~learn_sensor_model)")
      ("snapshot-every", cl::number(&options.snapshot_every_s, cl::above(0.0))->value_name("S"),
       "also write all layers every S seconds of bag time into DIR/snapshots/<t>s/")
      ("prediction-horizon", cl::number(&options.prediction_horizon_s, cl::between(0.0, 1.0e9))->value_name("S"),
       "the 'predicted' layer looks S seconds ahead (default 60)")
      ("transition-scale", cl::number(&options.transition_scale, cl::between(1.0e-6, 1.0))->value_name("P"),
       "transition layers: P per step is written as 100 (default 0.1)")
      ("trajectory", cl::nonEmpty(&options.trajectory_path, "a file name")->value_name("FILE"),
       "pose correction: the laser's poses in the map frame at the filter's updates, as the scans were mapped "
       "(odometry moved by the correction in use), in TUM format, for evo (default DIR/trajectory.tum)");
  dog::bag_tools::addMappingOptions(line, &options.shared);
  dog::bag_tools::addEmOptions(line, &options.shared);
  dog::bag_tools::addPoseCorrectionOptions(line, &options.correction);
  line.hidden().add_options()("bag", boost::program_options::value(&bags));
  line.positional("bag");
  line.parse(argc, argv);
  if (bags.empty()) line.fail("no bag given");
  if (bags.size() > 1) line.fail("more than one bag given");
  options.shared.source.bag_path = bags.front();
  if (no_learning) options.shared.mapper.learn_transitions = false;
  if (no_learn_sensor_model) options.shared.mapper.learn_sensor_model = false;
  dog::bag_tools::validateSharedOptions(line, &options.shared);
  dog::bag_tools::validatePoseCorrectionOptions(line, options.shared, &options.correction);
  if (!options.correction.enabled && !options.trajectory_path.empty()) line.fail("--trajectory needs --pose-correction rbpf");
  if (options.model_path.empty()) options.model_path = (std::filesystem::path(options.out_dir) / "model.dogm").string();
  if (options.trajectory_path.empty()) {
    options.trajectory_path = (std::filesystem::path(options.out_dir) / "trajectory.tum").string();
  }
  return options;
}

// --prediction-horizon in the mapper's time steps.
std::int64_t horizonSteps(const Options& options) {
  return static_cast<std::int64_t>(std::llround(options.prediction_horizon_s / options.shared.mapper.time_step_s));
}

// All six layers at the mapper's last applied step into `directory` (PGM + YAML + .npy);
// with `report`, one line per layer on stdout.
void exportLayers(const dog::core::Mapper& mapper, const Options& options, const std::string& directory, bool report) {
  using dog::core::Layer;
  std::filesystem::create_directories(directory);
  const std::int64_t step = *mapper.lastAppliedStep();
  const std::int64_t horizon_steps = horizonSteps(options);
  const dog::core::CellBox box = mapper.grid().bounds();
  const dog::core::MapWindow window = mapper.grid().window(box);
  std::vector<float> values;
  std::vector<std::int8_t> occupancy;
  for (const Layer layer : {Layer::kBelief, Layer::kPredicted, Layer::kStationary, Layer::kOccGivenFree,
                            Layer::kFreeGivenOcc, Layer::kStatic}) {
    dog::core::evaluateLayer(mapper.grid(), layer, step, horizon_steps, box, &values);
    const bool transitions = layer == Layer::kOccGivenFree || layer == Layer::kFreeGivenOcc;
    dog::core::toOccupancyValues(values, transitions ? static_cast<float>(options.transition_scale) : 1.0f,
                                 &occupancy);
    const std::string name = dog::core::layerName(layer);
    dog::core::writeMapServerFiles(directory, name, window, occupancy);
    dog::core::writeNpyLayer(directory, name, window, values);
    if (!report) continue;
    std::size_t known = 0;
    std::size_t occupied = 0;
    for (const std::int8_t value : occupancy) {
      known += value >= 0 ? 1 : 0;
      occupied += value >= 65 ? 1 : 0;
    }
    std::printf("%-10s %lld x %lld cells, %zu observed, %zu occupied -> %s/%s.pgm (.yaml, .npy)\n", name.c_str(),
                static_cast<long long>(box.width()), static_cast<long long>(box.height()), known, occupied,
                directory.c_str(), name.c_str());
  }
}

// The trajectory as TUM text ("stamp x y z qx qy qz qw" per line, as evo reads it): the
// laser's poses in the map frame, a rotation about z.
std::string tumTrajectory(const std::vector<dog::core::TrajectoryNode>& trajectory) {
  std::string text = "# timestamp x y z qx qy qz qw: the laser's pose in the map frame (process_bag --pose-correction rbpf)\n";
  char line[256];
  for (const dog::core::TrajectoryNode& node : trajectory) {
    const geometry_msgs::Quaternion rotation = dog::ros_layer::toTransform(node.pose).rotation;
    std::snprintf(line, sizeof(line), "%.9f %.6f %.6f 0 0 0 %.9f %.9f\n", node.stamp_s, node.pose.x_m, node.pose.y_m,
                  rotation.z, rotation.w);
    text += line;
  }
  return text;
}

int run(const Options& options) {
  dog::core::Mapper mapper(options.shared.mapper);
  std::optional<dog::core::CorrectedMapping> correction;
  if (options.correction.enabled) {
    correction.emplace(mapper, options.correction.filter, options.correction.learned_min_observed_steps);
  }
  dog::ros_layer::BagScanSource source(options.shared.source);
  dog::core::SequenceBuilder recorder;
  if (options.offline_em) mapper.recordObservations(&recorder);
  dog::bag_tools::ProgressBar bar;

  // Snapshots: after the first scan past each multiple of snapshot_every_s (bag time since
  // the first scan), the layers at the last applied step.
  double next_snapshot_s = options.snapshot_every_s;
  std::size_t snapshots = 0;
  const auto snapshot = [&](const dog::core::Scan& scan) {
    if (options.snapshot_every_s <= 0.0 || !mapper.lastAppliedStep()) return;
    const double elapsed_s = scan.stamp_s - *mapper.clock().origin();
    if (elapsed_s < next_snapshot_s) return;
    const double taken_at_s = std::floor(elapsed_s / options.snapshot_every_s) * options.snapshot_every_s;
    exportLayers(mapper, options,
                 (std::filesystem::path(options.out_dir) / "snapshots" / dog::bag_tools::secondsName(taken_at_s)).string(),
                 false);
    ++snapshots;
    next_snapshot_s = taken_at_s + options.snapshot_every_s;
  };

  const auto start = std::chrono::steady_clock::now();
  const dog::ros_layer::BagMappingStats mapping = dog::ros_layer::mapBag(
      source, mapper, false,
      [&bar](double fraction) {
        bar.show("reading", fraction);
        return true;
      },
      snapshot, correction ? &*correction : nullptr);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const dog::ros_layer::BagScanStats& stats = mapping.source;

  std::printf("scans read: %zu, integrated: %zu, rejected: %zu", stats.scans_read, mapping.scans_integrated,
              mapping.scans_rejected);
  if (options.shared.source.static_laser_pose) {
    std::printf(" (static laser pose given, tf not read)\n");
  } else {
    std::printf(", without a pose in '%s': %zu\n", source.options().fixed_frame.c_str(), stats.scans_without_pose);
  }
  if (stats.scans_outside_time_range > 0) std::printf("  outside the time range: %zu\n", stats.scans_outside_time_range);
  if (mapping.scans_rejected > 0) std::printf("  last rejection: %s\n", mapping.last_rejection.c_str());
  if (stats.scans_without_pose > 0) std::printf("  last tf error: %s\n", stats.last_pose_error.c_str());
  std::printf("beams: %zu hits, %zu without return, %zu ignored (NaN, -inf, < range_min)\n", mapping.beams_hit,
              mapping.beams_no_return, mapping.beams_ignored);
  if (!mapper.lastAppliedStep()) {
    std::fprintf(stderr, "process_bag: %s; nothing to write\n",
                 dog::ros_layer::describeUnusableBag(options.shared.source.bag_path, mapping).c_str());
    return 1;
  }
  std::printf("time steps: %lld of %.3f s; bag %.1f s processed in %.2f s (%.0fx real time)\n",
              static_cast<long long>(*mapper.lastAppliedStep() + 1), options.shared.mapper.time_step_s,
              stats.bag_duration_s, seconds, seconds > 0.0 ? stats.bag_duration_s / seconds : 0.0);
  if (snapshots > 0) {
    std::printf("snapshots: %zu, every %g s -> %s/snapshots/\n", snapshots, options.snapshot_every_s,
                options.out_dir.c_str());
  }

  if (correction) {
    const dog::core::PoseFilter& filter = correction->filter();
    const std::vector<dog::core::TrajectoryNode> trajectory = correction->trajectory();
    const std::filesystem::path directory = std::filesystem::path(options.trajectory_path).parent_path();
    if (!directory.empty()) std::filesystem::create_directories(directory);
    dog::core::writeFileAtomically(options.trajectory_path, tumTrajectory(trajectory));
    const dog::core::Pose2D correction_now = correction->mapToOdometry();
    std::printf("pose correction: %zu particles, %zu updates, %zu resamplings; map -> odom changed %zu times (%zu "
                "scans mapped again), at the end (%.3f m, %.3f m, %.4f rad); %zu poses -> %s\n",
                filter.particles().size(), filter.updates(), filter.resamplings(), correction->correctionsTaken(),
                correction->scansRemapped(), correction_now.x_m, correction_now.y_m, correction_now.yaw_rad,
                trajectory.size(), options.trajectory_path.c_str());
    std::vector<double> n_eff = filter.effectiveSampleSizes();
    if (!n_eff.empty()) {
      std::sort(n_eff.begin(), n_eff.end());
      const std::size_t n = n_eff.size();
      const double median = n % 2 == 1 ? n_eff[n / 2] : 0.5 * (n_eff[n / 2 - 1] + n_eff[n / 2]);
      std::printf("pose filter: N_eff median %.2f (min %.2f, max %.2f) of %zu over %zu updates; %zu resampled; "
                  "%zu particle-updates refused by the guard; %.1f ms per update\n",
                  median, n_eff.front(), n_eff.back(), filter.particles().size(), n, filter.resamplings(),
                  filter.guardRefusals(), 1000.0 * filter.updateSeconds() / static_cast<double>(n));
    }
  }
  if (options.offline_em) dog::bag_tools::runOfflineEmAndApply(mapper, recorder, options.shared.em, bar);

  exportLayers(mapper, options, options.out_dir, true);
  if (correction) {
    // The best particle's own map (its trajectory's scans only) now and --prediction-horizon
    // ahead, beside the layers of the scans at the best particle's pose of their time. Empty
    // when no scan gave the filter a cell (every beam of the scans before the first update
    // unusable).
    for (const auto& [name, horizon] : {std::pair<const char*, std::int64_t>{"best_particle_belief", 0},
                                        std::pair<const char*, std::int64_t>{"best_particle_predicted", horizonSteps(options)}}) {
      const dog::core::ParticleBelief belief = correction->bestParticleBelief(horizon);
      if (belief.values.empty()) {
        std::printf("%s: the best particle has no cell yet; not written\n", name);
        continue;
      }
      std::vector<std::int8_t> occupancy;
      dog::core::toOccupancyValues(belief.values, 1.0f, &occupancy);
      dog::core::writeMapServerFiles(options.out_dir, name, belief.window, occupancy);
      dog::core::writeNpyLayer(options.out_dir, name, belief.window, belief.values);
      std::printf("%s %lld x %lld cells -> %s/%s.pgm (.yaml, .npy)\n", name,
                  static_cast<long long>(belief.window.cells.width()),
                  static_cast<long long>(belief.window.cells.height()), options.out_dir.c_str(), name);
    }
  }
  if (correction && !options.offline_em) {
    // The cells' beliefs from the best particle's own map, as the node's ~save_model.
    dog::core::BestParticleCells cells;
    dog::core::saveModelBytes(correction->serializeModel(&cells), options.model_path);
    std::printf("model -> %s (beliefs of %zu cells from the best particle's map, %zu kept)\n",
                options.model_path.c_str(), cells.replaced, cells.kept);
  } else {
    dog::core::saveModel(mapper, options.model_path);
    std::printf("model -> %s\n", options.model_path.c_str());
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const Options options = parseArguments(argc, argv);
  try {
    return run(options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "process_bag: %s\n", e.what());
    return 1;
  }
}
