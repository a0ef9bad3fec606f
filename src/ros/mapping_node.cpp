// MappingNode: construction and start-up (parameters, publishers, subscriptions, services),
// the scan path (tf, the stamps' clock, the cell HMM and the memory model) and the pose
// correction. Diagnostics and dynamic_reconfigure: mapping_node_diagnostics.cpp; the map
// topics: mapping_node_publishing.cpp; the services: mapping_node_services.cpp.
#include "dynamic_occupancy_grid/ros/mapping_node.h"

#include <dynamic_occupancy_grid/OfflineEmProgress.h>
#include <geometry_msgs/TransformStamped.h>
#include <std_msgs/Float64.h>
#include <tf2/exceptions.h>

#include <boost/bind/bind.hpp>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <exception>
#include <iomanip>
#include <stdexcept>
#include <string>
#include <sstream>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "dynamic_occupancy_grid/core/cell/online_em.h"
#include "dynamic_occupancy_grid/ros/conversions.h"
#include "mapping_node_internal.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {
namespace {

using mapping_node_internal::kStampOffsetToleranceS;
using mapping_node_internal::toRosTime;
using mapping_node_internal::sameLattice;
using mapping_node_internal::horizonSteps;
using mapping_node_internal::applySettingsModelFilesLeaveOut;

// Seconds between repeated warnings of the same kind from per-message callbacks.
constexpr double kWarnPeriodS = 5.0;
/// Wall seconds a scan's frame may lack its transform before the node warns (tf at start-up).
constexpr double kMissingFrameGraceS = 1.0;
constexpr std::size_t kMaxFramesWithoutTransform = 64;
/// The scans whose stamps the node measures against ROS time at the start (and after ROS
/// time went back); their lower median is the offset, so one scan stamped wrong among them
/// does not set it.
constexpr std::size_t kStampOffsetScans = 5;

// The start-up lines on the learners in use (a loaded model's configuration, if any).
void logLearners(const core::MapperConfig& config) {
  const core::OnlineEmConfig& em = config.online_em;
  if (config.learn_transitions && config.learner == core::TransitionLearner::kKinds) {
    ROS_INFO("online learning of the transitions: %d kinds of cells learned from the whole map (kind switch "
             "probability %g per step, forgetting %g per step, a cell's state switches with probability %g at an "
             "observed step from a new view: kinds/view_switch_probability)",
             core::kKindCount, config.kinds.switch_probability, config.kinds.forgetting,
             config.kinds.view_switch_probability);
  } else if (config.learn_transitions) {
    std::ostringstream line;
    line << "online EM of the transitions: prior weight " << em.prior_weight << ", learning rate floor "
         << em.learning_rate_floor << ", prior fixed (" << config.prior_transitions.p_occ_given_free << " / "
         << config.prior_transitions.p_free_given_occ << ")";
    ROS_INFO("%s", line.str().c_str());
  }
  if (config.sensor_model_mixed_step_probability > 0.0) {
    ROS_INFO("steps whose beams disagree may come from a partly covered cell with probability %g "
             "(sensor_model/mixed_step_probability)",
             config.sensor_model_mixed_step_probability);
  }
  if (config.learn_sensor_model) {
    ROS_INFO("online learning of the sensor model: from p_hit_given_occ %g, p_hit_given_free %g, worth %g beam "
             "ends per state (sensor_model/prior_weight), within [%g, %g] (sensor_model/p_min)",
             config.p_hit_given_occ, config.p_hit_given_free, config.sensor_model_prior_weight,
             config.sensor_model_p_min, 1.0 - config.sensor_model_p_min);
  }
}

}  // namespace

MappingNode::MappingNode(const ros::NodeHandle& nh, const ros::NodeHandle& private_nh)
    : nh_(nh), private_nh_(private_nh), service_nh_(private_nh) {
  service_nh_.setCallbackQueue(&service_queue_);
}

MappingNode::~MappingNode() {
  if (correction_spinner_) correction_spinner_->stop();
  // No request is served once this returns (it waits for those being served).
  if (service_spinner_) service_spinner_->stop();
  services_.clear();
  offline_em_cancel_ = true;
  if (offline_em_thread_.joinable()) offline_em_thread_.join();
}

