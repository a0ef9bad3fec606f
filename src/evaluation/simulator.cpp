#include "dynamic_occupancy_grid/evaluation/simulator.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <stdexcept>
#include <utility>

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

constexpr double kPi = 3.14159265358979323846;
// Chords through an occupied cell shorter than this (in cells) are corner grazes (castRay).
constexpr double kMinChord = 0.1;

std::uint64_t splitmix64(std::uint64_t& x) {
  x += 0x9e3779b97f4a7c15ULL;
  std::uint64_t z = x;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

std::uint64_t rotl(std::uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

void require(bool condition, const std::string& message) {
  if (!condition) throw std::invalid_argument(message);
}

// Independent streams of one seed: the layout, the dynamics and the sensor noise of a run
// never draw from each other's numbers, so e.g. the door's changes do not depend on how
// many scans the robot took.
std::uint64_t streamSeed(std::uint64_t seed, std::uint64_t stream) {
  std::uint64_t x = seed ^ (0x5851f42d4c957f2dULL * (stream + 1));
  return splitmix64(x);
}

double cellCentre(std::int32_t cell, double resolution) { return (cell + 0.5) * resolution; }

// Li, Barão & Rato's simulation (Sec. IV, Fig. 3) in cells. The robot's loop, counter-
// clockwise through these cell centres: 24 + 12 + 24 + 12 = 72 cells, 24 steps at 3 cells per
// step. Every square's near face is 3.5 cells from the loop (within the 8-cell beams, with
// room behind it for beams that pass when it is free), the wall 6.5 cells from its left side.
constexpr std::array<std::array<std::int32_t, 2>, 4> kMrfLoop{{{10, 9}, {34, 9}, {34, 21}, {10, 21}}};
constexpr std::int32_t kMrfSpeedCells = 3;
constexpr std::int32_t kMrfSquareSide = 4;
// Below the bottom side (the first two), right of the right side, above the top side: where
// the loop's outward (-pi/2 and -pi/4) beams look.
constexpr std::array<std::array<std::int32_t, 2>, 4> kMrfSquares{{{15, 2}, {26, 2}, {38, 13}, {20, 25}}};
// The paper's unit of the hold times (it leaves dt open), in steps: 7/8 of the loop, so that
// no hold is a multiple or a simple fraction of the loop (scenarioConfig("mrf_squares")).
constexpr std::int64_t kMrfDeltaTSteps = 21;

// The dividers office (scenarioConfig("dividers")), in cells.
constexpr std::int32_t kDividersWidth = 40;
constexpr std::int32_t kDividersHeight = 25;
constexpr std::int32_t kDividersWallX = 20;
constexpr std::int32_t kDividersPassageHeight = 3;
constexpr std::array<std::int32_t, 3> kDividersPassages{{3, 11, 19}};

std::int64_t mrfLoopSteps() {
  std::int32_t cells = 0;
  for (std::size_t i = 0; i < kMrfLoop.size(); ++i) {
    const auto& a = kMrfLoop[i];
    const auto& b = kMrfLoop[(i + 1) % kMrfLoop.size()];
    cells += std::abs(b[0] - a[0]) + std::abs(b[1] - a[1]);  // axis-parallel sides
  }
  return cells / kMrfSpeedCells;
}

}  // namespace

// ---------------------------------------------------------------- Rng

std::uint64_t mixSeed(std::uint64_t x) { return splitmix64(x); }

Rng::Rng(std::uint64_t seed) {
  for (auto& word : state_) word = splitmix64(seed);
}

std::uint64_t Rng::next() {
  const std::uint64_t result = rotl(state_[1] * 5, 7) * 9;
  const std::uint64_t t = state_[1] << 17;
  state_[2] ^= state_[0];
  state_[3] ^= state_[1];
  state_[1] ^= state_[2];
  state_[0] ^= state_[3];
  state_[2] ^= t;
  state_[3] = rotl(state_[3], 45);
  return result;
}

double Rng::uniform() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }

double Rng::normal() {
  // 1 - uniform() is in (0, 1]: the logarithm is finite.
  const double u1 = 1.0 - uniform();
  const double u2 = uniform();
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
}

std::uint64_t Rng::below(std::uint64_t n) {
  if (n == 0) throw std::invalid_argument("Rng::below: n must be positive");
  // Reject the top partial block of 2^64 so every residue is equally likely.
  const std::uint64_t limit = std::numeric_limits<std::uint64_t>::max() - std::numeric_limits<std::uint64_t>::max() % n;
  std::uint64_t x;
  do {
    x = next();
  } while (x >= limit);
  return x % n;
}

// ---------------------------------------------------------------- World

World::World(std::int32_t width, std::int32_t height, double resolution_m)
    : width_(width), height_(height), resolution_m_(resolution_m) {
  require(width > 0 && height > 0, "World: width and height must be positive");
  require(resolution_m > 0.0 && std::isfinite(resolution_m), "World: resolution must be positive");
  const auto cells = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  occupancy_.assign(cells, 0);
  random_.assign(cells, 0);
  truth_.assign(cells, core::TransitionParams{0.0, 0.0});
}

void World::check(std::int32_t x, std::int32_t y) const {
  if (!inside(x, y)) {
    throw std::invalid_argument("World: cell (" + std::to_string(x) + ", " + std::to_string(y) + ") is outside");
  }
}

void World::setStatic(std::int32_t x, std::int32_t y, bool occupied) {
  check(x, y);
  const std::size_t i = index(x, y);
  occupancy_[i] = occupied ? 1 : 0;
  random_[i] = 0;
  truth_[i] = core::TransitionParams{0.0, 0.0};
}

void World::setDynamic(std::int32_t x, std::int32_t y, const core::TransitionParams& truth, bool occupied) {
  check(x, y);
  require(truth.isValid(), "World::setDynamic: transition probabilities must be in [0, 1]");
  const std::size_t i = index(x, y);
  occupancy_[i] = occupied ? 1 : 0;
  random_[i] = 1;
  truth_[i] = truth;
}

void World::setScheduled(std::int32_t x, std::int32_t y, const core::TransitionParams& truth, bool occupied) {
  check(x, y);
  require(truth.isValid(), "World::setScheduled: transition probabilities must be in [0, 1]");
  const std::size_t i = index(x, y);
  occupancy_[i] = occupied ? 1 : 0;
  random_[i] = 0;
  truth_[i] = truth;
}

void World::setState(std::int32_t x, std::int32_t y, bool occupied) {
  check(x, y);
  occupancy_[index(x, y)] = occupied ? 1 : 0;
}

void World::step(Rng& rng) {
  for (std::size_t i = 0; i < occupancy_.size(); ++i) {
    if (random_[i] == 0) continue;
    const double p_change = occupancy_[i] != 0 ? truth_[i].p_free_given_occ : truth_[i].p_occ_given_free;
    if (rng.bernoulli(p_change)) occupancy_[i] ^= 1;
  }
}

std::vector<std::size_t> World::dynamicCells() const {
  std::vector<std::size_t> cells;
  for (std::size_t i = 0; i < random_.size(); ++i) {
    if (random_[i] != 0) cells.push_back(i);
  }
  return cells;
}

// ---------------------------------------------------------------- laser

