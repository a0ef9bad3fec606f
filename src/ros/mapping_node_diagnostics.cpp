// MappingNode: its health on /diagnostics (diagnostic_updater) and the parameters that may
// change while mapping (dynamic_reconfigure).
#include "dynamic_occupancy_grid/ros/mapping_node.h"

#include <boost/bind/bind.hpp>
#include <cmath>
#include <cstdint>
#include <iomanip>
#include <stdexcept>
#include <string>
#include <sstream>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "mapping_node_internal.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {
namespace {

using mapping_node_internal::kStampOffsetToleranceS;
using mapping_node_internal::horizonSteps;

}  // namespace

void MappingNode::startDiagnostics() {
  // Named after the node (the nodelet's name in a manager), as ros::this_node would be.
  diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh_, private_nh_, private_nh_.getNamespace());
  diagnostics_->setHardwareID("none");  // a mapping node, no device of its own
  for (const std::string& topic : parameters_.scan_topics) {
    // The rate over the last 5 reports, against [min, max] +- 10 % (diagnostic_updater's
    // FrequencyStatus: ERROR without any scan in that window, WARN outside the range).
    scan_rates_.push_back(std::make_unique<diagnostic_updater::HeaderlessTopicDiagnostic>(
        "scans " + nh_.resolveName(topic), *diagnostics_,
        diagnostic_updater::FrequencyStatusParam(&parameters_.min_scan_rate_hz, &parameters_.max_scan_rate_hz, 0.1,
                                                 5)));
  }
  diagnostics_->add("scans dropped", this, &MappingNode::diagnoseScans);
  diagnostics_->add("tf", this, &MappingNode::diagnoseTf);
  diagnostics_->add("map", this, &MappingNode::diagnoseMap);
  if (mapper_) diagnostics_->add("offline EM", this, &MappingNode::diagnoseOfflineEm);
  diagnostics_timer_ = private_nh_.createTimer(ros::Duration(parameters_.diagnostics_period_s),
                                               [this](const ros::TimerEvent&) { diagnostics_->force_update(); });
}

void MappingNode::diagnoseScans(diagnostic_updater::DiagnosticStatusWrapper& status) {
  const std::uint64_t tf = scan_counts_.dropped_tf;
  const std::uint64_t invalid = scan_counts_.dropped_invalid;
  const std::uint64_t late = scan_counts_.dropped_late;
  const std::uint64_t memory = scan_counts_.memory_rejected;
  const std::uint64_t dropped = tf + invalid + late + memory;
  std::uint64_t new_drops = 0;
  {
    std::lock_guard<std::mutex> lock(diagnostics_mutex_);
    new_drops = dropped - scans_reported_dropped_;
    scans_reported_dropped_ = dropped;
  }
  if (new_drops == 0) {
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "no scan dropped since the last report");
  } else {
    status.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "%llu scans dropped since the last report (see the log)",
                    static_cast<unsigned long long>(new_drops));
  }
  status.add("received", scan_counts_.received.load());
  status.add("integrated", scan_counts_.integrated.load());
  status.add("dropped: no transform (tf)", tf);
  status.add("dropped: invalid (stamp, shape, laser pose)", invalid);
  status.add("dropped: late (step already applied)", late);
  if (memory_) status.add("refused by the memory model", memory);
}

void MappingNode::diagnoseTf(diagnostic_updater::DiagnosticStatusWrapper& status) {
  const std::uint64_t dropped = scan_counts_.dropped_tf;
  const std::uint64_t integrated = scan_counts_.integrated;
  std::lock_guard<std::mutex> lock(diagnostics_mutex_);
  const std::uint64_t new_drops = dropped - tf_reported_dropped_;
  const std::uint64_t new_integrated = integrated - tf_reported_integrated_;
  tf_reported_dropped_ = dropped;
  tf_reported_integrated_ = integrated;
  if (new_drops == 0) {
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, "no scan lacked its transform since the last report");
  } else if (new_integrated == 0) {
    status.summaryf(diagnostic_msgs::DiagnosticStatus::ERROR,
                    "no transform to '%s' for any scan since the last report (%llu dropped)",
                    parameters_.fixed_frame.c_str(), static_cast<unsigned long long>(new_drops));
  } else {
    status.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "%llu scans without a transform to '%s' since the last report",
                    static_cast<unsigned long long>(new_drops), parameters_.fixed_frame.c_str());
  }
  status.add("fixed frame", parameters_.fixed_frame);
  status.add("scans dropped for tf since the last report", new_drops);
  status.add("tf failures", dropped);
  status.add("last tf failure", last_tf_error_.empty() ? std::string("none") : last_tf_error_);
}