bool MappingNode::start() {
  std::string error;
  std::vector<std::string> unknown;
  if (!readParameters(private_nh_, &parameters_, &error, &unknown)) {
    ROS_FATAL("%s", error.c_str());
    return false;
  }
  for (const std::string& name : unknown) {
    ROS_WARN("parameter %s is not one of this node's parameters (a typo?); it is ignored", name.c_str());
  }
  if (!prepareFiles()) return false;
  if (parameters_.runsHmm() && !parameters_.model_file.empty()) {
    try {
      mapper_ = core::loadModel(parameters_.model_file);
      applySettingsModelFilesLeaveOut(*mapper_, parameters_.mapper);
    } catch (const std::exception& e) {
      ROS_FATAL("~model_file: %s", e.what());
      return false;
    }
    if (!sameLattice(mapper_->config(), parameters_.mapper)) {
      ROS_WARN("the model %s has its own resolution/origin/time step (%.3f m, %.3f s), which replace the "
               "parameters'", parameters_.model_file.c_str(), mapper_->config().resolution_m,
               mapper_->config().time_step_s);
    }
    if (mapper_->lastAppliedStep()) {
      newest_stamp_s_ = mapper_->clock().stepStart(*mapper_->lastAppliedStep() + 1);
    }
    ROS_INFO("loaded model %s", parameters_.model_file.c_str());
  } else if (parameters_.runsHmm()) {
    mapper_ = std::make_unique<core::Mapper>(parameters_.mapper);
  }
  if (parameters_.pose_correction) restartCorrection();
  if (parameters_.runsMemory()) {
    core::MemoryModelConfig memory_config = parameters_.memory;
    if (mapper_) {
      // Both models on one lattice: a loaded model's, if any.
      const core::MapperConfig& lattice = mapper_->config();
      memory_config.resolution_m = lattice.resolution_m;
      memory_config.origin_x_m = lattice.origin_x_m;
      memory_config.origin_y_m = lattice.origin_y_m;
      memory_config.max_free_range_m = lattice.max_free_range_m;
      memory_config.max_map_size_m = lattice.max_map_size_m;
    }
    try {
      memory_ = std::make_unique<core::MemoryModel>(memory_config);
    } catch (const std::invalid_argument& e) {
      ROS_FATAL("the memory model cannot use the grid of the model %s: %s", parameters_.model_file.c_str(), e.what());
      return false;
    }
  }

  if (mapper_) advertiseHmm();
  if (memory_) advertiseMemory();
  startDiagnostics();
  services_.push_back(service_nh_.advertiseService("reset", &MappingNode::reset, this));
  services_.push_back(service_nh_.advertiseService("get_status", &MappingNode::getStatus, this));

  tf_listener_ = std::make_unique<tf2_ros::TransformListener>(tf_buffer_, nh_);
  for (const std::string& topic : parameters_.scan_topics) {
    scan_subscribers_.push_back(
        std::make_unique<message_filters::Subscriber<sensor_msgs::LaserScan>>(nh_, topic, parameters_.scan_queue_size));
    scan_filters_.push_back(std::make_unique<tf2_ros::MessageFilter<sensor_msgs::LaserScan>>(
        *scan_subscribers_.back(), tf_buffer_, laserPoseFrame(),
        static_cast<std::uint32_t>(parameters_.scan_queue_size), nh_));
    scan_filters_.back()->registerCallback(boost::bind(&MappingNode::scanCallback, this, boost::placeholders::_1));
    scan_filters_.back()->registerFailureCallback(
        boost::bind(&MappingNode::scanDropped, this, boost::placeholders::_1, boost::placeholders::_2));
    // After the tf filter's own connection: every scan that arrives, for its rate.
    scan_subscribers_.back()->registerCallback(
        boost::bind(&MappingNode::scanArrived, this, boost::placeholders::_1, scan_subscribers_.size() - 1));
  }
  publish_timer_ = private_nh_.createTimer(ros::Duration(parameters_.publish_period_s), &MappingNode::publishTimer, this);
  if (correction_) {
    effective_sample_size_ = private_nh_.advertise<std_msgs::Float64>("effective_sample_size", 10);
    pose_entropy_ = private_nh_.advertise<std_msgs::Float64>("pose_entropy", 10);
    const auto connected = [this](const ros::SingleSubscriberPublisher&) {
      std::lock_guard<std::mutex> lock(mutex_);
      publishBestParticle(true);
    };
    best_particle_belief_ = private_nh_.advertise<nav_msgs::OccupancyGrid>(
        "best_particle_belief", 1, connected, ros::SubscriberStatusCallback(), ros::VoidConstPtr(), true);
    best_particle_predicted_ = private_nh_.advertise<nav_msgs::OccupancyGrid>(
        "best_particle_predicted", 1, connected, ros::SubscriberStatusCallback(), ros::VoidConstPtr(), true);
    tf_broadcaster_ = std::make_unique<tf2_ros::TransformBroadcaster>();
    ros::NodeHandle correction_nh(private_nh_);
    correction_nh.setCallbackQueue(&correction_queue_);
    correction_timer_ = correction_nh.createTimer(ros::Duration(parameters_.transform_publish_period_s),
                                                  &MappingNode::publishCorrection, this);
    correction_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &correction_queue_);
    correction_spinner_->start();
  }
  startReconfigure();
  // The services from here on, on their own threads (scans and tf stay on nh_'s queue).
  service_spinner_ = std::make_unique<ros::AsyncSpinner>(kServiceThreads, &service_queue_);
  service_spinner_->start();

  std::ostringstream topics;
  for (const std::string& topic : parameters_.scan_topics) topics << " " << nh_.resolveName(topic);
  if (mapper_) {
    const core::MapperConfig& config = mapper_->config();
    ROS_INFO("mapping scans from%s in frame '%s' with the cell HMM: %.3f m cells, time step %.3f s, transitions %s, "
             "sensor model %s (in use: p_hit_given_occ %.3f, p_hit_given_free %.3f)",
             topics.str().c_str(), parameters_.fixed_frame.c_str(), config.resolution_m, config.time_step_s,
             config.learn_transitions ? "learned online" : "fixed",
             config.learn_sensor_model ? "learned online" : "fixed", mapper_->sensor().pHitGivenOcc(),
             mapper_->sensor().pHitGivenFree());
    logLearners(config);
  }
  if (correction_) {
    const core::PoseFilterConfig& filter = correction_->filter().config();
    ROS_INFO("pose correction: the laser's pose in '%s' is odometry, corrected by %zu particles (an update every "
             "%.2f m or %.2f rad, odometry alphas %.3f %.3f %.3f %.3f); publishing %s -> %s every %.3f s",
             parameters_.odom_frame.c_str(), filter.particles, filter.update_distance_m, filter.update_angle_rad,
             filter.motion_noise.rot_from_rot, filter.motion_noise.rot_from_trans, filter.motion_noise.trans_from_trans,
             filter.motion_noise.trans_from_rot, parameters_.fixed_frame.c_str(), parameters_.odom_frame.c_str(),
             parameters_.transform_publish_period_s);
  }
  if (memory_) {
    ROS_INFO("mapping scans from%s in frame '%s' with the STM/LTM memory model: %.3f m cells, an update every "
             "%.2f m of laser travel, %d configurations in the hypotheses",
             topics.str().c_str(), parameters_.fixed_frame.c_str(), memory_->config().resolution_m,
             memory_->config().update_distance_m, memory_->config().hypothesis_configurations);
  }
  return true;
}

