#pragma once
// The mapping node: LaserScans (through tf2_ros::MessageFilter on the fixed frame; on the
// odom frame with ~pose_correction rbpf, corrected by core::CorrectedMapping) into a
// core::Mapper (the cell HMM) and/or a core::MemoryModel (Morris et al.'s STM/LTM, ~model),
// the map layers out as latched OccupancyGrids plus their updates, the memory model's map
// hypotheses, and the services; its health on /diagnostics (diagnostic_updater) and the
// parameters that may change while mapping through dynamic_reconfigure. One class for the
// node (src/nodes/mapping_node.cpp) and the nodelet (src/ros/mapping_nodelet.cpp), defined in
// src/ros/mapping_node*.cpp by concern (docs/architecture.md). Topics, services and
// parameters: README.md.
//
// Threads: scans, tf, the publish timer and dynamic_reconfigure run on the callback queues
// of the node handles given (the node's global queue, a nodelet's own); the services run
// on a queue of their own, served by kServiceThreads threads of their own, so that a slow
// or stuck request (a big file, a slow disk, a file another process holds) never delays a
// scan, and one stuck request leaves the other services answering. Everything they share
// is under mutex_, held only for the in-memory part of a request (never for file I/O).
// With ~pose_correction rbpf the map -> odom broadcast runs on a queue and thread of its
// own and reads only the correction, under correction_mutex_ (taken inside mutex_, never
// the other way).

#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/publisher.h>
#include <dynamic_reconfigure/server.h>
#include <message_filters/subscriber.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <ros/spinner.h>
#include <sensor_msgs/LaserScan.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/message_filter.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>

#include <boost/thread/recursive_mutex.hpp>

#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "dynamic_occupancy_grid/DynamicOccupancyGridConfig.h"
#include "dynamic_occupancy_grid/ExportLayers.h"
#include "dynamic_occupancy_grid/GetCell.h"
#include "dynamic_occupancy_grid/GetStatus.h"
#include "dynamic_occupancy_grid/LoadModel.h"
#include "dynamic_occupancy_grid/PredictMap.h"
#include "dynamic_occupancy_grid/RunOfflineEm.h"
#include "dynamic_occupancy_grid/SaveModel.h"
#include "dynamic_occupancy_grid/core/pose/corrected_mapping.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/memory/memory_model.h"
#include "dynamic_occupancy_grid/ros/grid_messages.h"
#include "dynamic_occupancy_grid/ros/parameters.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {

class MappingNode {
 public:
  /// Threads serving the services' callback queue.
  static constexpr int kServiceThreads = 2;

  /// `nh` for the `map` topic (publish_map_topic), `private_nh` for everything else.
  MappingNode(const ros::NodeHandle& nh, const ros::NodeHandle& private_nh);
  /// Stops the services' threads (waiting for requests being served) and a running
  /// offline EM (waiting for it).
  ~MappingNode();
  MappingNode(const MappingNode&) = delete;
  MappingNode& operator=(const MappingNode&) = delete;

  /// Reads and checks the parameters (a bad one: logged with its name, returns false,
  /// nothing advertised), loads ~model_file if set, then subscribes and advertises.
  bool start();

 private:
  /// One published layer: the full grid and its updates.
  struct Output {
    LayerView view;
    ros::Publisher full;
    ros::Publisher updates;
    bool needs_full = true;        ///< a new subscriber, new bounds or a new model
    bool horizon_from_parameter = false;
    /// The int8 tiles of a layer that changes only where cells are written (stationary, the
    /// transitions, static_map): made at first use, dropped with the mapper or a new scaling.
    std::optional<core::LayerTileCache> cache;
  };

  /// One published store of the memory model (~ltm, ~stm): the full grid and its updates.
  struct MemoryOutput {
    bool long_term = true;   ///< LTM, else STM
    ros::Publisher full;
    ros::Publisher updates;
    bool needs_full = true;  ///< a new subscriber, new bounds or a reset
  };

