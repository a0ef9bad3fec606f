#include "dynamic_occupancy_grid/evaluation/memory_experiment.h"

#include "dynamic_occupancy_grid/core/common/parallel.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <numeric>
#include <optional>
#include <stdexcept>

#include "dynamic_occupancy_grid/evaluation/evaluation.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/grid/scan_beams.h"

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

void require(bool ok, const std::string& message) {
  if (!ok) throw std::invalid_argument(message);
}

// Accumulated factors stay within these bounds: a long run of penalties must not underflow
// a hypothesis out of reach for good.
constexpr double kMinFactor = 1e-6;
constexpr double kMaxFactor = 1e6;

bool contains(const std::vector<core::CellXY>& cells, core::CellXY c) {
  return std::find(cells.begin(), cells.end(), c) != cells.end();
}

bool wallCell(const DividersLayout& layout, const World& world, std::int32_t x, std::int32_t y) {
  if (x <= 0 || y <= 0 || x >= world.width() - 1 || y >= world.height() - 1) return true;
  return x == layout.wall_x && layout.dividerAt(x, y) < 0;
}

// What the memory robot's migrations were, judged against the truth of the update's time.
class MigrationJudge {
 public:
  explicit MigrationJudge(const World& world)
      : width_(world.width()), person_seen_(static_cast<std::size_t>(world.width()) * world.height(), 0) {}

  // People's cells at a scan of the current view.
  void sawPeople(const std::vector<core::CellXY>& people) {
    for (const core::CellXY& p : people) person_seen_[index(p)] = 1;
  }

  void judge(const core::MemoryUpdate& update, const DividersLayout& layout, const World& world, MemoryRepetition* out,
             bool base) {
    bool divider_configuration = false;
    for (const core::CellXY& c : update.migrated) {
      const int divider = layout.dividerAt(c.x, c.y);
      const bool structure = wallCell(layout, world, c.x, c.y) ||
                             (divider >= 0 && layout.closed[static_cast<std::size_t>(divider)] != 0);
      if (structure) {
        if (divider >= 0) {
          ++out->divider_cells_in_ltm;
          divider_configuration = true;
        }
      } else if (person_seen_[index(c)] != 0) {
        ++out->people_in_ltm;
      } else {
        ++out->other_non_structure_in_ltm;
      }
    }
    if (update.configuration && !base) {
      ++out->configurations;
      if (divider_configuration) ++out->divider_configurations;
    }
    std::fill(person_seen_.begin(), person_seen_.end(), 0);
  }

 private:
  std::size_t index(const core::CellXY& c) const {
    return static_cast<std::size_t>(c.y) * static_cast<std::size_t>(width_) + static_cast<std::size_t>(c.x);
  }
  std::int32_t width_;
  std::vector<std::uint8_t> person_seen_;
};

// What the mapping phase recorded at each scan: the scan, and the truth the judge needs.
struct MappingRecord {
  core::Scan scan;
  std::vector<core::CellXY> people;
  std::vector<std::uint8_t> closed;
};

core::MapperConfig staticConfig(const ScenarioConfig& scenario) {
  core::MapperConfig config = evaluationMapperConfig(scenario);
  config.learn_transitions = false;
  config.static_clamp = core::LogOddsClamp{-1e6, 1e6};  // the textbook grid (Method::kStaticUnclamped)
  return config;
}

struct Robot {
  NavigationMethod method;
  std::optional<Simulation> simulation;
  std::unique_ptr<core::Mapper> mapper;       // static, hmm
  std::unique_ptr<core::MemoryModel> memory;  // memory
  std::unique_ptr<MigrationJudge> judge;
  std::unique_ptr<HypothesisSelector> selector;
  AStarPlanner planner;
  core::CellXY cell;
  double yaw_rad = 0.0;
};

class RepetitionRunner {
 public:
  RepetitionRunner(const ScenarioConfig& scenario, const MemoryExperimentConfig& config, std::size_t repetition)
      : scenario_(scenario), config_(config), repetition_(repetition) {}