void MappingNode::advertiseHmm() {
  const auto add_output = [this](ros::NodeHandle& nh, const std::string& name, LayerView view) {
    const std::size_t index = outputs_.size();
    outputs_.emplace_back();
    Output& output = outputs_.back();
    output.view = view;
    output.horizon_from_parameter = view.layer == core::Layer::kPredicted;
    // A new subscriber gets a full grid at once (costmap_2d does the same), also when time
    // stands still (a paused or finished bag with /use_sim_time).
    const ros::SubscriberStatusCallback connected = [this, index](const ros::SingleSubscriberPublisher&) {
      std::lock_guard<std::mutex> lock(mutex_);
      publishFull(outputs_[index]);
    };
    output.full = nh.advertise<nav_msgs::OccupancyGrid>(name, 1, connected, ros::SubscriberStatusCallback(),
                                                        ros::VoidConstPtr(), true);
    output.updates = nh.advertise<map_msgs::OccupancyGridUpdate>(name + "_updates", 10);
  };
  const auto probability = [](core::Layer layer) { return LayerView{layer, 1.0f, 0, std::nullopt}; };
  const auto transition = [this](core::Layer layer) {
    return LayerView{layer, static_cast<float>(parameters_.transition_scale), 0, std::nullopt};
  };
  outputs_.reserve(7);
  add_output(private_nh_, "belief", probability(core::Layer::kBelief));
  const std::int64_t horizon_steps = horizonSteps(parameters_.prediction_horizon_s, mapper_->config().time_step_s);
  add_output(private_nh_, "predicted", LayerView{core::Layer::kPredicted, 1.0f, horizon_steps, std::nullopt});
  add_output(private_nh_, "stationary", probability(core::Layer::kStationary));
  add_output(private_nh_, "p_occ_given_free", transition(core::Layer::kOccGivenFree));
  add_output(private_nh_, "p_free_given_occ", transition(core::Layer::kFreeGivenOcc));
  add_output(private_nh_, "static_map", probability(core::Layer::kStatic));
  if (parameters_.publish_map_topic) {
    // For map consumers (move_base's static layer, amcl): map_server's thresholds by default.
    add_output(nh_, "map",
               LayerView{parameters_.map_layer, 1.0f,
                         parameters_.map_layer == core::Layer::kPredicted ? horizon_steps : std::int64_t{0},
                         parameters_.map_thresholds});
  }

  offline_em_progress_ = private_nh_.advertise<OfflineEmProgress>("offline_em_progress", 10, true);
  services_.push_back(service_nh_.advertiseService("run_offline_em", &MappingNode::runOfflineEm, this));
  services_.push_back(service_nh_.advertiseService("save_model", &MappingNode::saveModel, this));
  services_.push_back(service_nh_.advertiseService("load_model", &MappingNode::loadModel, this));
  services_.push_back(service_nh_.advertiseService("export_layers", &MappingNode::exportLayers, this));
  services_.push_back(service_nh_.advertiseService("get_cell", &MappingNode::getCell, this));
  services_.push_back(service_nh_.advertiseService("predict_map", &MappingNode::predictMap, this));
}

