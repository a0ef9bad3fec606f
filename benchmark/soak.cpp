// Soak of the core (issue 20): a robot explores a building and then loops in it for a
// million scans, faster than real time, with the node's defaults (online learning of the
// transitions and of the sensor model on) and the node's publication of all six layers.
// Memory (RSS) and the time per scan must stay flat once the explored area stops growing.
//
// Every --window scans a line of the CSV: scans done, cells allocated, VmRSS, the per-scan
// time (median and p99 of Mapper::integrate), the per-step time (Mapper::finishStep at
// each step's end, what the first scan of the next step would do otherwise), the layers'
// time per publication, and the whole map's work per scan. Times are process CPU time
// (CLOCK_PROCESS_CPUTIME_ID, so the layers' worker threads count and other processes on
// the machine do not), with the wall-clock median of a scan next to it. At the end the
// verdict: RSS growth from the window in which the explored area last grew to the end,
// and the per-scan time of the first against the last looping windows (the least disturbed
// of --compare-windows at each end); exit status 1 when either grows beyond its bound.
// Results and commands are in BENCHMARKS.md.

#include <ros/serialization.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/evaluation/simulator.h"
#include "dynamic_occupancy_grid/ros/grid_messages.h"
#include "dynamic_occupancy_grid/ros/parameters.h"
#include "../src/nodes/command_line.h"

namespace dog = dynamic_occupancy_grid::core;
namespace evaluation = dynamic_occupancy_grid::evaluation;
namespace rl = dynamic_occupancy_grid::ros_layer;
namespace cl = dynamic_occupancy_grid::command_line;

namespace {

constexpr double kResolutionM = 0.05;  // the world's cells: the node's default map resolution
constexpr double kWidthM = 30.0;
constexpr double kHeightM = 20.0;

// A group of cells that changes as one: a two-state Markov chain per step with `truth`.
struct Part {
  std::vector<dog::CellXY> cells;
  dog::TransitionParams truth;
  bool occupied = false;
};

// A person (0.4 m square) walking back and forth along a horizontal segment.
struct Person {
  double x_min_m;
  double x_max_m;
  double y_m;
  double speed_m_s;
  std::vector<dog::CellXY> cells;  // occupied now
};

// A 30 m x 20 m office floor: a 3 m corridor along its middle, three rooms on each side
// (10 m x 8 m), each with a 1.2 m doorway onto the corridor. The robot's tour runs the
// corridor and loops through three of the rooms, whose doorways stay open; the other three
// have doors that open and close, so their rooms are seen only through open doors. Chairs
// (0.5 m) in every room come and go, people walk in the corridor and in the toured rooms.
class Building {
 public:
  explicit Building(std::uint64_t seed)
      : world_(static_cast<std::int32_t>(std::lround(kWidthM / kResolutionM)),
               static_cast<std::int32_t>(std::lround(kHeightM / kResolutionM)), kResolutionM),
        rng_(seed) {
    // Outer walls, the corridor's walls (y 8.3..8.5 and 11.5..11.7) and the rooms' walls.
    fill(0.0, 0.0, kWidthM, 0.2, true);
    fill(0.0, kHeightM - 0.2, kWidthM, kHeightM, true);
    fill(0.0, 0.0, 0.2, kHeightM, true);
    fill(kWidthM - 0.2, 0.0, kWidthM, kHeightM, true);
    fill(0.0, 8.3, kWidthM, 8.5, true);
    fill(0.0, 11.5, kWidthM, 11.7, true);
    for (const double x : {9.9, 19.9}) {
      fill(x, 0.0, x + 0.2, 8.5, true);
      fill(x, 11.5, x + 0.2, kHeightM, true);
    }
    // Rooms along x at centres 5, 15, 25; below (wall y 8.3) or above (11.5) the corridor.
    // The tour enters the rooms below at x 5 and 25 and the one above at x 15.
    const TransitionParams door{0.01, 0.02};    // shut about every 100 s, open again within 50 s
    const TransitionParams chair{0.002, 0.004};  // comes and goes over minutes
    for (const double centre_x : {5.0, 15.0, 25.0}) {
      for (const bool below : {true, false}) {
        const bool toured = below == (centre_x != 15.0);
        const double wall_y = below ? 8.3 : 11.5;
        fill(centre_x - 0.6, wall_y, centre_x + 0.6, wall_y + 0.2, false);  // the doorway
        if (!toured) parts_.push_back(makePart(centre_x - 0.6, wall_y, centre_x + 0.6, wall_y + 0.2, door, false));
        const double chair_y = below ? 4.8 : 15.2;
        parts_.push_back(makePart(centre_x + 1.25, chair_y - 0.25, centre_x + 1.75, chair_y + 0.25, chair, true));
        if (toured) {
          people_.push_back(Person{centre_x - 2.0, centre_x + 2.0, below ? 4.0 : 16.0, 0.7, {}});
          addRoomTour(centre_x, below);
        }
      }
    }
    people_.push_back(Person{6.2, 13.8, 9.0, 0.8, {}});
    people_.push_back(Person{16.2, 23.8, 9.0, 1.1, {}});
    route_.push_back({28.0, 10.0});
    moveParts(0.0);
  }