RayHit castRay(const World& world, double x_m, double y_m, double angle_rad, double max_range_m) {
  // Amanatides–Woo in cell units: t is the distance in metres along the ray to the next
  // vertical / horizontal cell boundary.
  const double r = world.resolution();
  const double dx = std::cos(angle_rad);
  const double dy = std::sin(angle_rad);
  auto cx = static_cast<std::int32_t>(std::floor(x_m / r));
  auto cy = static_cast<std::int32_t>(std::floor(y_m / r));
  const std::int32_t step_x = dx > 0.0 ? 1 : -1;
  const std::int32_t step_y = dy > 0.0 ? 1 : -1;
  constexpr double kInf = std::numeric_limits<double>::infinity();
  const double t_delta_x = dx != 0.0 ? r / std::abs(dx) : kInf;
  const double t_delta_y = dy != 0.0 ? r / std::abs(dy) : kInf;
  double t_x = dx > 0.0 ? ((cx + 1) * r - x_m) / dx : (dx < 0.0 ? (cx * r - x_m) / dx : kInf);
  double t_y = dy > 0.0 ? ((cy + 1) * r - y_m) / dy : (dy < 0.0 ? (cy * r - y_m) / dy : kInf);
  // Outside the world nothing is occupied: stop once the ray has left it for good.
  const double leave = [&] {
    const double w = world.width() * r;
    const double h = world.height() * r;
    const double tx = dx > 0.0 ? (w - x_m) / dx : (dx < 0.0 ? -x_m / dx : kInf);
    const double ty = dy > 0.0 ? (h - y_m) / dy : (dy < 0.0 ? -y_m / dy : kInf);
    return std::max(0.0, std::min(tx, ty));
  }();
  const double limit = std::min(max_range_m, leave);
  if (world.occupied(cx, cy)) return RayHit{0.0, std::min(t_x, t_y)};
  while (true) {
    double t;
    if (t_x < t_y) {
      t = t_x;
      cx += step_x;
      t_x += t_delta_x;
    } else {
      t = t_y;
      cy += step_y;
      t_y += t_delta_y;
    }
    if (t >= limit) return RayHit{kInf, kInf};
    // A ray that only grazes an occupied cell's corner (a chord shorter than a tenth of a
    // cell) passes it: objects have slightly rounded corners. Without this a beam aimed
    // exactly at a corner returns from the corner point itself, and its noisy end point lands
    // in a free cell half of the time.
    if (world.occupied(cx, cy) && std::min(t_x, t_y) - t >= kMinChord * r) return RayHit{t, std::min(t_x, t_y)};
  }
}

void LaserConfig::validate() const {
  require(beams > 0, "LaserConfig: beams must be positive");
  require(std::isfinite(angle_min_rad) && std::isfinite(angle_increment_rad) &&
              (beams == 1 || angle_increment_rad != 0.0),
          "LaserConfig: angle_min and angle_increment must be finite, angle_increment non-zero");
  require(range_min_m >= 0.0 && range_max_m > range_min_m && std::isfinite(range_max_m),
          "LaserConfig: need 0 <= range_min < range_max < inf");
  require(noise_sigma_m >= 0.0 && std::isfinite(noise_sigma_m), "LaserConfig: noise_sigma must be >= 0");
  require(dropout_probability >= 0.0 && dropout_probability <= 1.0,
          "LaserConfig: dropout_probability must be in [0, 1]");
  for (std::size_t i = 0; i < active_beams.size(); ++i) {
    require(active_beams[i] >= 0 && active_beams[i] < beams && (i == 0 || active_beams[i] > active_beams[i - 1]),
            "LaserConfig: active_beams must be strictly increasing beam indices in [0, beams)");
  }
}

core::Scan simulateScan(const World& world, const core::Pose2D& laser_pose, const LaserConfig& laser, double stamp_s,
                        Rng& rng) {
  core::Scan scan;
  scan.stamp_s = stamp_s;
  scan.laser_pose = laser_pose;
  scan.angle_min_rad = laser.angle_min_rad;
  scan.angle_increment_rad = laser.angle_increment_rad;
  scan.range_min_m = laser.range_min_m;
  scan.range_max_m = laser.range_max_m;
  scan.ranges_m.resize(static_cast<std::size_t>(laser.beams));
  std::size_t next_active = 0;  // the first entry of active_beams not passed yet
  for (int i = 0; i < laser.beams; ++i) {
    if (!laser.active_beams.empty()) {
      if (next_active == laser.active_beams.size() || laser.active_beams[next_active] != i) {
        // A dark beam: no reading, and no draw (the noise stream is that of the beams that exist).
        scan.ranges_m[static_cast<std::size_t>(i)] = std::numeric_limits<float>::quiet_NaN();
        continue;
      }
      ++next_active;
    }
    const double angle = laser_pose.yaw_rad + laser.angle_min_rad + i * laser.angle_increment_rad;
    // Draw the noise for every beam, used or not: the stream stays aligned whatever the world.
    const bool dropout = rng.bernoulli(laser.dropout_probability);
    const double noise = laser.noise_sigma_m * rng.normal();
    const RayHit hit = castRay(world, laser_pose.x_m, laser_pose.y_m, angle, laser.range_max_m);
    const double range = 0.5 * (hit.entry_m + hit.exit_m);
    float reading;
    if (dropout) {
      reading = std::numeric_limits<float>::quiet_NaN();
    } else if (!std::isfinite(range) || range + noise >= laser.range_max_m) {
      reading = std::numeric_limits<float>::infinity();
    } else {
      reading = static_cast<float>(std::max(laser.range_min_m, range + noise));
    }
    scan.ranges_m[static_cast<std::size_t>(i)] = reading;
  }
  return scan;
}

// ---------------------------------------------------------------- DriftingOdometry

DriftingOdometry::DriftingOdometry(const core::OdometryNoise& noise, std::uint64_t seed) : noise_(noise), rng_(seed) {
  noise_.validate();
}

core::Pose2D DriftingOdometry::update(const core::Pose2D& truth) {
  if (!last_truth_) {
    last_truth_ = truth;
    odometry_ = truth;
    return odometry_;
  }
  const core::OdometryMotion read = core::perturbMotion(core::odometryMotion(*last_truth_, truth), noise_,
                                            {rng_.normal(), rng_.normal(), rng_.normal()});
  odometry_ = core::applyMotion(odometry_, read);
  last_truth_ = truth;
  return odometry_;
}

// ---------------------------------------------------------------- LoopPath

LoopPath::LoopPath(std::vector<std::array<double, 2>> waypoints_m, double speed_m_per_step)
    : waypoints_(std::move(waypoints_m)), speed_(speed_m_per_step) {
  require(speed_ > 0.0 && std::isfinite(speed_), "LoopPath: speed must be positive");
  require(waypoints_.size() >= 2, "LoopPath: need at least two waypoints");
  cumulative_.push_back(0.0);
  for (std::size_t i = 0; i < waypoints_.size(); ++i) {
    const auto& a = waypoints_[i];
    const auto& b = waypoints_[(i + 1) % waypoints_.size()];
    cumulative_.push_back(cumulative_.back() + std::hypot(b[0] - a[0], b[1] - a[1]));
  }
  require(cumulative_.back() > 0.0, "LoopPath: the waypoints must not all be the same point");
}

core::Pose2D LoopPath::poseAt(double steps) const {
  const double length = cumulative_.back();
  double s = std::fmod(steps * speed_, length);
  if (s < 0.0) s += length;
  // The segment holding s (segments of zero length are skipped by upper_bound).
  const auto it = std::upper_bound(cumulative_.begin(), cumulative_.end(), s);
  const std::size_t segment = std::min<std::size_t>(static_cast<std::size_t>(it - cumulative_.begin()) - 1,
                                                    waypoints_.size() - 1);
  const auto& a = waypoints_[segment];
  const auto& b = waypoints_[(segment + 1) % waypoints_.size()];
  const double segment_length = cumulative_[segment + 1] - cumulative_[segment];
  const double f = segment_length > 0.0 ? (s - cumulative_[segment]) / segment_length : 0.0;
  return core::Pose2D{a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), std::atan2(b[1] - a[1], b[0] - a[0])};
}

// ---------------------------------------------------------------- scenarios

