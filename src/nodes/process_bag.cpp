// process_bag: runs the mapping pipeline over the laser scans of a bag, faster than real
// time, and writes the map layers as map_server files. See README.md, "process_bag".

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <iostream>
#include <sstream>
#include <string>
#include <unistd.h>
#include <vector>

#include "dynamic_occupancy_grid/core/layers.h"
#include "dynamic_occupancy_grid/core/map_export.h"
#include "dynamic_occupancy_grid/core/mapper.h"
#include "dynamic_occupancy_grid/ros/bag_scan_source.h"

namespace dog = dynamic_occupancy_grid;

namespace {

const char* const kUsage =
    "usage: process_bag BAG [options]\n"
    "  --topic NAME          LaserScan topic (default /scan)\n"
    "  --fixed-frame NAME    frame the map is built in (default odom)\n"
    "  --laser-pose X,Y,YAW  static laser pose in the fixed frame (m, m, rad); tf is not\n"
    "                        read (for bags recorded without tf)\n"
    "  --resolution M        cell size in metres (default 0.05)\n"
    "  --time-step S         HMM time step in seconds (default 1.0)\n"
    "  --out DIR             output directory (default ./dynamic_occupancy_grid_output)\n";

struct Options {
  dog::ros_layer::BagScanSourceOptions source;
  dog::core::MapperConfig mapper;
  std::string out_dir = "dynamic_occupancy_grid_output";
};

[[noreturn]] void usageError(const std::string& message) {
  std::cerr << "process_bag: " << message << "\n" << kUsage;
  std::exit(2);
}

double parseNumber(const std::string& option, const std::string& text) {
  std::size_t used = 0;
  double value = 0.0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() || !std::isfinite(value)) usageError(option + " expects a number, got '" + text + "'");
  return value;
}

Options parseArguments(int argc, char** argv) {
  Options options;
  std::vector<std::string> args(argv + 1, argv + argc);
  for (std::size_t i = 0; i < args.size(); ++i) {
    const std::string& arg = args[i];
    const auto value = [&]() -> const std::string& {
      if (i + 1 >= args.size()) usageError(arg + " needs a value");
      return args[++i];
    };
    if (arg == "-h" || arg == "--help") {
      std::cout << kUsage;
      std::exit(0);
    } else if (arg == "--topic") {
      options.source.scan_topic = value();
    } else if (arg == "--fixed-frame") {
      options.source.fixed_frame = value();
    } else if (arg == "--laser-pose") {
      std::stringstream parts(value());
      std::string item;
      std::vector<double> numbers;
      while (std::getline(parts, item, ',')) numbers.push_back(parseNumber(arg, item));
      if (numbers.size() != 3) usageError("--laser-pose expects X,Y,YAW");
      options.source.static_laser_pose = dog::core::Pose2D{numbers[0], numbers[1], numbers[2]};
    } else if (arg == "--resolution") {
      options.mapper.resolution_m = parseNumber(arg, value());
    } else if (arg == "--time-step") {
      options.mapper.time_step_s = parseNumber(arg, value());
    } else if (arg == "--out") {
      options.out_dir = value();
    } else if (!arg.empty() && arg[0] == '-') {
      usageError("unknown option " + arg);
    } else if (options.source.bag_path.empty()) {
      options.source.bag_path = arg;
    } else {
      usageError("more than one bag given");
    }
  }
  if (options.source.bag_path.empty()) usageError("no bag given");
  return options;
}

void showProgress(double fraction) {
  if (!isatty(STDERR_FILENO)) return;
  const int width = 40;
  const int filled = static_cast<int>(std::lround(fraction * width));
  std::fprintf(stderr, "\r[%s%s] %3d%%", std::string(filled, '#').c_str(),
               std::string(width - filled, ' ').c_str(), static_cast<int>(std::lround(fraction * 100)));
  if (fraction >= 1.0) std::fputc('\n', stderr);
}

}  // namespace

int main(int argc, char** argv) {
  const Options options = parseArguments(argc, argv);
  try {
    dog::core::Mapper mapper(options.mapper);
    dog::ros_layer::BagScanSource source(options.source);
    std::size_t integrated = 0;
    std::size_t rejected = 0;
    std::size_t beams_hit = 0;
    std::size_t beams_no_return = 0;
    std::size_t beams_ignored = 0;
    std::string last_rejection;
    const auto start = std::chrono::steady_clock::now();
    const dog::ros_layer::BagScanStats stats = source.forEachScan(
        [&](const dog::core::Scan& scan) {
          const dog::core::ScanResult result = mapper.integrate(scan);
          if (result.status != dog::core::ScanStatus::kIntegrated) {
            ++rejected;
            last_rejection = result.error;
            return;
          }
          ++integrated;
          beams_hit += result.beams_hit;
          beams_no_return += result.beams_no_return;
          beams_ignored += result.beams_ignored;
        },
        showProgress);
    mapper.finishStep();
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

    std::printf("scans read: %zu, integrated: %zu, rejected: %zu", stats.scans_read, integrated, rejected);
    if (options.source.static_laser_pose) {
      std::printf(" (static laser pose given, tf not read)\n");
    } else {
      std::printf(", without a pose in '%s': %zu\n", options.source.fixed_frame.c_str(), stats.scans_without_pose);
    }
    if (rejected > 0) std::printf("  last rejection: %s\n", last_rejection.c_str());
    if (stats.scans_without_pose > 0) std::printf("  last tf error: %s\n", stats.last_pose_error.c_str());
    std::printf("beams: %zu hits, %zu without return, %zu ignored (NaN, -inf, < range_min)\n",
                beams_hit, beams_no_return, beams_ignored);
    if (!mapper.lastAppliedStep()) {
      std::fprintf(stderr, "process_bag: no scan could be integrated; nothing to write\n");
      return 1;
    }
    std::printf("time steps: %lld of %.3f s; bag %.1f s processed in %.2f s (%.0fx real time)\n",
                static_cast<long long>(*mapper.lastAppliedStep() + 1), options.mapper.time_step_s,
                stats.bag_duration_s, seconds, seconds > 0.0 ? stats.bag_duration_s / seconds : 0.0);

    std::filesystem::create_directories(options.out_dir);
    const dog::core::CellBox box = mapper.grid().bounds();
    const dog::core::MapWindow window = mapper.grid().window(box);
    std::vector<float> values;
    std::vector<std::int8_t> occupancy;
    for (const dog::core::Layer layer : {dog::core::Layer::kBelief, dog::core::Layer::kStatic}) {
      dog::core::evaluateLayer(mapper.grid(), layer, *mapper.lastAppliedStep(), 0, box, &values);
      dog::core::toOccupancyValues(values, 1.0f, &occupancy);
      std::size_t known = 0;
      std::size_t occupied = 0;
      for (const std::int8_t value : occupancy) {
        known += value >= 0 ? 1 : 0;
        occupied += value >= 65 ? 1 : 0;
      }
      const std::string name = dog::core::layerName(layer);
      dog::core::writeMapServerFiles(options.out_dir, name, window, occupancy);
      std::printf("%-10s %lld x %lld cells, %zu observed, %zu occupied -> %s/%s.pgm\n", name.c_str(),
                  static_cast<long long>(box.width()), static_cast<long long>(box.height()), known,
                  occupied, options.out_dir.c_str(), name.c_str());
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "process_bag: %s\n", e.what());
    return 1;
  }
  return 0;
}