  const evaluation::World& world() const { return world_; }
  const std::vector<std::array<double, 2>>& route() const { return route_; }

  // Moves the people to where they are at `stamp_s`.
  void moveParts(double stamp_s) {
    for (Person& person : people_) {
      // A triangle wave between the segment's ends.
      const double length = person.x_max_m - person.x_min_m;
      const double travelled = std::fmod(person.speed_m_s * stamp_s, 2.0 * length);
      const double x = person.x_min_m + (travelled < length ? travelled : 2.0 * length - travelled);
      for (const dog::CellXY& cell : person.cells) world_.setState(cell.x, cell.y, false);
      person.cells = cellsIn(x - 0.2, person.y_m - 0.2, x + 0.2, person.y_m + 0.2);
      for (const dog::CellXY& cell : person.cells) world_.setState(cell.x, cell.y, true);
    }
  }

  // One time step of the doors and chairs.
  void stepParts() {
    for (Part& part : parts_) {
      const double p_change = part.occupied ? part.truth.p_free_given_occ : part.truth.p_occ_given_free;
      if (!rng_.bernoulli(p_change)) continue;
      part.occupied = !part.occupied;
      for (const dog::CellXY& cell : part.cells) world_.setState(cell.x, cell.y, part.occupied);
    }
  }

 private:
  using TransitionParams = dog::TransitionParams;

  // The cells whose centres lie in [x0, x1) x [y0, y1) (metres).
  std::vector<dog::CellXY> cellsIn(double x0, double y0, double x1, double y1) const {
    std::vector<dog::CellXY> cells;
    const auto first = [](double v) { return static_cast<std::int32_t>(std::ceil(v / kResolutionM - 0.5)); };
    for (std::int32_t y = first(y0); y < first(y1); ++y) {
      for (std::int32_t x = first(x0); x < first(x1); ++x) {
        if (world_.inside(x, y)) cells.push_back({x, y});
      }
    }
    return cells;
  }

  void fill(double x0, double y0, double x1, double y1, bool occupied) {
    for (const dog::CellXY& cell : cellsIn(x0, y0, x1, y1)) world_.setStatic(cell.x, cell.y, occupied);
  }

  Part makePart(double x0, double y0, double x1, double y1, const TransitionParams& truth, bool occupied) {
    Part part{cellsIn(x0, y0, x1, y1), truth, occupied};
    for (const dog::CellXY& cell : part.cells) world_.setScheduled(cell.x, cell.y, truth, occupied);
    return part;
  }

  // From the corridor (y 10) into a room and once around a 6 m x 4 m loop in it.
  void addRoomTour(double centre_x, bool below) {
    const double side = below ? -1.0 : 1.0;
    const double near_y = 10.0 + 4.0 * side;  // 6 (below) or 14 (above)
    const double far_y = 10.0 + 8.0 * side;   // 2 or 18
    for (const std::array<double, 2>& point :
         std::vector<std::array<double, 2>>{{centre_x, 10.0}, {centre_x, near_y}, {centre_x + 3.0, near_y},
                                            {centre_x + 3.0, far_y}, {centre_x - 3.0, far_y},
                                            {centre_x - 3.0, near_y}, {centre_x, near_y}}) {
      route_.push_back(point);
    }
    route_.push_back({centre_x, 10.0});  // back in the corridor
  }

  evaluation::World world_;
  evaluation::Rng rng_;
  std::vector<Part> parts_;
  std::vector<Person> people_;
  std::vector<std::array<double, 2>> route_{{2.0, 10.0}};
};

double cpuSeconds() {
  timespec now{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &now);
  return static_cast<double>(now.tv_sec) + 1e-9 * static_cast<double>(now.tv_nsec);
}

double wallSeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// VmRSS of this process, MB (1e6 bytes); NaN if /proc cannot tell.
double rssMb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.compare(0, 6, "VmRSS:") == 0) return std::stod(line.substr(6)) * 1024.0 / 1e6;
  }
  return std::nan("");
}