  /// The cell HMM's layers, offline EM progress and services (not with ~model memory).
  void advertiseHmm();
  /// ~ltm, ~stm (and their updates), ~hypotheses.
  void advertiseMemory();
  /// /diagnostics: the scan rate of each topic, scans dropped by cause, tf, the map, offline EM.
  void startDiagnostics();
  /// The dynamic_reconfigure server, starting from the parameters read.
  void startReconfigure();
  /// The reconfigurable values in use; caller holds mutex_.
  DynamicOccupancyGridConfig reconfigurableValues() const;
  /// A dynamic_reconfigure request: applied under mutex_, or refused (`config` reverted).
  void reconfigure(DynamicOccupancyGridConfig& config, std::uint32_t level);
  void diagnoseScans(diagnostic_updater::DiagnosticStatusWrapper& status);
  void diagnoseTf(diagnostic_updater::DiagnosticStatusWrapper& status);
  void diagnoseMap(diagnostic_updater::DiagnosticStatusWrapper& status);
  void diagnoseOfflineEm(diagnostic_updater::DiagnosticStatusWrapper& status);
  /// Every scan as it arrives on topic `topic_index` (before tf): its rate.
  void scanArrived(const sensor_msgs::LaserScan::ConstPtr& msg, std::size_t topic_index);
  /// A throttled warning naming `frame_id` and the fixed frame once scans from it have had no
  /// transform for kMissingFrameGraceS (they would wait silently in the tf2 filter's queue).
  void warnIfNoTransform(const std::string& frame_id);
  /// A scan dropped for want of a transform (tf2 filter or lookup), with tf's reason.
  void countTfDrop(const std::string& error);
  /// The offline EM run's state for the diagnostics.
  void setOfflineEmState(const std::string& phase, double fraction, const std::string& message);
  void scanCallback(const sensor_msgs::LaserScan::ConstPtr& msg);
  /// A scan's stamp and the ROS time it was taken at, towards the scans' clock offset
  /// (stamp_offset_s_, from the first kStampOffsetScans scans and again after ROS time
  /// went back); returns the offset in use.
  double observeStampOffset(double stamp_s, double now_s);
  /// ROS time on the scans' clock: ros::Time::now() + stamp_offset_s_ (maps and broadcasts
  /// are stamped in it, as the scans and the tf they came with are).
  ros::Time scanClockNow() const;
  /// The scan into the memory model (false: refused); caller holds mutex_.
  bool integrateMemory(const core::Scan& scan, const std::string& frame_id);
  void scanDropped(const sensor_msgs::LaserScan::ConstPtr& msg, tf2_ros::FilterFailureReason reason);
  void publishTimer(const ros::TimerEvent& event);
  void publishLayers(bool force_full);
  /// The full grid of `output` now; caller holds mutex_.
  void publishFull(Output& output);
  /// `output`'s values over `box` at `step`: from its tile cache where the layer has one.
  std::vector<std::int8_t> outputValues(Output& output, std::int64_t step, const core::CellBox& box);
  /// After a memory update (or with `force_full`): ~ltm, ~stm (full or their updates) and
  /// ~hypotheses; caller holds mutex_.
  void publishMemory(bool force_full);
  void publishMemoryFull(MemoryOutput& output);
  void publishHypotheses();
  /// Stamp of the memory model's outputs: the scan that completed the last update.
  ros::Time memoryStamp() const;
  /// The frame the laser's pose is looked up in: ~odom_frame with pose correction, else
  /// ~fixed_frame.
  const std::string& laserPoseFrame() const;
  /// The scan into the cell HMM, through the pose correction if on; caller holds mutex_.
  /// With pose correction, `corrected_scan` gets the scan at the corrected pose once the
  /// filter has taken it (whatever the map then does with it).
  core::ScanResult integrateHmm(const core::Scan& scan, std::optional<core::Scan>* corrected_scan);
  /// (Re)starts the pose correction on mapper_ (at start, a new mapper, time jumping back),
  /// keeping the map -> odom transform in use; caller holds mutex_.
  void restartCorrection();
  /// ~best_particle_belief and ~best_particle_predicted (each if someone listens) when the
  /// filter has updated since they were last sent (or `force`); caller holds mutex_.
  void publishBestParticle(bool force);
  /// ~fixed_frame -> ~odom_frame, the latest correction, stamped now + ~rbpf/transform_tolerance.
  void publishCorrection(const ros::TimerEvent& event);
  /// Puts `mapper` in place of the live one (load, reset); caller holds mutex_.
  void replaceMapper(std::unique_ptr<core::Mapper> mapper);
  /// ~file_directory made absolute (created if missing) and the stale temporaries of
  /// interrupted saves removed from the directories the node writes to; false (logged)
  /// if ~file_directory cannot be used.
  bool prepareFiles();
  /// A request's path as the node uses it: absolute; with ~file_directory, relative to it,
  /// `..` and symbolic links resolved, and refused (std::runtime_error) outside it.
  std::string requestPath(const std::string& path) const;