void MappingNode::diagnoseMap(diagnostic_updater::DiagnosticStatusWrapper& status) {
  std::lock_guard<std::mutex> lock(mutex_);
  status.summary(diagnostic_msgs::DiagnosticStatus::OK, "mapping");
  // 0: the scans' stamps are on ROS time's clock (within kStampOffsetToleranceS).
  const double offset_s = stamp_offset_s_;
  status.addf("scan stamps - ROS time (s)", "%.3f", offset_s);
  if (mapper_) {
    const std::optional<std::int64_t> step = mapper_->lastAppliedStep();
    const double cells = static_cast<double>(mapper_->grid().allocatedTiles()) * core::CellGrid::kTileCells;
    status.add("cells allocated", static_cast<std::uint64_t>(cells));
    status.addf("cell memory (MiB)", "%.1f", cells * core::CellGrid::bytesPerCell() / (1024.0 * 1024.0));
    status.add("time step (s)", mapper_->config().time_step_s);
    status.add("learn transitions", mapper_->config().learn_transitions);
    const bool kinds = mapper_->config().learner == core::TransitionLearner::kKinds;
    status.add("learner", kinds ? "kinds" : "cell_em");
    if (kinds) {
      // What the map has learned its places to be: each kind's transitions and share.
      for (int k = 0; k < core::kKindCount; ++k) {
        const core::TransitionParams& t = mapper_->kinds().transitions(k);
        status.addf("kind " + std::to_string(k), "p_occ_given_free %.5f, p_free_given_occ %.5f, share %.4f",
                    t.p_occ_given_free, t.p_free_given_occ, mapper_->kinds().weight(k));
      }
    }
    // The sensor model in use: the configured one, or the one learned so far.
    status.add("learn sensor model", mapper_->config().learn_sensor_model);
    status.add("sensor model p_hit_given_occ", mapper_->sensor().pHitGivenOcc());
    status.add("sensor model p_hit_given_free", mapper_->sensor().pHitGivenFree());
    const core::SensorModelStats& sensor_stats = mapper_->sensorModelStats();
    status.add("sensor model learned from (beam ends)", sensor_stats.trials[0] + sensor_stats.trials[1]);
    if (correction_) {
      const core::PoseFilter& filter = correction_->filter();
      const core::Pose2D map_to_odom = correction_->mapToOdometry();
      status.add("pose correction", "rbpf");
      status.add("pose correction particles", filter.particles().size());
      status.add("pose correction updates", filter.updates());
      status.add("pose correction resamplings", filter.resamplings());
      if (filter.started()) {
        status.addf("pose correction effective sample size (last update, before resampling)", "%.2f",
                    last_effective_sample_size_);
        status.addf("pose correction pose entropy", "%.3f", filter.poseEntropy());
      }
      status.addf("pose correction map -> odom", "x %.3f m, y %.3f m, yaw %.4f rad", map_to_odom.x_m, map_to_odom.y_m,
                  map_to_odom.yaw_rad);
    }
    if (!step) {
      status.summary(diagnostic_msgs::DiagnosticStatus::OK, "no step applied yet");
      status.add("last applied step", "none");
    } else {
      // The map's time is the end of its last applied step; how far ROS time (on the scans'
      // clock) is ahead of it.
      const double lag_s = scanClockNow().toSec() - mapper_->clock().stepStart(*step + 1);
      std::ostringstream time;
      time << "ROS time";
      if (offset_s != 0.0) {
        time << " on the scans' clock (their stamps are " << std::fixed << std::setprecision(3) << std::abs(offset_s)
             << " s " << (offset_s > 0.0 ? "ahead of" : "behind") << " ROS time)";
      }
      status.add("last applied step", *step);
      status.addf("step lag (s)", "%.3f", lag_s);
      if (lag_s > parameters_.max_step_lag_s) {
        status.summaryf(diagnostic_msgs::DiagnosticStatus::WARN,
                        "the map is %.1f s behind %s (more than diagnostics/max_step_lag %.1f s)", lag_s,
                        time.str().c_str(), parameters_.max_step_lag_s);
      } else {
        status.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "mapping, %.2f s behind %s", lag_s, time.str().c_str());
      }
    }
    status.add("gathering step", mapper_->gatheringStep() ? std::to_string(*mapper_->gatheringStep()) : "none");
  }
  if (memory_) {
    status.add("memory model updates", static_cast<std::uint64_t>(memory_->updates()));
    status.add("memory model LTM cells", static_cast<std::uint64_t>(memory_->ltmCells()));
    status.add("memory model STM cells", static_cast<std::uint64_t>(memory_->stmCells()));
  }
}

