#include "dynamic_occupancy_grid/evaluation/murphy_doors.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "dynamic_occupancy_grid/core/common/parallel.h"
#include "dynamic_occupancy_grid/core/pose/resampling.h"
#include "dynamic_occupancy_grid/evaluation/simulator.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

namespace {

constexpr std::array<std::array<int, 2>, 4> kMoves{{{1, 0}, {0, 1}, {-1, 0}, {0, -1}}};  // E, N, W, S
constexpr int kValueIterations = 60;
constexpr double kExploration = 0.1;  ///< the entropy policy's share of random moves
/// H(L) is normalised by log of this many cells (and capped at 1): a cloud spread evenly over
/// ten cells is lost. Normalised over the whole grid (log 165), a cloud over ten cells was
/// H = 0.45, and the reward kept sending a robot that was losing itself to uncertain cells.
constexpr double kLostCells = 10.0;

double binaryEntropy(double p) {  // normalised: bits
  if (p <= 0.0 || p >= 1.0) return 0.0;
  return -(p * std::log2(p) + (1.0 - p) * std::log2(1.0 - p));
}

std::string fixed(double value, int digits) {
  std::ostringstream text;
  text << std::fixed << std::setprecision(digits) << value;
  return text.str();
}

/// One particle: the robot's cell and every cell's p(occ).
struct DoorsParticle {
  int cell = 0;
  std::vector<double> p_occ;
  double log_weight = 0.0;
};

class DoorsRunner {
 public:
  DoorsRunner(const DoorsLayout& layout, const DoorsWorldConfig& config, DoorsPolicy policy)
      : layout_(layout), config_(config), policy_(policy), world_rng_(mixSeed(config.seed ^ 0x776f726c64ULL)),
        robot_rng_(mixSeed(config.seed ^ 0x726f626f74ULL ^ (static_cast<std::uint64_t>(policy) << 40))) {
    const std::size_t cells = layout.cells.size();
    // The doors' first states: open or closed at random (the world's draws, the same for
    // both policies).
    occupied_.assign(cells, false);
    for (std::size_t i = 0; i < cells; ++i) {
      occupied_[i] = layout.cells[i] == DoorsCell::kWall ||
                     (layout.cells[i] == DoorsCell::kDoor && world_rng_.bernoulli(0.5));
      if (layout.cells[i] == DoorsCell::kDoor) doors_.push_back(static_cast<int>(i));
    }
    robot_ = layout.start;
    DoorsParticle first;
    first.cell = layout.start;
    first.p_occ.assign(cells, 0.5);
    first.p_occ[static_cast<std::size_t>(layout.start)] = 0.0;  // the robot stands there
    // The grid's edge is known, as the corridor's ends are in Murphy's 1D world.
    for (int x = 0; x < layout.width; ++x) {
      first.p_occ[static_cast<std::size_t>(x)] = 1.0;
      first.p_occ[static_cast<std::size_t>((layout.height - 1) * layout.width + x)] = 1.0;
    }
    for (int y = 0; y < layout.height; ++y) {
      first.p_occ[static_cast<std::size_t>(y * layout.width)] = 1.0;
      first.p_occ[static_cast<std::size_t>(y * layout.width + layout.width - 1)] = 1.0;
    }
    particles_.assign(static_cast<std::size_t>(config.particles), first);
    last_seen_.assign(doors_.size(), -1);
    result_.policy = policy;
    result_.visits.assign(cells, 0);
  }

