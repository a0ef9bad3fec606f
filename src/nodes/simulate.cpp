// simulate: writes a simulated run of one of the evaluation's scenarios (evaluation/simulator.h)
// to a bag, as a robot would have recorded it, with the true state of the world next to the
// scans, so that the bag tools and the mapping node can be run and checked on a world whose
// truth is known. See README.md, "simulate".
//
// Simulation time t (seconds) is ROS time kStartTime_s + t: not 0, because tf reads a stamp
// of 0 as "the latest transform", and a round number so that stamps read back easily.

#include <algorithm>
#include <chrono>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <filesystem>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

#include <boost/make_shared.hpp>
#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/OccupancyGrid.h>
#include <ros/message_traits.h>
#include <ros/time.h>
#include <rosbag/bag.h>
#include <sensor_msgs/LaserScan.h>
#include <tf2_msgs/TFMessage.h>

#include "bag_tools.h"
#include "dynamic_occupancy_grid/ros/conversions.h"
#include "dynamic_occupancy_grid/evaluation/simulator.h"

namespace dog = dynamic_occupancy_grid;

namespace {

constexpr double kStartTime_s = 1.0e9;
const std::string kFixedFrame = "odom";
const std::string kRobotFrame = "base_link";
const std::string kLaserFrame = "laser";
const std::string kScanTopic = "/scan";
const std::string kTfTopic = "/tf";
const std::string kTfStaticTopic = "/tf_static";
const std::string kGroundTruthTopic = "/ground_truth";
const std::string kTruePoseTopic = "/ground_truth_pose";
const std::string kTruthOccGivenFreeTopic = "/ground_truth_p_occ_given_free";
const std::string kTruthFreeGivenOccTopic = "/ground_truth_p_free_given_occ";

std::string scenarioList() {
  std::string names;
  for (const std::string& name : dog::evaluation::scenarioNames()) names += (names.empty() ? "" : ", ") + name;
  return names;
}

struct Options {
  dog::evaluation::ScenarioConfig scenario = dog::evaluation::scenarioConfig("dynamic_5_5");
  std::uint64_t world_seed = 1;
  std::uint64_t run_seed = 1;
  std::optional<std::int64_t> steps;  ///< none: the scenario's
  double transition_scale = 0.1;
  dog::core::OdometryNoise odometry_noise;  ///< none: /tf carries the true pose
  std::string out_path;
};

Options parseArguments(int argc, char** argv) {
  namespace cl = dog::command_line;
  Options options;
  const auto seeds = cl::between<std::uint64_t>(0, std::numeric_limits<long>::max());
  cl::CommandLine line(
      "simulate",
      "usage: simulate --out FILE.bag [options]\n"
      "Writes a simulated run of a scenario to a bag, with the true state of its world:\n"
      "  /scan          sensor_msgs/LaserScan, frame laser\n"
      "  /tf            odom -> base_link: the robot's pose at every scan\n"
      "  /tf_static     base_link -> laser, once (latched)\n"
      "  /ground_truth  nav_msgs/OccupancyGrid in odom, origin (0, 0): every cell's true state\n"
      "                 (100 occupied, 0 free), one per step, stamped at the step's start\n"
      "  /ground_truth_p_occ_given_free, /ground_truth_p_free_given_occ\n"
      "                 the same with every cell's true transition probability per step (see\n"
      "                 --transition-scale), at the start and whenever it changes (latched)\n"
      "  /ground_truth_pose  geometry_msgs/PoseStamped in odom: the true pose at every scan,\n"
      "                 only with --odometry-noise (/tf then carries the drifting odometry)\n"
      "Simulation time t (s) is ROS time 1000000000 + t.\n");
  line.options().add_options()
      ("scenario",
       // scenarioConfig's error lists the scenarios there are.
       cl::converted(dog::evaluation::scenarioConfig,
                     [&options](const dog::evaluation::ScenarioConfig& scenario) { options.scenario = scenario; })
           ->value_name("NAME"),
       ("the scenario (default dynamic_5_5), one of: " + scenarioList()).c_str())
      ("world-seed", cl::number(&options.world_seed, seeds)->value_name("N"),
       "draws the layout: walls, which cells are dynamic (default 1)")
      ("seed", cl::number(&options.run_seed, seeds)->value_name("N"),
       "draws the run: state changes, parked cars, sensor noise (default 1)")
      ("steps",
       cl::number<std::int64_t>(nullptr, cl::between<std::int64_t>(1, std::numeric_limits<std::int32_t>::max()))
           ->value_name("N")
           ->notifier([&options](std::int64_t steps) { options.steps = steps; }),
       "time steps to simulate (default: the scenario's)")
      ("transition-scale", cl::number(&options.transition_scale, cl::between(1.0e-6, 1.0))->value_name("P"),
       "true transitions: P per step is written as 100, larger values too (default 0.1, as process_bag's layers)")
      ("odometry-noise",
       cl::converted(dog::bag_tools::toOdometryNoise,
                     [&options](const dog::core::OdometryNoise& noise) { options.odometry_noise = noise; })
           ->value_name("A1,A2,A3,A4"),
       "drifting odometry on /tf (odom -> base_link) and the true pose on /ground_truth_pose: the "
       "odometry motion model's rot-from-rot, rot-from-trans, trans-from-trans and trans-from-rot "
       "variances (amcl's odom_alpha1..4), e.g. 0.01,0.0005,0.002,0.0005 (a few degrees and about a metre "
       "of drift in 60 m; default: none, /tf is the truth)")
      ("out", cl::nonEmpty(&options.out_path, "a file name")->value_name("FILE")->required(),
       "the bag to write (through FILE.tmp, renamed when complete)");
  line.parse(argc, argv);
  return options;
}

// Separates the odometry's random stream from the simulation's, both drawn from the run seed.
constexpr std::uint64_t kOdometrySeedSalt = 0x6f646f6d65747279ULL;  // "odometry"

geometry_msgs::PoseStamped poseStamped(const dog::core::Pose2D& pose, const ros::Time& stamp) {
  geometry_msgs::PoseStamped message;
  message.header.frame_id = kFixedFrame;
  message.header.stamp = stamp;
  message.pose.position.x = pose.x_m;
  message.pose.position.y = pose.y_m;
  message.pose.orientation.z = std::sin(pose.yaw_rad / 2.0);
  message.pose.orientation.w = std::cos(pose.yaw_rad / 2.0);
  return message;
}

ros::Time rosTime(double simulation_time_s) { return ros::Time(kStartTime_s) + ros::Duration(simulation_time_s); }

geometry_msgs::TransformStamped transform(const std::string& parent, const std::string& child,
                                          const dog::core::Pose2D& pose, const ros::Time& stamp) {
  geometry_msgs::TransformStamped message;
  message.header.stamp = stamp;
  message.header.frame_id = parent;
  message.child_frame_id = child;
  message.transform = dog::ros_layer::toTransform(pose);
  return message;
}

sensor_msgs::LaserScan laserScan(const dog::core::Scan& scan, const dog::evaluation::ScenarioConfig& scenario) {
  sensor_msgs::LaserScan message;
  message.header.stamp = rosTime(scan.stamp_s);
  message.header.frame_id = kLaserFrame;
  message.angle_min = static_cast<float>(scan.angle_min_rad);
  message.angle_increment = static_cast<float>(scan.angle_increment_rad);
  message.angle_max =
      static_cast<float>(scan.angle_min_rad + scan.angle_increment_rad * static_cast<double>(scan.ranges_m.size() - 1));
  // The simulator casts all beams of a scan at once.
  message.time_increment = 0.0f;
  message.scan_time = static_cast<float>(scenario.time_step_s / scenario.scans_per_step);
  message.range_min = static_cast<float>(scan.range_min_m);
  message.range_max = static_cast<float>(scan.range_max_m);
  message.ranges = scan.ranges_m;
  return message;
}

// An OccupancyGrid over the whole world (origin (0, 0), the world's cells in its row-major
// order, which is OccupancyGrid's) with one value per cell.
nav_msgs::OccupancyGrid worldGrid(const dog::evaluation::World& world, std::vector<std::int8_t> values,
                                  const ros::Time& stamp) {
  nav_msgs::OccupancyGrid message;
  message.header.stamp = stamp;
  message.header.frame_id = kFixedFrame;
  message.info.map_load_time = stamp;
  message.info.resolution = static_cast<float>(world.resolution());
  message.info.width = static_cast<std::uint32_t>(world.width());
  message.info.height = static_cast<std::uint32_t>(world.height());
  message.info.origin.orientation.w = 1.0;
  message.data = std::move(values);
  return message;
}

std::vector<std::int8_t> occupancyValues(const dog::evaluation::World& world) {
  std::vector<std::int8_t> values;
  values.reserve(world.occupancy().size());
  for (const std::uint8_t occupied : world.occupancy()) values.push_back(occupied != 0 ? 100 : 0);
  return values;
}

// Every cell's true transitions, row-major (World::index order).
std::vector<dog::core::TransitionParams> truthOf(const dog::evaluation::World& world) {
  std::vector<dog::core::TransitionParams> truth;
  truth.reserve(world.occupancy().size());
  for (std::int32_t y = 0; y < world.height(); ++y) {
    for (std::int32_t x = 0; x < world.width(); ++x) truth.push_back(world.truth(x, y));
  }
  return truth;
}

std::vector<std::int8_t> scaledTransitions(const std::vector<dog::core::TransitionParams>& truth, bool occ_given_free,
                                           double scale) {
  std::vector<std::int8_t> values;
  values.reserve(truth.size());
  for (const dog::core::TransitionParams& cell : truth) {
    const double p = occ_given_free ? cell.p_occ_given_free : cell.p_free_given_occ;
    values.push_back(static_cast<std::int8_t>(std::lround(std::min(1.0, p / scale) * 100.0)));
  }
  return values;
}

bool sameTruth(const std::vector<dog::core::TransitionParams>& a, const std::vector<dog::core::TransitionParams>& b) {
  return std::equal(a.begin(), a.end(), b.begin(), b.end(),
                    [](const dog::core::TransitionParams& p, const dog::core::TransitionParams& q) {
                      return p.p_occ_given_free == q.p_occ_given_free && p.p_free_given_occ == q.p_free_given_occ;
                    });
}

// The connection header rosbag record keeps for a latched publisher of `Message` (a custom
// header replaces rosbag's, so it carries the type fields too): rosbag play then latches
// the topic again, as a robot's /tf_static and map topics are.
template <class Message>
boost::shared_ptr<ros::M_string> latchedConnection() {
  auto header = boost::make_shared<ros::M_string>();
  (*header)["type"] = ros::message_traits::datatype<Message>();
  (*header)["md5sum"] = ros::message_traits::md5sum<Message>();
  (*header)["message_definition"] = ros::message_traits::definition<Message>();
  (*header)["callerid"] = "/simulate";
  (*header)["latching"] = "1";
  return header;
}

struct RunSummary {
  std::int64_t steps = 0;
  std::size_t scans = 0;
  std::size_t dynamic_cells_at_start = 0;
  std::size_t truth_updates = 0;
};

// Writes the whole run into the open `bag`.
RunSummary writeRun(const Options& options, std::int64_t steps, rosbag::Bag& bag) {
  dog::evaluation::Simulation simulation(options.scenario, options.world_seed, options.run_seed);
  const dog::evaluation::World& world = simulation.world();
  RunSummary summary;
  summary.steps = steps;
  summary.dynamic_cells_at_start = world.dynamicCells().size();

  // Its own stream of the run seed: the run's other draws are the same with or without it.
  const bool drifting = !options.odometry_noise.none();
  dog::evaluation::DriftingOdometry drift(options.odometry_noise,
                                          dog::evaluation::mixSeed(options.run_seed ^ kOdometrySeedSalt));

  const ros::Time start = rosTime(0.0);
  tf2_msgs::TFMessage mount;
  mount.transforms.push_back(transform(kRobotFrame, kLaserFrame, options.scenario.laser_mount, start));
  bag.write(kTfStaticTopic, start, mount, latchedConnection<tf2_msgs::TFMessage>());
  const boost::shared_ptr<ros::M_string> latched_grid = latchedConnection<nav_msgs::OccupancyGrid>();

  dog::bag_tools::ProgressBar bar;
  std::vector<dog::core::TransitionParams> written_truth;
  for (std::int64_t step = 0; step < steps; ++step) {
    const ros::Time step_start = rosTime(static_cast<double>(step) * options.scenario.time_step_s);
    bag.write(kGroundTruthTopic, step_start, worldGrid(world, occupancyValues(world), step_start));
    // The truth changes rarely (a re-draw) but is compared every step: a few thousand cells.
    std::vector<dog::core::TransitionParams> truth = truthOf(world);
    if (step == 0 || !sameTruth(truth, written_truth)) {
      bag.write(kTruthOccGivenFreeTopic, step_start,
                worldGrid(world, scaledTransitions(truth, true, options.transition_scale), step_start), latched_grid);
      bag.write(kTruthFreeGivenOccTopic, step_start,
                worldGrid(world, scaledTransitions(truth, false, options.transition_scale), step_start), latched_grid);
      written_truth = std::move(truth);
      ++summary.truth_updates;
    }
    for (int scan_index = 0; scan_index < options.scenario.scans_per_step; ++scan_index) {
      const dog::core::Pose2D robot = simulation.robotPose(scan_index);
      const sensor_msgs::LaserScan scan = laserScan(simulation.scan(scan_index), options.scenario);
      tf2_msgs::TFMessage odometry;
      odometry.transforms.push_back(
          transform(kFixedFrame, kRobotFrame, drifting ? drift.update(robot) : robot, scan.header.stamp));
      bag.write(kTfTopic, scan.header.stamp, odometry);
      if (drifting) bag.write(kTruePoseTopic, scan.header.stamp, poseStamped(robot, scan.header.stamp));
      bag.write(kScanTopic, scan.header.stamp, scan);
      ++summary.scans;
    }
    simulation.advance();
    bar.show("simulate", static_cast<double>(step + 1) / static_cast<double>(steps));
  }
  return summary;
}

// rosbag's error for a file it cannot open does not say why; fopen's errno does.
void checkCreatable(const std::string& path, const std::string& purpose) {
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) {
    throw std::runtime_error("cannot create " + path + " (" + purpose + "): " + std::strerror(errno));
  }
  std::fclose(file);
}