void MappingNode::advertiseMemory() {
  for (const bool long_term : {true, false}) {
    const std::string name = long_term ? "ltm" : "stm";
    const std::size_t index = memory_outputs_.size();
    memory_outputs_.emplace_back();
    MemoryOutput& output = memory_outputs_.back();
    output.long_term = long_term;
    const ros::SubscriberStatusCallback connected = [this, index](const ros::SingleSubscriberPublisher&) {
      std::lock_guard<std::mutex> lock(mutex_);
      publishMemoryFull(memory_outputs_[index]);
    };
    output.full = private_nh_.advertise<nav_msgs::OccupancyGrid>(name, 1, connected, ros::SubscriberStatusCallback(),
                                                                 ros::VoidConstPtr(), true);
    output.updates = private_nh_.advertise<map_msgs::OccupancyGridUpdate>(name + "_updates", 10);
  }
  // Latched: a new subscriber gets the last hypotheses, or the current ones if they were not
  // published for want of subscribers.
  const ros::SubscriberStatusCallback connected = [this](const ros::SingleSubscriberPublisher&) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (hypotheses_need_publish_) publishHypotheses();
  };
  hypotheses_ = private_nh_.advertise<MapHypotheses>("hypotheses", 1, connected, ros::SubscriberStatusCallback(),
                                                     ros::VoidConstPtr(), true);
}