  MemoryRepetition run() {
    const std::uint64_t world_seed = mixSeed(config_.seed * 1000003ULL + repetition_ + 0x6d656dULL);
    const std::uint64_t run_seed = mixSeed(world_seed ^ 0x6c746dULL);
    Simulation simulation(scenario_, world_seed, run_seed);
    layout_ = simulation.dividersLayout();
    period_ = scenario_.divider_period_steps;
    MemoryRepetition out;

    // 1. Initial mapping by an oracle driver; the scans are replayed into every method's map.
    std::vector<MappingRecord> records;
    core::CellXY cell = layout_.a;
    double yaw = 0.0;
    for (int e = 0; e < config_.mapping_episodes; ++e) {
      const core::CellXY goal = e % 2 == 0 ? layout_.b : layout_.a;
      for (std::int64_t k = 0; k < period_; ++k) {
        if (!(cell == goal)) {
          records.push_back(MappingRecord{simulation.scanFrom(pose(cell, yaw)), simulation.dividersLayout().people,
                                          simulation.dividersLayout().closed});
          const std::vector<core::CellXY> path = planner_.plan(structureGrid(simulation), cell, goal);
          if (path.size() >= 2 && !simulation.world().occupied(path[1].x, path[1].y)) move(cell, yaw, path[1]);
        }
        simulation.advance();
      }
      cell = goal;
    }
    // The memory model's base map: every update of the mapping phase (counted on a copy).
    core::MemoryModelConfig memory_config = config_.memory;
    memory_config.resolution_m = scenario_.resolution_m;
    memory_config.origin_x_m = 0.0;
    memory_config.origin_y_m = 0.0;
    memory_config.initial_mapping_updates = 0;
    {
      core::MemoryModel counter(memory_config);
      for (const MappingRecord& record : records) counter.integrate(record.scan);
      memory_config.initial_mapping_updates = static_cast<int>(counter.updates()) + 1;
    }

    std::vector<std::unique_ptr<Robot>> robots;
    for (const NavigationMethod method : kAllNavigationMethods) {
      auto robot = std::make_unique<Robot>();
      robot->method = method;
      robot->simulation.emplace(simulation);
      robot->cell = cell;
      if (method == NavigationMethod::kMemory) {
        robot->memory = std::make_unique<core::MemoryModel>(memory_config);
        robot->judge = std::make_unique<MigrationJudge>(simulation.world());
        robot->selector = std::make_unique<HypothesisSelector>(config_.penalty, config_.reward);
        for (const MappingRecord& record : records) {
          robot->judge->sawPeople(record.people);
          const core::MemoryScanResult result = robot->memory->integrate(record.scan);
          if (result.update) judgeUpdate(*robot, *result.update, record.closed, &out);
        }
        judgeUpdate(*robot, robot->memory->update(), records.empty() ? layout_.closed : records.back().closed, &out);
        refreshHypotheses(*robot);
      } else {
        robot->mapper = std::make_unique<core::Mapper>(method == NavigationMethod::kHmm
                                                     ? evaluationMapperConfig(scenario_)
                                                     : staticConfig(scenario_));
        for (const MappingRecord& record : records) {
          robot->mapper->integrate(record.scan);
          robot->mapper->finishStep();
        }
      }
      robots.push_back(std::move(robot));
    }

    // 2. Scored episodes, each robot on its own copy of the world.
    std::vector<std::uint8_t> closed_before = simulation.dividersLayout().closed;
    for (int e = 0; e < config_.episodes; ++e) {
      const bool forward = (config_.mapping_episodes + e) % 2 == 0;
      const core::CellXY goal = forward ? layout_.b : layout_.a;
      const std::vector<std::uint8_t>& closed = robots.front()->simulation->dividersLayout().closed;
      for (std::size_t p = 0; p < closed.size(); ++p) out.divider_moves += closed[p] != closed_before[p] ? 1 : 0;
      closed_before = closed;
      for (std::size_t m = 0; m < robots.size(); ++m) out.episodes[m].push_back(runEpisode(*robots[m], goal, &out));
    }
    out.memory_updates = robots.back()->memory->updates();
    return out;
  }

 private:
  core::Pose2D pose(core::CellXY cell, double yaw) const {
    const double r = scenario_.resolution_m;
    return core::Pose2D{(cell.x + 0.5) * r, (cell.y + 0.5) * r, yaw};
  }

  static void move(core::CellXY& cell, double& yaw, core::CellXY next) {
    yaw = std::atan2(static_cast<double>(next.y - cell.y), static_cast<double>(next.x - cell.x));
    cell = next;
  }