void ScenarioConfig::validate() const {
  require(width_cells > 0 && height_cells > 0, "scenario " + name + ": width and height must be positive");
  require(resolution_m > 0.0 && time_step_s > 0.0 && std::isfinite(resolution_m) && std::isfinite(time_step_s),
          "scenario " + name + ": resolution and time_step must be positive and finite");
  require(steps > 0, "scenario " + name + ": steps must be positive");
  require(scans_per_step > 0, "scenario " + name + ": scans_per_step must be positive");
  require(robot_speed_m_per_step > 0.0, "scenario " + name + ": robot_speed must be positive");
  require(path_noise_sigma_m >= 0.0 && std::isfinite(path_noise_sigma_m) && path_noise_sigma_rad >= 0.0 &&
              std::isfinite(path_noise_sigma_rad),
          "scenario " + name + ": path_noise_sigma_m and path_noise_sigma_rad must be >= 0");
  require(p_hit_given_occ > p_hit_given_free && p_hit_given_free > 0.0 && p_hit_given_occ < 1.0,
          "scenario " + name + ": need 0 < p_hit_given_free < p_hit_given_occ < 1");
  laser.validate();
  require(dynamic_fraction >= 0.0 && dynamic_fraction <= 1.0, "scenario " + name + ": dynamic_fraction must be in [0, 1]");
  require(change_probability >= 0.0 && change_probability <= 1.0,
          "scenario " + name + ": change_probability must be in [0, 1]");
  require(redraw_at_step == -1 || (redraw_at_step > 0 && redraw_at_step < steps),
          "scenario " + name + ": redraw_at_step must be -1 (never) or a step in [1, steps)");
  require(hours > 0 && steps_per_hour > 0, "scenario " + name + ": hours and steps_per_hour must be positive");
  require(p_arrive_per_hour >= 0.0 && p_arrive_per_hour <= 1.0 && p_leave_per_hour >= 0.0 && p_leave_per_hour <= 1.0,
          "scenario " + name + ": p_arrive_per_hour and p_leave_per_hour must be in [0, 1]");
  require(door_change_probability >= 0.0 && door_change_probability <= 1.0,
          "scenario " + name + ": door_change_probability must be in [0, 1]");
  if (kind == ScenarioKind::kMrfSquares) {
    for (const std::int64_t hold : square_hold_steps) {
      require(hold > 0, "scenario " + name + ": square_hold_steps must be positive");
    }
  }
  if (kind == ScenarioKind::kDividers) {
    require(divider_period_steps > 0, "scenario " + name + ": divider_period_steps must be positive");
    require(divider_toggle_probability >= 0.0 && divider_toggle_probability <= 1.0,
            "scenario " + name + ": divider_toggle_probability must be in [0, 1]");
    require(people >= 0 && people <= 20, "scenario " + name + ": people must be in [0, 20]");
    require(width_cells == kDividersWidth && height_cells == kDividersHeight,
            "scenario " + name + ": the dividers office is " + std::to_string(kDividersWidth) + " x " +
                std::to_string(kDividersHeight) + " cells");
  }
}

std::vector<std::string> scenarioNames() {
  return {"dynamic_5_5", "dynamic_25_25", "redraw_100", "redraw_300", "parking_lot", "door", "mrf_squares",
          "dividers", "patrol", "patrol_long", "patrol_office", "sparse_office"};
}