double loadAverage() {
  std::ifstream file("/proc/loadavg");
  double load = std::nan("");
  file >> load;
  return load;
}

// The q-quantile (nearest rank) of `values`, which it reorders.
double quantile(std::vector<double>* values, double q) {
  if (values->empty()) return std::nan("");
  const double n = static_cast<double>(values->size());
  const std::size_t rank = static_cast<std::size_t>(std::clamp(std::ceil(q * n), 1.0, n)) - 1;
  std::nth_element(values->begin(), values->begin() + static_cast<std::ptrdiff_t>(rank), values->end());
  return (*values)[rank];
}

double median(std::vector<double> values) { return quantile(&values, 0.5); }

// What the node does every ~publish_period with a subscriber on every layer
// (MappingNode::publishLayers): the full grid of each layer when the bounds changed or
// ~full_map_period passed, else an update of the changed cells' box; each message
// serialized as ros::Publisher does for a remote subscriber.
class LayerPublisher {
 public:
  explicit LayerPublisher(const rl::NodeParameters& node, const dog::MapperConfig& mapper)
      : full_map_period_s_(node.full_map_period_s) {
    // The node's six layers and their scaling (MappingNode::advertiseHmm).
    const float transition_scale = static_cast<float>(node.transition_scale);
    const std::int64_t horizon = std::llround(node.prediction_horizon_s / mapper.time_step_s);
    views_ = {{dog::Layer::kBelief, 1.0f, 0, std::nullopt},
              {dog::Layer::kPredicted, 1.0f, horizon, std::nullopt},
              {dog::Layer::kStationary, 1.0f, 0, std::nullopt},
              {dog::Layer::kOccGivenFree, transition_scale, 0, std::nullopt},
              {dog::Layer::kFreeGivenOcc, transition_scale, 0, std::nullopt},
              {dog::Layer::kStatic, 1.0f, 0, std::nullopt}};
  }

  void publish(dog::Mapper* mapper, double now_s) {
    const std::optional<std::int64_t> step = mapper->lastAppliedStep();
    if (!step) return;
    const dog::CellBox bounds = mapper->grid().bounds();
    const dog::CellBox changed = mapper->takeChangedCells();
    const bool full_due = !same(bounds, published_bounds_) || now_s - last_full_s_ >= full_map_period_s_;
    const ros::Time stamp(mapper->clock().stepStart(*step + 1));
    for (const rl::LayerView& view : views_) {
      if (full_due) {
        send(rl::toOccupancyGrid(mapper->grid().window(bounds), rl::layerValues(mapper->grid(), view, *step, bounds),
                                 "map", stamp));
        ++full_grids_;
      } else if (!changed.empty()) {
        send(rl::toOccupancyGridUpdate(bounds, changed, rl::layerValues(mapper->grid(), view, *step, changed), "map",
                                       stamp));
        ++updates_;
      }
    }
    if (full_due) {
      published_bounds_ = bounds;
      last_full_s_ = now_s;
    }
  }

  std::uint64_t fullGrids() const { return full_grids_; }
  std::uint64_t updates() const { return updates_; }
  std::uint64_t bytes() const { return bytes_; }

 private:
  static bool same(const dog::CellBox& a, const dog::CellBox& b) {
    return a.min_x == b.min_x && a.min_y == b.min_y && a.max_x == b.max_x && a.max_y == b.max_y;
  }

  template <class Message>
  void send(const Message& message) {
    bytes_ += ros::serialization::serializeMessage(message).num_bytes;
  }

  double full_map_period_s_;
  std::vector<rl::LayerView> views_;
  dog::CellBox published_bounds_;
  double last_full_s_ = -1e300;
  std::uint64_t full_grids_ = 0;
  std::uint64_t updates_ = 0;
  std::uint64_t bytes_ = 0;
};

struct Window {
  std::int64_t scans = 0;         // done at the end of the window
  double sim_time_s = 0.0;
  std::uint64_t cells_allocated = 0;
  double rss_mb = 0.0;
  double scan_median_us = 0.0;    // Mapper::integrate, CPU
  double scan_p99_us = 0.0;
  double scan_wall_median_us = 0.0;
  double step_median_ms = 0.0;    // Mapper::finishStep, CPU
  double step_p99_ms = 0.0;
  double layers_ms = 0.0;         // CPU per publication of the six layers
  double map_us_per_scan = 0.0;   // integrate + steps + layers over the window, CPU per scan
  double wall_s = 0.0;            // the whole window, simulation included
  double load = 0.0;              // /proc/loadavg, 1 minute, at the end of the window
};