  bool runOfflineEm(RunOfflineEm::Request& request, RunOfflineEm::Response& response);
  bool saveModel(SaveModel::Request& request, SaveModel::Response& response);
  bool loadModel(LoadModel::Request& request, LoadModel::Response& response);
  bool exportLayers(ExportLayers::Request& request, ExportLayers::Response& response);
  bool reset(std_srvs::Trigger::Request& request, std_srvs::Trigger::Response& response);
  bool getCell(GetCell::Request& request, GetCell::Response& response);
  bool getStatus(GetStatus::Request& request, GetStatus::Response& response);
  bool predictMap(PredictMap::Request& request, PredictMap::Response& response);

  ros::NodeHandle nh_;
  ros::NodeHandle private_nh_;
  /// The services' queue and private_nh_ on it; served by service_spinner_.
  ros::CallbackQueue service_queue_;
  ros::NodeHandle service_nh_;
  NodeParameters parameters_;
  std::string file_directory_;  ///< ~file_directory, absolute and canonical; empty: none

  // Diagnostics; declared before the subscriptions, which tick them, so they outlive them.
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  std::vector<std::unique_ptr<diagnostic_updater::HeaderlessTopicDiagnostic>> scan_rates_;  ///< per topic
  /// Scans by fate since the start (counted where they are dropped).
  struct ScanCounts {
    std::atomic<std::uint64_t> received{0};
    std::atomic<std::uint64_t> integrated{0};       ///< by the cell HMM (or the memory model alone)
    std::atomic<std::uint64_t> dropped_tf{0};       ///< no transform (tf2 filter or lookup)
    std::atomic<std::uint64_t> dropped_invalid{0};  ///< stamp, shape, laser pose, the model's checks
    std::atomic<std::uint64_t> dropped_late{0};     ///< for a step already applied
    std::atomic<std::uint64_t> memory_rejected{0};  ///< refused by the memory model
  };
  ScanCounts scan_counts_;
  /// Scan stamps minus ROS time when the scans run on another clock than ROS time (a bag
  /// recorded on a computer whose clock differed from the recorder's, played with --clock;
  /// a bag played without --clock): 0 while they agree within kStampOffsetToleranceS. The
  /// node compares stamps with ROS time + this (scanClockNow); the core maps in stamp time.
  std::atomic<double> stamp_offset_s_{0.0};
  /// Guards the estimate of stamp_offset_s_ below (never held while taking another mutex).
  std::mutex stamp_offset_mutex_;
  std::vector<double> stamp_offset_samples_;  ///< stamp - ROS time of the first scans
  double stamp_offset_reported_s_ = 0.0;      ///< the offset last logged (0: none)
  double last_scan_ros_time_s_ = 0.0;         ///< ROS time of the last scan observed
  /// Guards the diagnostics' own state below (never held while taking mutex_).
  std::mutex diagnostics_mutex_;
  std::string last_tf_error_;
  std::map<std::string, ros::WallTime> frames_without_transform_;  ///< since when, per scan frame
  std::uint64_t tf_reported_dropped_ = 0;     ///< dropped_tf at the last tf report
  std::uint64_t tf_reported_integrated_ = 0;  ///< integrated at the last tf report
  std::uint64_t scans_reported_dropped_ = 0;  ///< all drops at the last scans report
  std::string offline_em_phase_ = "idle";
  double offline_em_fraction_ = 0.0;
  std::string offline_em_message_;
  ros::Timer diagnostics_timer_;