ScenarioConfig scenarioConfig(const std::string& name) {
  ScenarioConfig config;
  config.name = name;
  if (name == "dynamic_5_5" || name == "dynamic_25_25" || name == "redraw_100" || name == "redraw_300") {
    // The papers' 50 x 50 grid (Figs. 4 and 5): walls around, four pillars, a robot
    // circling the middle with a 360° laser that sees the whole room.
    config.kind = ScenarioKind::kRandomDynamic;
    config.width_cells = 50;
    config.height_cells = 50;
    config.resolution_m = 0.1;
    config.steps = 1000;
    // A 270° laser of 3 m range: the robot sees about half of the room at a time, so cells
    // go unobserved for a while and the model's predictions matter, as in the papers.
    config.laser.beams = 271;
    config.laser.angle_min_rad = -0.75 * kPi;
    config.laser.angle_increment_rad = 1.5 * kPi / 270.0;
    config.laser.range_max_m = 3.0;
    config.laser.noise_sigma_m = 0.01;
    config.laser.dropout_probability = 0.05;
    config.robot_speed_m_per_step = 0.2;
    const bool high = name == "dynamic_25_25";
    config.dynamic_fraction = high ? 0.25 : 0.05;
    config.change_probability = high ? 0.25 : 0.05;
    if (name == "redraw_100") config.redraw_at_step = 100;
    if (name == "redraw_300") config.redraw_at_step = 300;
    config.description = high ? "50x50 grid, 25 % dynamic cells changing with probability 0.25 per step"
                              : "50x50 grid, 5 % dynamic cells changing with probability 0.05 per step";
    if (config.redraw_at_step >= 0) {
      config.description += ", a new set of dynamic cells from step " + std::to_string(config.redraw_at_step);
    }
    return config;
  }
  if (name == "parking_lot") {
    // Fig. 3: two rows of six bays (2.5 m x 5 m), cars of 2 m x 4.5 m, a robot driving up
    // and down the aisle; the cars change every "hour" of 108 steps (two passes).
    config.kind = ScenarioKind::kParkingLot;
    config.width_cells = 62;
    config.height_cells = 54;
    config.resolution_m = 0.25;
    config.hours = 12;
    config.steps_per_hour = 108;
    config.steps = config.hours * config.steps_per_hour;
    config.laser.beams = 360;
    config.laser.range_max_m = 12.0;
    config.laser.noise_sigma_m = 0.02;
    config.robot_speed_m_per_step = 0.5;
    config.description = "parking lot, 12 bays whose cars come and go every hour (108 steps), 12 hours";
    return config;
  }
  if (name == "door") {
    // Fig. 6 / Table 1: a short corridor with a door between A and B, and a long detour.
    config.kind = ScenarioKind::kDoor;
    config.width_cells = 30;
    config.height_cells = 15;
    config.resolution_m = 0.5;
    config.steps = 20000;
    config.laser.beams = 72;
    config.laser.angle_increment_rad = 2.0 * kPi / 72.0;
    config.laser.range_max_m = 3.0;
    config.laser.noise_sigma_m = 0.02;
    config.laser_mount = core::Pose2D{0.0, 0.0, 0.0};
    config.robot_speed_m_per_step = 0.5;
    // Beams from the corridor's centre line graze the walls beside it: noisier per beam.
    config.p_hit_given_occ = 0.8;
    config.p_hit_given_free = 0.1;
    config.description = "a door on the short path between A and B (p = 0.001 per step), and a long detour";
    return config;
  }
  if (name == "mrf_squares") {
    // Li, Barão & Rato, Sec. IV: static walls on the left, four square objects holding their
    // state for dt/3, 2 dt, 3 dt and 7 dt, a robot making 20 loops near a path at 3 cells per
    // step, four beams at -pi/2, -pi/4, pi/4, pi/2 from its heading, 8 cells long. The paper
    // leaves dt open. It is not the loop (24 steps) but 21 steps, 7/8 of it: holds of 7, 42,
    // 63 and 147 steps (0.29, 1.75, 2.6 and 6.1 loops), true rates 1/7 ... 1/147 per step.
    // A square's state repeats every 2 hold steps; the robot passes every 24, so it meets
    // the square at the same point of its cycle again only after lcm(2 hold, 24) / 24 loops:
    // 7, 7, 21 and 49 loops (all 20 of a run at a new point for the two slow squares). With
    // dt = one loop (holds 8, 48, 72, 168) that was 2, 4, 6 and 14: the fast square was met
    // at only two points of its cycle, each visit the mirror of the one before. dt must be a
    // multiple of 3 (dt/3 whole) and, for every hold to be off the loop's divisors, odd and
    // not a multiple of 9; 21 is the one near the loop (15 gives 5, 5, 15, 35 loops; 33
    // holds the slowest square 231 steps, two toggles a run).
    config.kind = ScenarioKind::kMrfSquares;
    config.width_cells = 46;
    config.height_cells = 32;
    config.resolution_m = 0.1;
    const std::int64_t loop = mrfLoopSteps();
    const std::int64_t dt = kMrfDeltaTSteps;
    config.square_hold_steps = {dt / 3, 2 * dt, 3 * dt, 7 * dt};
    config.steps = 20 * loop;
    config.laser.beams = 5;
    config.laser.angle_min_rad = -0.5 * kPi;
    config.laser.angle_increment_rad = 0.25 * kPi;
    config.laser.active_beams = {0, 1, 3, 4};
    config.laser.range_max_m = 8 * config.resolution_m;
    // The paper's sensor errs in range ("the static walls are observed free and the free
    // space around objects occupied sometimes"): a third of a cell makes about one reading
    // in ten end in the cell before or behind the one it hit. It always returns a reading.
    config.laser.noise_sigma_m = 0.3 * config.resolution_m;
    config.laser.dropout_probability = 0.0;
    config.laser_mount = core::Pose2D{0.0, 0.0, 0.0};
    config.robot_speed_m_per_step = kMrfSpeedCells * config.resolution_m;
    // "Runs near the dashed line randomly": half a cell and 3 degrees per step move the beams'
    // cells from loop to loop, and 5 sigma still keep the robot a cell clear of every object.
    config.path_noise_sigma_m = 0.5 * config.resolution_m;
    config.path_noise_sigma_rad = 0.05;
    config.p_hit_given_occ = 0.8;
    config.p_hit_given_free = 0.05;
    config.description = "Li, Barão & Rato's simulation: walls, four squares holding their state for 7, 42, 63 and "
                         "147 steps (dt/3 to 7 dt, dt = 21 steps, 7/8 of the robot's 24-step loop), 20 noisy loops "
                         "with 4 beams of 8 cells";
    return config;
  }
  if (name == "dividers") {
    // Morris et al., Sec. IV, in 2D and smaller: an 8 m x 5 m office of 0.2 m cells split by
    // a wall with three passages (DividersLayout); dividers move every 150 steps (the
    // memory experiment's episode) with probability 0.2 each, so a configuration holds for
    // about five episodes; three people walk at one cell per step. A 360° laser of 4 m:
    // from the middle of a half it sees the wall's three passages.
    config.kind = ScenarioKind::kDividers;
    config.width_cells = kDividersWidth;
    config.height_cells = kDividersHeight;
    config.resolution_m = 0.2;
    config.steps = 3000;
    // One beam per degree: even at range several beams cross each cell, so a person's cell
    // is seen free again in the scans after it left (the memory model's view needs more
    // than two misses per hit to call a cell free).
    config.laser.beams = 360;
    config.laser.range_max_m = 4.0;
    config.laser.noise_sigma_m = 0.01;
    config.laser_mount = core::Pose2D{0.0, 0.0, 0.0};
    config.robot_speed_m_per_step = config.resolution_m;
    config.divider_period_steps = 150;
    config.divider_toggle_probability = 0.2;
    config.people = 3;
    config.description = "an office split by a wall with 3 passages, dividers moving every 150 steps (p = 0.2 "
                         "each), 3 people walking one cell per step";
    return config;
  }
  if (name == "patrol" || name == "patrol_long") {
    // A robot on patrol (PatrolLayout): each place is seen for about ten steps every 112;
    // 1800 steps are 16 loops (half an hour at one step per second), patrol_long 3600.
    config.kind = ScenarioKind::kPatrol;
    config.width_cells = 240;
    config.height_cells = 140;
    config.resolution_m = 0.1;
    config.steps = name == "patrol" ? 1800 : 3600;
    config.scans_per_step = 2;
    config.laser.beams = 360;
    config.laser.range_max_m = 3.0;
    config.laser.noise_sigma_m = 0.01;
    config.laser.dropout_probability = 0.01;
    config.laser_mount = core::Pose2D{0.0, 0.0, 0.0};
    config.robot_speed_m_per_step = 0.5;
    config.description = "a robot patrolling a 56 m loop around two rooms (112 steps a loop, 3 m laser): doors "
                         "(0.025 / 0.05 per step), carts (0.004 / 0.012), people (0.12 / 0.25)";
    return config;
  }
  if (name == "patrol_office") {
    // The learning issue's kind of world, on a floor of our own: each place seen for a few
    // steps every 100, and every moving part forgets its state within about one loop.
    config.kind = ScenarioKind::kPatrol;
    config.patrol_floor = PatrolFloor::kOffice;
    config.width_cells = 200;
    config.height_cells = 140;
    config.resolution_m = 0.1;
    config.steps = 1800;
    config.scans_per_step = 2;
    config.laser.beams = 360;
    config.laser.range_max_m = 4.0;
    config.laser.noise_sigma_m = 0.01;
    config.laser.dropout_probability = 0.01;
    config.laser_mount = core::Pose2D{0.0, 0.0, 0.0};
    config.robot_speed_m_per_step = 0.5;
    config.patrol_door = core::TransitionParams{0.02, 0.04};
    config.patrol_cart = core::TransitionParams{0.01, 0.02};
    config.patrol_person = core::TransitionParams{0.1, 0.2};
    config.description = "a robot patrolling a 50 m loop around three offices (100 steps a loop, 4 m laser): doors "
                         "(0.02 / 0.04 per step), carts (0.01 / 0.02), people (0.1 / 0.2)";
    return config;
  }
  if (name == "sparse_office") {
    // A users' report (docs/online_learning.md, "The sparse office"): an office at the
    // package's default resolution where few places change, each in a niche the robot's
    // laser sees for a few steps of its 120-step loop; 600 steps are five loops.
    config.kind = ScenarioKind::kPatrol;
    config.patrol_floor = PatrolFloor::kSparseOffice;
    config.width_cells = 320;
    config.height_cells = 240;
    config.resolution_m = 0.05;
    config.steps = 600;
    config.scans_per_step = 2;
    // Like a Hokuyo URG: 5.6 m; half a degree between beams, about a cell at the range's end.
    config.laser.beams = 720;
    config.laser.angle_increment_rad = 2.0 * kPi / 720.0;
    config.laser.range_max_m = 5.6;
    config.laser.noise_sigma_m = 0.01;
    config.laser.dropout_probability = 0.03;
    config.laser_mount = core::Pose2D{0.0, 0.0, 0.0};
    config.robot_speed_m_per_step = 0.5;
    config.patrol_door = core::TransitionParams{0.03, 0.03};
    config.patrol_cart = core::TransitionParams{0.01, 0.02};
    config.patrol_person = core::TransitionParams{0.15, 0.30};
    config.description = "a robot patrolling a 60 m loop through a 16 m x 12 m office at 0.05 m (120 steps a loop, "
                         "5.6 m laser), each moving part in a niche seen a few steps a loop: 3 doors (0.03 / 0.03 "
                         "per step), 4 parking bays (0.01 / 0.02), 6 busy spots (0.15 / 0.3)";
    return config;
  }
  std::string names;
  for (const std::string& known : scenarioNames()) names += (names.empty() ? "" : ", ") + known;
  throw std::invalid_argument("unknown scenario '" + name + "' (known: " + names + ")");
}

// ---------------------------------------------------------------- Simulation

Simulation::Simulation(const ScenarioConfig& config, std::uint64_t world_seed, std::uint64_t run_seed)
    : config_(config),
      world_((config.validate(), config.width_cells), config.height_cells, config.resolution_m),
      layout_rng_(streamSeed(world_seed, 0)),
      dynamics_rng_(streamSeed(run_seed, 1)),
      sensor_rng_(streamSeed(run_seed, 2)),
      path_rng_(streamSeed(run_seed, 3)) {
  switch (config_.kind) {
    case ScenarioKind::kRandomDynamic:
      buildRandomDynamic();
      break;
    case ScenarioKind::kParkingLot:
      buildParkingLot();
      break;
    case ScenarioKind::kDoor:
      buildDoor();
      break;
    case ScenarioKind::kMrfSquares:
      buildMrfSquares();
      break;
    case ScenarioKind::kDividers:
      buildDividers();
      break;
    case ScenarioKind::kPatrol:
      buildPatrol();
      break;
  }
  path_.emplace(route_, config_.robot_speed_m_per_step);
  drawPathNoise();
}

