// MappingNode: the services (run_offline_em, save_model, load_model, export_layers, reset,
// get_status, get_cell, predict_map) and what they share: ~file_directory, a new mapper.
#include "dynamic_occupancy_grid/ros/mapping_node.h"

#include <dynamic_occupancy_grid/OfflineEmProgress.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <iomanip>
#include <limits>
#include <stdexcept>
#include <string>
#include <sstream>
#include <utility>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/core/layers/file_io.h"
#include "dynamic_occupancy_grid/core/layers/map_export.h"
#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "dynamic_occupancy_grid/core/cell/online_em.h"
#include "dynamic_occupancy_grid/ros/bag_offline_em.h"
#include "mapping_node_internal.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {
namespace {

using mapping_node_internal::toRosTime;
using mapping_node_internal::sameLattice;
using mapping_node_internal::horizonSteps;
using mapping_node_internal::applySettingsModelFilesLeaveOut;

}  // namespace

void MappingNode::replaceMapper(std::unique_ptr<core::Mapper> mapper) {
  correction_.reset();  // it reads the mapper being replaced
  mapper_ = std::move(mapper);
  if (parameters_.pose_correction) restartCorrection();
  newest_stamp_s_.reset();
  steady_since_restart_s_.reset();
  if (mapper_->lastAppliedStep()) newest_stamp_s_ = mapper_->clock().stepStart(*mapper_->lastAppliedStep() + 1);
  for (Output& output : outputs_) {
    output.cache.reset();  // its tiles and versions were the old mapper's
    if (output.horizon_from_parameter) {
      output.view.horizon_steps = horizonSteps(parameters_.prediction_horizon_s, mapper_->config().time_step_s);
    }
  }
  publishLayers(true);
}