  DoorsRun run() {
    const int half = config_.steps / 2;
    double door_right = 0.0;
    double staleness = 0.0;
    double near_door = 0.0;
    double localisation = 0.0;
    std::size_t scored_steps = 0;
    for (int t = 0; t < config_.steps; ++t) {
      const int action = chooseAction();
      stepWorld(action);
      const std::array<bool, 4> seen = observe();
      updateParticles(action, seen);
      ++result_.visits[static_cast<std::size_t>(robot_)];
      const std::vector<double> weights = normalisedWeights();
      double at_truth = 0.0;
      for (std::size_t j = 0; j < particles_.size(); ++j) at_truth += particles_[j].cell == robot_ ? weights[j] : 0.0;
      localisation += at_truth;
      bool next_to_door = false;
      for (std::size_t d = 0; d < doors_.size(); ++d) {
        if (adjacent(robot_, doors_[d])) {
          last_seen_[d] = t;
          next_to_door = true;
        }
      }
      near_door += next_to_door ? 1.0 : 0.0;
      if (t >= half) {
        const std::vector<double> map = mixtureMap(weights);
        for (std::size_t d = 0; d < doors_.size(); ++d) {
          const auto door = static_cast<std::size_t>(doors_[d]);
          door_right += (map[door] > 0.5) == occupied_[door] ? 1.0 : 0.0;
          staleness += last_seen_[d] < 0 ? static_cast<double>(t + 1) : static_cast<double>(t - last_seen_[d]);
        }
        ++scored_steps;
      }
      resampleIfNeeded(weights);
    }
    const double door_steps = static_cast<double>(scored_steps * doors_.size());
    result_.door_accuracy = door_steps > 0.0 ? door_right / door_steps : 0.0;
    result_.door_staleness_steps = door_steps > 0.0 ? staleness / door_steps : 0.0;
    result_.near_door_share = near_door / static_cast<double>(config_.steps);
    result_.localisation = localisation / static_cast<double>(config_.steps);
    result_.final_map = mixtureMap(normalisedWeights());
    std::size_t static_cells = 0;
    std::size_t static_right = 0;
    for (std::size_t i = 0; i < layout_.cells.size(); ++i) {
      if (layout_.cells[i] == DoorsCell::kDoor) continue;
      ++static_cells;
      const double p = result_.final_map[i];
      static_right += p != 0.5 && (p > 0.5) == occupied_[i] ? 1 : 0;
    }
    result_.static_accuracy = static_cast<double>(static_right) / static_cast<double>(static_cells);
    return result_;
  }

 private:
  int neighbour(int cell, int move) const {
    const int x = cell % layout_.width + kMoves[static_cast<std::size_t>(move)][0];
    const int y = cell / layout_.width + kMoves[static_cast<std::size_t>(move)][1];
    return y * layout_.width + x;  // inside: the border is wall and the robot never on it
  }
  bool adjacent(int a, int b) const {
    for (int move = 0; move < 4; ++move) {
      if (neighbour(a, move) == b) return true;
    }
    return false;
  }
  double transitionOf(std::size_t cell) const {
    return layout_.cells[cell] == DoorsCell::kDoor ? config_.p_change : 0.0;
  }

  std::vector<double> normalisedWeights() const {
    std::vector<double> log_weights;
    log_weights.reserve(particles_.size());
    for (const DoorsParticle& particle : particles_) log_weights.push_back(particle.log_weight);
    return core::normalisedWeights(log_weights);
  }

  std::vector<double> mixtureMap(const std::vector<double>& weights) const {
    std::vector<double> map(layout_.cells.size(), 0.0);
    for (std::size_t j = 0; j < particles_.size(); ++j) {
      for (std::size_t i = 0; i < map.size(); ++i) map[i] += weights[j] * particles_[j].p_occ[i];
    }
    return map;
  }