void MappingNode::scanDropped(const sensor_msgs::LaserScan::ConstPtr& msg, tf2_ros::FilterFailureReason reason) {
  const char* why = "no transform arrived in time (the scan waited longest in the queue)";
  if (reason == tf2_ros::filter_failure_reasons::OutTheBack) {
    why = "it is older than the oldest transform in the tf buffer";
  } else if (reason == tf2_ros::filter_failure_reasons::EmptyFrameID) {
    why = "its header.frame_id is empty";
  }
  ROS_WARN_THROTTLE(kWarnPeriodS, "dropping scan from frame '%s' stamped %.3f: %s (transform to '%s')",
                    msg->header.frame_id.c_str(), msg->header.stamp.toSec(), why, laserPoseFrame().c_str());
  countTfDrop(std::string("scan from frame '") + msg->header.frame_id + "': " + why);
}

void MappingNode::countTfDrop(const std::string& error) {
  ++scan_counts_.dropped_tf;
  std::lock_guard<std::mutex> lock(diagnostics_mutex_);
  last_tf_error_ = error;
}

void MappingNode::scanArrived(const sensor_msgs::LaserScan::ConstPtr& msg, std::size_t topic_index) {
  ++scan_counts_.received;
  scan_rates_[topic_index]->tick();
  warnIfNoTransform(msg->header.frame_id);
}

void MappingNode::warnIfNoTransform(const std::string& frame_id) {
  // The tf2 filter keeps such scans quietly until its queue overflows: say why at once (after
  // a moment's grace for tf at start-up), naming both frames.
  if (frame_id.empty()) return;  // the filter drops it and says so
  std::string error;
  const std::string& target = laserPoseFrame();
  const bool known = tf_buffer_.canTransform(target, frame_id, ros::Time(0), &error);
  const ros::WallTime now = ros::WallTime::now();
  std::lock_guard<std::mutex> lock(diagnostics_mutex_);
  if (known) {
    frames_without_transform_.erase(frame_id);
    return;
  }
  // Bounded against a stream of made-up frame names.
  if (frames_without_transform_.size() >= kMaxFramesWithoutTransform) frames_without_transform_.clear();
  const auto since = frames_without_transform_.emplace(frame_id, now).first->second;
  if ((now - since).toSec() < kMissingFrameGraceS) return;
  const bool frame_known = tf_buffer_._frameExists(frame_id);
  const bool fixed_known = tf_buffer_._frameExists(target);
  const std::string parameter = parameters_.pose_correction ? "~odom_frame" : "~fixed_frame";
  const std::string why = !frame_known ? "tf has no frame '" + frame_id + "' (nothing publishes it)"
                          : !fixed_known ? "tf has no frame '" + target + "' (is " + parameter + " right?)"
                                         : "the two frames are not connected in tf";
  ROS_WARN_THROTTLE(kWarnPeriodS,
                    "scans from frame '%s' get no transform to the %s '%s' (for %.1f s now): %s; they wait "
                    "in the queue of %d scans and are dropped from it (tf: %s)",
                    frame_id.c_str(), parameters_.pose_correction ? "odom frame" : "fixed frame", target.c_str(), (now - since).toSec(), why.c_str(),
                    parameters_.scan_queue_size, error.c_str());
  last_tf_error_ = "scans from frame '" + frame_id + "': " + why;
}

