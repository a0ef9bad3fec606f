#include "dynamic_occupancy_grid/ros/mapping_node.h"

#include <dynamic_occupancy_grid/OfflineEmProgress.h>
#include <geometry_msgs/TransformStamped.h>
#include <std_msgs/Float64.h>
#include <tf2/exceptions.h>

#include <boost/bind/bind.hpp>
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
#include "dynamic_occupancy_grid/ros/conversions.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {
namespace {

// Seconds between repeated warnings of the same kind from per-message callbacks.
constexpr double kWarnPeriodS = 5.0;
/// Wall seconds a scan's frame may lack its transform before the node warns (tf at start-up).
constexpr double kMissingFrameGraceS = 1.0;
constexpr std::size_t kMaxFramesWithoutTransform = 64;
/// The scans whose stamps the node measures against ROS time at the start (and after ROS
/// time went back); their lower median is the offset, so one scan stamped wrong among them
/// does not set it.
constexpr std::size_t kStampOffsetScans = 5;
/// Stamps this close to ROS time are on its clock (a scan's way to the node, one arriving
/// before /clock moved on); further off, the scans run on another clock.
constexpr double kStampOffsetToleranceS = 1.0;

bool sameBox(const core::CellBox& a, const core::CellBox& b) {
  return (a.empty() && b.empty()) ||
         (a.min_x == b.min_x && a.min_y == b.min_y && a.max_x == b.max_x && a.max_y == b.max_y);
}

// Map stamps are sensor times; ros::Time cannot hold negative ones.
ros::Time toRosTime(double stamp_s) {
  return stamp_s > 0.0 && stamp_s < 4.0e9 ? ros::Time(stamp_s) : ros::Time(0, 0);
}

// Same lattice: the cells of one map are the cells of the other.
bool sameLattice(const core::MapperConfig& a, const core::MapperConfig& b) {
  return a.resolution_m == b.resolution_m && a.origin_x_m == b.origin_x_m && a.origin_y_m == b.origin_y_m &&
         a.time_step_s == b.time_step_s;
}

std::int64_t horizonSteps(double horizon_s, double time_step_s) {
  return static_cast<std::int64_t>(std::llround(horizon_s / time_step_s));
}

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

// A loaded model takes this node's settings for what model files leave out: how a step's
// beams are read and how readings change with the view.
void applySettingsModelFilesLeaveOut(core::Mapper& mapper, const core::MapperConfig& config) {
  mapper.setViewSwitchProbability(config.kinds.view_switch_probability);
  mapper.setMixedStepProbability(config.sensor_model_mixed_step_probability);
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
    {
      std::lock_guard<std::mutex> lock(correction_mutex_);
      map_to_odom_ = correction_->mapToOdometry();
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

void MappingNode::publishTimer(const ros::TimerEvent&) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (memory_) publishMemory(false);
  if (!mapper_) return;
  // Apply the step being gathered once no scan of it can still come (scans of a later step
  // apply it anyway). Only when ROS time (on the scans' clock) and the scans' stamps agree:
  // not after stamps jumped back while ROS time ran on.
  const std::optional<std::int64_t> gathering = mapper_->gatheringStep();
  if (gathering && newest_stamp_s_) {
    const double now_s = scanClockNow().toSec();
    const double step_end_s = mapper_->clock().stepStart(*gathering + 1);
    const bool clocks_agree = std::abs(now_s - *newest_stamp_s_) < 10.0 * mapper_->config().time_step_s + 10.0;
    if (clocks_agree && now_s >= step_end_s + parameters_.max_scan_latency_s) mapper_->finishStep();
  }
  publishLayers(false);
  if (correction_) publishBestParticle(false);
}

void MappingNode::publishBestParticle(bool force) {
  const std::size_t updates = correction_->filter().updates();
  const bool belief_wanted = best_particle_belief_.getNumSubscribers() > 0;
  const bool predicted_wanted = best_particle_predicted_.getNumSubscribers() > 0;
  if (updates == 0 || !(belief_wanted || predicted_wanted)) return;
  if (!force && updates == best_particle_published_updates_) return;
  best_particle_published_updates_ = updates;
  // Stamped as the layers are: the end of the last update's step, the predicted one too (the
  // filter's steps are the Mapper's moved by whole steps: its own clock gives the time).
  const core::StepClock& clock = correction_->filter().clock();
  const std::int64_t last = correction_->filter().lastUpdateStep();
  const auto publish = [&](ros::Publisher& publisher, std::int64_t horizon_steps) {
    const core::ParticleBelief belief = correction_->bestParticleBelief(horizon_steps);
    std::vector<std::int8_t> occupancy;
    core::toOccupancyValues(belief.values, 1.0f, &occupancy);
    const double stamp_s = clock.origin() ? clock.stepStart(last + 1) : scanClockNow().toSec();
    publisher.publish(toOccupancyGrid(belief.window, std::move(occupancy), parameters_.fixed_frame, toRosTime(stamp_s)));
  };
  if (belief_wanted) publish(best_particle_belief_, 0);
  if (predicted_wanted) {
    publish(best_particle_predicted_, horizonSteps(parameters_.prediction_horizon_s, mapper_->config().time_step_s));
  }
}

void MappingNode::publishLayers(bool force_full) {
  const ros::Time now = ros::Time::now();
  const std::optional<std::int64_t> step = mapper_->lastAppliedStep();
  const core::CellBox bounds = step ? mapper_->grid().bounds() : core::CellBox{};
  const core::CellBox changed = mapper_->takeChangedCells();
  const bool full_due = force_full || !sameBox(bounds, published_bounds_) || parameters_.full_map_period_s == 0.0 ||
                        (now - last_full_publish_).toSec() >= parameters_.full_map_period_s;
  const ros::Time stamp = step ? toRosTime(mapper_->clock().stepStart(*step + 1)) : scanClockNow();
  bool sent_full = false;
  for (Output& output : outputs_) {
    if (full_due || output.needs_full) {
      if (output.full.getNumSubscribers() == 0) {
        output.needs_full = true;  // evaluated when someone listens
        continue;
      }
      publishFull(output);
      sent_full = true;
    } else if (step && !changed.empty() && output.updates.getNumSubscribers() > 0) {
      output.updates.publish(toOccupancyGridUpdate(bounds, changed, outputValues(output, *step, changed),
                                                   parameters_.fixed_frame, stamp));
    }
  }
  if (full_due || sent_full) {
    published_bounds_ = bounds;
    if (full_due) last_full_publish_ = now;
  }
}

void MappingNode::publishFull(Output& output) {
  const std::optional<std::int64_t> step = mapper_->lastAppliedStep();
  const core::CellBox bounds = step ? mapper_->grid().bounds() : core::CellBox{};
  const ros::Time stamp = step ? toRosTime(mapper_->clock().stepStart(*step + 1)) : scanClockNow();
  std::vector<std::int8_t> values = step ? outputValues(output, *step, bounds) : std::vector<std::int8_t>{};
  output.full.publish(toOccupancyGrid(mapper_->grid().window(bounds), std::move(values), parameters_.fixed_frame, stamp));
  output.needs_full = false;
}

std::vector<std::int8_t> MappingNode::outputValues(Output& output, std::int64_t step, const core::CellBox& box) {
  const core::Layer layer = output.view.layer;
  if (layer == core::Layer::kBelief || layer == core::Layer::kPredicted) {
    return layerValues(mapper_->grid(), output.view, step, box);  // they change with the step
  }
  if (!output.cache) output.cache.emplace(layer, core::OccupancyScaling{output.view.full_scale, output.view.thresholds});
  std::vector<std::int8_t> values;
  output.cache->occupancy(mapper_->grid(), mapper_->tileVersions(), box, &values);
  return values;
}

void MappingNode::publishMemory(bool force_full) {
  if (!force_full && !memory_updated_) return;  // the grids change at updates only
  memory_updated_ = false;
  const ros::Time now = ros::Time::now();
  const core::CellBox bounds = memory_->bounds();
  const core::CellBox changed = memory_->takeChangedCells();
  const bool full_due = force_full || !sameBox(bounds, memory_published_bounds_) ||
                        parameters_.full_map_period_s == 0.0 ||
                        (now - memory_last_full_publish_).toSec() >= parameters_.full_map_period_s;
  bool sent_full = false;
  for (MemoryOutput& output : memory_outputs_) {
    if (full_due || output.needs_full) {
      if (output.full.getNumSubscribers() == 0) {
        output.needs_full = true;  // rendered when someone listens
        continue;
      }
      publishMemoryFull(output);
      sent_full = true;
    } else if (!changed.empty() && output.updates.getNumSubscribers() > 0) {
      std::vector<std::int8_t> values = output.long_term ? memory_->ltmGrid(changed) : memory_->stmGrid(changed);
      output.updates.publish(
          toOccupancyGridUpdate(bounds, changed, std::move(values), parameters_.fixed_frame, memoryStamp()));
    }
  }
  if (full_due || sent_full) {
    memory_published_bounds_ = bounds;
    if (full_due) memory_last_full_publish_ = now;
  }
  if (hypotheses_.getNumSubscribers() > 0) {
    publishHypotheses();
  } else {
    hypotheses_need_publish_ = true;
  }
}

void MappingNode::publishMemoryFull(MemoryOutput& output) {
  const core::CellBox bounds = memory_->bounds();
  std::vector<std::int8_t> values = output.long_term ? memory_->ltmGrid(bounds) : memory_->stmGrid(bounds);
  output.full.publish(toOccupancyGrid(memory_->window(bounds), std::move(values), parameters_.fixed_frame, memoryStamp()));
  output.needs_full = false;
}

void MappingNode::publishHypotheses() {
  hypotheses_.publish(toMapHypotheses(*memory_, static_cast<std::size_t>(parameters_.max_published_hypotheses),
                                      parameters_.fixed_frame, memoryStamp()));
  hypotheses_need_publish_ = false;
}

ros::Time MappingNode::memoryStamp() const { return memory_stamp_.value_or(scanClockNow()); }

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
    // With pose correction, the cells' beliefs are the best particle's own map.
    corrected = correction_ != nullptr;
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
