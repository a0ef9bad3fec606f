#include "dynamic_occupancy_grid/ros/parameters.h"

#include <ros/names.h>
#include <ros/param.h>
#include <xmlrpcpp/XmlRpcValue.h>

#include "dynamic_occupancy_grid/core/pose/corrected_mapping.h"
#include "dynamic_occupancy_grid/ros/bag_offline_em.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>

namespace dynamic_occupancy_grid {
namespace ros_layer {
namespace {

// Reads typed parameters, remembering every name it was asked for and the first error.
class Reader {
 public:
  explicit Reader(const ros::NodeHandle& nh) : nh_(nh) {}

  void number(const std::string& name, double* value) {
    known_.insert(name);
    XmlRpc::XmlRpcValue raw;
    if (!nh_.getParam(name, raw)) return;
    if (raw.getType() == XmlRpc::XmlRpcValue::TypeDouble) {
      *value = static_cast<double>(raw);
    } else if (raw.getType() == XmlRpc::XmlRpcValue::TypeInt) {
      *value = static_cast<int>(raw);
    } else {
      fail(name, "must be a number");
      return;
    }
    if (!std::isfinite(*value)) fail(name, "must be finite");
  }

  void integer(const std::string& name, int* value, int min_value, int max_value) {
    known_.insert(name);
    XmlRpc::XmlRpcValue raw;
    if (!nh_.getParam(name, raw)) return;
    if (raw.getType() != XmlRpc::XmlRpcValue::TypeInt) {
      fail(name, "must be an integer");
      return;
    }
    *value = static_cast<int>(raw);
    if (*value < min_value || *value > max_value) {
      fail(name, "must be in [" + std::to_string(min_value) + ", " + std::to_string(max_value) + "], got " +
                     std::to_string(*value));
    }
  }

  void boolean(const std::string& name, bool* value) {
    known_.insert(name);
    XmlRpc::XmlRpcValue raw;
    if (!nh_.getParam(name, raw)) return;
    if (raw.getType() != XmlRpc::XmlRpcValue::TypeBoolean) {
      fail(name, "must be true or false");
      return;
    }
    *value = static_cast<bool>(raw);
  }

  void text(const std::string& name, std::string* value) {
    known_.insert(name);
    XmlRpc::XmlRpcValue raw;
    if (!nh_.getParam(name, raw)) return;
    if (raw.getType() != XmlRpc::XmlRpcValue::TypeString) {
      fail(name, "must be a string");
      return;
    }
    *value = static_cast<std::string>(raw);
  }

  void textList(const std::string& name, std::vector<std::string>* value) {
    known_.insert(name);
    XmlRpc::XmlRpcValue raw;
    if (!nh_.getParam(name, raw)) return;
    if (raw.getType() == XmlRpc::XmlRpcValue::TypeString) {  // one topic given as a string
      *value = {static_cast<std::string>(raw)};
      return;
    }
    if (raw.getType() != XmlRpc::XmlRpcValue::TypeArray) {
      fail(name, "must be a list of strings");
      return;
    }
    value->clear();
    for (int i = 0; i < raw.size(); ++i) {
      if (raw[i].getType() != XmlRpc::XmlRpcValue::TypeString) {
        fail(name, "must be a list of strings");
        return;
      }
      value->push_back(static_cast<std::string>(raw[i]));
    }
  }

  /// A value check: fails with `message` unless `ok`.
  void require(bool ok, const std::string& name, const std::string& message) {
    if (!ok) fail(name, message);
  }

  void fail(const std::string& name, const std::string& message) {
    if (error_.empty()) error_ = "parameter " + nh_.resolveName(name) + " " + message;
  }

  const std::string& error() const { return error_; }
  const std::set<std::string>& known() const { return known_; }

