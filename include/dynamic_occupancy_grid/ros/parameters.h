#pragma once
// The mapping node's parameters: read from the private namespace, checked, and turned into
// the core's configuration. Every name here is the one in config/dynamic_occupancy_grid.yaml
// and in README.md.

#include <ros/node_handle.h>

#include <cstdint>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/layers/layers.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/memory/memory_model.h"
#include "dynamic_occupancy_grid/core/cell/offline_em.h"
#include "dynamic_occupancy_grid/core/pose/pose_filter.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {

/// The pose filter's odometry noise by default (~rbpf/odom_alpha1..4; amcl's defaults are
/// 0.2, made for worse odometry than most robots' calibrated wheels). 0.001: measured on the
/// Hokuyo office recordings against their localizer (docs/pose_correction_real.md, "The
/// motion model's noise"): odometry's heading drifts 0.01-0.015 rad and its position 0.02 m
/// (median) per 0.5 m, which alphas of 0.001 cover (0.022 rad, 0.016 m per 0.5 m).
constexpr double kDefaultOdometryAlpha = 0.001;

/// ~learn_sensor_model's default: the node learns the sensor model (core::MapperConfig's
/// own default is the fixed model).
constexpr bool kDefaultLearnSensorModel = true;

/// Which map model the node runs on the scans (~model).
enum class MapModel { kHmm, kMemory, kBoth };

struct NodeParameters {
  MapModel model = MapModel::kHmm;      ///< ~model: "hmm", "memory" or "both"
  std::string fixed_frame = "map";
  std::vector<std::string> scan_topics{"scan"};
  int scan_queue_size = 50;            ///< scans waiting for their transform, per topic
  double publish_period_s = 1.0;       ///< layers and their updates
  double full_map_period_s = 10.0;     ///< full layers also at least this often; 0 = every publish
  double prediction_horizon_s = 60.0;  ///< ~predicted shows p(occ) this far ahead
  double transition_scale = 0.1;       ///< p per step shown as 100 in the transition layers
  bool publish_map_topic = false;      ///< a layer also on `map` / `map_updates`
  core::Layer map_layer = core::Layer::kBelief;  ///< ~map_topic/layer
  core::OccupancyThresholds map_thresholds;      ///< ~map_topic/mode, occupied_thresh, free_thresh
  double max_scan_latency_s = 0.5;     ///< a step is applied this long after it ends
  double time_jump_threshold_s = 3.0;  ///< a scan this much older than the newest restarts time
  double max_range_m = 50.0;           ///< longer readings count as no return
  std::string model_file;              ///< loaded at start-up when set
  /// ~file_directory: when set, the services' paths are confined to it (relative ones in it).
  std::string file_directory;
  double diagnostics_period_s = 1.0;   ///< ~diagnostics/period: /diagnostics this often
  double min_scan_rate_hz = 1.0;       ///< ~diagnostics/min_scan_rate_hz, per scan topic
  double max_scan_rate_hz = 100.0;     ///< ~diagnostics/max_scan_rate_hz, per scan topic
  double max_step_lag_s = 5.0;         ///< ~diagnostics/max_step_lag: map older than this: WARN
  core::MapperConfig mapper;
  core::OfflineEmConfig offline_em;
  /// ~memory/*; its lattice, max_free_range and max_map_size are the mapper's.
  core::MemoryModelConfig memory;
  int max_published_hypotheses = 4;    ///< best hypotheses in ~hypotheses
  /// ~pose_correction "rbpf": the laser's pose in ~odom_frame is odometry, corrected by the
  /// pose filter (core/pose/corrected_mapping.h), which publishes ~fixed_frame -> ~odom_frame;
  /// "none" (false): tf's pose in ~fixed_frame is the truth.
  bool pose_correction = false;
  std::string odom_frame = "odom";
  /// ~rbpf/*; the map's fields (resolution, time step, sensor model, ranges) are the mapper's.
  core::PoseFilterConfig filter;
  std::uint32_t learned_min_observed_steps = 30;  ///< ~rbpf/learned_min_observed_steps
  double transform_publish_period_s = 0.05;       ///< ~rbpf/transform_publish_period
  double transform_tolerance_s = 0.1;             ///< ~rbpf/transform_tolerance
  bool runsHmm() const { return model != MapModel::kMemory; }
  bool runsMemory() const { return model != MapModel::kHmm; }
};

/// Reads and validates every parameter under `private_nh` (defaults for missing ones).
/// Returns false and a message naming the parameter for a wrong type or a bad value.
/// Parameters under the namespace that the node does not know are listed in `unknown`
/// (likely typos; the node warns).
bool readParameters(const ros::NodeHandle& private_nh, NodeParameters* parameters, std::string* error,
                    std::vector<std::string>* unknown);

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