void Simulation::addBorderWalls() {
  for (std::int32_t x = 0; x < world_.width(); ++x) {
    world_.setStatic(x, 0, true);
    world_.setStatic(x, world_.height() - 1, true);
  }
  for (std::int32_t y = 0; y < world_.height(); ++y) {
    world_.setStatic(0, y, true);
    world_.setStatic(world_.width() - 1, y, true);
  }
}

void Simulation::buildRandomDynamic() {
  addBorderWalls();
  const std::int32_t w = world_.width();
  const std::int32_t h = world_.height();
  // Four 4 x 4 pillars at a fifth of the way in from each corner.
  for (const std::int32_t px : {w / 5, w - w / 5 - 4}) {
    for (const std::int32_t py : {h / 5, h - h / 5 - 4}) {
      for (std::int32_t y = py; y < py + 4; ++y) {
        for (std::int32_t x = px; x < px + 4; ++x) world_.setStatic(x, y, true);
      }
    }
  }
  // The robot circles a square around the middle (a third of the room's side).
  const double r = world_.resolution();
  const double x0 = w * r / 3.0;
  const double x1 = w * r * 2.0 / 3.0;
  const double y0 = h * r / 3.0;
  const double y1 = h * r * 2.0 / 3.0;
  route_ = {{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}};
  // Its lane (within 0.3 m of the route) stays free: the robot drives there.
  const auto in_lane = [&](double cx, double cy) {
    const bool near_x_edge = cx > x0 - 0.3 && cx < x1 + 0.3 && (std::abs(cy - y0) < 0.3 || std::abs(cy - y1) < 0.3);
    const bool near_y_edge = cy > y0 - 0.3 && cy < y1 + 0.3 && (std::abs(cx - x0) < 0.3 || std::abs(cx - x1) < 0.3);
    return near_x_edge || near_y_edge;
  };
  for (std::int32_t y = 0; y < h; ++y) {
    for (std::int32_t x = 0; x < w; ++x) {
      if (world_.occupied(x, y) || in_lane(cellCentre(x, r), cellCentre(y, r))) continue;
      free_candidates_.push_back(world_.index(x, y));
    }
  }
  drawDynamicCells(layout_rng_);
}

void Simulation::drawDynamicCells(Rng& layout_rng) {
  // Every candidate becomes static, keeping its current state; then a fresh random set of
  // them becomes dynamic, starting from the stationary distribution (p = 0.5 for the
  // papers' symmetric cells).
  for (const std::size_t i : free_candidates_) {
    const core::CellXY c = world_.cellOf(i);
    world_.setStatic(c.x, c.y, world_.occupied(c.x, c.y));
  }
  const auto count = static_cast<std::size_t>(std::llround(config_.dynamic_fraction * free_candidates_.size()));
  std::vector<std::size_t> pool = free_candidates_;
  const double p = config_.change_probability;
  const core::TransitionParams truth{p, p};
  for (std::size_t k = 0; k < count; ++k) {
    // Partial Fisher–Yates: pool[k] becomes a uniform pick from the rest.
    const std::size_t pick = k + static_cast<std::size_t>(layout_rng.below(pool.size() - k));
    std::swap(pool[k], pool[pick]);
    const core::CellXY c = world_.cellOf(pool[k]);
    world_.setDynamic(c.x, c.y, truth, layout_rng.bernoulli(0.5));
  }
}

void Simulation::buildParkingLot() {
  addBorderWalls();
  // Bays 10 x 20 cells along the bottom (y 1..20) and the top (y 33..52) walls; a car
  // fills its bay but one cell on every side.
  const std::int32_t bay_w = 10;
  const std::int32_t bay_d = 20;
  const std::int32_t rows[2] = {1, world_.height() - 1 - bay_d};
  const double hours = static_cast<double>(config_.steps_per_hour);
  const core::TransitionParams truth{config_.p_arrive_per_hour / hours, config_.p_leave_per_hour / hours};
  const double p_parked = config_.p_arrive_per_hour + config_.p_leave_per_hour > 0.0
                              ? config_.p_arrive_per_hour / (config_.p_arrive_per_hour + config_.p_leave_per_hour)
                              : 0.0;
  for (const std::int32_t row : rows) {
    for (std::int32_t bx = 1; bx + bay_w <= world_.width() - 1; bx += bay_w) {
      std::vector<std::size_t> car;
      for (std::int32_t y = row + 1; y < row + bay_d - 1; ++y) {
        for (std::int32_t x = bx + 1; x < bx + bay_w - 1; ++x) car.push_back(world_.index(x, y));
      }
      const bool parked = dynamics_rng_.bernoulli(p_parked);
      for (const std::size_t i : car) {
        const core::CellXY c = world_.cellOf(i);
        world_.setScheduled(c.x, c.y, truth, parked);
      }
      bays_.push_back(std::move(car));
      bay_occupied_.push_back(parked ? 1 : 0);
    }
  }
  // Up and down the middle of the aisle.
  const double r = world_.resolution();
  const double aisle_y = world_.height() * r / 2.0;
  route_ = {{1.0, aisle_y}, {world_.width() * r - 1.0, aisle_y}};
}

void Simulation::parkingHour() {
  for (std::size_t b = 0; b < bays_.size(); ++b) {
    const bool parked = bay_occupied_[b] != 0;
    const bool change = dynamics_rng_.bernoulli(parked ? config_.p_leave_per_hour : config_.p_arrive_per_hour);
    if (!change) continue;
    bay_occupied_[b] = parked ? 0 : 1;
    for (const std::size_t i : bays_[b]) {
      const core::CellXY c = world_.cellOf(i);
      world_.setState(c.x, c.y, !parked);
    }
  }
}

void Simulation::buildDoor() {
  addBorderWalls();
  const std::int32_t w = world_.width();
  const std::int32_t h = world_.height();
  // The block between the two corridors: everything but the border ring's inner ring.
  for (std::int32_t y = 2; y <= h - 3; ++y) {
    for (std::int32_t x = 2; x <= w - 3; ++x) world_.setStatic(x, y, true);
  }
  const std::int32_t corridor = h - 2;
  door_.a = core::CellXY{1, corridor};
  door_.b = core::CellXY{w - 2, corridor};
  door_.door = core::CellXY{w / 2 - 1, corridor};
  door_.short_path_cells = door_.b.x - door_.a.x;
  door_.long_path_cells = 2 * (corridor - 1) + (door_.b.x - door_.a.x);
  const double p = config_.door_change_probability;
  world_.setDynamic(door_.door.x, door_.door.y, core::TransitionParams{p, p}, dynamics_rng_.bernoulli(0.5));
  // Exploration: look at the door from both sides without passing it, and drive the
  // detour both ways.
  const double r = world_.resolution();
  const auto at = [r](std::int32_t x, std::int32_t y) { return std::array<double, 2>{cellCentre(x, r), cellCentre(y, r)}; };
  route_ = {at(door_.a.x, corridor),      at(door_.door.x - 1, corridor), at(door_.a.x, corridor),
            at(1, 1),                     at(w - 2, 1),                   at(door_.b.x, corridor),
            at(door_.door.x + 1, corridor), at(door_.b.x, corridor),      at(w - 2, 1),
            at(1, 1)};
}