  // The true structure now (walls, closed dividers), people left out.
  const BlockedGrid& structureGrid(const Simulation& simulation) {
    const World& world = simulation.world();
    if (!structure_) structure_.emplace(world.width(), world.height());
    for (std::int32_t y = 0; y < world.height(); ++y) {
      for (std::int32_t x = 0; x < world.width(); ++x) structure_->setBlocked(x, y, simulation.isStructure(x, y));
    }
    return *structure_;
  }

  void judgeUpdate(Robot& robot, const core::MemoryUpdate& update, const std::vector<std::uint8_t>& closed,
                   MemoryRepetition* out) const {
    DividersLayout at_update = layout_;
    at_update.closed = closed;
    const bool base = update.index < robot.memory->config().initial_mapping_updates;
    robot.judge->judge(update, at_update, robot.simulation->world(), out, base);
  }

  void refreshHypotheses(Robot& robot) const {
    const World& world = robot.simulation->world();
    core::CellBox box;
    box.include(0, 0);
    box.include(world.width() - 1, world.height() - 1);
    std::vector<core::MapHypothesis> hypotheses = robot.memory->hypotheses();
    std::vector<BlockedGrid> grids;
    for (const core::MapHypothesis& hypothesis : hypotheses) {
      const std::vector<std::int8_t> values = robot.memory->hypothesisGrid(hypothesis, box);
      BlockedGrid grid(world.width(), world.height());
      for (std::int32_t y = 0; y < world.height(); ++y) {
        for (std::int32_t x = 0; x < world.width(); ++x) {
          grid.setBlocked(x, y, values[grid.index(x, y)] == core::kGridOccupied);
        }
      }
      grids.push_back(std::move(grid));
    }
    robot.selector->setHypotheses(std::move(hypotheses), std::move(grids));
  }

  // The static / hmm planning grid: the map's p(occ) > 0.5 overlaid with the live layer.
  void mapGrid(const Robot& robot, const LiveLayer& live, BlockedGrid* grid) const {
    const core::Mapper& mapper = *robot.mapper;
    const std::int64_t now = mapper.lastAppliedStep().value_or(0);
    for (std::int32_t y = 0; y < grid->height(); ++y) {
      for (std::int32_t x = 0; x < grid->width(); ++x) {
        const std::optional<core::CellState> cell = mapper.grid().cell(x, y);
        double p = 0.0;  // never observed: free
        if (cell) {
          if (robot.method == NavigationMethod::kStatic) {
            p = core::logOddsToProbability(cell->log_odds);
          } else {
            p = core::predictOccupancy(cell->p_occ,
                                       core::TransitionParams{cell->p_occ_given_free, cell->p_free_given_occ},
                                       now - cell->last_step);
          }
        }
        grid->setBlocked(x, y, p > 0.5);
      }
    }
    live.applyTo(*grid);
  }

