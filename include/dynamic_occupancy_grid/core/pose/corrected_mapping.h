#pragma once
// Mapping with the laser's pose corrected by the pose filter (issue 19's node mode and
// process_bag --pose-correction): each scan arrives with the laser's *odometry* pose, the
// PoseFilter updates its particles on it, and the Mapper integrates the scan at odometry's
// pose moved by the correction in use (map -> odom). The filter's transitions are the ones
// that Mapper learns (MapperTransitions), so the map the user sees is also the filter's
// learner.
//
// The correction in use changes only when the filter's (its best particle's) has passed a
// test at two filter updates in a row: it moves the scan (the laser or a beam's end) by
// more than two cells, and the scan fits the *settled* map better with it than with the
// correction in use. The settled map is the Mapper's map as it was 30 to 60 s of sensor
// time ago: which cells had been observed and which of them were occupied. Each change of
// map -> odom misaligns the scans mapped before it with those after, and a real robot's
// odometry is millimetres off over seconds while the filter's estimate wanders by
// centimetres and hundredths of a radian; the map built in the last seconds was built at
// odometry's poses and so always agrees with odometry best. The settled map is where drift
// shows: a place seen again after a loop (docs/pose_correction_real.md, "Corrections taken
// only where the settled map asks for them"). Until a settled map exists (the first 60 s)
// and where the scan sees none of it, the correction in use is kept.
//
// Frames: the map frame starts at odometry's at the first scan, shifted by a start
// correction (the map -> odom transform in use when mapping restarts: a reset, a loaded
// model, time jumping back), so that a restart does not move the map frame. The filter is
// given odometry moved by the start correction: its frame is the map frame, and its cells
// are the Mapper's.
//
// ROS-free: the core's Mapper and PoseFilter.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/pose/pose_filter.h"

namespace dynamic_occupancy_grid {
namespace core {

/// `filter` with the fields that describe the map and its sensor taken from `mapper`
/// (resolution, time step, sensor model, max_free_range) and max_range_m lowered to what
/// the filter can walk at that resolution (1000 cells).
PoseFilterConfig poseFilterConfigFor(const MapperConfig& mapper, PoseFilterConfig filter);

/// A particle's own map as values: p(occ) per cell of `window`, row by row from the lowest
/// row; NaN where the particle has never observed the cell. Cell (x, y) covers
/// [x r, (x + 1) r) x [y r, (y + 1) r) of the map frame, so the window's origin is its
/// first cell's corner.
struct ParticleBelief {
  MapWindow window;
  std::vector<float> values;
};

/// The cells of a model file that CorrectedMapping::serializeModel took from the best
/// particle's own map, and those it kept the Mapper's belief in.
struct BestParticleCells {
  std::size_t replaced = 0;
  /// The particle had not observed the cell by the Mapper's last update of it: never, or
  /// only later (its last update of the cell is in the Mapper's step being gathered, which
  /// a model does not hold).
  std::size_t kept = 0;
};

/// What one scan did.
struct CorrectedScan {
  PoseUpdate update;  ///< the filter's
  Scan corrected;     ///< the scan at the corrected laser pose, as the mapper was given it
  ScanResult mapped;  ///< the mapper's
};

class CorrectedMapping {
 public:
  /// `mapper` must outlive this and be changed only through it (or while no scan is being
  /// integrated). Throws std::invalid_argument for a bad filter config.
  CorrectedMapping(Mapper& mapper, const PoseFilterConfig& filter, std::uint32_t learned_min_observed_steps,
                   const Pose2D& start_correction = Pose2D{});

  /// One scan whose laser_pose is the laser's odometry pose. Throws std::invalid_argument
  /// (nothing changed) for a scan the filter refuses (scanFieldsError, a stamp before the
  /// first scan's step).
  CorrectedScan integrate(const Scan& odometry_scan);

  /// map -> odom for the laser's poses: the correction in use (see above) after the start
  /// correction; the start correction before the first scan.
  Pose2D mapToOdometry() const;
  /// The laser's poses in the map frame at the filter's updates, as the scans were mapped
  /// (odometry moved by the correction in use), oldest first. The filter's own estimate is
  /// filter().bestTrajectory().
  std::vector<TrajectoryNode> trajectory() const;
  /// How often the correction in use changed.
  std::size_t correctionsTaken() const { return corrections_taken_; }
  /// The best particle's own map predicted to the filter's last update plus `horizon_steps`
  /// (>= 0; the node's `predicted` layer's horizon for its `~best_particle_predicted`), over
  /// its tiles (a later resampling may pick another particle: the Mapper holds the scans as
  /// they came). Empty before the first scan.
  ParticleBelief bestParticleBelief(std::int64_t horizon_steps = 0) const;
  /// The Mapper's model file (model_io.h) with the best particle's own map: each cell's
  /// belief is the best particle's, predicted to the cell's last update in the Mapper (with
  /// the filter's transitions), where the particle has observed the cell by then; the rest
  /// of the cell (transitions, static baseline; the learner state split over the state now
  /// by the new belief: serializeModel's CellBeliefOverride) and the other cells are the
  /// Mapper's. Before the first scan, serializeModel(mapper()).
  std::string serializeModel(BestParticleCells* cells = nullptr) const;
  const PoseFilter& filter() const { return *filter_; }
  const Mapper& mapper() const { return mapper_; }

 private:
  /// The Mapper's map at one step: per allocated tile of its grid, the cells observed by
  /// then and those of them with p(occ) > 0.5.
  struct MapSnapshot;
  /// Whether the filter's correction passes the test (see above) for this scan.
  bool correctionPasses(const Pose2D& candidate, const Scan& shifted) const;
  void refreshSnapshots();

  Mapper& mapper_;
  std::unique_ptr<PoseFilter> filter_;
  Pose2D start_correction_;
  Pose2D correction_;  ///< in use, in the filter's frame (after the start correction)
  bool passed_last_update_ = false;
  std::size_t corrections_taken_ = 0;
  std::vector<TrajectoryNode> trajectory_;
  std::shared_ptr<const MapSnapshot> settled_;  ///< 30 to 60 s old; null before
  std::shared_ptr<const MapSnapshot> newest_;   ///< 0 to 30 s old
  std::int64_t newest_step_ = 0;
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