  boost::recursive_mutex reconfigure_mutex_;  ///< the dynamic_reconfigure server's
  std::unique_ptr<dynamic_reconfigure::Server<DynamicOccupancyGridConfig>> reconfigure_server_;

  tf2_ros::Buffer tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  std::vector<std::unique_ptr<message_filters::Subscriber<sensor_msgs::LaserScan>>> scan_subscribers_;
  std::vector<std::unique_ptr<tf2_ros::MessageFilter<sensor_msgs::LaserScan>>> scan_filters_;

  std::vector<Output> outputs_;            ///< the HMM's layers (none with ~model memory)
  std::vector<MemoryOutput> memory_outputs_;  ///< ~ltm, ~stm (none with ~model hmm)
  ros::Publisher hypotheses_;
  ros::Publisher offline_em_progress_;
  std::vector<ros::ServiceServer> services_;
  std::unique_ptr<ros::AsyncSpinner> service_spinner_;  ///< kServiceThreads on service_queue_
  ros::Timer publish_timer_;

  /// Guards everything below (scans, services, the timer and the offline EM thread).
  std::mutex mutex_;
  std::unique_ptr<core::Mapper> mapper_;  ///< null with ~model memory
  DynamicOccupancyGridConfig reconfigured_;  ///< the values applied last
  std::optional<double> newest_stamp_s_;  ///< newest scan stamp integrated
  /// Seconds time ran on in steps below ~time_jump_threshold since the map's clock last
  /// restarted (none: it never did); a further restart needs ~time_jump_threshold of it.
  std::optional<double> steady_since_restart_s_;
  core::CellBox published_bounds_;        ///< bounds of the last full grids
  ros::Time last_full_publish_;
  std::unique_ptr<core::MemoryModel> memory_;  ///< null with ~model hmm
  std::optional<ros::Time> memory_stamp_;     ///< of the scan that completed the last update
  bool memory_updated_ = false;               ///< an update (or reset) not published yet
  bool hypotheses_need_publish_ = true;       ///< for the next subscriber of ~hypotheses
  core::CellBox memory_published_bounds_;
  ros::Time memory_last_full_publish_;
  /// ~pose_correction rbpf: the pose filter on mapper_ (null without).
  std::unique_ptr<core::CorrectedMapping> correction_;
  ros::Publisher effective_sample_size_;  ///< ~effective_sample_size, at each filter update
  ros::Publisher pose_entropy_;           ///< ~pose_entropy, at each filter update
  ros::Publisher best_particle_belief_;   ///< ~best_particle_belief (latched), after filter updates
  ros::Publisher best_particle_predicted_;  ///< ~best_particle_predicted (latched), with it
  std::size_t best_particle_published_updates_ = 0;  ///< the filter's updates when it was last sent
  double last_effective_sample_size_ = 0.0;  ///< of the last filter update, before resampling

  /// Held by the load_model request putting its model in place and telling
  /// dynamic_reconfigure (two loads at once end as the later one, everywhere).
  std::mutex load_mutex_;
  /// Held by the run_offline_em request being handled (a second one is refused meanwhile).
  std::mutex offline_em_request_mutex_;
  std::thread offline_em_thread_;
  std::atomic<bool> offline_em_running_{false};
  std::atomic<bool> offline_em_cancel_{false};

  /// The map -> odom broadcast runs on a queue and thread of its own, so that tf keeps
  /// flowing while a scan updates the particles (which holds mutex_ for a filter update).
  std::mutex correction_mutex_;         ///< guards map_to_odom_ (never held with mutex_ waited for)
  core::Pose2D map_to_odom_;            ///< the latest correction
  std::unique_ptr<tf2_ros::TransformBroadcaster> tf_broadcaster_;
  ros::Time last_correction_stamp_;     ///< of the last broadcast (the correction thread's own)
  ros::CallbackQueue correction_queue_;
  ros::Timer correction_timer_;         ///< on correction_queue_
  std::unique_ptr<ros::AsyncSpinner> correction_spinner_;  ///< last: stopped first
};

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