void MappingNode::setOfflineEmState(const std::string& phase, double fraction, const std::string& message) {
  std::lock_guard<std::mutex> lock(diagnostics_mutex_);
  offline_em_phase_ = phase;
  offline_em_fraction_ = fraction;
  offline_em_message_ = message;
}

void MappingNode::diagnoseOfflineEm(diagnostic_updater::DiagnosticStatusWrapper& status) {
  std::lock_guard<std::mutex> lock(diagnostics_mutex_);
  if (offline_em_phase_ == "failed") {
    status.summary(diagnostic_msgs::DiagnosticStatus::WARN, "the last run failed: " + offline_em_message_);
  } else if (offline_em_running_) {
    status.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "running: %s, %.0f %%", offline_em_phase_.c_str(),
                    100.0 * offline_em_fraction_);
  } else {
    status.summary(diagnostic_msgs::DiagnosticStatus::OK, offline_em_phase_ == "idle" ? "idle (never run)" : "idle");
  }
  status.add("running", static_cast<bool>(offline_em_running_));
  status.add("phase", offline_em_phase_);
  status.add("fraction", offline_em_fraction_);
  status.add("message", offline_em_message_);
}

DynamicOccupancyGridConfig MappingNode::reconfigurableValues() const {
  // From the .cfg defaults: a default-constructed config leaves its members uninitialised
  // (UBSan: a bool holding 191), and the copy below would read them.
  DynamicOccupancyGridConfig values = DynamicOccupancyGridConfig::__getDefault__();
  // A loaded model's sensor model (the start of learning, with learn_sensor_model) and
  // learning flags are the ones in use.
  const core::MapperConfig& mapper = mapper_ ? mapper_->config() : parameters_.mapper;
  values.p_hit_given_occ = mapper.p_hit_given_occ;
  values.p_hit_given_free = mapper.p_hit_given_free;
  values.learn_transitions = mapper.learn_transitions;
  values.learn_sensor_model = mapper.learn_sensor_model;
  values.max_range = parameters_.max_range_m;
  values.publish_period = parameters_.publish_period_s;
  values.full_map_period = parameters_.full_map_period_s;
  values.prediction_horizon = parameters_.prediction_horizon_s;
  values.transition_scale = parameters_.transition_scale;
  return values;
}

void MappingNode::startReconfigure() {
  DynamicOccupancyGridConfig values;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    values = reconfigurableValues();
    reconfigured_ = values;
  }
  reconfigure_server_ =
      std::make_unique<dynamic_reconfigure::Server<DynamicOccupancyGridConfig>>(reconfigure_mutex_, private_nh_);
  // The server starts from its .cfg defaults and the parameter server; the values read (or
  // a loaded model's) win.
  reconfigure_server_->updateConfig(values);
  reconfigure_server_->setCallback(
      boost::bind(&MappingNode::reconfigure, this, boost::placeholders::_1, boost::placeholders::_2));
}