bool MappingNode::runOfflineEm(RunOfflineEm::Request& request, RunOfflineEm::Response& response) {
  // The services have threads of their own: another request may be opening its bag.
  std::unique_lock<std::mutex> request_lock(offline_em_request_mutex_, std::try_to_lock);
  if (!request_lock.owns_lock()) {
    response.success = false;
    response.message = "another run_offline_em request is being handled; try again when it has been answered";
    return true;
  }
  if (offline_em_running_) {
    response.success = false;
    response.message = "an offline EM run is already in progress; wait for phase 'done' or 'failed' on " +
                       offline_em_progress_.getTopic();
    return true;
  }
  BagOfflineEmOptions options;
  options.source.bag_path = request.bag_path;
  options.source.scan_topic = request.scan_topic.empty() ? parameters_.scan_topics.front() : request.scan_topic;
  options.source.fixed_frame = parameters_.fixed_frame;
  options.source.start_time_s = request.start_time.toSec();
  options.source.end_time_s = request.end_time.toSec();
  options.em = parameters_.offline_em;
  if (request.max_iterations > 0) options.em.max_iterations = request.max_iterations;
  if (request.tolerance >= 0.0) options.em.tolerance = request.tolerance;
  const auto refuse = [&response](const std::string& why) {
    response.success = false;
    response.message = why;
    ROS_ERROR("run_offline_em refused: %s", why.c_str());
    return true;
  };
  if (request.bag_path.empty()) return refuse("bag_path is empty");
  try {
    options.source.bag_path = requestPath(request.bag_path);
    // rosbag opens the bag by its name: a FIFO would block that open, a device be read.
    core::requireRegularFile(options.source.bag_path, "cannot read bag " + options.source.bag_path);
  } catch (const std::exception& e) {
    return refuse(e.what());
  }
  if (!std::isfinite(request.tolerance)) return refuse("tolerance must be a finite number");
  // 0 is the field's value when a caller leaves it out, so it means the node's parameter.
  if (!std::isfinite(request.mrf_temperature) || request.mrf_temperature < 0.0) {
    return refuse("mrf_temperature must be a finite number >= 0 (0 = ~offline_em/mrf_temperature)");
  }
  if (request.mrf_temperature > 0.0) {
    options.em.mrf_temperature = request.mrf_temperature;
    options.em.learn_sensor_model = false;  // the MRF's M-step does not learn it
  }
  if (options.source.end_time_s > 0.0 && options.source.end_time_s < options.source.start_time_s) {
    return refuse("end_time is before start_time");
  }
  try {
    options.em.validate();
  } catch (const std::invalid_argument& e) {
    return refuse(e.what());
  }
  // Open the bag now (index and /tf_static), so that a bad path, a corrupt bag, a topic it
  // lacks or a bag without tf is refused at once.
  std::shared_ptr<BagScanSource> source;
  try {
    source = std::make_shared<BagScanSource>(options.source);
  } catch (const std::exception& e) {
    return refuse(e.what());
  }
  core::MapperConfig geometry;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    geometry = mapper_->config();
  }
  if (offline_em_thread_.joinable()) offline_em_thread_.join();  // the previous run has ended
  offline_em_running_ = true;
  offline_em_cancel_ = false;
  offline_em_thread_ = std::thread([this, options, geometry, source] {
    OfflineEmProgress progress;
    progress.bag_path = options.source.bag_path;
    auto last_report = std::chrono::steady_clock::now();
    const auto report = [&](const std::string& phase, double fraction, const std::string& message) {
      progress.phase = phase;
      progress.fraction = static_cast<float>(fraction);
      progress.message = message;
      offline_em_progress_.publish(progress);
      setOfflineEmState(phase, fraction, message);
    };
    report("reading", 0.0, "reading the bag");
    ROS_INFO("offline EM: reading %s", options.source.bag_path.c_str());
    try {
      std::string current_phase = "reading";
      const BagOfflineEmRun run = runOfflineEmOnBag(*source, options.em, geometry, [&](const std::string& phase, double fraction) {
        const auto now = std::chrono::steady_clock::now();
        if (phase != current_phase || now - last_report > std::chrono::milliseconds(500)) {
          if (phase != current_phase) ROS_INFO("offline EM: %s", phase == "em" ? "running EM" : phase.c_str());
          current_phase = phase;
          last_report = now;
          report(phase, fraction, phase == "em" ? "running EM over the cells" : "reading the bag");
        }
        return !offline_em_cancel_;
      });
      if (run.result.cancelled) {
        report("failed", 0.0, "cancelled (the node is shutting down)");
      } else {
        std::lock_guard<std::mutex> lock(mutex_);
        if (!sameLattice(mapper_->config(), geometry)) {
          const std::string message =
              "a model with another resolution, origin or time step was loaded during the run; nothing applied";
          ROS_ERROR("offline EM: %s", message.c_str());
          report("failed", 1.0, message);
        } else {
          const core::OfflineEmApplied applied = mapper_->applyOfflineEm(run.sequences, run.result, false);
          progress.cells_applied = static_cast<std::uint32_t>(applied.cells_applied);
          progress.cells_not_in_map = static_cast<std::uint32_t>(applied.cells_not_in_map);
          progress.objective = run.result.objective;
          progress.mrf_temperature = options.em.mrf_temperature;
          for (const std::array<int, 2>& newton : run.result.mrf_newton_iterations) {
            progress.mrf_newton_iterations_occ.push_back(static_cast<std::uint32_t>(newton[0]));
            progress.mrf_newton_iterations_free.push_back(static_cast<std::uint32_t>(newton[1]));
          }
          std::ostringstream message;
          message << "transitions of " << applied.cells_applied << " cells replaced (" << applied.cells_not_in_map
                  << " cells of the bag not in this map were skipped); " << run.scans_integrated << " scans, "
                  << run.result.cells_converged << " of " << run.sequences.cellCount() << " cells converged";
          if (!run.result.objective.empty()) {
            message << "; " << run.result.objective.size() - 1 << " EM iterations, objective " << std::setprecision(10)
                    << run.result.objective.front() << " -> " << run.result.objective.back();
          }
          if (!run.result.mrf_newton_iterations.empty()) {
            const auto most = [](const std::vector<std::uint32_t>& values) {
              return *std::max_element(values.begin(), values.end());
            };
            message << "; MRF temperature " << options.em.mrf_temperature << ", at most "
                    << most(progress.mrf_newton_iterations_occ) << "/" << most(progress.mrf_newton_iterations_free)
                    << " Newton iterations per M-step (p(occ->occ)/p(free->free))";
          }
          ROS_INFO("offline EM done: %s", message.str().c_str());
          report("done", 1.0, message.str());
        }
      }
    } catch (const std::exception& e) {
      ROS_ERROR("offline EM on %s failed, the live model is unchanged: %s", options.source.bag_path.c_str(), e.what());
      report("failed", 0.0, e.what());
    }
    offline_em_running_ = false;
  });
  response.success = true;
  response.message =
      "offline EM started on " + options.source.bag_path + "; progress on " + offline_em_progress_.getTopic();
  return true;
}