  /// The action for this step (0..3: E, N, W, S).
  int chooseAction() {
    if (policy_ == DoorsPolicy::kRandom) return static_cast<int>(robot_rng_.below(4));
    const std::vector<double> weights = normalisedWeights();
    const std::vector<double> map = mixtureMap(weights);
    // H(L): the particles' distribution over cells, normalised by log(kLostCells).
    std::vector<double> location(layout_.cells.size(), 0.0);
    for (std::size_t j = 0; j < particles_.size(); ++j) location[static_cast<std::size_t>(particles_[j].cell)] += weights[j];
    double h_location = 0.0;
    for (const double p : location) {
      if (p > 0.0) h_location -= p * std::log(p);
    }
    h_location = std::min(1.0, h_location / std::log(kLostCells));
    // The reward of standing on a cell: that of the four cells seen from it.
    std::vector<double> reward(layout_.cells.size(), 0.0);
    for (std::size_t i = 0; i < reward.size(); ++i) {
      const int x = static_cast<int>(i) % layout_.width;
      const int y = static_cast<int>(i) / layout_.width;
      if (x == 0 || y == 0 || x == layout_.width - 1 || y == layout_.height - 1) continue;
      for (int move = 0; move < 4; ++move) {
        const double h = binaryEntropy(map[static_cast<std::size_t>(neighbour(static_cast<int>(i), move))]);
        reward[i] += h_location * (1.0 - h) + (1.0 - h_location) * h;
      }
    }
    // Value iteration: a move into a cell the map holds occupied (p >= 0.5) stays.
    const auto passable = [&](int cell) { return map[static_cast<std::size_t>(cell)] < 0.5; };
    std::vector<double> value(reward.size(), 0.0);
    std::vector<double> next(reward.size(), 0.0);
    const auto target = [&](int cell, int move) {
      const int to = neighbour(cell, move);
      return passable(to) ? to : cell;
    };
    for (int iteration = 0; iteration < kValueIterations; ++iteration) {
      for (std::size_t i = 0; i < reward.size(); ++i) {
        const int x = static_cast<int>(i) % layout_.width;
        const int y = static_cast<int>(i) / layout_.width;
        if (x == 0 || y == 0 || x == layout_.width - 1 || y == layout_.height - 1) continue;
        double best = -std::numeric_limits<double>::infinity();
        for (int move = 0; move < 4; ++move) {
          best = std::max(best, value[static_cast<std::size_t>(target(static_cast<int>(i), move))]);
        }
        next[i] = reward[i] + config_.discount * best;
      }
      value.swap(next);
    }
    // QMDP: each action's value averaged over where the particles put the robot (a move
    // that stays, into an occupied cell, is worth the cell's own value).
    int action = 0;
    double best = -std::numeric_limits<double>::infinity();
    for (int move = 0; move < 4; ++move) {
      double q = 0.0;
      for (std::size_t j = 0; j < particles_.size(); ++j) {
        q += weights[j] * value[static_cast<std::size_t>(target(particles_[j].cell, move))];
      }
      if (q > best) {
        best = q;
        action = move;
      }
    }
    // Now and then a random move (epsilon-greedy): a robot that took one place for another
    // may push at a wall forever while its beliefs stand still.
    if (robot_rng_.bernoulli(kExploration)) action = static_cast<int>(robot_rng_.below(4));
    return action;
  }

  void stepWorld(int action) {
    for (const int door : doors_) {
      if (world_rng_.bernoulli(config_.p_change)) occupied_[static_cast<std::size_t>(door)] = !occupied_[static_cast<std::size_t>(door)];
    }
    if (robot_rng_.bernoulli(config_.p_action)) {
      const int to = neighbour(robot_, action);
      if (!occupied_[static_cast<std::size_t>(to)]) robot_ = to;
    }
  }

  std::array<bool, 4> observe() {
    std::array<bool, 4> seen{};
    for (int move = 0; move < 4; ++move) {
      const bool truth = occupied_[static_cast<std::size_t>(neighbour(robot_, move))];
      seen[static_cast<std::size_t>(move)] = robot_rng_.bernoulli(config_.p_observation) ? truth : !truth;
    }
    return seen;
  }

  /// The likelihood of the four readings from `cell` under `p_occ`.
  double readingsLikelihood(const std::vector<double>& p_occ, int cell, const std::array<bool, 4>& seen) const {
    const double p_o = config_.p_observation;
    double likelihood = 1.0;
    for (int move = 0; move < 4; ++move) {
      const double q = p_occ[static_cast<std::size_t>(neighbour(cell, move))];
      likelihood *= seen[static_cast<std::size_t>(move)] ? q * p_o + (1.0 - q) * (1.0 - p_o)
                                                          : q * (1.0 - p_o) + (1.0 - q) * p_o;
    }
    return likelihood;
  }