void MappingNode::reconfigure(DynamicOccupancyGridConfig& config, std::uint32_t) {
  std::lock_guard<std::mutex> lock(mutex_);
  std::string refused;
  const bool sensor_changed = config.p_hit_given_occ != reconfigured_.p_hit_given_occ ||
                              config.p_hit_given_free != reconfigured_.p_hit_given_free;
  if (!(config.p_hit_given_occ > config.p_hit_given_free)) {
    refused = "p_hit_given_occ (" + std::to_string(config.p_hit_given_occ) + ") must be > p_hit_given_free (" +
              std::to_string(config.p_hit_given_free) + ")";
  } else if (!(config.publish_period > 0.0) || !(config.full_map_period >= 0.0) ||
             !(config.prediction_horizon >= 0.0) || !(config.transition_scale > 0.0 && config.transition_scale <= 1.0) ||
             !(config.max_range > 0.0)) {
    refused = "a value is out of its range (publish_period > 0, full_map_period >= 0, prediction_horizon >= 0, "
              "transition_scale in (0, 1], max_range > 0)";
  } else if (sensor_changed) {
    // Only a new sensor model is set: with learn_sensor_model, setting it restarts learning
    // from it, which another parameter's change (or the server's first call) must not do.
    try {
      if (mapper_) {
        mapper_->setSensorModel(config.p_hit_given_occ, config.p_hit_given_free);
      } else {
        static_cast<void>(core::ObservationModel(config.p_hit_given_occ, config.p_hit_given_free));
      }
    } catch (const std::invalid_argument& e) {
      refused = e.what();
    }
  }
  if (!refused.empty()) {
    ROS_WARN("dynamic_reconfigure: refused, keeping the previous values: %s", refused.c_str());
    config = reconfigured_;
    return;
  }
  parameters_.mapper.p_hit_given_occ = config.p_hit_given_occ;
  parameters_.mapper.p_hit_given_free = config.p_hit_given_free;
  parameters_.mapper.learn_transitions = config.learn_transitions;
  if (mapper_) mapper_->setLearnTransitions(config.learn_transitions);
  parameters_.mapper.learn_sensor_model = config.learn_sensor_model;
  if (mapper_) mapper_->setLearnSensorModel(config.learn_sensor_model);
  parameters_.max_range_m = config.max_range;
  parameters_.full_map_period_s = config.full_map_period;
  if (config.publish_period != parameters_.publish_period_s) {
    parameters_.publish_period_s = config.publish_period;
    publish_timer_.setPeriod(ros::Duration(parameters_.publish_period_s));
  }
  const bool horizon_changed = config.prediction_horizon != parameters_.prediction_horizon_s;
  const bool scale_changed = config.transition_scale != parameters_.transition_scale;
  parameters_.prediction_horizon_s = config.prediction_horizon;
  parameters_.transition_scale = config.transition_scale;
  for (Output& output : outputs_) {
    if (output.horizon_from_parameter && horizon_changed) {
      output.view.horizon_steps = horizonSteps(parameters_.prediction_horizon_s, mapper_->config().time_step_s);
      output.needs_full = true;
    }
    const bool transition = output.view.layer == core::Layer::kOccGivenFree ||
                            output.view.layer == core::Layer::kFreeGivenOcc;
    if (transition && scale_changed) {
      output.view.full_scale = static_cast<float>(parameters_.transition_scale);
      output.cache.reset();
      output.needs_full = true;
    }
  }
  reconfigured_ = config;
  ROS_INFO("dynamic_reconfigure: p_hit_given_occ %.3f, p_hit_given_free %.3f%s, learn_transitions %s, "
           "learn_sensor_model %s, max_range %.2f m, publish_period %.3f s, full_map_period %.3f s, "
           "prediction_horizon %.3f s, transition_scale %.4f",
           config.p_hit_given_occ, config.p_hit_given_free,
           sensor_changed && config.learn_sensor_model ? " (sensor model learning restarts from them)" : "",
           config.learn_transitions ? "true" : "false", config.learn_sensor_model ? "true" : "false",
           config.max_range, config.publish_period, config.full_map_period, config.prediction_horizon,
           config.transition_scale);
}

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