namespace {

// A service's path without ~file_directory: relative to the node's working directory (as
// any file the node opens; ~/.ros under roslaunch), made absolute for the reply.
std::string absoluteServicePath(const std::string& path) {
  return std::filesystem::absolute(std::filesystem::path(path)).lexically_normal().string();
}

}  // namespace

bool MappingNode::prepareFiles() {
  namespace fs = std::filesystem;
  std::vector<std::string> directories;
  if (!parameters_.file_directory.empty()) {
    try {
      const fs::path directory = fs::absolute(fs::path(parameters_.file_directory));
      if (!fs::exists(directory)) {
        fs::create_directories(directory);
        ROS_INFO("~file_directory: created %s", directory.string().c_str());
      }
      if (!fs::is_directory(directory)) {
        ROS_FATAL("~file_directory: %s is not a directory", directory.string().c_str());
        return false;
      }
      file_directory_ = fs::canonical(directory).string();
    } catch (const fs::filesystem_error& e) {
      ROS_FATAL("~file_directory: cannot use %s: %s", parameters_.file_directory.c_str(), e.code().message().c_str());
      return false;
    }
    ROS_INFO("the services' paths are confined to %s (~file_directory)", file_directory_.c_str());
    directories.push_back(file_directory_);
  }
  if (!parameters_.model_file.empty()) {
    directories.push_back(fs::absolute(fs::path(parameters_.model_file)).lexically_normal().parent_path().string());
  }
  // Temporaries of saves killed mid-write (only the package's own pattern, only those no
  // writer holds), in the directories the node is configured to write to.
  std::sort(directories.begin(), directories.end());
  directories.erase(std::unique(directories.begin(), directories.end()), directories.end());
  for (const std::string& directory : directories) {
    const std::vector<std::string> removed = core::removeStaleTemporaries(directory);
    if (removed.empty()) continue;
    std::string names;
    for (const std::string& name : removed) names += (names.empty() ? "" : ", ") + name;
    ROS_WARN("removed %zu stale temporary file%s of interrupted saves from %s: %s", removed.size(),
             removed.size() == 1 ? "" : "s", directory.c_str(), names.c_str());
  }
  return true;
}

std::string MappingNode::requestPath(const std::string& path) const {
  if (path.empty()) throw std::runtime_error("path is empty");
  if (file_directory_.empty()) return absoluteServicePath(path);
  try {
    return core::resolveWithin(path, file_directory_);
  } catch (const std::runtime_error& e) {
    throw std::runtime_error("refused by ~file_directory: " + std::string(e.what()));
  }
}

