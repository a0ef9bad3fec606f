#pragma once
// Reads the laser scans of a bag with the laser's pose in a fixed frame at each scan's
// stamp, from the bag's /tf and /tf_static (or from a given static pose for bags recorded
// without tf), as a stream of core::Scan.
//
// The bag is read in one pass, in recording order: /tf_static is loaded when the bag is
// opened, /tf is fed to a tf2::BufferCore as it comes, and each scan waits until the
// transforms recorded up to tf_lookahead_s after it have been read, so that its pose can
// be interpolated. Memory and time stay proportional to the bag, whatever its length, and a
// long read can be cancelled at any point through the progress callback.

#include <cstddef>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <string>

#include "dynamic_occupancy_grid/core/grid/scan.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {

struct BagScanSourceOptions {
  std::string bag_path;
  std::string scan_topic = "/scan";
  std::string fixed_frame = "odom";
  /// When set, every scan is taken from this pose in the fixed frame and tf is not read.
  std::optional<core::Pose2D> static_laser_pose;
  /// Only scans whose header stamps lie in [start_time_s, end_time_s] (absolute ROS time,
  /// seconds) are used; 0 leaves that end unbounded.
  double start_time_s = 0.0;
  double end_time_s = 0.0;
  /// Seconds of bag (recording) time of /tf read after a scan before its pose is looked up:
  /// transforms are often recorded a little after the scans they apply to.
  double tf_lookahead_s = 2.0;
  /// Readings longer than this count as "no return", as the node's ~max_range: the scan's
  /// range_max is lowered to it (infinity keeps the sensor's).
  double max_range_m = std::numeric_limits<double>::infinity();
};

struct BagScanStats {
  std::size_t scans_read = 0;               ///< scans of the topic in the time range
  std::size_t scans_outside_time_range = 0;  ///< skipped: stamped outside [start, end]
  std::size_t scans_without_pose = 0;       ///< no transform at the scan's stamp
  std::string last_pose_error;              ///< the last tf error, for the user
  /// Recording time spanned by the scans read (the whole topic before forEachScan).
  double bag_duration_s = 0.0;
  /// Header stamps of the first and last scans handed out (seconds).
  std::optional<double> first_stamp_s;
  std::optional<double> last_stamp_s;
  /// The progress callback asked to stop: the scans after that point were not read.
  bool cancelled = false;
};

/// Fraction of the bag read, in [0, 1]; return false to stop reading.
using BagReadProgress = std::function<bool(double fraction)>;

class BagScanSource {
 public:
  /// Opens the bag, checks the scan topic and loads /tf_static. Cheap: the scans and /tf are
  /// read by forEachScan. Throws std::runtime_error with a message naming the file for a
  /// missing, unreadable or corrupt bag, a topic it lacks or that holds another type, a bag
  /// without any transform when no static pose is given, or a bad time range (end < start).
  explicit BagScanSource(BagScanSourceOptions options);
  ~BagScanSource();
  BagScanSource(const BagScanSource&) = delete;
  BagScanSource& operator=(const BagScanSource&) = delete;

  const BagScanSourceOptions& options() const { return options_; }

  /// Calls `on_scan` for every scan of the topic in the time range whose pose is known, in
  /// bag order, and `on_progress` at the start, at most every 20 ms while reading, and with
  /// 1 at the end. Throws std::runtime_error naming the file if the bag turns out corrupt
  /// while reading; exceptions of `on_scan` pass through unchanged.
  BagScanStats forEachScan(const std::function<void(const core::Scan&)>& on_scan,
                           const BagReadProgress& on_progress = {});

 private:
  struct Impl;
  BagScanSourceOptions options_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