void Simulation::buildMrfSquares() {
  // "The walls on the left are static": a wall along the loop's left side with two short
  // stubs towards it, a bracket.
  for (std::int32_t y = 4; y <= 27; ++y) world_.setStatic(3, y, true);
  for (std::int32_t x = 3; x <= 8; ++x) {
    world_.setStatic(x, 4, true);
    world_.setStatic(x, 27, true);
  }
  squares_.square_side_cells = kMrfSquareSide;
  squares_.loop_steps = mrfLoopSteps();
  squares_.delta_t_steps = kMrfDeltaTSteps;
  for (std::size_t k = 0; k < kMrfSquares.size(); ++k) {
    squares_.square_corner[k] = core::CellXY{kMrfSquares[k][0], kMrfSquares[k][1]};
    const std::int64_t hold = config_.square_hold_steps[k];
    // A fixed hold is no Markov chain; its truth is the Markov rate of the same changes, one
    // per `hold` steps in either state (as the parking lot's hourly rates spread over the hour).
    const double rate = 1.0 / static_cast<double>(hold);
    const bool occupied = dynamics_rng_.bernoulli(0.5);
    // The run starts anywhere in the current hold, so the toggles' phase differs by run.
    square_next_toggle_[k] = 1 + static_cast<std::int64_t>(dynamics_rng_.below(static_cast<std::uint64_t>(hold)));
    for (std::int32_t y = kMrfSquares[k][1]; y < kMrfSquares[k][1] + kMrfSquareSide; ++y) {
      for (std::int32_t x = kMrfSquares[k][0]; x < kMrfSquares[k][0] + kMrfSquareSide; ++x) {
        world_.setScheduled(x, y, core::TransitionParams{rate, rate}, occupied);
      }
    }
  }
  const double r = world_.resolution();
  for (const auto& corner : kMrfLoop) route_.push_back({cellCentre(corner[0], r), cellCentre(corner[1], r)});
}

void Simulation::toggleSquares() {
  for (std::size_t k = 0; k < square_next_toggle_.size(); ++k) {
    if (step_ != square_next_toggle_[k]) continue;
    square_next_toggle_[k] += config_.square_hold_steps[k];
    const core::CellXY corner = squares_.square_corner[k];
    const bool occupied = !world_.occupied(corner.x, corner.y);
    for (std::int32_t y = corner.y; y < corner.y + squares_.square_side_cells; ++y) {
      for (std::int32_t x = corner.x; x < corner.x + squares_.square_side_cells; ++x) world_.setState(x, y, occupied);
    }
  }
}

void Simulation::drawPathNoise() {
  // Only a noisy path draws: the other scenarios' runs stay as they were.
  if (config_.path_noise_sigma_m == 0.0 && config_.path_noise_sigma_rad == 0.0) return;
  path_noise_.x_m = config_.path_noise_sigma_m * path_rng_.normal();
  path_noise_.y_m = config_.path_noise_sigma_m * path_rng_.normal();
  path_noise_.yaw_rad = config_.path_noise_sigma_rad * path_rng_.normal();
}

core::Pose2D Simulation::robotPose(int scan_index) const {
  core::Pose2D pose =
      path_->poseAt(static_cast<double>(step_) + static_cast<double>(scan_index) / config_.scans_per_step);
  pose.x_m += path_noise_.x_m;
  pose.y_m += path_noise_.y_m;
  pose.yaw_rad += path_noise_.yaw_rad;
  return pose;
}

core::Scan Simulation::scan(int scan_index) { return scanFrom(robotPose(scan_index), scan_index); }

core::Scan Simulation::scanFrom(const core::Pose2D& robot_pose, int scan_index) {
  if (scan_index < 0 || scan_index >= config_.scans_per_step) {
    throw std::invalid_argument("Simulation::scan: scan_index must be in [0, scans_per_step)");
  }
  const double stamp =
      (static_cast<double>(step_) + (scan_index + 0.5) / config_.scans_per_step) * config_.time_step_s;
  const core::Pose2D laser = core::composePose(robot_pose, config_.laser_mount);
  if (config_.kind == ScenarioKind::kDividers) {
    // A person passing through the laser's own cell is too close to be seen (DividersLayout):
    // hide it for this scan.
    const auto x = static_cast<std::int32_t>(std::floor(laser.x_m / world_.resolution()));
    const auto y = static_cast<std::int32_t>(std::floor(laser.y_m / world_.resolution()));
    if (isPerson(x, y)) {
      world_.setState(x, y, false);
      core::Scan scan = simulateScan(world_, laser, config_.laser, stamp, sensor_rng_);
      world_.setState(x, y, true);
      return scan;
    }
  }
  return simulateScan(world_, laser, config_.laser, stamp, sensor_rng_);
}

void Simulation::advance() {
  world_.step(dynamics_rng_);
  ++step_;
  if (config_.kind == ScenarioKind::kRandomDynamic && step_ == config_.redraw_at_step) drawDynamicCells(layout_rng_);
  if (config_.kind == ScenarioKind::kParkingLot && step_ % config_.steps_per_hour == 0) parkingHour();
  if (config_.kind == ScenarioKind::kMrfSquares) toggleSquares();
  if (config_.kind == ScenarioKind::kDividers) {
    if (step_ % config_.divider_period_steps == 0) moveDividers(false);
    movePeople();
  }
  if (config_.kind == ScenarioKind::kPatrol) stepPatrolParts();
  drawPathNoise();
}