bool MappingNode::saveModel(SaveModel::Request& request, SaveModel::Response& response) {
  if (request.path.empty()) {
    response.success = false;
    response.message = "path is empty";
    return true;
  }
  std::string path;
  try {
    path = requestPath(request.path);
  } catch (const std::exception& e) {
    response.success = false;
    response.message = "cannot save model file " + request.path + ": " + e.what();
    ROS_ERROR("save_model: %s", response.message.c_str());
    return true;
  }
  // Only the in-memory part under the map's lock; the file is written after.
  std::string bytes;
  core::BestParticleCells best_particle;
  bool corrected = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    // With pose correction, the cells' beliefs are the best particle's own map; a
    // re-mapping still running is waited for (the map the next scan would find).
    corrected = correction_ != nullptr;
    if (corrected) correction_->finish();
    bytes = corrected ? correction_->serializeModel(&best_particle) : core::serializeModel(*mapper_);
  }
  try {
    core::saveModelBytes(bytes, path);
  } catch (const std::exception& e) {
    response.success = false;
    response.message = e.what();
    ROS_ERROR("save_model: %s", e.what());
    return true;
  }
  response.success = true;
  response.message = "saved " + std::to_string(bytes.size()) + " bytes to " + path;
  if (corrected) {
    response.message += "; beliefs of " + std::to_string(best_particle.replaced) + " cells from the best particle's map, " +
                        std::to_string(best_particle.kept) + " kept";
  }
  return true;
}

bool MappingNode::loadModel(LoadModel::Request& request, LoadModel::Response& response) {
  const auto fail = [&response](const std::string& why) {
    response.success = false;
    response.message = why + "; the live model is unchanged";
    ROS_ERROR("load_model: %s", response.message.c_str());
    return true;
  };
  std::string path;
  try {
    path = requestPath(request.path);
  } catch (const std::exception& e) {
    return fail("cannot load model file " + request.path + ": " + e.what());
  }
  // Reading and checking the file without the map's lock: mapping goes on meanwhile.
  std::unique_ptr<core::Mapper> loaded;
  try {
    loaded = core::loadModel(path);
    applySettingsModelFilesLeaveOut(*loaded, parameters_.mapper);
  } catch (const std::exception& e) {
    return fail(e.what());
  }
  std::ostringstream message;
  message << "loaded " << path << ": " << loaded->config().resolution_m << " m cells, time step "
          << loaded->config().time_step_s << " s";
  if (loaded->lastAppliedStep()) message << ", steps up to " << *loaded->lastAppliedStep();
  std::lock_guard<std::mutex> load_lock(load_mutex_);
  DynamicOccupancyGridConfig values;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    replaceMapper(std::move(loaded));
    // The model's sensor model and learning flags replace the reconfigured ones.
    parameters_.mapper.p_hit_given_occ = mapper_->config().p_hit_given_occ;
    parameters_.mapper.p_hit_given_free = mapper_->config().p_hit_given_free;
    parameters_.mapper.learn_transitions = mapper_->config().learn_transitions;
    parameters_.mapper.learn_sensor_model = mapper_->config().learn_sensor_model;
    values = reconfigurableValues();
    reconfigured_ = values;
  }
  // Outside mutex_: the server's mutex is taken before mutex_ (reconfigure).
  if (reconfigure_server_) reconfigure_server_->updateConfig(values);
  response.success = true;
  response.message = message.str();
  ROS_INFO("%s", response.message.c_str());
  return true;
}