  EpisodeRecord runEpisode(Robot& robot, core::CellXY goal, MemoryRepetition* out) {
    Simulation& simulation = *robot.simulation;
    const World& world = simulation.world();
    EpisodeRecord record;
    const std::vector<core::CellXY> optimal = planner_.plan(structureGrid(simulation), robot.cell, goal);
    record.optimal = optimal.empty() ? 0 : static_cast<std::int64_t>(optimal.size()) - 1;
    BlockedGrid grid(world.width(), world.height());
    std::vector<core::CellXY> plan;  // the plan being followed, from the robot's cell
    bool select = true;        // the memory robot re-selects its hypothesis (departure, new maps)
    for (std::int64_t k = 0; k < period_; ++k) {
      if (!(robot.cell == goal)) {
        const core::Scan scan = simulation.scanFrom(pose(robot.cell, robot.yaw_rad));
        const LiveLayer live = LiveLayer::fromScan(scan, world.resolution(), world.width(), world.height());
        if (robot.method == NavigationMethod::kMemory) {
          robot.judge->sawPeople(simulation.dividersLayout().people);
          const core::MemoryScanResult result = robot.memory->integrate(scan);
          if (result.update) {
            judgeUpdate(robot, *result.update, simulation.dividersLayout().closed, out);
            refreshHypotheses(robot);
            select = true;
          }
          HypothesisSelector& selector = *robot.selector;
          if (select) {
            selector.select(robot.cell, goal, live);
            select = false;
          }
          grid = selector.grid(selector.actioned());
          live.applyTo(grid);
          if (blockedAhead(plan, grid)) {
            ++record.replans;
            // Unexpected obstacles: cells ahead the scan sees occupied that the actioned
            // hypothesis holds free (Algorithm 1).
            std::vector<core::CellXY> obstacles;
            const BlockedGrid& actioned = selector.grid(selector.actioned());
            for (std::size_t i = 1; i < plan.size(); ++i) {
              const core::CellXY c = plan[i];
              if (!actioned.blocked(c.x, c.y) && contains(live.occupied, c)) {
                obstacles.push_back(c);
              }
            }
            if (!obstacles.empty() && selector.reportObstacles(obstacles)) {
              const std::size_t before = selector.actioned();
              selector.select(robot.cell, goal, live);
              if (selector.actioned() != before) ++out->hypothesis_switches;
            }
          }
          plan = selector.plan(robot.cell, goal, live);
          if (plan.empty()) plan = selector.select(robot.cell, goal, live);
        } else {
          robot.mapper->integrate(scan);
          robot.mapper->finishStep();
          mapGrid(robot, live, &grid);
          if (blockedAhead(plan, grid)) ++record.replans;
          plan = robot.planner.plan(grid, robot.cell, goal);
        }
        if (plan.size() >= 2 && !world.occupied(plan[1].x, plan[1].y)) {
          move(robot.cell, robot.yaw_rad, plan[1]);
          plan.erase(plan.begin());
          ++record.moves;
        }
      }
      simulation.advance();
    }
    record.reached = robot.cell == goal;
    robot.cell = goal;  // a failed episode: the next starts where it should
    return record;
  }

  // Whether a cell of `plan` after the robot's (plan[0]) is blocked in `grid`.
  static bool blockedAhead(const std::vector<core::CellXY>& plan, const BlockedGrid& grid) {
    for (std::size_t i = 1; i < plan.size(); ++i) {
      if (grid.blocked(plan[i].x, plan[i].y)) return true;
    }
    return false;
  }

  const ScenarioConfig& scenario_;
  const MemoryExperimentConfig& config_;
  std::size_t repetition_;
  DividersLayout layout_;
  std::int64_t period_ = 0;
  AStarPlanner planner_;
  std::optional<BlockedGrid> structure_;
};

std::size_t methodIndex(NavigationMethod method) {
  for (std::size_t m = 0; m < kAllNavigationMethods.size(); ++m) {
    if (kAllNavigationMethods[m] == method) return m;
  }
  throw std::invalid_argument("memory experiment: unknown method");
}

}  // namespace

std::string navigationMethodName(NavigationMethod method) {
  switch (method) {
    case NavigationMethod::kStatic:
      return "static";
    case NavigationMethod::kHmm:
      return "hmm";
    case NavigationMethod::kMemory:
      return "memory";
  }
  return "unknown";
}

// ---------------------------------------------------------------- LiveLayer

LiveLayer LiveLayer::fromScan(const core::Scan& scan, double resolution_m, std::int32_t width, std::int32_t height) {
  LiveLayer layer;
  BlockedGrid seen(width, height);  // cells already listed
  const auto inside = [&](std::int32_t x, std::int32_t y) { return x >= 0 && y >= 0 && x < width && y < height; };
  const double u0 = scan.laser_pose.x_m / resolution_m;
  const double v0 = scan.laser_pose.y_m / resolution_m;
  // The reading rules of every map (scan_beams.h); a beam without return clears up to range_max.
  core::BeamRules rules;
  rules.cells_per_m = 1.0 / resolution_m;
  rules.max_free_range_m = scan.range_max_m;
  rules.max_beam_m = std::numeric_limits<double>::infinity();
  std::vector<core::BeamEnd> beams;
  core::BeamCounts counts;
  core::CellBox box;
  if (core::beamEnds(scan, u0, v0, rules, beams, counts, box)) {
    throw std::invalid_argument("LiveLayer: a beam ends too far from the origin");
  }
  std::vector<core::CellXY> ends;
  for (const core::BeamEnd& beam : beams) {
    const core::CellXY end = core::traverseSegment(u0, v0, beam.u1, beam.v1, [&](std::int32_t x, std::int32_t y) {
      if (!inside(x, y) || seen.blocked(x, y)) return;
      seen.setBlocked(x, y, true);
      layer.free.push_back(core::CellXY{x, y});
    });
    if (beam.hit && inside(end.x, end.y) && !contains(ends, end)) ends.push_back(end);
  }
  layer.occupied = std::move(ends);
  return layer;
}

