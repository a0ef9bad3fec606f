// write_model_cli: a small test tool that maps a scripted, deterministic run (a square room
// with a pillar that circles, the laser wandering near the middle), saves the model with
// core::saveModel and writes what the mapper holds as text, so that a reader of the file
// (test/python/test_read_model.py for scripts/read_model.py) can be checked against the C++
// values exactly. Not installed; built by test/core_standalone.
//
// Usage: write_model_cli [--fixed | --empty | --cell-em] MODEL_PATH VALUES_PATH
//   (default)  a growing map that learns transitions with kinds of cells (configured apart
//              from the defaults; pairs across gaps fill several distance bins), 30 steps
//              with gaps
//   --cell-em  the same map learning with each cell's own online EM (kinds' defaults)
//   --fixed    a fixed-bounds map (partly outside the room) with fixed transitions
//   --empty    a growing map that has seen nothing
//
// VALUES_PATH, read from the mapper (not from the file), every float and double written
// with %a (hexadecimal, exact; Python's float.fromhex reads it):
//   lines "# config NAME VALUE" for every MapperConfig field (nested names with dots, a
//   kind's index as a name, booleans 0/1, choices by name), "# clock_origin_s VALUE|none",
//   "# last_applied_step VALUE|none", "# sensor_model_stats TRIALS_OCC TRIALS_FREE HITS_OCC
//   HITS_FREE", "# kind_sums" with the kinds' 5 x 124 x 4 expected pairs ([kind][bin][2 i + j],
//   i the state then, j now), 5 memberships and cells, "# kind_transitions" with the kinds'
//   learned transitions (p_occ_given_free, p_free_given_occ per kind), "# gap_bin_steps"
//   with gapBinSteps of every bin, "# gap_bin" with STEPS:BIN for some distances, "# cells N",
//   then the header line
//   x,y,p_occ,last_step,log_odds,p_occ_given_free,p_free_given_occ,learner_state_0,...,
//   learner_state_9,observed_steps,last_hits,last_misses
//   and one line per observed cell, by row (y) then column (x).
//
// Exit status: 0 done, 2 usage, 3 a library error (message on stderr).

#include <algorithm>
#include <cerrno>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/layers/model_io.h"

namespace dog = dynamic_occupancy_grid::core;