void MappingNode::scanCallback(const sensor_msgs::LaserScan::ConstPtr& msg) {
  std::string error;
  const auto drop = [this, &msg](const std::string& why) {
    ++scan_counts_.dropped_invalid;
    ROS_WARN_THROTTLE(kWarnPeriodS, "dropping scan from frame '%s' stamped %.3f: %s", msg->header.frame_id.c_str(),
                      msg->header.stamp.toSec(), why.c_str());
  };
  const auto drop_tf = [this, &msg](const std::string& why) {
    ROS_WARN_THROTTLE(kWarnPeriodS, "dropping scan from frame '%s' stamped %.3f: %s", msg->header.frame_id.c_str(),
                      msg->header.stamp.toSec(), why.c_str());
    countTfDrop(std::string("scan from frame '") + msg->header.frame_id + "': " + why);
  };
  // A zero stamp means "no time" (tf2 even reads it as "latest"); as a time it would look
  // like time jumping back to 0 and restart the map's clock.
  if (msg->header.stamp.isZero()) return drop("its header.stamp is zero (unset)");
  // So would one stamped far ahead of the scans' clock: the map would jump there and back.
  const double stamp_s = msg->header.stamp.toSec();
  const double now_s = ros::Time::now().toSec();
  const double offset_s = observeStampOffset(stamp_s, now_s);
  if (now_s > 0.0 && stamp_s > now_s + offset_s + parameters_.time_jump_threshold_s) {
    std::ostringstream why;
    why << std::fixed << std::setprecision(3) << "it is stamped " << stamp_s - now_s - offset_s << " s in the future";
    if (offset_s != 0.0) {
      why << " of the scans' clock (ROS time " << std::showpos << offset_s << std::noshowpos << " s)";
    }
    why << ", more than ~time_jump_threshold (" << parameters_.time_jump_threshold_s << " s)";
    return drop(why.str());
  }
  if (!checkScanShape(*msg, &error)) return drop(error);
  geometry_msgs::TransformStamped transform;
  try {
    transform = tf_buffer_.lookupTransform(laserPoseFrame(), msg->header.frame_id, msg->header.stamp);
  } catch (const tf2::LookupException& e) {
    return drop_tf(std::string("unknown frame: ") + e.what());
  } catch (const tf2::ConnectivityException& e) {
    return drop_tf(std::string("frames not connected: ") + e.what());
  } catch (const tf2::ExtrapolationException& e) {
    return drop_tf(std::string("no transform at the scan's stamp: ") + e.what());
  } catch (const tf2::TransformException& e) {
    return drop_tf(std::string("transform failed: ") + e.what());
  }
  core::Pose2D pose;
  bool upside_down = false;
  if (!toLaserPose(transform.transform, &pose, &upside_down, &error)) return drop(error);
  core::Scan scan = toCoreScan(*msg, pose, upside_down);
  // Readings beyond max_range count as "no return" (free up to max_free_range): one absurd
  // reading must not trace (and allocate) hundreds of metres of map.
  scan.range_max_m = std::min(scan.range_max_m, parameters_.max_range_m);

  std::lock_guard<std::mutex> lock(mutex_);
  // With pose correction (~model both) the memory model maps the scan after the filter, at
  // the corrected pose.
  const bool memory_integrated = memory_ && !correction_ && integrateMemory(scan, msg->header.frame_id);
  if (!mapper_) {
    if (memory_integrated) ++scan_counts_.integrated;
    return;
  }
  const double threshold_s = parameters_.time_jump_threshold_s;
  if (newest_stamp_s_ && scan.stamp_s < *newest_stamp_s_ - threshold_s) {
    if (steady_since_restart_s_ && *steady_since_restart_s_ < threshold_s) {
      // Again, before time ran on steadily: two clocks on the scans, or stamps that keep
      // going back. Restarting for each would make every scan a new step.
      ++scan_counts_.dropped_late;
      ROS_WARN_THROTTLE(kWarnPeriodS,
                        "dropping scan from frame '%s' stamped %.3f: time jumped back by %.1f s again, only %.1f s "
                        "of steady time after the map's clock restarted (scans with different clocks?); the clock "
                        "restarts once per ~time_jump_threshold (%.1f s) of steady time",
                        msg->header.frame_id.c_str(), scan.stamp_s, *newest_stamp_s_ - scan.stamp_s,
                        *steady_since_restart_s_, threshold_s);
      return;
    }
    // A bag played again or a simulator reset: keep the map, go on from the next step.
    ROS_WARN_THROTTLE(1.0, "time jumped back by %.1f s (bag restarted?): keeping the map, continuing it after step %lld",
                      *newest_stamp_s_ - scan.stamp_s,
                      static_cast<long long>(mapper_->lastAppliedStep().value_or(-1)));
    mapper_->restartClockAt(scan.stamp_s);
    if (correction_) restartCorrection();
    newest_stamp_s_.reset();
    steady_since_restart_s_ = 0.0;
  }
  std::optional<core::Scan> corrected;
  const core::ScanResult result = integrateHmm(scan, &corrected);
  if (memory_ && corrected) integrateMemory(*corrected, msg->header.frame_id);
  if (result.status != core::ScanStatus::kIntegrated) {
    const bool late = result.status == core::ScanStatus::kRejectedTimeBackwards;
    ++(late ? scan_counts_.dropped_late : scan_counts_.dropped_invalid);
    std::ostringstream why;
    why << result.error;
    if (late) {
      // Say how late: a scan delayed on its way (a recording's hiccup) more than the timer waits.
      why << std::fixed << std::setprecision(3) << "; it came " << scanClockNow().toSec() - scan.stamp_s
          << " s after its stamp, and a step is applied ~max_scan_latency (" << parameters_.max_scan_latency_s
          << " s) after its end";
    }
    ROS_WARN_THROTTLE(kWarnPeriodS, "dropping scan from frame '%s' stamped %.3f: %s", msg->header.frame_id.c_str(),
                      scan.stamp_s, why.str().c_str());
    return;
  }
  ++scan_counts_.integrated;
  // Time runs steadily in steps below the threshold; a leap forward does not count.
  const double advance_s = newest_stamp_s_ ? scan.stamp_s - *newest_stamp_s_ : 0.0;
  if (steady_since_restart_s_ && advance_s > 0.0 && advance_s <= threshold_s) *steady_since_restart_s_ += advance_s;
  newest_stamp_s_ = std::max(newest_stamp_s_.value_or(scan.stamp_s), scan.stamp_s);
  if (result.cells_outside > 0) {
    ROS_WARN_THROTTLE(30.0, "beams reach beyond the map's bounds (fixed_bounds / max_map_size); those cells are not mapped");
  }
}