void Simulation::buildPatrol() {
  addBorderWalls();
  const double r = world_.resolution();
  const auto cell = [r](double m) { return static_cast<std::int32_t>(std::floor(m / r + 1e-9)); };
  const auto add_part = [&](const std::string& kind, const core::TransitionParams& truth, std::int32_t x0,
                            std::int32_t y0, std::int32_t w, std::int32_t h) {
    PatrolLayout::Part part{kind, {}, truth};
    for (std::int32_t y = y0; y < y0 + h; ++y) {
      for (std::int32_t x = x0; x < x0 + w; ++x) part.cells.push_back(core::CellXY{x, y});
    }
    patrol_.parts.push_back(std::move(part));
  };
  if (config_.patrol_floor == PatrolFloor::kSparseOffice) {
    // Rectangles in metres, [x0, x1) x [y0, y1): solid blocks, then what is carved out of
    // them (rooms, recesses, niches) and the parts in them.
    const auto fill = [&](double x0, double y0, double x1, double y1, bool occupied) {
      for (std::int32_t y = cell(y0); y < cell(y1); ++y) {
        for (std::int32_t x = cell(x0); x < cell(x1); ++x) world_.setStatic(x, y, occupied);
      }
    };
    // A part is the outline of its rectangle, one cell thick: what a laser in the plane can
    // see of it. The inside, never seen while the part is there, is floor (docs: "The
    // sparse office").
    const auto place = [&](const std::string& kind, const core::TransitionParams& truth, double x0, double y0,
                           double x1, double y1) {
      PatrolLayout::Part part{kind, {}, truth};
      for (std::int32_t y = cell(y0); y < cell(y1); ++y) {
        for (std::int32_t x = cell(x0); x < cell(x1); ++x) {
          const bool edge = x == cell(x0) || x == cell(x1) - 1 || y == cell(y0) || y == cell(y1) - 1;
          if (edge) part.cells.push_back(core::CellXY{x, y});
        }
      }
      patrol_.parts.push_back(std::move(part));
    };
    // The loop's corridors are 1.6 m wide; the blocks between them are solid but for the
    // rooms behind the doors.
    fill(1.8, 1.8, 14.2, 4.2, true);    // inside the loop, below its notch
    fill(1.8, 4.2, 4.7, 10.2, true);    // inside the loop, left
    fill(11.3, 4.2, 14.2, 10.2, true);  // inside the loop, right
    fill(6.3, 5.8, 9.7, 12.0, true);    // in the loop's notch
    // Doors: 1 m leaves one cell thick at the back of 0.8 m deep recesses, a room behind each.
    fill(6.0, 1.8, 7.0, 2.6, false);
    place("door", config_.patrol_door, 6.0, 2.6, 7.0, 2.65);
    fill(5.2, 2.65, 8.0, 3.8, false);
    fill(13.4, 6.5, 14.2, 7.5, false);
    place("door", config_.patrol_door, 13.35, 6.5, 13.4, 7.5);
    fill(11.8, 5.0, 13.35, 9.0, false);
    fill(6.3, 8.0, 7.1, 9.0, false);
    place("door", config_.patrol_door, 7.1, 8.0, 7.15, 9.0);
    fill(7.15, 7.2, 8.3, 11.2, false);
    // Parking bays: 1.2 m wide, 0.9 m deep niches, a 0.6 m x 0.4 m cart against the back of each.
    fill(1.8, 6.0, 2.7, 7.2, false);
    place("cart", config_.patrol_cart, 2.3, 6.3, 2.7, 6.9);
    fill(11.4, 1.8, 12.6, 2.7, false);
    place("cart", config_.patrol_cart, 11.7, 2.3, 12.3, 2.7);
    fill(12.4, 9.3, 13.6, 10.2, false);
    place("cart", config_.patrol_cart, 12.7, 9.3, 13.3, 9.7);
    fill(8.3, 5.8, 9.5, 6.7, false);
    place("cart", config_.patrol_cart, 8.6, 6.3, 9.2, 6.7);
    // Busy spots: 0.3 m squares 0.1 m from the back of 1.6 m wide, 1.2 m deep alcoves.
    fill(2.6, 1.8, 4.2, 3.0, false);
    place("person", config_.patrol_person, 3.25, 2.6, 3.55, 2.9);
    fill(13.0, 2.4, 14.2, 4.0, false);
    place("person", config_.patrol_person, 13.1, 3.05, 13.4, 3.35);
    fill(8.5, 7.0, 9.7, 8.6, false);
    place("person", config_.patrol_person, 8.75, 7.65, 9.05, 7.95);
    fill(6.5, 5.8, 8.1, 7.0, false);
    place("person", config_.patrol_person, 7.15, 6.45, 7.45, 6.75);
    fill(2.8, 9.0, 4.4, 10.2, false);
    place("person", config_.patrol_person, 3.45, 9.25, 3.75, 9.55);
    fill(1.8, 3.4, 3.0, 5.0, false);
    place("person", config_.patrol_person, 2.45, 4.05, 2.75, 4.35);
    startPatrolParts();
    // The loop in the corridors, 1 m from the outer walls, into the notch and out: 60 m.
    route_ = {{1.0, 1.0}, {15.0, 1.0}, {15.0, 11.0}, {10.5, 11.0}, {10.5, 5.0}, {5.5, 5.0}, {5.5, 11.0}, {1.0, 11.0}};
    return;
  }
  if (config_.patrol_floor == PatrolFloor::kOffice) {
    // The block of offices, x in [4, 16) m, y in [4.5, 9.5) m: 0.2 m walls, three rooms.
    const std::int32_t bx0 = cell(4.0), bx1 = cell(16.0) - 1, by0 = cell(4.5), by1 = cell(9.5) - 1;
    for (std::int32_t x = bx0; x <= bx1; ++x) {
      for (std::int32_t y = by0; y <= by1; ++y) {
        const bool inner = (x >= cell(8.0) && x < cell(8.0) + 2) || (x >= cell(12.0) && x < cell(12.0) + 2);
        if (x < bx0 + 2 || x > bx1 - 2 || y < by0 + 2 || y > by1 - 2 || inner) world_.setStatic(x, y, true);
      }
    }
    // Doors: 1 m leaves, one cell thick, in the outer row of the wall's gap (the inner row is
    // floor): three facing the lower corridor, two the upper one.
    for (const double door_x : {5.5, 9.5, 14.0}) add_part("door", config_.patrol_door, cell(door_x), by0, 10, 1);
    for (const double door_x : {6.5, 13.0}) add_part("door", config_.patrol_door, cell(door_x), by1, 10, 1);
    for (const std::int32_t y : {by0 + 1, by1 - 1}) {
      for (const double door_x : {5.5, 9.5, 14.0, 6.5, 13.0}) {
        for (std::int32_t x = cell(door_x); x < cell(door_x) + 10; ++x) world_.setStatic(x, y, false);
      }
    }
    // Carts of 0.6 m x 0.6 m against the outer walls (0.1 m clear of them).
    add_part("cart", config_.patrol_cart, cell(10.0), 2, 6, 6);
    add_part("cart", config_.patrol_cart, cell(7.0), world_.height() - 8, 6, 6);
    add_part("cart", config_.patrol_cart, world_.width() - 8, cell(6.5), 6, 6);
    // People: 0.3 m spots beside the corridor, inside and outside the loop.
    const std::array<std::array<double, 2>, 8> spots{{{3.0, 1.0}, {15.0, 3.4}, {19.0, 9.0}, {11.0, 12.8},
                                                      {2.8, 10.4}, {0.8, 5.0}, {17.0, 10.6}, {7.5, 3.4}}};
    for (const auto& spot : spots) add_part("person", config_.patrol_person, cell(spot[0]), cell(spot[1]), 3, 3);
    startPatrolParts();
    // The loop in the corridor, 2.25 m from the outer walls.
    route_ = {{2.25, 2.25}, {17.75, 2.25}, {17.75, 11.75}, {2.25, 11.75}};
    return;
  }
  // The block of rooms, x in [5, 19) m, y in [5, 9) m: 0.2 m walls, split in two rooms.
  const std::int32_t bx0 = cell(5.0), bx1 = cell(19.0) - 1, by0 = cell(5.0), by1 = cell(9.0) - 1;
  const std::int32_t split = cell(12.0);
  for (std::int32_t x = bx0; x <= bx1; ++x) {
    for (std::int32_t y = by0; y <= by1; ++y) {
      const bool wall = x < bx0 + 2 || x > bx1 - 2 || y < by0 + 2 || y > by1 - 2 || (x >= split && x < split + 2);
      if (wall) world_.setStatic(x, y, true);
    }
  }
  // Doors: 1 m gaps in the block's long walls, two per room, one facing each corridor.
  for (const double door_x : {7.0, 15.0}) {
    add_part("door", config_.patrol_door, cell(door_x), by0, 10, 2);
  }
  for (const double door_x : {9.5, 16.5}) {
    add_part("door", config_.patrol_door, cell(door_x), by1 - 1, 10, 2);
  }
  // Carts: in bays along the outer walls, against the wall (0.1 m clear of it).
  for (const double cart_x : {4.0, 12.0, 20.0}) {
    add_part("cart", config_.patrol_cart, cell(cart_x), 2, 12, 6);
  }
  add_part("cart", config_.patrol_cart, world_.width() - 8, cell(6.0), 6, 12);
  // People: 0.3 m spots between the robot's lane and the walls, on both sides of the loop.
  const std::array<std::array<double, 2>, 6> spots{{{6.0, 1.2}, {14.5, 3.8}, {22.8, 4.0}, {17.0, 12.8},
                                                    {9.0, 10.2}, {1.1, 9.0}}};
  for (const auto& spot : spots) add_part("person", config_.patrol_person, cell(spot[0]), cell(spot[1]), 3, 3);
  startPatrolParts();
  // The loop in the corridor, 2.5 m from the outer walls: 19 m + 9 m, twice.
  route_ = {{2.5, 2.5}, {21.5, 2.5}, {21.5, 11.5}, {2.5, 11.5}};
}

void Simulation::startPatrolParts() {
  // Each part starts in its stationary distribution.
  for (const PatrolLayout::Part& part : patrol_.parts) {
    const std::optional<double> pi = core::stationaryOccupancy(part.truth);
    const bool occupied = dynamics_rng_.bernoulli(pi.value_or(0.0));
    part_occupied_.push_back(occupied ? 1 : 0);
    for (const core::CellXY& c : part.cells) world_.setScheduled(c.x, c.y, part.truth, occupied);
  }
}

void Simulation::stepPatrolParts() {
  for (std::size_t k = 0; k < patrol_.parts.size(); ++k) {
    const PatrolLayout::Part& part = patrol_.parts[k];
    const bool occupied = part_occupied_[k] != 0;
    const double p_change = occupied ? part.truth.p_free_given_occ : part.truth.p_occ_given_free;
    if (!dynamics_rng_.bernoulli(p_change)) continue;
    part_occupied_[k] = occupied ? 0 : 1;
    for (const core::CellXY& c : part.cells) world_.setState(c.x, c.y, !occupied);
  }
}