 private:
  const ros::NodeHandle& nh_;
  std::set<std::string> known_;
  std::string error_;
};

/// The memory model's checks name its config fields ("stm.p_hit must be ...", "ltm: need
/// l_min < l_max", "update_distance must be ..."): the same message naming the parameters.
/// The grid fields it shares with the mapper (resolution, max_map_size, ...) keep their names.
std::string memoryParameterMessage(const std::string& message) {
  const auto starts_with = [&message](const std::string& prefix) { return message.compare(0, prefix.size(), prefix) == 0; };
  for (const std::string store : {"stm", "ltm"}) {
    if (starts_with(store + ".")) return "memory/" + store + "_" + message.substr(store.size() + 1);
    if (starts_with(store + ":")) {
      return "memory/" + store + "_l_min, memory/" + store + "_l_max" + message.substr(store.size());
    }
  }
  for (const std::string field :
       {"update_distance", "initial_mapping_updates", "ltm_occupied_log_odds", "hypothesis_configurations"}) {
    if (starts_with(field)) return "memory/" + message;
  }
  return message;
}

/// The mapper's checks name most fields as their parameters are named; those whose
/// parameter sits in a namespace ("online_em prior_weight must be ...",
/// "sensor_model_p_min must be ...") get the parameter's name ("online_em/prior_weight",
/// "sensor_model/p_min").
std::string mapperParameterMessage(const std::string& message) {
  const auto starts_with = [&message](const std::string& prefix) { return message.compare(0, prefix.size(), prefix) == 0; };
  for (const std::string field : {"prior_weight", "learning_rate_floor", "min_observed_steps"}) {
    const std::string prefix = "online_em " + field + " ";
    if (starts_with(prefix)) return "online_em/" + message.substr(std::string("online_em ").size());
  }
  for (const std::string field : {"prior_weight", "p_min", "mixed_step_probability"}) {
    const std::string prefix = "sensor_model_" + field + " ";
    if (starts_with(prefix)) return "sensor_model/" + message.substr(std::string("sensor_model_").size());
  }
  if (starts_with("kinds ")) return "kinds/" + message.substr(std::string("kinds ").size());
  return message;
}

/// The pose filter's checks name its config fields ("PoseFilterConfig: update_distance_m
/// must be ..."): the same message naming the parameter where one sets the field.
std::string filterParameterMessage(const std::string& message) {
  std::string text = message;
  const std::string prefix = "PoseFilterConfig: ";
  if (text.compare(0, prefix.size(), prefix) == 0) text = text.substr(prefix.size());
  const std::string noise = "OdometryNoise:";
  if (text.compare(0, noise.size(), noise) == 0) return "rbpf/odom_alpha1..4:" + text.substr(noise.size());
  const std::pair<const char*, const char*> names[] = {
      {"particles", "rbpf/particles"}, {"update_distance_m", "rbpf/linear_update"},
      {"update_angle_rad", "rbpf/angular_update"}, {"resample_below", "rbpf/resample_threshold"}};
  for (const auto& [field, parameter] : names) {
    const std::string name = field;
    if (text.compare(0, name.size() + 1, name + " ") == 0) return std::string(parameter) + text.substr(name.size());
  }
  return text;
}

}  // namespace

bool readParameters(const ros::NodeHandle& private_nh, NodeParameters* parameters, std::string* error,
                    std::vector<std::string>* unknown) {
  NodeParameters p;
  Reader read(private_nh);
  read.text("fixed_frame", &p.fixed_frame);
  read.textList("scan_topics", &p.scan_topics);
  read.integer("scan_queue_size", &p.scan_queue_size, 1, 100000);
  read.number("publish_period", &p.publish_period_s);
  read.number("full_map_period", &p.full_map_period_s);
  read.number("prediction_horizon", &p.prediction_horizon_s);
  read.number("transition_scale", &p.transition_scale);
  read.boolean("publish_map_topic", &p.publish_map_topic);
  std::string map_layer = "belief";
  read.text("map_topic/layer", &map_layer);
  bool map_layer_known = false;
  for (const core::Layer layer : {core::Layer::kBelief, core::Layer::kPredicted, core::Layer::kStationary,
                                  core::Layer::kStatic}) {
    if (map_layer == core::layerName(layer)) {
      p.map_layer = layer;
      map_layer_known = true;
    }
  }
  read.require(map_layer_known, "map_topic/layer",
               "must be \"belief\", \"predicted\", \"stationary\" or \"static_map\", got \"" + map_layer + "\"");
  std::string map_mode = "trinary";
  read.text("map_topic/mode", &map_mode);
  if (map_mode == "trinary") {
    p.map_thresholds.mode = core::ThresholdMode::kTrinary;
  } else if (map_mode == "scale") {
    p.map_thresholds.mode = core::ThresholdMode::kScale;
  } else if (map_mode == "raw") {
    p.map_thresholds.mode = core::ThresholdMode::kRaw;
  } else {
    read.fail("map_topic/mode", "must be \"trinary\", \"scale\" or \"raw\", got \"" + map_mode + "\"");
  }
  read.number("map_topic/occupied_thresh", &p.map_thresholds.occupied_thresh);
  read.number("map_topic/free_thresh", &p.map_thresholds.free_thresh);
  read.number("diagnostics/period", &p.diagnostics_period_s);
  read.number("diagnostics/min_scan_rate_hz", &p.min_scan_rate_hz);
  read.number("diagnostics/max_scan_rate_hz", &p.max_scan_rate_hz);
  read.number("diagnostics/max_step_lag", &p.max_step_lag_s);
  read.number("max_scan_latency", &p.max_scan_latency_s);
  read.number("time_jump_threshold", &p.time_jump_threshold_s);
  read.number("max_range", &p.max_range_m);
  read.text("model_file", &p.model_file);
  read.text("file_directory", &p.file_directory);
  std::string model = "hmm";
  read.text("model", &model);
  if (model == "hmm") {
    p.model = MapModel::kHmm;
  } else if (model == "memory") {
    p.model = MapModel::kMemory;
  } else if (model == "both") {
    p.model = MapModel::kBoth;
  } else {
    read.fail("model", "must be \"hmm\", \"memory\" or \"both\", got \"" + model + "\"");
  }

  core::MapperConfig& m = p.mapper;
  read.number("resolution", &m.resolution_m);
  read.number("time_step", &m.time_step_s);
  read.number("p_hit_given_occ", &m.p_hit_given_occ);
  read.number("p_hit_given_free", &m.p_hit_given_free);
  read.number("prior_p_occ_given_free", &m.prior_transitions.p_occ_given_free);
  read.number("prior_p_free_given_occ", &m.prior_transitions.p_free_given_occ);
  read.boolean("learn_transitions", &m.learn_transitions);
  // The node learns the sensor model by default (the core's default is the fixed model).
  m.learn_sensor_model = kDefaultLearnSensorModel;
  read.boolean("learn_sensor_model", &m.learn_sensor_model);
  read.number("sensor_model/prior_weight", &m.sensor_model_prior_weight);
  read.number("sensor_model/p_min", &m.sensor_model_p_min);
  read.number("sensor_model/mixed_step_probability", &m.sensor_model_mixed_step_probability);
  std::string learner = "kinds";
  read.text("learner", &learner);
  if (learner == "kinds") {
    m.learner = core::TransitionLearner::kKinds;
  } else if (learner == "cell_em") {
    m.learner = core::TransitionLearner::kCellEm;
  } else {
    read.fail("learner", "must be \"kinds\" or \"cell_em\", got \"" + learner + "\"");
  }
  read.number("kinds/switch_probability", &m.kinds.switch_probability);
  read.number("kinds/view_switch_probability", &m.kinds.view_switch_probability);
  read.number("kinds/forgetting", &m.kinds.forgetting);
  read.number("kinds/transition_prior_weight", &m.kinds.transition_prior_weight);
  read.number("kinds/weight_prior_cells", &m.kinds.weight_prior_cells);
  read.number("online_em/prior_weight", &m.online_em.prior_weight);
  read.number("online_em/learning_rate_floor", &m.online_em.learning_rate_floor);
  read.number("online_em/p_min", &m.online_em.p_min);
  read.number("online_em/p_max", &m.online_em.p_max);
  read.boolean("online_em/symmetric", &m.online_em.symmetric);
  int min_observed_steps = static_cast<int>(m.online_em.min_observed_steps);
  read.integer("online_em/min_observed_steps", &min_observed_steps, 0, 65535);
  m.online_em.min_observed_steps = static_cast<std::uint32_t>(min_observed_steps);
  read.number("initial_p_occ", &m.initial_p_occ);
  read.number("static_min_log_odds", &m.static_clamp.min_log_odds);
  read.number("static_max_log_odds", &m.static_clamp.max_log_odds);
  read.number("max_free_range", &m.max_free_range_m);
  read.number("origin_x", &m.origin_x_m);
  read.number("origin_y", &m.origin_y_m);
  read.boolean("fixed_bounds", &m.fixed_bounds);
  read.number("width", &m.width_m);
  read.number("height", &m.height_m);
  read.number("max_map_size", &m.max_map_size_m);

  core::OfflineEmConfig& em = p.offline_em;
  em.prior_weight = kDefaultOfflinePriorWeight;
  int max_iterations = em.max_iterations;
  read.integer("offline_em/max_iterations", &max_iterations, 1, 65535);
  em.max_iterations = max_iterations;
  read.number("offline_em/tolerance", &em.tolerance);
  int threads = static_cast<int>(em.threads);
  read.integer("offline_em/threads", &threads, 0, 1024);
  em.threads = static_cast<unsigned>(threads);
  read.number("offline_em/prior_weight", &em.prior_weight);
  read.boolean("offline_em/symmetric", &em.symmetric);
  read.number("offline_em/mrf_temperature", &em.mrf_temperature);
  // Offline EM learns the sensor model when the node does (not with the MRF, whose joint
  // M-step does not include it), unless told otherwise.
  em.learn_sensor_model = m.learn_sensor_model && em.mrf_temperature == 0.0;
  read.boolean("offline_em/learn_sensor_model", &em.learn_sensor_model);
  // Offline EM learns within the same bounds as online EM and starts from the prior.
  em.p_min = m.online_em.p_min;
  em.p_max = m.online_em.p_max;
  em.initial_params = m.prior_transitions;
  em.prior = m.prior_transitions;
  em.initial_p_occ = m.initial_p_occ;

  // The memory model (Morris et al.) on the mapper's lattice.
  core::MemoryModelConfig& memory = p.memory;
  read.number("memory/update_distance", &memory.update_distance_m);
  read.integer("memory/initial_mapping_updates", &memory.initial_mapping_updates, 0, 1000000000);
  read.number("memory/stm_l_min", &memory.stm.l_min);
  read.number("memory/stm_l_max", &memory.stm.l_max);
  read.number("memory/stm_p_hit", &memory.stm.p_hit);
  read.number("memory/stm_p_miss", &memory.stm.p_miss);
  read.number("memory/ltm_l_min", &memory.ltm.l_min);
  read.number("memory/ltm_l_max", &memory.ltm.l_max);
  read.number("memory/ltm_p_hit", &memory.ltm.p_hit);
  read.number("memory/ltm_p_miss", &memory.ltm.p_miss);
  read.number("memory/ltm_occupied_log_odds", &memory.ltm_occupied_log_odds);
  read.integer("memory/hypothesis_configurations", &memory.hypothesis_configurations, 0, 10);
  read.integer("memory/max_published_hypotheses", &p.max_published_hypotheses, 1, 1024);
  memory.resolution_m = m.resolution_m;
  memory.origin_x_m = m.origin_x_m;
  memory.origin_y_m = m.origin_y_m;
  memory.max_free_range_m = m.max_free_range_m;
  memory.max_map_size_m = m.max_map_size_m;

  // Pose correction: the pose filter (core/pose/pose_filter.h) under gmapping's and amcl's names.
  std::string pose_correction = "none";
  read.text("pose_correction", &pose_correction);
  if (pose_correction == "rbpf") {
    p.pose_correction = true;
  } else if (pose_correction != "none") {
    read.fail("pose_correction", "must be \"none\" or \"rbpf\", got \"" + pose_correction + "\"");
  }
  read.text("odom_frame", &p.odom_frame);
  core::PoseFilterConfig& f = p.filter;
  int particles = static_cast<int>(f.particles);
  read.integer("rbpf/particles", &particles, 1, 100000);
  f.particles = static_cast<std::size_t>(particles);
  f.motion_noise = {kDefaultOdometryAlpha, kDefaultOdometryAlpha, kDefaultOdometryAlpha, kDefaultOdometryAlpha};
  read.number("rbpf/odom_alpha1", &f.motion_noise.rot_from_rot);
  read.number("rbpf/odom_alpha2", &f.motion_noise.rot_from_trans);
  read.number("rbpf/odom_alpha3", &f.motion_noise.trans_from_trans);
  read.number("rbpf/odom_alpha4", &f.motion_noise.trans_from_rot);
  read.number("rbpf/linear_update", &f.update_distance_m);
  read.number("rbpf/angular_update", &f.update_angle_rad);
  read.number("rbpf/resample_threshold", &f.resample_below);
  read.boolean("rbpf/scan_matching", &f.scan_matching);
  int seed = static_cast<int>(f.seed);
  read.integer("rbpf/seed", &seed, 0, std::numeric_limits<int>::max());
  f.seed = static_cast<std::uint64_t>(seed);
  int filter_threads = static_cast<int>(f.threads);
  read.integer("rbpf/threads", &filter_threads, 0, 1024);
  f.threads = static_cast<unsigned>(filter_threads);
  int learned_min_observed = static_cast<int>(p.learned_min_observed_steps);
  read.integer("rbpf/learned_min_observed_steps", &learned_min_observed, 0, std::numeric_limits<int>::max());
  p.learned_min_observed_steps = static_cast<std::uint32_t>(learned_min_observed);
  read.number("rbpf/transform_publish_period", &p.transform_publish_period_s);
  read.number("rbpf/transform_tolerance", &p.transform_tolerance_s);
  f = core::poseFilterConfigFor(m, f);

  read.require(!p.fixed_frame.empty(), "fixed_frame", "must not be empty");
  read.require(!p.odom_frame.empty(), "odom_frame", "must not be empty");
  read.require(!p.pose_correction || p.odom_frame != p.fixed_frame, "odom_frame",
               "must differ from ~fixed_frame with ~pose_correction rbpf (the node publishes " + p.fixed_frame +
                   " -> " + p.odom_frame + ")");
  read.require(!p.pose_correction || p.model != MapModel::kMemory, "pose_correction",
               "rbpf needs ~model hmm or both: the pose filter's transitions are the cell HMM's");
  read.require(p.transform_publish_period_s > 0.0 && p.transform_publish_period_s <= 3600.0,
               "rbpf/transform_publish_period", "must be in (0, 3600] s");
  read.require(p.transform_tolerance_s >= 0.0 && p.transform_tolerance_s <= 60.0, "rbpf/transform_tolerance",
               "must be in [0, 60] s");
  read.require(!p.pose_correction || p.scan_topics.size() == 1, "scan_topics",
               "must list one topic with ~pose_correction rbpf: the filter follows one laser's odometry");
  read.require(!p.scan_topics.empty(), "scan_topics", "must list at least one topic");
  for (const std::string& topic : p.scan_topics) {
    std::string why;
    read.require(!topic.empty(), "scan_topics", "has an empty topic");
    read.require(topic.empty() || ros::names::validate(topic, why), "scan_topics",
                 "has '" + topic + "', which is not a valid topic name: " + why);
  }
  read.require(p.publish_period_s > 0.0, "publish_period", "must be > 0 s");
  read.require(p.full_map_period_s >= 0.0, "full_map_period", "must be >= 0 s");
  read.require(p.prediction_horizon_s >= 0.0, "prediction_horizon", "must be >= 0 s");
  read.require(p.transition_scale > 0.0 && p.transition_scale <= 1.0, "transition_scale", "must be in (0, 1]");
  read.require(p.max_scan_latency_s >= 0.0, "max_scan_latency", "must be >= 0 s");
  read.require(p.time_jump_threshold_s > 0.0, "time_jump_threshold", "must be > 0 s");
  read.require(p.max_range_m > 0.0, "max_range", "must be > 0 m");
  read.require(p.map_thresholds.free_thresh >= 0.0 &&
                   p.map_thresholds.free_thresh < p.map_thresholds.occupied_thresh &&
                   p.map_thresholds.occupied_thresh <= 1.0,
               "map_topic/free_thresh", "and map_topic/occupied_thresh need 0 <= free_thresh < occupied_thresh <= 1");
  read.require(p.diagnostics_period_s > 0.0, "diagnostics/period", "must be > 0 s");
  read.require(p.min_scan_rate_hz >= 0.0, "diagnostics/min_scan_rate_hz", "must be >= 0 Hz");
  read.require(p.max_scan_rate_hz > p.min_scan_rate_hz, "diagnostics/max_scan_rate_hz",
               "must be > diagnostics/min_scan_rate_hz");
  read.require(p.max_step_lag_s > 0.0, "diagnostics/max_step_lag", "must be > 0 s");
  read.require(p.model != MapModel::kMemory || p.model_file.empty(), "model_file",
               "holds a cell HMM model: it needs ~model hmm or both, not memory");
  if (read.error().empty()) {
    // The core's own checks name the value (their names are these parameters' names).
    try {
      m.validate();
      em.validate();
    } catch (const std::invalid_argument& e) {
      *error = std::string("invalid parameter value (in ") + private_nh.getNamespace() +
               "): " + mapperParameterMessage(e.what());
      return false;
    }
    try {
      f.validate();
    } catch (const std::invalid_argument& e) {
      *error = std::string("invalid parameter value (in ") + private_nh.getNamespace() +
               "): " + filterParameterMessage(e.what());
      return false;
    }
    try {
      memory.validate();
    } catch (const std::invalid_argument& e) {
      *error = std::string("invalid parameter value (in ") + private_nh.getNamespace() +
               "): " + memoryParameterMessage(e.what());
      return false;
    }
  }
  if (!read.error().empty()) {
    *error = read.error();
    return false;
  }

  unknown->clear();
  std::vector<std::string> names;
  ros::param::getParamNames(names);
  const std::string prefix = private_nh.getNamespace() + "/";
  for (const std::string& name : names) {
    if (name.compare(0, prefix.size(), prefix) != 0) continue;
    const std::string relative = name.substr(prefix.size());
    if (read.known().count(relative) == 0) unknown->push_back(name);
  }
  *parameters = p;
  return true;
}

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