double MappingNode::observeStampOffset(double stamp_s, double now_s) {
  std::lock_guard<std::mutex> lock(stamp_offset_mutex_);
  if (now_s <= 0.0) return stamp_offset_s_;  // no ROS time yet (/use_sim_time before any /clock)
  if (now_s < last_scan_ros_time_s_ - kStampOffsetToleranceS) {
    // ROS time went back (a bag played again, or another bag): its stamps may be off it by
    // another amount.
    stamp_offset_samples_.clear();
  }
  last_scan_ros_time_s_ = now_s;
  if (stamp_offset_samples_.size() >= kStampOffsetScans) return stamp_offset_s_;
  stamp_offset_samples_.push_back(stamp_s - now_s);
  std::vector<double> sorted = stamp_offset_samples_;
  std::sort(sorted.begin(), sorted.end());
  const double median_s = sorted[(sorted.size() - 1) / 2];
  const double offset_s = std::abs(median_s) > kStampOffsetToleranceS ? median_s : 0.0;
  stamp_offset_s_ = offset_s;
  // Said once per estimate that differs from the last one said: at the start, and after ROS
  // time went back onto another clock difference (never per scan).
  if (stamp_offset_samples_.size() == kStampOffsetScans &&
      std::abs(offset_s - stamp_offset_reported_s_) > kStampOffsetToleranceS) {
    if (offset_s != 0.0) {
      ROS_WARN("scan stamps are %.3f s %s ROS time (median of the first %zu scans): taken as a constant difference "
               "between the scans' clock and ROS time (a bag recorded with two computers' clocks, or played without "
               "--clock); the node compares stamps with ROS time %+.3f s from now on",
               std::abs(offset_s), offset_s > 0.0 ? "ahead of" : "behind", kStampOffsetScans, offset_s);
    } else {
      ROS_INFO("scan stamps agree with ROS time again (within %.1f s)", kStampOffsetToleranceS);
    }
    stamp_offset_reported_s_ = offset_s;
  }
  return offset_s;
}

ros::Time MappingNode::scanClockNow() const {
  const ros::Time now = ros::Time::now();
  const double offset_s = stamp_offset_s_;
  if (offset_s == 0.0 || now.isZero()) return now;
  return toRosTime(now.toSec() + offset_s);
}