const PatrolLayout& Simulation::patrolLayout() const {
  if (config_.kind != ScenarioKind::kPatrol) throw std::logic_error("patrolLayout: not the patrol scenario");
  return patrol_;
}

const DoorLayout& Simulation::doorLayout() const {
  if (config_.kind != ScenarioKind::kDoor) throw std::logic_error("doorLayout: not the door scenario");
  return door_;
}

const MrfSquaresLayout& Simulation::mrfSquaresLayout() const {
  if (config_.kind != ScenarioKind::kMrfSquares) throw std::logic_error("mrfSquaresLayout: not the mrf_squares scenario");
  return squares_;
}

const DividersLayout& Simulation::dividersLayout() const {
  if (config_.kind != ScenarioKind::kDividers) throw std::logic_error("dividersLayout: not the dividers scenario");
  return dividers_;
}

bool Simulation::isPerson(std::int32_t x, std::int32_t y) const {
  if (config_.kind != ScenarioKind::kDividers) return false;
  for (const core::CellXY& person : dividers_.people) {
    if (person.x == x && person.y == y) return true;
  }
  return false;
}

bool Simulation::isStructure(std::int32_t x, std::int32_t y) const { return world_.occupied(x, y) && !isPerson(x, y); }

int DividersLayout::dividerAt(std::int32_t x, std::int32_t y) const {
  for (std::size_t p = 0; p < passage_min_y.size(); ++p) {
    if (inDivider(p, x, y)) return static_cast<int>(p);
  }
  return -1;
}

// ---------------------------------------------------------------- dividers

void Simulation::buildDividers() {
  addBorderWalls();
  dividers_.wall_x = kDividersWallX;
  dividers_.passage_height = kDividersPassageHeight;
  dividers_.passage_min_y.assign(kDividersPassages.begin(), kDividersPassages.end());
  const std::int32_t middle = kDividersPassages[1] + kDividersPassageHeight / 2;
  dividers_.a = core::CellXY{4, middle};
  dividers_.b = core::CellXY{world_.width() - 5, middle};
  // A divider's truth is the Markov rate of its moves (as the parking lot's hourly rates).
  const double rate = config_.divider_toggle_probability / static_cast<double>(config_.divider_period_steps);
  for (std::int32_t y = 1; y < world_.height() - 1; ++y) {
    if (dividers_.dividerAt(kDividersWallX, y) >= 0) {
      world_.setScheduled(kDividersWallX, y, core::TransitionParams{rate, rate}, false);
    } else {
      world_.setStatic(kDividersWallX, y, true);
    }
  }
  dividers_.closed.assign(dividers_.passage_min_y.size(), 0);
  moveDividers(true);
  for (int i = 0; i < config_.people; ++i) {
    const core::CellXY cell = randomFreeCell(dynamics_rng_);
    world_.setState(cell.x, cell.y, true);
    dividers_.people.push_back(cell);
    waypoints_.push_back(randomFreeCell(dynamics_rng_));
  }
  // The scripted robot (tools, tests) loops around the left half; the memory experiment
  // drives its own robots.
  const double r = world_.resolution();
  const auto at = [r](std::int32_t x, std::int32_t y) { return std::array<double, 2>{cellCentre(x, r), cellCentre(y, r)}; };
  route_ = {at(4, 4), at(kDividersWallX - 5, 4), at(kDividersWallX - 5, world_.height() - 5),
            at(4, world_.height() - 5)};
}

void Simulation::moveDividers(bool initial) {
  std::vector<std::size_t> just_closed;
  for (std::size_t p = 0; p < dividers_.closed.size(); ++p) {
    const bool was_closed = dividers_.closed[p] != 0;
    const bool closed = initial ? dynamics_rng_.bernoulli(0.5)
                                : was_closed != dynamics_rng_.bernoulli(config_.divider_toggle_probability);
    if (closed && (initial || !was_closed)) just_closed.push_back(p);
    dividers_.closed[p] = closed ? 1 : 0;
  }
  if (std::all_of(dividers_.closed.begin(), dividers_.closed.end(), [](std::uint8_t c) { return c != 0; })) {
    // Every passage closed: one that just closed stays open (there is one: they were not
    // all closed before).
    dividers_.closed[just_closed[dynamics_rng_.below(just_closed.size())]] = 0;
  }
  for (std::size_t p = 0; p < dividers_.closed.size(); ++p) {
    const bool closed = dividers_.closed[p] != 0;
    for (std::int32_t y = dividers_.passage_min_y[p]; y < dividers_.passage_min_y[p] + dividers_.passage_height; ++y) {
      if (!closed) {
        if (!isPerson(dividers_.wall_x, y)) world_.setState(dividers_.wall_x, y, false);
        continue;
      }
      for (core::CellXY& person : dividers_.people) {
        if (person.x != dividers_.wall_x || person.y != y) continue;
        // Pushed out to the nearest free cell (rows of the wall column excluded).
        world_.setState(person.x, person.y, false);
        core::CellXY best = person;
        std::int32_t best_distance = std::numeric_limits<std::int32_t>::max();
        for (std::int32_t cy = 1; cy < world_.height() - 1; ++cy) {
          for (std::int32_t cx = 1; cx < world_.width() - 1; ++cx) {
            const std::int32_t d = std::abs(cx - person.x) + std::abs(cy - person.y);
            if (cx == dividers_.wall_x || d >= best_distance || world_.occupied(cx, cy)) continue;
            best = core::CellXY{cx, cy};
            best_distance = d;
          }
        }
        person = best;
        world_.setState(person.x, person.y, true);
      }
      world_.setState(dividers_.wall_x, y, true);
    }
  }
}

bool Simulation::freeForPerson(std::int32_t x, std::int32_t y) const {
  // Occupied covers walls, closed dividers and the other people.
  return world_.inside(x, y) && !world_.occupied(x, y);
}

core::CellXY Simulation::randomFreeCell(Rng& rng) const {
  while (true) {
    const auto x = static_cast<std::int32_t>(rng.below(static_cast<std::uint64_t>(world_.width())));
    const auto y = static_cast<std::int32_t>(rng.below(static_cast<std::uint64_t>(world_.height())));
    if (x != dividers_.wall_x && freeForPerson(x, y)) return core::CellXY{x, y};
  }
}

void Simulation::movePeople() {
  constexpr std::array<std::array<std::int32_t, 2>, 4> kMoves{{{1, 0}, {-1, 0}, {0, 1}, {0, -1}}};
  for (std::size_t i = 0; i < dividers_.people.size(); ++i) {
    core::CellXY& person = dividers_.people[i];
    const auto distance = [&](std::int32_t x, std::int32_t y) {
      return std::abs(x - waypoints_[i].x) + std::abs(y - waypoints_[i].y);
    };
    std::array<core::CellXY, 4> options{};
    std::size_t count = 0;
    for (const auto& move : kMoves) {
      const core::CellXY next{person.x + move[0], person.y + move[1]};
      if (distance(next.x, next.y) < distance(person.x, person.y) && freeForPerson(next.x, next.y)) {
        options[count++] = next;
      }
    }
    if (count == 0) {
      // Arrived or stuck: a new waypoint, and a random free step.
      waypoints_[i] = randomFreeCell(dynamics_rng_);
      for (const auto& move : kMoves) {
        const core::CellXY next{person.x + move[0], person.y + move[1]};
        if (freeForPerson(next.x, next.y)) options[count++] = next;
      }
      if (count == 0) continue;  // boxed in
    }
    const core::CellXY next = options[dynamics_rng_.below(count)];
    world_.setState(person.x, person.y, false);
    world_.setState(next.x, next.y, true);
    person = next;
  }
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