void writeCsvHeader(std::ostream& out) {
  out << "scans,sim_time_s,cells_allocated,rss_mb,scan_median_us,scan_p99_us,scan_wall_median_us,step_median_ms,"
         "step_p99_ms,layers_ms_per_publish,map_cpu_us_per_scan,window_wall_s,loadavg_1min\n";
}

void writeCsvRow(std::ostream& out, const Window& w) {
  char line[512];
  std::snprintf(line, sizeof line, "%lld,%.1f,%llu,%.2f,%.1f,%.1f,%.1f,%.3f,%.3f,%.3f,%.1f,%.2f,%.2f\n",
                static_cast<long long>(w.scans), w.sim_time_s, static_cast<unsigned long long>(w.cells_allocated),
                w.rss_mb, w.scan_median_us, w.scan_p99_us, w.scan_wall_median_us, w.step_median_ms, w.step_p99_ms,
                w.layers_ms, w.map_us_per_scan, w.wall_s, w.load);
  out << line;
}

struct Options {
  std::int64_t scans = 1000000;
  std::int64_t window = 10000;
  std::string csv;
  bool quick = false;
  double scan_rate_hz = 40.0;
  double speed_m_s = 1.0;
  double max_rss_growth_percent = 2.0;
  double max_time_growth_percent = 25.0;
  int compare_windows = 10;
  std::uint64_t seed = 1;
};

}  // namespace