void LiveLayer::applyTo(BlockedGrid& grid) const {
  for (const core::CellXY& c : free) {
    if (grid.inside(c.x, c.y)) grid.setBlocked(c.x, c.y, false);
  }
  for (const core::CellXY& c : occupied) {
    if (grid.inside(c.x, c.y)) grid.setBlocked(c.x, c.y, true);
  }
}

// ---------------------------------------------------------------- HypothesisSelector

HypothesisSelector::HypothesisSelector(double penalty, double reward) : penalty_(penalty), reward_(reward) {
  require(penalty > 0.0 && penalty <= 1.0, "HypothesisSelector: penalty must be in (0, 1]");
  require(reward >= 1.0 && std::isfinite(reward), "HypothesisSelector: reward must be >= 1");
}

void HypothesisSelector::setHypotheses(std::vector<core::MapHypothesis> hypotheses, std::vector<BlockedGrid> grids) {
  require(hypotheses.size() == grids.size(), "HypothesisSelector: one grid per hypothesis");
  hypotheses_ = std::move(hypotheses);
  grids_ = std::move(grids);
  actioned_ = 0;
}

double& HypothesisSelector::factor(std::size_t h) {
  return factors_.try_emplace(hypotheses_.at(h).configurations, 1.0).first->second;
}

double HypothesisSelector::score(std::size_t h) const {
  const auto it = factors_.find(hypotheses_.at(h).configurations);
  return hypotheses_[h].weight * (it == factors_.end() ? 1.0 : it->second);
}