  void updateParticles(int action, const std::array<bool, 4>& seen) {
    const double p_o = config_.p_observation;
    for (DoorsParticle& particle : particles_) {
      // The map one step on: doors change, the rest does not.
      for (std::size_t i = 0; i < particle.p_occ.size(); ++i) {
        const double c = transitionOf(i);
        if (c > 0.0) particle.p_occ[i] = particle.p_occ[i] * (1.0 - c) + (1.0 - particle.p_occ[i]) * c;
      }
      // The proposal that sees the readings (Murphy's optimal one): three ways the step can
      // have gone (a slip; a move into an occupied target, which stays; a move into a free
      // one), each weighed by its prior and the readings' likelihood from where it leaves
      // the robot, one drawn; the particle's weight grows by their sum.
      const auto target = static_cast<std::size_t>(neighbour(particle.cell, action));
      const double q = particle.p_occ[target];
      const double saved = particle.p_occ[target];
      const double slip = 1.0 - config_.p_action;
      const double blocked = config_.p_action * q;
      const double moved = config_.p_action * (1.0 - q);
      const double slip_likelihood = readingsLikelihood(particle.p_occ, particle.cell, seen);
      particle.p_occ[target] = 1.0;
      const double blocked_likelihood = readingsLikelihood(particle.p_occ, particle.cell, seen);
      particle.p_occ[target] = 0.0;
      // (A target known occupied, the grid's edge among them, cannot be moved into.)
      const double moved_likelihood = moved > 0.0 ? readingsLikelihood(particle.p_occ, static_cast<int>(target), seen) : 0.0;
      particle.p_occ[target] = saved;
      const std::array<double, 3> mass{slip * slip_likelihood, blocked * blocked_likelihood, moved * moved_likelihood};
      const double total = mass[0] + mass[1] + mass[2];
      const double draw = robot_rng_.uniform() * total;
      if (draw < mass[0]) {
        // slipped: nothing learned about the target
      } else if (draw < mass[0] + mass[1]) {
        particle.p_occ[target] = 1.0;
      } else {
        particle.p_occ[target] = 0.0;
        particle.cell = static_cast<int>(target);
      }
      particle.log_weight += std::log(total);
      // Bayes on the four cells seen.
      for (int move = 0; move < 4; ++move) {
        double& cell = particle.p_occ[static_cast<std::size_t>(neighbour(particle.cell, move))];
        const bool hit = seen[static_cast<std::size_t>(move)];
        const double if_occ = hit ? p_o : 1.0 - p_o;
        const double if_free = hit ? 1.0 - p_o : p_o;
        cell = cell * if_occ / (cell * if_occ + (1.0 - cell) * if_free);
      }
    }
  }

  void resampleIfNeeded(const std::vector<double>& weights) {
    if (core::effectiveSampleSize(weights) >= config_.resample_below * static_cast<double>(particles_.size())) return;
    const std::vector<std::size_t> copies =
        core::residualResample(weights, particles_.size(), [this] { return robot_rng_.uniform(); });
    std::vector<DoorsParticle> next;
    next.reserve(particles_.size());
    for (std::size_t j = 0; j < particles_.size(); ++j) {
      for (std::size_t k = 0; k < copies[j]; ++k) {
        next.push_back(particles_[j]);
        next.back().log_weight = 0.0;
      }
    }
    particles_ = std::move(next);
  }

  const DoorsLayout& layout_;
  const DoorsWorldConfig& config_;
  DoorsPolicy policy_;
  Rng world_rng_;  ///< the doors' changes
  Rng robot_rng_;  ///< slips, readings, the particles, random actions
  std::vector<bool> occupied_;
  std::vector<int> doors_;
  std::vector<int> last_seen_;  ///< per door: the last step the robot stood next to it
  int robot_ = 0;
  std::vector<DoorsParticle> particles_;
  DoorsRun result_;
};

}  // namespace

void DoorsLayout::validate() const {
  if (width < 3 || height < 3 || cells.size() != static_cast<std::size_t>(width) * static_cast<std::size_t>(height)) {
    throw std::invalid_argument("DoorsLayout: need width, height >= 3 and width * height cells");
  }
  for (int x = 0; x < width; ++x) {
    if (at(x, 0) != DoorsCell::kWall || at(x, height - 1) != DoorsCell::kWall) {
      throw std::invalid_argument("DoorsLayout: the border must be wall");
    }
  }
  for (int y = 0; y < height; ++y) {
    if (at(0, y) != DoorsCell::kWall || at(width - 1, y) != DoorsCell::kWall) {
      throw std::invalid_argument("DoorsLayout: the border must be wall");
    }
  }
  if (start < 0 || start >= static_cast<int>(cells.size()) || cells[static_cast<std::size_t>(start)] != DoorsCell::kFree) {
    throw std::invalid_argument("DoorsLayout: the start must be a free cell");
  }
}

