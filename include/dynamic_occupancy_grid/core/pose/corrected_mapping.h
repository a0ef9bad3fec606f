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
// only where the settled map asks for them"). Until a settled map exists (the first 30 s)
// and where the scan sees none of it, the correction in use is kept.
//
// When it takes a correction, the recent map moves with it: the Mapper goes back to its
// checkpoint at the settled map (a copy kept with each snapshot) and maps the scans since
// again, each at its correction plus a share of the change (new minus the one in use) that
// grows with the laser's travel (path plus turns at 1 m per radian) from none, at the last
// change, the checkpoint or 10 m of travel back (whichever is nearest), to all of it at
// the scan that takes it, as a graph optimizer spreads a loop's closure over the loop. So
// the places seen in the last seconds agree with the scans that follow. That runs on a
// thread of its own; at the next scan (a later stamp), once the filter has updated on it,
// the result becomes the Mapper (waiting for it if need be: the same scans always give the
// same map), and that scan goes into it. The snapshots stay
// as they were taken: the settled map is the map as it was. Not where the mapper's
// settings changed since the checkpoint (Mapper::settingsRevision): then only the new
// scans take the correction. What the Mapper records for offline EM (recordObservations)
// is recorded again from the checkpoint on.
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
#include <deque>
#include <memory>
#include <optional>
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
  /// The scans before this one that were mapped again because it changed the correction in
  /// use: the last `remapped` (see CorrectedMapping); 0 if it changed nothing.
  std::size_t remapped = 0;
};

class CorrectedMapping {
 public:
  /// `mapper` must outlive this and be changed only through it (or while no scan is being
  /// integrated). Throws std::invalid_argument for a bad filter config.
  CorrectedMapping(Mapper& mapper, const PoseFilterConfig& filter, std::uint32_t learned_min_observed_steps,
                   const Pose2D& start_correction = Pose2D{});
  /// Waits for a re-mapping still running (see above), without taking it.
  ~CorrectedMapping();
  CorrectedMapping(const CorrectedMapping&) = delete;
  CorrectedMapping& operator=(const CorrectedMapping&) = delete;

  /// The end of the data: takes a re-mapping still running (waiting for it). The Mapper's
  /// step being gathered stays open (Mapper::finishStep).
  void finish();
  /// Takes a re-mapping that has ended, without waiting: the Mapper becomes what the next
  /// scan would make it before that scan is mapped (the same map, as finish() between
  /// scans). For a caller between scans, such as the node's publish timer, so that a map
  /// whose scans stopped shows the last correction. false: none running, or not ended yet.
  bool takeFinishedRemap();

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
  /// Scans mapped again when a correction was taken (see above), over all corrections.
  std::size_t scansRemapped() const { return scans_remapped_; }
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
  /// A snapshot with the Mapper as it was then, to map the scans since again.
  struct Checkpoint;
  /// A scan since the settled checkpoint, as the filter saw it (odometry after the start
  /// correction).
  struct RecentScan {
    Scan shifted;
    Pose2D correction;    ///< it is mapped at
    double travel = 0.0;  ///< the laser's travel up to this scan since the first scan
    std::size_t trajectory_node = 0;  ///< its node in trajectory_ + 1; 0: none
  };
  /// Whether the filter's correction passes the test (see above) for this scan.
  bool correctionPasses(const Pose2D& candidate, const Scan& shifted) const;
  /// A new checkpoint every 30 s (of the Mapper as it is before this scan); the one before
  /// becomes the settled one.
  void refreshSnapshots();
  /// The correction in use becomes `correction` at the scan stamped `stamp_s`; the scans
  /// since the settled checkpoint are mapped again (see above), beside the mapping. Returns
  /// how many.
  std::size_t takeCorrection(const Pose2D& correction, double stamp_s);
  /// Takes the re-mapping's result (waiting for it): the scans since the correction was
  /// taken mapped into it too, it becomes the Mapper (Mapper::adopt).
  void completeRemap();
  struct Remap;

  Mapper& mapper_;
  std::unique_ptr<PoseFilter> filter_;
  Pose2D start_correction_;
  Pose2D correction_;  ///< in use, in the filter's frame (after the start correction)
  bool passed_last_update_ = false;
  std::size_t corrections_taken_ = 0;
  std::size_t scans_remapped_ = 0;
  std::vector<TrajectoryNode> trajectory_;
  std::shared_ptr<const Checkpoint> settled_;  ///< 30 to 60 s old; null before
  std::shared_ptr<const Checkpoint> newest_;   ///< 0 to 30 s old
  /// The scans since the settled checkpoint (since the newest while there is none).
  std::deque<RecentScan> recent_;
  std::size_t recent_first_ = 0;  ///< the number of scans before recent_.front()
  std::size_t scans_seen_ = 0;    ///< scans the filter took
  std::unique_ptr<Remap> remap_;  ///< running; null if none
  double travel_ = 0.0;
  double last_taken_travel_ = 0.0;  ///< travel_ when the correction in use was taken
  std::optional<Pose2D> last_shifted_pose_;
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
