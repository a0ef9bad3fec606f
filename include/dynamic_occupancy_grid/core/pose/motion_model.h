#pragma once
// The odometry motion model (Thrun, Burgard, Fox, "Probabilistic Robotics", §5.4; amcl's
// and gmapping's): the motion between two odometry poses read as a rotation, a
// translation and a second rotation, each with noise that grows with the motion.
//
// ROS-free: standard library only. The caller draws the standard normal numbers, so the
// simulator's drifting odometry and the pose filter's proposal use one formula with their
// own generators.

#include <array>

#include "dynamic_occupancy_grid/core/grid/scan.h"

namespace dynamic_occupancy_grid {
namespace core {

/// amcl's odom_alpha1..4: the variances of a motion's two rotations grow as
/// alpha1 rot^2 + alpha2 trans^2, its translation's as alpha3 trans^2 + alpha4 (rot1^2 +
/// rot2^2) (rad, m).
struct OdometryNoise {
  double rot_from_rot = 0.0;      ///< alpha1
  double rot_from_trans = 0.0;    ///< alpha2
  double trans_from_trans = 0.0;  ///< alpha3
  double trans_from_rot = 0.0;    ///< alpha4
  /// Throws std::invalid_argument unless all four are finite and >= 0.
  void validate() const;
  bool none() const { return rot_from_rot == 0.0 && rot_from_trans == 0.0 && trans_from_trans == 0.0 && trans_from_rot == 0.0; }
};

/// A motion as rotation, translation, rotation (rad, m, rad).
struct OdometryMotion {
  double rot1_rad = 0.0;
  double trans_m = 0.0;
  double rot2_rad = 0.0;
};

/// The motion from `from` to `to`. A turn on the spot has no direction of travel: all of it
/// is the second rotation. Rotations in [-pi, pi].
OdometryMotion odometryMotion(const Pose2D& from, const Pose2D& to);

/// `motion` read with noise (§5.4, sample_motion_model_odometry): each part plus the square
/// root of its variance times one of `standard_normals` (rot1, trans, rot2 in that order).
/// A rotation's size in the variances is its distance to the nearer of 0 and ±pi, as in
/// amcl: moving backwards is not a half turn.
OdometryMotion perturbMotion(const OdometryMotion& motion, const OdometryNoise& noise,
                             const std::array<double, 3>& standard_normals);

/// `pose` moved by `motion` (yaw in [-pi, pi]).
Pose2D applyMotion(const Pose2D& pose, const OdometryMotion& motion);

/// The pose `pose` seen from `frame` (frame^-1 * pose; yaw in [-pi, pi]).
Pose2D relativePose(const Pose2D& frame, const Pose2D& pose);
/// The pose `relative` to `frame` in the frame's parent (frame * relative; yaws added, not
/// wrapped): a laser mounted at `relative` on a robot at `frame`.
Pose2D composePose(const Pose2D& frame, const Pose2D& relative);

}  // namespace core
}  // namespace dynamic_occupancy_grid