bool MappingNode::exportLayers(ExportLayers::Request& request, ExportLayers::Response& response) {
  struct Export {
    std::string name;
    std::vector<float> values;           // the layer's own values (.npy), NaN unknown
    std::vector<std::int8_t> occupancy;  // as published (PGM)
  };
  std::vector<Export> exports;
  core::MapWindow window;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (correction_) correction_->finish();  // a re-mapping still running: the map it makes
    const std::optional<std::int64_t> step = mapper_->lastAppliedStep();
    if (!step) {
      response.success = false;
      response.message = "no map yet: nothing to export";
      return true;
    }
    const core::CellBox bounds = mapper_->grid().bounds();
    window = mapper_->grid().window(bounds);
    // The six layers once each (the `map` output repeats the belief).
    for (std::size_t i = 0; i < 6 && i < outputs_.size(); ++i) {
      const LayerView& view = outputs_[i].view;
      Export layer{core::layerName(view.layer), {}, {}};
      core::evaluateLayer(mapper_->grid(), view.layer, *step, view.horizon_steps, bounds, &layer.values);
      core::toOccupancyValues(layer.values, view.full_scale, &layer.occupancy);
      exports.push_back(std::move(layer));
    }
  }
  // The files are written without the map's lock: mapping goes on meanwhile.
  std::string directory;
  try {
    if (request.directory.empty()) throw std::runtime_error("directory is empty");
    directory = requestPath(request.directory);
    std::filesystem::create_directories(directory);
    if (!file_directory_.empty()) {
      // Each file too (before any is written): one may be a link leading out of it.
      for (const Export& layer : exports) {
        for (const char* extension : {".pgm", ".yaml", ".npy"}) requestPath(directory + "/" + layer.name + extension);
      }
    }
    for (const Export& layer : exports) {
      core::writeMapServerFiles(directory, layer.name, window, layer.occupancy);
      core::writeNpyLayer(directory, layer.name, window, layer.values);
      for (const char* extension : {".pgm", ".yaml", ".npy"}) {
        response.files.push_back(directory + "/" + layer.name + extension);
      }
    }
  } catch (const std::exception& e) {
    response.success = false;
    response.message = e.what();
    ROS_ERROR("export_layers: %s", e.what());
    return true;
  }
  response.success = true;
  response.message = "wrote " + std::to_string(exports.size()) + " layers to " + directory;
  return true;
}

bool MappingNode::reset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& response) {
  std::lock_guard<std::mutex> lock(mutex_);
  // An empty map with the current model's configuration (a loaded model's, if any).
  if (mapper_) replaceMapper(std::make_unique<core::Mapper>(mapper_->config()));
  if (memory_) {
    memory_ = std::make_unique<core::MemoryModel>(memory_->config());
    memory_stamp_.reset();
    publishMemory(true);
  }
  response.success = true;
  response.message = mapper_ && memory_ ? "map and memory cleared" : mapper_ ? "map cleared" : "memory cleared";
  ROS_INFO("%s by ~reset", response.message.c_str());
  return true;
}

bool MappingNode::getStatus(GetStatus::Request&, GetStatus::Response& response) {
  response.scans_received = scan_counts_.received;
  response.scans_integrated = scan_counts_.integrated;
  response.scans_dropped_tf = scan_counts_.dropped_tf;
  response.scans_dropped_invalid = scan_counts_.dropped_invalid;
  response.scans_dropped_late = scan_counts_.dropped_late;
  response.scans_refused_by_memory = scan_counts_.memory_rejected;
  response.last_applied_step = -1;
  std::lock_guard<std::mutex> lock(mutex_);
  const std::optional<std::int64_t> step = mapper_ ? mapper_->lastAppliedStep() : std::nullopt;
  if (step) {
    response.last_applied_step = *step;
    response.map_stamp = mapper_->clock().stepStart(*step + 1);
  }
  if (correction_) {
    const core::PoseFilter& filter = correction_->filter();
    const core::Pose2D map_to_odom = correction_->mapToOdometry();
    response.pose_correction = true;
    response.pose_correction_updates = filter.updates();
    response.pose_correction_resamplings = filter.resamplings();
    response.map_to_odom_x = map_to_odom.x_m;
    response.map_to_odom_y = map_to_odom.y_m;
    response.map_to_odom_yaw = map_to_odom.yaw_rad;
    if (filter.started()) {
      response.effective_sample_size = last_effective_sample_size_;
      response.pose_entropy = filter.poseEntropy();
    }
  }
  return true;
}