DoorsLayout murphyDoorsLayout() {
  // '#' wall, '.' free, 'D' door; row 0 is the bottom row (y = 0). Four rooms of different
  // sizes, each with its own pillars: four equal rooms look alike to a robot that sees only
  // its neighbours, and once it took one for another it never found out.
  const std::vector<std::string> rows = {
      "###############",
      "#....#........#",
      "#.#..#....##..#",
      "#....D........#",
      "#....#..#.....#",
      "###D#####D#####",
      "#.......#.....#",
      "#..##...D...#.#",
      "#.......#.....#",
      "#.......#..#..#",
      "###############",
  };

  DoorsLayout layout;
  layout.width = static_cast<int>(rows.front().size());
  layout.height = static_cast<int>(rows.size());
  for (const std::string& row : rows) {
    for (const char c : row) layout.cells.push_back(c == '#' ? DoorsCell::kWall : c == 'D' ? DoorsCell::kDoor : DoorsCell::kFree);
  }
  layout.start = 1 * layout.width + 2;
  layout.validate();
  return layout;
}

const char* doorsPolicyName(DoorsPolicy policy) { return policy == DoorsPolicy::kEntropy ? "entropy" : "random"; }

void DoorsWorldConfig::validate() const {
  const auto require = [](bool ok, const char* message) {
    if (!ok) throw std::invalid_argument(std::string("DoorsWorldConfig: ") + message);
  };
  require(p_action >= 0.0 && p_action <= 1.0, "p_action must be in [0, 1]");
  require(p_observation > 0.5 && p_observation < 1.0, "p_observation must be in (0.5, 1)");
  require(p_change >= 0.0 && p_change <= 0.5, "p_change must be in [0, 0.5]");
  require(particles >= 1, "particles must be >= 1");
  require(resample_below >= 0.0 && resample_below <= 1.0, "resample_below must be in [0, 1]");
  require(discount >= 0.0 && discount < 1.0, "discount must be in [0, 1)");
  require(steps >= 2, "steps must be >= 2");
}

DoorsRun runDoorsWorld(const DoorsLayout& layout, const DoorsWorldConfig& config, DoorsPolicy policy) {
  layout.validate();
  config.validate();
  return DoorsRunner(layout, config, policy).run();
}

DoorsExperimentResult runDoorsExperiment(const DoorsExperimentConfig& config) {
  config.world.validate();
  if (config.runs < 1) throw std::invalid_argument("DoorsExperimentConfig: runs must be >= 1");
  const auto start = std::chrono::steady_clock::now();
  DoorsExperimentResult result;
  result.layout = murphyDoorsLayout();
  result.entropy.resize(static_cast<std::size_t>(config.runs));
  result.random.resize(static_cast<std::size_t>(config.runs));
  core::runRepetitions(
      2 * static_cast<std::size_t>(config.runs), config.threads,
      [&](std::size_t job) {
        DoorsWorldConfig world = config.world;
        world.seed = config.world.seed + job / 2;
        const DoorsPolicy policy = job % 2 == 0 ? DoorsPolicy::kEntropy : DoorsPolicy::kRandom;
        (policy == DoorsPolicy::kEntropy ? result.entropy : result.random)[job / 2] =
            runDoorsWorld(result.layout, world, policy);
      },
      nullptr);
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

std::vector<std::pair<std::string, std::string>> doorsCsvTables(const DoorsExperimentResult& result) {
  std::ostringstream runs;
  runs << "run,policy,door_accuracy,door_staleness_steps,near_door_share,localisation,static_accuracy\n";
  for (std::size_t r = 0; r < result.entropy.size(); ++r) {
    for (const DoorsRun* run : {&result.entropy[r], &result.random[r]}) {
      runs << r << ',' << doorsPolicyName(run->policy) << ',' << fixed(run->door_accuracy, 6) << ','
           << fixed(run->door_staleness_steps, 3) << ',' << fixed(run->near_door_share, 6) << ','
           << fixed(run->localisation, 6) << ',' << fixed(run->static_accuracy, 6) << '\n';
    }
  }
  // The maps of a typical run: the one whose entropy-driven robot has the (lower) median
  // door accuracy.
  std::vector<std::size_t> order(result.entropy.size());
  for (std::size_t r = 0; r < order.size(); ++r) order[r] = r;
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return result.entropy[a].door_accuracy < result.entropy[b].door_accuracy;
  });
  const std::size_t shown = order[(order.size() - 1) / 2];
  std::ostringstream maps;
  maps << "run,x,y,cell,entropy_visits,entropy_p_occ,random_visits,random_p_occ\n";
  const DoorsLayout& layout = result.layout;
  for (int y = 0; y < layout.height; ++y) {
    for (int x = 0; x < layout.width; ++x) {
      const auto i = static_cast<std::size_t>(y * layout.width + x);
      const DoorsCell cell = layout.cells[i];
      maps << shown << ',' << x << ',' << y << ','
           << (cell == DoorsCell::kWall ? "wall" : cell == DoorsCell::kDoor ? "door" : "free") << ','
           << result.entropy[shown].visits[i] << ',' << fixed(result.entropy[shown].final_map[i], 6) << ','
           << result.random[shown].visits[i] << ',' << fixed(result.random[shown].final_map[i], 6) << '\n';
    }
  }
  return {{"murphy_doors_runs.csv", runs.str()}, {"murphy_doors_maps.csv", maps.str()}};
}