namespace {

constexpr double kPi = 3.14159265358979323846;

// Range from (x, y) along (c, s) to the walls of [-half, half]^2 or a pillar of radius r.
double rayRange(double x, double y, double c, double s, double half, double px, double py, double r) {
  double range = std::numeric_limits<double>::infinity();
  if (c > 1e-12) range = std::min(range, (half - x) / c);
  if (c < -1e-12) range = std::min(range, (-half - x) / c);
  if (s > 1e-12) range = std::min(range, (half - y) / s);
  if (s < -1e-12) range = std::min(range, (-half - y) / s);
  const double ox = x - px;
  const double oy = y - py;
  const double b = ox * c + oy * s;
  const double disc = b * b - (ox * ox + oy * oy - r * r);
  if (disc >= 0.0) {
    const double t = -b - std::sqrt(disc);
    if (t > 0.0) range = std::min(range, t);
  }
  return range;
}

dog::Scan roomScan(double stamp_s, int k) {
  dog::Scan scan;
  scan.stamp_s = stamp_s;
  scan.laser_pose.x_m = 0.3 * std::sin(0.37 * k);
  scan.laser_pose.y_m = 0.2 * std::cos(0.23 * k);
  scan.laser_pose.yaw_rad = 0.05 * k;
  const int beams = 180;
  scan.angle_min_rad = -kPi;
  scan.angle_increment_rad = 2.0 * kPi / beams;
  scan.range_min_m = 0.05;
  scan.range_max_m = 6.0;
  const double pillar_x = 1.2 * std::cos(0.5 * k);
  const double pillar_y = 1.2 * std::sin(0.5 * k);
  for (int i = 0; i < beams; ++i) {
    const double angle = scan.laser_pose.yaw_rad + scan.angle_min_rad + i * scan.angle_increment_rad;
    double range = rayRange(scan.laser_pose.x_m, scan.laser_pose.y_m, std::cos(angle), std::sin(angle), 2.4,
                            pillar_x, pillar_y, 0.25);
    if ((i + k) % 17 == 0) range = std::numeric_limits<double>::infinity();
    scan.ranges_m.push_back(static_cast<float>(range));
  }
  return scan;
}

dog::MapperConfig growingConfig() {
  dog::MapperConfig config;
  config.resolution_m = 0.05;
  config.time_step_s = 0.5;
  config.prior_transitions = dog::TransitionParams{0.02, 0.03};
  config.learn_transitions = true;
  config.online_em.prior_weight = 4.0;
  config.online_em.learning_rate_floor = 0.01;
  config.online_em.min_observed_steps = 3;
  config.learn_sensor_model = true;
  config.sensor_model_prior_weight = 30.0;
  config.initial_p_occ = 0.45;
  config.max_free_range_m = 3.5;
  config.origin_x_m = -0.35;
  config.origin_y_m = 0.2;
  config.max_map_size_m = 40.0;
  config.kinds.initial_transitions = {{{2e-4, 3e-4}, {3e-3, 1e-3}, {0.02, 0.015}, {0.06, 0.04}, {0.2, 0.3}}};
  config.kinds.initial_weights = {{0.7, 0.1, 0.08, 0.07, 0.05}};
  config.kinds.transition_prior_weight = 20.0;
  config.kinds.weight_prior_cells = 50.0;
  config.kinds.switch_probability = 2e-3;
  config.kinds.forgetting = 5e-3;
  return config;
}

dog::MapperConfig cellEmConfig() {
  dog::MapperConfig config = growingConfig();
  config.learner = dog::TransitionLearner::kCellEm;
  config.kinds = dog::KindsConfig{};
  return config;
}

dog::MapperConfig fixedConfig() {
  dog::MapperConfig config;
  config.resolution_m = 0.125;
  config.time_step_s = 0.3;
  config.learn_transitions = false;
  config.prior_transitions = dog::TransitionParams{0.1, 0.2};
  config.online_em.symmetric = true;
  config.initial_p_occ = 0.3;
  config.origin_x_m = -4.0;
  config.origin_y_m = -3.75;
  config.fixed_bounds = true;
  config.width_m = 7.0;
  config.height_m = 7.5;
  config.max_map_size_m = 8.0;
  return config;
}

// 30 steps, every third one without scans, three scans per step.
void run(dog::Mapper& mapper) {
  const double origin_s = 1700000000.25;
  const double dt = mapper.config().time_step_s;
  for (int step = 0; step < 30; ++step) {
    if (step % 3 == 2) continue;
    for (int part = 0; part < 3; ++part) {
      const dog::ScanResult result = mapper.integrate(roomScan(origin_s + (step + 0.1 + 0.4 * part) * dt, step * 3 + part));
      if (result.status != dog::ScanStatus::kIntegrated) throw std::runtime_error("scan rejected: " + result.error);
    }
  }
  mapper.finishStep();
}

void writeValues(const dog::Mapper& mapper, std::FILE* out) {
  const dog::MapperConfig& c = mapper.config();
  const auto real = [out](const char* name, double value) { std::fprintf(out, "# config %s %a\n", name, value); };
  const auto integer = [out](const char* name, long long value) { std::fprintf(out, "# config %s %lld\n", name, value); };
  real("resolution_m", c.resolution_m);
  real("time_step_s", c.time_step_s);
  real("p_hit_given_occ", c.p_hit_given_occ);
  real("p_hit_given_free", c.p_hit_given_free);
  real("prior_transitions.p_occ_given_free", c.prior_transitions.p_occ_given_free);
  real("prior_transitions.p_free_given_occ", c.prior_transitions.p_free_given_occ);
  integer("learn_transitions", c.learn_transitions);
  real("online_em.prior_weight", c.online_em.prior_weight);
  real("online_em.learning_rate_floor", c.online_em.learning_rate_floor);
  real("online_em.p_min", c.online_em.p_min);
  real("online_em.p_max", c.online_em.p_max);
  integer("online_em.symmetric", c.online_em.symmetric);
  integer("online_em.min_observed_steps", c.online_em.min_observed_steps);
  real("initial_p_occ", c.initial_p_occ);
  real("static_clamp.min_log_odds", c.static_clamp.min_log_odds);
  real("static_clamp.max_log_odds", c.static_clamp.max_log_odds);
  real("max_free_range_m", c.max_free_range_m);
  real("origin_x_m", c.origin_x_m);
  real("origin_y_m", c.origin_y_m);
  integer("fixed_bounds", c.fixed_bounds);
  real("width_m", c.width_m);
  real("height_m", c.height_m);
  real("max_map_size_m", c.max_map_size_m);
  integer("learn_sensor_model", c.learn_sensor_model);
  real("sensor_model_prior_weight", c.sensor_model_prior_weight);
  real("sensor_model_p_min", c.sensor_model_p_min);
  std::fprintf(out, "# config learner %s\n", c.learner == dog::TransitionLearner::kCellEm ? "cell_em" : "kinds");
  for (int k = 0; k < dog::kKindCount; ++k) {
    const std::string kind = std::to_string(k);
    real(("kinds.initial_transitions." + kind + ".p_occ_given_free").c_str(),
         c.kinds.initial_transitions[k].p_occ_given_free);
    real(("kinds.initial_transitions." + kind + ".p_free_given_occ").c_str(),
         c.kinds.initial_transitions[k].p_free_given_occ);
    real(("kinds.initial_weights." + kind).c_str(), c.kinds.initial_weights[k]);
  }
  real("kinds.transition_prior_weight", c.kinds.transition_prior_weight);
  real("kinds.weight_prior_cells", c.kinds.weight_prior_cells);
  real("kinds.switch_probability", c.kinds.switch_probability);
  real("kinds.forgetting", c.kinds.forgetting);
  const dog::SensorModelStats& stats = mapper.sensorModelStats();
  std::fprintf(out, "# sensor_model_stats %a %a %a %a\n", stats.trials[0], stats.trials[1], stats.hits[0],
               stats.hits[1]);
  const dog::CellKinds::Sums& sums = mapper.kinds().sums();
  std::fprintf(out, "# kind_sums");
  for (const auto& kind : sums.pairs) {
    for (const auto& bin : kind) {
      for (const double value : bin) std::fprintf(out, " %a", value);
    }
  }
  for (const double membership : sums.membership) std::fprintf(out, " %a", membership);
  std::fprintf(out, " %a\n", sums.cells);
  std::fprintf(out, "# kind_transitions");
  for (int k = 0; k < dog::kKindCount; ++k) {
    std::fprintf(out, " %a %a", mapper.kinds().transitions(k).p_occ_given_free,
                 mapper.kinds().transitions(k).p_free_given_occ);
  }
  std::fprintf(out, "\n# gap_bin_steps");
  for (int bin = 0; bin < dog::kGapBins; ++bin) std::fprintf(out, " %a", dog::gapBinSteps(bin));
  std::fprintf(out, "\n# gap_bin");
  // Every distance to 100, the edges of the bins beyond, and the far ends.
  std::vector<std::int64_t> distances;
  for (std::int64_t steps = 1; steps <= 100; ++steps) distances.push_back(steps);
  for (int bin = 17; bin < dog::kGapBins + 4; ++bin) {
    const auto edge = static_cast<std::int64_t>(std::ceil(16.0 * std::exp2((bin - 16) / 4.0)));
    for (const std::int64_t steps : {edge - 1, edge, edge + 1}) distances.push_back(steps);
  }
  for (const std::int64_t steps : {std::int64_t{1} << 40, std::numeric_limits<std::int64_t>::max()}) {
    distances.push_back(steps);
  }
  for (const std::int64_t steps : distances) std::fprintf(out, " %" PRId64 ":%d", steps, dog::gapBin(steps));
  std::fprintf(out, "\n");
  if (mapper.clock().origin()) {
    std::fprintf(out, "# clock_origin_s %a\n", *mapper.clock().origin());
  } else {
    std::fprintf(out, "# clock_origin_s none\n");
  }
  if (mapper.lastAppliedStep()) {
    std::fprintf(out, "# last_applied_step %" PRId64 "\n", *mapper.lastAppliedStep());
  } else {
    std::fprintf(out, "# last_applied_step none\n");
  }
  // The cells through CellGrid::cell, row by row over the bounds: independent of how
  // model_io walks the tiles.
  std::vector<std::string> lines;
  const dog::CellBox bounds = mapper.grid().bounds();
  if (!bounds.empty()) {
    for (std::int32_t y = bounds.min_y; y <= bounds.max_y; ++y) {
      for (std::int32_t x = bounds.min_x; x <= bounds.max_x; ++x) {
        const std::optional<dog::CellState> cell = mapper.grid().cell(x, y);
        if (!cell) continue;
        char line[1024];
        int used = std::snprintf(line, sizeof(line), "%d,%d,%a,%d,%a,%a,%a", x, y, cell->p_occ, cell->last_step,
                                 cell->log_odds, cell->p_occ_given_free, cell->p_free_given_occ);
        for (const float stat : cell->em_stats) {
          used += std::snprintf(line + used, sizeof(line) - static_cast<std::size_t>(used), ",%a", stat);
        }
        std::snprintf(line + used, sizeof(line) - static_cast<std::size_t>(used), ",%u,%u,%u",
                      static_cast<unsigned>(cell->observed_steps), static_cast<unsigned>(cell->last_hits),
                      static_cast<unsigned>(cell->last_misses));
        lines.emplace_back(line);
      }
    }
  }
  std::fprintf(out, "# cells %zu\n", lines.size());
  std::fprintf(out, "x,y,p_occ,last_step,log_odds,p_occ_given_free,p_free_given_occ");
  for (int k = 0; k < dog::kLearnerStateSize; ++k) std::fprintf(out, ",learner_state_%d", k);
  std::fprintf(out, ",observed_steps,last_hits,last_misses\n");
  for (const std::string& line : lines) std::fprintf(out, "%s\n", line.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  std::string mode = "growing";
  if (!args.empty() && (args[0] == "--fixed" || args[0] == "--empty" || args[0] == "--cell-em")) {
    mode = args[0].substr(2);
    args.erase(args.begin());
  }
  if (args.size() != 2) {
    std::fprintf(stderr, "usage: write_model_cli [--fixed | --empty | --cell-em] MODEL_PATH VALUES_PATH\n");
    return 2;
  }
  try {
    dog::Mapper mapper(mode == "fixed" ? fixedConfig() : mode == "cell-em" ? cellEmConfig() : growingConfig());
    if (mode != "empty") run(mapper);
    dog::saveModel(mapper, args[0]);
    std::FILE* out = std::fopen(args[1].c_str(), "w");
    if (out == nullptr) throw std::runtime_error("cannot open " + args[1] + ": " + std::strerror(errno));
    writeValues(mapper, out);
    if (std::fclose(out) != 0) throw std::runtime_error("cannot write " + args[1]);
  } catch (const std::exception& error) {
    std::fprintf(stderr, "write_model_cli: %s\n", error.what());
    return 3;
  }
  return 0;
}