int main(int argc, char** argv) {
  Options options;
  cl::CommandLine command_line(
      "soak",
      "usage: soak [--scans N] [--window N] [--csv FILE] [--quick]\n"
      "A robot explores a 30 m x 20 m office floor (corridor, six rooms, doors, chairs, people) and then\n"
      "loops in it; every scan goes into a core::Mapper with the mapping node's defaults (online learning\n"
      "of transitions and sensor model on) and the six layers are published as the node does. Prints a\n"
      "line per window and a verdict; exits 1 if RSS or the per-scan time grows beyond its bound once the\n"
      "explored area stopped growing.\n");
  namespace po = boost::program_options;
  command_line.options().add_options()
      ("scans", cl::number(&options.scans, cl::atLeast<std::int64_t>(1)), "scans to run (default 1,000,000; --quick: 20,000)")
      ("window", cl::number(&options.window, cl::atLeast<std::int64_t>(1)), "scans per CSV line (default 10,000; --quick: 500)")
      ("csv", cl::nonEmpty(&options.csv, "a file name"), "write the windows to this CSV file")
      ("quick", po::bool_switch(&options.quick), "a short run for CI: 20,000 scans in windows of 500, 8 windows compared")
      ("scan-rate", cl::number(&options.scan_rate_hz, cl::above(0.0)), "scans per second of sensor time (default 40)")
      ("speed", cl::number(&options.speed_m_s, cl::above(0.0)), "robot speed, m/s (default 1)")
      ("max-rss-growth", cl::number(&options.max_rss_growth_percent, cl::atLeast(0.0)),
       "bound on RSS growth after exploration, % (default 2)")
      ("max-time-growth", cl::number(&options.max_time_growth_percent, cl::atLeast(0.0)),
       "bound on the growth of the per-scan median and of the map's CPU per scan, % (default 25)")
      ("compare-windows", cl::number(&options.compare_windows, cl::between(1, 1000)),
       "looping windows compared at each end (default 10; --quick: 8)")
      ("seed", cl::number(&options.seed, cl::atLeast<std::uint64_t>(0)), "seed of the doors, chairs and sensor noise");
  const po::variables_map given = command_line.parse(argc, argv);
  if (options.quick) {
    if (given.count("scans") == 0) options.scans = 20000;
    if (given.count("window") == 0) options.window = 500;
    if (given.count("compare-windows") == 0) options.compare_windows = 8;
  }

  // The node's defaults, through its own parameter struct (ros/parameters.h).
  const rl::NodeParameters node{};
  dog::MapperConfig config = node.mapper;
  config.learn_sensor_model = rl::kDefaultLearnSensorModel;
  dog::Mapper mapper(config);
  LayerPublisher layers(node, config);

  Building building(options.seed);
  // The evaluation's default laser (LaserConfig: 360 beams over 360 degrees, 8 m, 1 cm
  // noise, 1 % dropouts), an RPLIDAR-class sensor: a scan costs about as much to simulate as
  // to map, so a million of them fit in about a quarter of an hour of one core.
  const evaluation::LaserConfig laser{};
  const double scan_period_s = 1.0 / options.scan_rate_hz;
  const evaluation::LoopPath path(building.route(), options.speed_m_s * scan_period_s);
  const double lap_scans = path.lengthM() / (options.speed_m_s * scan_period_s);
  evaluation::Rng sensor_rng(evaluation::mixSeed(options.seed + 1));

  std::ofstream csv;
  if (!options.csv.empty()) {
    csv.open(options.csv);
    if (!csv) command_line.fail("cannot write " + options.csv);
    writeCsvHeader(csv);
  }
  std::cout << "soak: " << options.scans << " scans at " << options.scan_rate_hz << " Hz of sensor time, laser "
            << laser.beams << " beams, " << laser.range_max_m << " m; tour " << path.lengthM() << " m at "
            << options.speed_m_s << " m/s = " << std::lround(lap_scans) << " scans per lap; node defaults: time_step "
            << config.time_step_s << " s, learn_transitions " << config.learn_transitions << ", learn_sensor_model "
            << config.learn_sensor_model << ", publish_period " << node.publish_period_s << " s, full_map_period "
            << node.full_map_period_s << " s\n";
  writeCsvHeader(std::cout);

  std::vector<Window> windows;
  std::vector<double> scan_cpu;
  std::vector<double> scan_wall;
  std::vector<double> step_cpu;
  double layers_cpu = 0.0;
  int publications = 0;
  double window_map_cpu = 0.0;
  double window_start_wall = wallSeconds();
  std::optional<std::int64_t> world_step;
  double next_publish_s = 0.0;
  for (std::int64_t i = 0; i < options.scans; ++i) {
    const double stamp_s = static_cast<double>(i) * scan_period_s;
    const std::int64_t step = mapper.clock().origin() ? mapper.clock().stepOf(stamp_s) : 0;
    if (world_step && step != *world_step) {
      // The step's scans are all in: apply it now (timed apart from the scans).
      const double t0 = cpuSeconds();
      mapper.finishStep();
      const double dt = cpuSeconds() - t0;
      step_cpu.push_back(dt);
      window_map_cpu += dt;
      building.stepParts();
    }
    world_step = step;
    if (stamp_s >= next_publish_s) {
      const double t0 = cpuSeconds();
      layers.publish(&mapper, stamp_s);
      const double dt = cpuSeconds() - t0;
      layers_cpu += dt;
      window_map_cpu += dt;
      ++publications;
      next_publish_s += node.publish_period_s;
    }
    building.moveParts(stamp_s);
    dog::Scan scan =
        evaluation::simulateScan(building.world(), path.poseAt(static_cast<double>(i)), laser, stamp_s, sensor_rng);
    scan.range_max_m = std::min(scan.range_max_m, node.max_range_m);  // as the node does
    const double wall0 = wallSeconds();
    const double cpu0 = cpuSeconds();
    const dog::ScanResult result = mapper.integrate(scan);
    const double cpu = cpuSeconds() - cpu0;
    scan_wall.push_back(wallSeconds() - wall0);
    scan_cpu.push_back(cpu);
    window_map_cpu += cpu;
    if (result.status != dog::ScanStatus::kIntegrated) {
      std::cerr << "soak: scan " << i << " rejected: " << result.error << "\n";
      return 1;
    }
    if ((i + 1) % options.window == 0 || i + 1 == options.scans) {
      Window w;
      w.scans = i + 1;
      w.sim_time_s = stamp_s + scan_period_s;
      w.cells_allocated = mapper.grid().allocatedTiles() * static_cast<std::uint64_t>(dog::CellGrid::kTileCells);
      w.rss_mb = rssMb();
      w.scan_wall_median_us = 1e6 * median(scan_wall);
      w.scan_median_us = 1e6 * quantile(&scan_cpu, 0.5);
      w.scan_p99_us = 1e6 * quantile(&scan_cpu, 0.99);
      w.step_median_ms = 1e3 * quantile(&step_cpu, 0.5);
      w.step_p99_ms = 1e3 * quantile(&step_cpu, 0.99);
      w.layers_ms = publications > 0 ? 1e3 * layers_cpu / publications : 0.0;
      w.map_us_per_scan = 1e6 * window_map_cpu / static_cast<double>(scan_cpu.size());
      const double now = wallSeconds();
      w.wall_s = now - window_start_wall;
      w.load = loadAverage();
      windows.push_back(w);
      writeCsvRow(std::cout, w);
      std::cout.flush();
      if (csv) {
        writeCsvRow(csv, w);
        csv.flush();  // a long run's windows are on disk as they come
      }
      scan_cpu.clear();
      scan_wall.clear();
      step_cpu.clear();
      layers_cpu = 0.0;
      publications = 0;
      window_map_cpu = 0.0;
      window_start_wall = now;
    }
  }
  if (csv) {
    csv.close();
    if (!csv) command_line.fail("writing " + options.csv + " failed");
  }

  // The explored area stopped growing after the last window in which cells were allocated.
  std::size_t explored = 0;
  for (std::size_t k = 1; k < windows.size(); ++k) {
    if (windows[k].cells_allocated != windows[k - 1].cells_allocated) explored = k;
  }
  const std::size_t looping = windows.size() - 1 - explored;
  const std::size_t compare = static_cast<std::size_t>(options.compare_windows);
  std::printf("layers published: %llu full grids, %llu updates, %.1f MB serialized\n",
              static_cast<unsigned long long>(layers.fullGrids()), static_cast<unsigned long long>(layers.updates()),
              layers.bytes() / 1e6);
  std::printf("exploration: cells allocated last grew in the window ending at scan %lld (%llu cells, %.1f laps); "
              "%zu looping windows after it\n",
              static_cast<long long>(windows[explored].scans),
              static_cast<unsigned long long>(windows[explored].cells_allocated),
              static_cast<double>(windows[explored].scans) / lap_scans, looping);
  if (looping < 2 * compare) {
    std::printf("verdict: FAIL: fewer than %zu looping windows (the explored area grew until late in the run)\n",
                2 * compare);
    return 1;
  }
  const double rss_start = windows[explored].rss_mb;
  const double rss_end = windows.back().rss_mb;
  double rss_max = rss_start;
  for (std::size_t k = explored; k < windows.size(); ++k) rss_max = std::max(rss_max, windows[k].rss_mb);
  const double rss_growth = 100.0 * (rss_end - rss_start) / rss_start;
  // The least disturbed of `compare` windows at each end: on a shared machine other
  // processes only ever add to a window's time (caches, memory bandwidth, the host's other
  // vCPUs: this VM has no hardware counters to count instructions instead), while a real
  // growth would raise every window.
  const auto ends = [&](double Window::*field) {
    std::vector<double> first;
    std::vector<double> last;
    for (std::size_t k = 0; k < compare; ++k) {
      first.push_back(windows[explored + 1 + k].*field);
      last.push_back(windows[windows.size() - compare + k].*field);
    }
    return std::array<double, 2>{*std::min_element(first.begin(), first.end()),
                                 *std::min_element(last.begin(), last.end())};
  };
  const std::array<double, 2> scan_time = ends(&Window::scan_median_us);
  const std::array<double, 2> map_time = ends(&Window::map_us_per_scan);
  const double scan_growth = 100.0 * (scan_time[1] - scan_time[0]) / scan_time[0];
  const double map_growth = 100.0 * (map_time[1] - map_time[0]) / map_time[0];
  std::printf("RSS after exploration: %.2f MB -> %.2f MB at the end (max %.2f MB): %+.2f MB, %+.2f %% (bound %.1f %%)\n",
              rss_start, rss_end, rss_max, rss_end - rss_start, rss_growth, options.max_rss_growth_percent);
  std::printf("per-scan CPU, lowest window median of the first / last %zu looping windows: %.1f us -> %.1f us, %+.1f %% "
              "(bound %.0f %%)\n",
              compare, scan_time[0], scan_time[1], scan_growth, options.max_time_growth_percent);
  std::printf("map CPU per scan (integrate + steps + layers), lowest window of each end: %.1f us -> %.1f us, %+.1f %% "
              "(bound %.0f %%)\n",
              map_time[0], map_time[1], map_growth, options.max_time_growth_percent);
  const bool rss_ok = rss_growth <= options.max_rss_growth_percent;
  const bool time_ok = scan_growth <= options.max_time_growth_percent && map_growth <= options.max_time_growth_percent;
  std::printf("verdict: %s\n", rss_ok && time_ok ? "PASS (RSS and per-scan time flat after exploration)"
                                                 : (!rss_ok ? "FAIL: RSS grew beyond its bound"
                                                            : "FAIL: the time per scan grew beyond its bound"));
  return rss_ok && time_ok ? 0 : 1;
}
