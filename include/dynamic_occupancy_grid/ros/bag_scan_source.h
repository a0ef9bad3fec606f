#pragma once
// Reads the laser scans of a bag with the laser's pose in a fixed frame at each scan's
// stamp, from the bag's /tf and /tf_static (or from a given static pose for bags recorded
// without tf), as a stream of core::Scan.

#include <cstddef>
#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "dynamic_occupancy_grid/core/scan.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {

struct BagScanSourceOptions {
  std::string bag_path;
  std::string scan_topic = "/scan";
  std::string fixed_frame = "odom";
  /// When set, every scan is taken from this pose in the fixed frame and tf is not read.
  std::optional<core::Pose2D> static_laser_pose;
};

struct BagScanStats {
  std::size_t scans_read = 0;
  std::size_t scans_without_pose = 0;  ///< no transform at the scan's stamp
  std::string last_pose_error;         ///< the last tf error, for the user
  double bag_duration_s = 0.0;
};

class BagScanSource {
 public:
  /// Opens the bag and loads its transforms. Throws std::runtime_error with a message
  /// naming the file for a missing, unreadable or corrupt bag, or a topic it lacks.
  explicit BagScanSource(BagScanSourceOptions options);
  ~BagScanSource();
  BagScanSource(const BagScanSource&) = delete;
  BagScanSource& operator=(const BagScanSource&) = delete;

  /// Calls `on_scan` for every scan of the topic whose pose is known, in bag order, and
  /// `on_progress(fraction)` now and then. Throws std::runtime_error if the bag turns out
  /// corrupt while reading.
  BagScanStats forEachScan(const std::function<void(const core::Scan&)>& on_scan,
                           const std::function<void(double)>& on_progress = {});

 private:
  struct Impl;
  BagScanSourceOptions options_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