bool MappingNode::getCell(GetCell::Request& request, GetCell::Response& response) {
  if (!std::isfinite(request.x) || !std::isfinite(request.y)) {
    response.message = "x and y must be finite";
    return true;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (correction_) correction_->finish();  // a re-mapping still running: the map it makes
  const core::CellGrid& grid = mapper_->grid();
  const double u = std::floor(grid.toLatticeX(request.x));
  const double v = std::floor(grid.toLatticeY(request.y));
  constexpr double kLimit = std::numeric_limits<std::int32_t>::max();
  if (std::abs(u) >= kLimit || std::abs(v) >= kLimit) {
    response.message = "point is far outside any map";
    return true;
  }
  response.cell_x = static_cast<std::int32_t>(u);
  response.cell_y = static_cast<std::int32_t>(v);
  response.center_x = grid.anchorX() + (u + 0.5) * grid.resolution();
  response.center_y = grid.anchorY() + (v + 0.5) * grid.resolution();
  const std::optional<core::CellState> state = grid.cell(response.cell_x, response.cell_y);
  if (!state || !mapper_->lastAppliedStep()) {
    response.observed = false;
    response.message = "cell never observed";
    return true;
  }
  const std::int64_t now = *mapper_->lastAppliedStep();
  const core::TransitionParams params{state->p_occ_given_free, state->p_free_given_occ};
  response.observed = true;
  response.belief = core::predictOccupancy(state->p_occ, params, now - state->last_step);
  response.p_occ_given_free = params.p_occ_given_free;
  response.p_free_given_occ = params.p_free_given_occ;
  response.stationary_p_occ = core::stationaryOccupancy(params).value_or(std::numeric_limits<double>::quiet_NaN());
  const std::optional<std::int64_t> mixing = core::mixingTime(response.belief, params, 0.01);
  response.mixing_time_steps = mixing.value_or(-1);
  response.mixing_time_s = mixing ? static_cast<double>(*mixing) * mapper_->config().time_step_s : -1.0;
  response.static_p_occ = core::logOddsToProbability(state->log_odds);
  response.last_observed_step = state->last_step;
  response.steps_since_observed = now - state->last_step;
  response.observed_steps = state->observed_steps;
  if (mapper_->config().learner == core::TransitionLearner::kKinds) {
    response.learner = "kinds";
    core::KindJoint joint;
    for (int k = 0; k < 2 * core::kKindCount; ++k) joint.p[k] = state->em_stats[k];
    double total = 0.0;
    for (int k = 0; k < core::kKindCount; ++k) total += joint.kind(k);
    for (int k = 0; k < core::kKindCount; ++k) response.kind_posterior.push_back(joint.kind(k) / total);
  } else {
    response.learner = "cell_em";
    core::TransitionStats stats;
    for (std::size_t k = 0; k < stats.s.size(); ++k) stats.s[k] = state->em_stats[k];
    response.expected_transitions = {stats.transitions(0, 0), stats.transitions(0, 1), stats.transitions(1, 0),
                                     stats.transitions(1, 1)};
  }
  response.message = "ok";
  return true;
}

bool MappingNode::predictMap(PredictMap::Request& request, PredictMap::Response& response) {
  if (!std::isfinite(request.horizon) || request.horizon < 0.0 || request.horizon > 1.0e12) {
    response.success = false;
    response.message = "horizon must be a number of seconds in [0, 1e12]";
    return true;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (correction_) correction_->finish();  // a re-mapping still running: the map it makes
  const std::optional<std::int64_t> step = mapper_->lastAppliedStep();
  if (!step) {
    response.success = false;
    response.message = "no map yet";
    return true;
  }
  const LayerView view{core::Layer::kPredicted, 1.0f, horizonSteps(request.horizon, mapper_->config().time_step_s),
                       std::nullopt};
  const core::CellBox bounds = mapper_->grid().bounds();
  response.map = toOccupancyGrid(mapper_->grid().window(bounds), layerValues(mapper_->grid(), view, *step, bounds),
                                 parameters_.fixed_frame,
                                 toRosTime(mapper_->clock().stepStart(*step + 1 + view.horizon_steps)));
  response.success = true;
  response.message = "p(occ) " + std::to_string(view.horizon_steps) + " steps after step " + std::to_string(*step);
  return true;
}

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
