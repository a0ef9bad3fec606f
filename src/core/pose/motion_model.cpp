#include "dynamic_occupancy_grid/core/pose/motion_model.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace dynamic_occupancy_grid {
namespace core {

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr double kTwoPi = 2.0 * kPi;
}  // namespace

void OdometryNoise::validate() const {
  for (const double alpha : {rot_from_rot, rot_from_trans, trans_from_trans, trans_from_rot}) {
    if (!(std::isfinite(alpha) && alpha >= 0.0)) {
      throw std::invalid_argument("OdometryNoise: every alpha must be finite and >= 0");
    }
  }
}

OdometryMotion odometryMotion(const Pose2D& from, const Pose2D& to) {
  const double dx = to.x_m - from.x_m;
  const double dy = to.y_m - from.y_m;
  OdometryMotion motion;
  motion.trans_m = std::hypot(dx, dy);
  motion.rot1_rad = motion.trans_m > 1e-9 ? std::remainder(std::atan2(dy, dx) - from.yaw_rad, kTwoPi) : 0.0;
  motion.rot2_rad = std::remainder(to.yaw_rad - from.yaw_rad - motion.rot1_rad, kTwoPi);
  return motion;
}

OdometryMotion perturbMotion(const OdometryMotion& motion, const OdometryNoise& noise,
                             const std::array<double, 3>& standard_normals) {
  const double trans = motion.trans_m;
  // The rotations' size for the noise: a sensor moving backwards (driving in reverse, or a
  // laser mounted facing back) turns by about pi on paper but not on its wheels, so the
  // turn is measured from the nearer of forward and backward (as amcl's diff model does).
  const auto turned = [](double rotation) { return std::min(std::abs(rotation), kPi - std::abs(rotation)); };
  const double rot1 = turned(motion.rot1_rad);
  const double rot2 = turned(motion.rot2_rad);
  const OdometryNoise& a = noise;
  OdometryMotion read;
  read.rot1_rad = motion.rot1_rad +
                  std::sqrt(a.rot_from_rot * rot1 * rot1 + a.rot_from_trans * trans * trans) * standard_normals[0];
  read.trans_m = trans + std::sqrt(a.trans_from_trans * trans * trans + a.trans_from_rot * (rot1 * rot1 + rot2 * rot2)) *
                             standard_normals[1];
  read.rot2_rad = motion.rot2_rad +
                  std::sqrt(a.rot_from_rot * rot2 * rot2 + a.rot_from_trans * trans * trans) * standard_normals[2];
  return read;
}

Pose2D applyMotion(const Pose2D& pose, const OdometryMotion& motion) {
  const double heading = pose.yaw_rad + motion.rot1_rad;
  Pose2D moved;
  moved.x_m = pose.x_m + motion.trans_m * std::cos(heading);
  moved.y_m = pose.y_m + motion.trans_m * std::sin(heading);
  moved.yaw_rad = std::remainder(heading + motion.rot2_rad, kTwoPi);
  return moved;
}

Pose2D relativePose(const Pose2D& frame, const Pose2D& pose) {
  const double c = std::cos(frame.yaw_rad);
  const double s = std::sin(frame.yaw_rad);
  const double dx = pose.x_m - frame.x_m;
  const double dy = pose.y_m - frame.y_m;
  return Pose2D{c * dx + s * dy, -s * dx + c * dy, std::remainder(pose.yaw_rad - frame.yaw_rad, kTwoPi)};
}

Pose2D composePose(const Pose2D& frame, const Pose2D& relative) {
  const double c = std::cos(frame.yaw_rad);
  const double s = std::sin(frame.yaw_rad);
  return Pose2D{frame.x_m + c * relative.x_m - s * relative.y_m, frame.y_m + s * relative.x_m + c * relative.y_m,
                frame.yaw_rad + relative.yaw_rad};
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