int run(const Options& options) {
  const std::int64_t steps = options.steps.value_or(options.scenario.steps);
  const std::string temporary = options.out_path + ".tmp";
  const auto started = std::chrono::steady_clock::now();
  checkCreatable(temporary, "written first, renamed to " + options.out_path + " when complete");
  RunSummary summary;
  // ~Bag closes the bag, which writes its index: after a failed write (a full disk) that
  // throws again, out of a destructor, which ends the program. A bag that failed is
  // therefore let go unclosed (the process ends with the error right after) and its file
  // removed.
  auto bag = std::make_unique<rosbag::Bag>();
  try {
    bag->open(temporary, rosbag::bagmode::Write);
    summary = writeRun(options, steps, *bag);
    bag->close();
  } catch (const std::exception& e) {
    // Reachable from a static to the end, so that a leak checker (the sanitized tests) does
    // not count it as lost; volatile, or the compiler drops a store nothing reads.
    [[maybe_unused]] static rosbag::Bag* volatile unclosed_bag = nullptr;
    unclosed_bag = bag.release();
    std::error_code ignored;
    std::filesystem::remove(temporary, ignored);
    throw std::runtime_error("cannot write " + temporary + ": " + e.what());
  }
  std::error_code error;
  std::filesystem::rename(temporary, options.out_path, error);
  if (error) {
    std::error_code ignored;
    std::filesystem::remove(temporary, ignored);
    throw std::runtime_error("cannot rename " + temporary + " to " + options.out_path + ": " + error.message());
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  const auto bytes = std::filesystem::file_size(options.out_path);
  std::printf("scenario %s: %s\n", options.scenario.name.c_str(), options.scenario.description.c_str());
  std::printf("world seed %llu, run seed %llu: %zu dynamic cells at the start, %lld steps of %g s, %zu scans, "
              "%zu ground-truth transition updates\n",
              static_cast<unsigned long long>(options.world_seed), static_cast<unsigned long long>(options.run_seed),
              summary.dynamic_cells_at_start, static_cast<long long>(summary.steps), options.scenario.time_step_s,
              summary.scans, summary.truth_updates);
  std::printf("bag -> %s (%.1f MB, %.2f s)\n", options.out_path.c_str(), static_cast<double>(bytes) / 1.0e6, seconds);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const Options options = parseArguments(argc, argv);
  try {
    return run(options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "simulate: %s\n", e.what());
    return 1;
  }
}