std::string formatDoorsSummary(const DoorsExperimentConfig& config, const DoorsExperimentResult& result,
                               std::vector<MurphyTarget>* targets) {
  const auto mean = [](const std::vector<DoorsRun>& runs, double DoorsRun::*field) {
    double total = 0.0;
    for (const DoorsRun& run : runs) total += run.*field;
    return total / static_cast<double>(runs.size());
  };
  const DoorsWorldConfig& w = config.world;
  std::ostringstream text;
  text << "\n## Murphy's 2D world with doors (Murphy 1999, Fig. 1(c), end of Section 4)\n\n"
       << "Four rooms, four doors (15 x 11 cells), p_a = " << w.p_action << ", p_o = " << w.p_observation
       << " for each of the four neighbours, doors open or close with p_c = " << w.p_change
       << " per step; the RBPF with " << w.particles << " particles learns the map from p = 0.5 (transitions known); "
       << config.runs << " runs of " << w.steps << " steps (seeds " << w.seed << "..), each world run by the robot "
       << "whose actions maximise the discounted entropy reward and by one that moves at random "
       << "(docs/murphy_corridor.md). Door accuracy and staleness over the second half. " << fixed(result.seconds, 1)
       << " s.\n\n"
       << "| policy | door state right | steps since a door was seen | steps next to a door | p(true cell) | walls and free space right at the end |\n"
       << "|---|---|---|---|---|---|\n";
  for (const auto* runs : {&result.entropy, &result.random}) {
    text << "| " << doorsPolicyName(runs->front().policy) << " | " << fixed(mean(*runs, &DoorsRun::door_accuracy), 3)
         << " | " << fixed(mean(*runs, &DoorsRun::door_staleness_steps), 1) << " | "
         << fixed(mean(*runs, &DoorsRun::near_door_share), 3) << " | " << fixed(mean(*runs, &DoorsRun::localisation), 3)
         << " | " << fixed(mean(*runs, &DoorsRun::static_accuracy), 3) << " |\n";
  }
  const double entropy_accuracy = mean(result.entropy, &DoorsRun::door_accuracy);
  const double random_accuracy = mean(result.random, &DoorsRun::door_accuracy);
  const double entropy_stale = mean(result.entropy, &DoorsRun::door_staleness_steps);
  const double random_stale = mean(result.random, &DoorsRun::door_staleness_steps);
  if (targets != nullptr) {
    targets->push_back({"Murphy's doors: the entropy-driven robot keeps the doors more current than a random walk "
                        "(door state right more often, doors seen more recently)",
                        fixed(entropy_accuracy, 3) + " against " + fixed(random_accuracy, 3) + "; " +
                            fixed(entropy_stale, 1) + " against " + fixed(random_stale, 1) + " steps",
                        entropy_accuracy > random_accuracy && entropy_stale < random_stale});
  }
  return text.str();
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