core::ScanResult MappingNode::integrateHmm(const core::Scan& scan, std::optional<core::Scan>* corrected_scan) {
  if (!correction_) return mapper_->integrate(scan);
  core::CorrectedScan corrected;
  try {
    corrected = correction_->integrate(scan);
  } catch (const std::invalid_argument& e) {
    core::ScanResult refused;
    refused.status = core::ScanStatus::kRejectedInvalid;
    refused.error = std::string("pose correction: ") + e.what();
    return refused;
  }
  *corrected_scan = corrected.corrected;
  if (corrected.update.updated) {
    const core::Pose2D map_to_odom = correction_->mapToOdometry();
    {
      std::lock_guard<std::mutex> lock(correction_mutex_);
      map_to_odom_ = map_to_odom;
    }
    if (corrected.remapped > 0) {
      ROS_INFO_THROTTLE(10.0, "pose correction: map -> odom is now (%.2f m, %.2f m, %.3f rad); the last %zu scans were "
                        "mapped again with it",
                        map_to_odom.x_m, map_to_odom.y_m, map_to_odom.yaw_rad, corrected.remapped);
    }
    std_msgs::Float64 value;
    last_effective_sample_size_ = corrected.update.effective_sample_size;
    value.data = corrected.update.effective_sample_size;
    effective_sample_size_.publish(value);
    value.data = correction_->filter().poseEntropy();
    pose_entropy_.publish(value);
  }
  return corrected.mapped;
}

const std::string& MappingNode::laserPoseFrame() const {
  return parameters_.pose_correction ? parameters_.odom_frame : parameters_.fixed_frame;
}

void MappingNode::restartCorrection() {
  core::Pose2D map_to_odom;
  {
    std::lock_guard<std::mutex> lock(correction_mutex_);
    map_to_odom = map_to_odom_;
  }
  correction_.reset();  // it reads the mapper it was made on
  last_effective_sample_size_ = 0.0;
  best_particle_published_updates_ = 0;
  // The map's lattice, time step and sensor model are the live mapper's (a loaded model's
  // may differ from the parameters'); a PoseFilterConfig made from a valid MapperConfig and
  // the checked ~rbpf/* is valid.
  correction_ = std::make_unique<core::CorrectedMapping>(
      *mapper_, core::poseFilterConfigFor(mapper_->config(), parameters_.filter), parameters_.learned_min_observed_steps,
      map_to_odom);
}

void MappingNode::publishCorrection(const ros::TimerEvent&) {
  geometry_msgs::TransformStamped message;
  {
    std::lock_guard<std::mutex> lock(correction_mutex_);
    message.transform = toTransform(map_to_odom_);
  }
  // Stamped ahead, as gmapping does, so that a user of the map frame looking up the newest
  // transform does not extrapolate between two broadcasts.
  // On the scans' clock, as the odometry it corrects.
  message.header.stamp = scanClockNow() + ros::Duration(parameters_.transform_tolerance_s);
  // A timer catching up with a clock that leapt (simulated time) fires several times at one
  // time: tf would warn about each repeated stamp. (Time going back is broadcast.)
  if (message.header.stamp == last_correction_stamp_) return;
  last_correction_stamp_ = message.header.stamp;
  message.header.frame_id = parameters_.fixed_frame;
  message.child_frame_id = parameters_.odom_frame;
  tf_broadcaster_->sendTransform(message);
}

bool MappingNode::integrateMemory(const core::Scan& scan, const std::string& frame_id) {
  // Views gather scans by the laser's travel, not by time: a bag played again goes on
  // with the same memory.
  const core::MemoryScanResult result = memory_->integrate(scan);
  if (!result.integrated) {
    ++scan_counts_.memory_rejected;
    ROS_WARN_THROTTLE(kWarnPeriodS, "memory model: dropping scan from frame '%s' stamped %.3f: %s", frame_id.c_str(),
                      scan.stamp_s, result.error.c_str());
    return false;
  }
  if (result.cells_outside > 0) {
    ROS_WARN_THROTTLE(30.0, "memory model: beams reach beyond max_map_size; those cells are not mapped");
  }
  if (result.update) {
    memory_stamp_ = toRosTime(scan.stamp_s);
    memory_updated_ = true;
    ROS_DEBUG("memory update %lld: %zu cells hit, %zu missed, %zu migrated to LTM, %zu forgotten",
              static_cast<long long>(result.update->index), result.update->view_hits, result.update->view_misses,
              result.update->migrated.size(), result.update->forgotten);
  }
  return true;
}

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