std::vector<core::CellXY> HypothesisSelector::select(core::CellXY start, core::CellXY goal, const LiveLayer& live) {
  if (hypotheses_.empty()) throw std::logic_error("HypothesisSelector::select: no hypotheses");
  std::vector<std::size_t> order(hypotheses_.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::stable_sort(order.begin(), order.end(), [this](std::size_t a, std::size_t b) { return score(a) > score(b); });
  for (const std::size_t h : order) {
    actioned_ = h;
    std::vector<core::CellXY> path = plan(start, goal, live);
    if (!path.empty()) return path;
  }
  actioned_ = order.front();
  return {};
}

std::vector<core::CellXY> HypothesisSelector::plan(core::CellXY start, core::CellXY goal, const LiveLayer& live) {
  BlockedGrid grid = grids_.at(actioned_);
  live.applyTo(grid);
  return planner_.plan(grid, start, goal);
}

bool HypothesisSelector::reportObstacles(const std::vector<core::CellXY>& obstacles) {
  std::vector<std::size_t> predicted;
  for (std::size_t h = 0; h < hypotheses_.size(); ++h) {
    if (h == actioned_) continue;
    for (const core::CellXY& c : obstacles) {
      if (grids_[h].blocked(c.x, c.y)) {
        predicted.push_back(h);
        break;
      }
    }
  }
  if (predicted.empty()) return false;
  double& actioned = factor(actioned_);
  actioned = std::max(kMinFactor, actioned * penalty_);
  // Hypotheses sharing a configuration set share a factor: reward each set once.
  std::vector<const std::vector<std::uint32_t>*> rewarded;
  for (const std::size_t h : predicted) {
    const std::vector<std::uint32_t>& key = hypotheses_[h].configurations;
    if (std::find_if(rewarded.begin(), rewarded.end(), [&](const auto* k) { return *k == key; }) != rewarded.end()) {
      continue;
    }
    rewarded.push_back(&key);
    double& f = factor(h);
    f = std::min(kMaxFactor, f * reward_);
  }
  return true;
}

// ---------------------------------------------------------------- experiment

void MemoryExperimentConfig::validate() const {
  require(repetitions > 0, "memory experiment: repetitions must be positive");
  require(mapping_episodes >= 0, "memory experiment: mapping_episodes must not be negative");
  require(episodes > 0, "memory experiment: episodes must be positive");
  require(penalty > 0.0 && penalty <= 1.0, "memory experiment: penalty must be in (0, 1]");
  require(reward >= 1.0 && std::isfinite(reward), "memory experiment: reward must be >= 1");
  memory.validate();
}

MeanStd MemoryExperimentResult::perRepetition(const std::function<double(const MemoryRepetition&)>& value) const {
  std::vector<double> values;
  for (const MemoryRepetition& repetition : repetitions) values.push_back(value(repetition));
  return meanStd(values);
}

MeanStd MemoryExperimentResult::goalReachedPercent(NavigationMethod method) const {
  const std::size_t m = methodIndex(method);
  return perRepetition([m](const MemoryRepetition& r) {
    const auto& episodes = r.episodes[m];
    const auto reached = std::count_if(episodes.begin(), episodes.end(), [](const EpisodeRecord& e) { return e.reached; });
    return 100.0 * static_cast<double>(reached) / static_cast<double>(episodes.size());
  });
}

MeanStd MemoryExperimentResult::pathRatio(NavigationMethod method) const {
  const std::size_t m = methodIndex(method);
  std::vector<double> values;
  for (const MemoryRepetition& r : repetitions) {
    double sum = 0.0;
    int count = 0;
    for (const EpisodeRecord& e : r.episodes[m]) {
      if (!e.reached || e.optimal <= 0) continue;
      sum += static_cast<double>(e.moves) / static_cast<double>(e.optimal);
      ++count;
    }
    if (count > 0) values.push_back(sum / count);
  }
  return meanStd(values);
}

MeanStd MemoryExperimentResult::replansPerEpisode(NavigationMethod method) const {
  const std::size_t m = methodIndex(method);
  return perRepetition([m](const MemoryRepetition& r) {
    double sum = 0.0;
    for (const EpisodeRecord& e : r.episodes[m]) sum += e.replans;
    return sum / static_cast<double>(r.episodes[m].size());
  });
}

MemoryExperimentResult runMemoryExperiment(const ScenarioConfig& dividers, const MemoryExperimentConfig& config,
                                           const std::function<void(int done)>& progress) {
  dividers.validate();
  require(dividers.kind == ScenarioKind::kDividers,
          "memory experiment: scenario " + dividers.name + " is not a dividers scenario");
  config.validate();
  const auto start = std::chrono::steady_clock::now();
  MemoryExperimentResult result;
  result.repetitions.resize(static_cast<std::size_t>(config.repetitions));
  core::runRepetitions(
      result.repetitions.size(), config.threads,
      [&](std::size_t r) { result.repetitions[r] = RepetitionRunner(dividers, config, r).run(); }, progress);
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

std::string formatMemoryTable(const MemoryExperimentResult& result) {
  const auto pm = [](const MeanStd& v, int digits) {
    char text[64];
    std::snprintf(text, sizeof(text), "%.*f ± %.*f", digits, v.mean, digits, v.std);
    return std::string(text);
  };
  std::string out = "| method | goal reached (%) | path / optimal | replans per episode |\n|---|---|---|---|\n";
  for (const NavigationMethod method : kAllNavigationMethods) {
    out += "| " + navigationMethodName(method) + " | " + pm(result.goalReachedPercent(method), 1) + " | " +
           pm(result.pathRatio(method), 3) + " | " + pm(result.replansPerEpisode(method), 2) + " |\n";
  }
  const auto count = [&](std::size_t MemoryRepetition::*field) {
    return result.perRepetition([field](const MemoryRepetition& r) { return static_cast<double>(r.*field); });
  };
  out += "\nMemory model, per repetition: people cells in LTM " + pm(count(&MemoryRepetition::people_in_ltm), 2) +
         ", other non-structure cells in LTM " + pm(count(&MemoryRepetition::other_non_structure_in_ltm), 2) +
         ", divider cells in LTM " + pm(count(&MemoryRepetition::divider_cells_in_ltm), 1) +
         ", configurations " + pm(count(&MemoryRepetition::configurations), 1) + " (with divider cells " +
         pm(count(&MemoryRepetition::divider_configurations), 1) + ").\n";
  return out;
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
