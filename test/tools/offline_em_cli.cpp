// offline_em_cli: a small test tool that runs the core's offline EM (core/cell/offline_em.h) on
// per-cell observation sequences read from stdin and prints what it learned, so that an
// outside implementation (test/python/compare_pomegranate.py, pomegranate's Baum-Welch)
// can check it. Not installed; built by test/core_standalone.
//
// Usage: offline_em_cli [--time] [--objective] < input
//
// Input (whitespace-separated numbers; '#' starts a comment that runs to the end of the
// line; blank lines are ignored):
//   line 1 (header):
//     p_hit_given_occ p_hit_given_free initial_p_occ p_of0 p_fo0 max_iterations tolerance threads
//   then one line per cell:
//     n  step_1 hits_1 misses_1  ...  step_n hits_n misses_n
//   n >= 1, steps strictly increasing (any integers), hits and misses in [0, 65535].
//
// EM runs with p_min = 0, p_max = 1, prior_weight = 0 (maximum likelihood), symmetric =
// false, starting from (p_of0, p_fo0).
//
// Output: one line per cell, in input order, every number printed with %.17g:
//     p_occ_given_free p_free_given_occ iterations final_p_occ log_likelihood
// where log_likelihood is log p(z | learned params) of that cell, from forwardBackward
// with the learned parameters. With --objective, then one line per entry k of the
// result's objective: "objective k value". With --time, finally one line
// "time_s seconds" with the wall time of runOfflineEm alone.
//
// Malformed input: a message on stderr naming the line, and exit status 2. Errors of
// the library (std::invalid_argument for a bad config or sensor model): exit status 3.

#include <chrono>
#include <cinttypes>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <iostream>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/core/cell/offline_em.h"

namespace dog = dynamic_occupancy_grid::core;

namespace {

struct InputError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Reads the next non-blank line (comments stripped) into `tokens`; false at end of input.
bool nextLine(std::istream& in, std::size_t& line_number, std::vector<std::string>& tokens) {
  std::string line;
  while (std::getline(in, line)) {
    ++line_number;
    const auto hash = line.find('#');
    if (hash != std::string::npos) line.erase(hash);
    std::istringstream words(line);
    tokens.clear();
    for (std::string word; words >> word;) tokens.push_back(word);
    if (!tokens.empty()) return true;
  }
  return false;
}

std::string where(std::size_t line_number) { return "line " + std::to_string(line_number) + ": "; }

double parseDouble(const std::string& text, const char* what, std::size_t line_number) {
  std::size_t used = 0;
  double value = 0.0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() || text.empty()) {
    throw InputError(where(line_number) + what + " is not a number: '" + text + "'");
  }
  return value;
}

long long parseInteger(const std::string& text, const char* what, long long min, long long max,
                       std::size_t line_number) {
  std::size_t used = 0;
  long long value = 0;
  try {
    value = std::stoll(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() || text.empty()) {
    throw InputError(where(line_number) + what + " is not an integer: '" + text + "'");
  }
  if (value < min || value > max) {
    throw InputError(where(line_number) + what + " = " + text + " is outside [" +
                     std::to_string(min) + ", " + std::to_string(max) + "]");
  }
  return value;
}

struct Input {
  double p_hit_given_occ = 0.0;
  double p_hit_given_free = 0.0;
  dog::OfflineEmConfig config;
  dog::ObservationSequences sequences;
};

Input readInput(std::istream& in) {
  Input input;
  std::size_t line_number = 0;
  std::vector<std::string> tokens;
  if (!nextLine(in, line_number, tokens)) throw InputError("empty input: no header line");
  if (tokens.size() != 8) {
    throw InputError(where(line_number) + "the header needs 8 numbers (p_hit_given_occ "
                     "p_hit_given_free initial_p_occ p_of0 p_fo0 max_iterations tolerance "
                     "threads), got " + std::to_string(tokens.size()));
  }
  input.p_hit_given_occ = parseDouble(tokens[0], "p_hit_given_occ", line_number);
  input.p_hit_given_free = parseDouble(tokens[1], "p_hit_given_free", line_number);
  dog::OfflineEmConfig& config = input.config;
  config.initial_p_occ = parseDouble(tokens[2], "initial_p_occ", line_number);
  config.initial_params.p_occ_given_free = parseDouble(tokens[3], "p_of0", line_number);
  config.initial_params.p_free_given_occ = parseDouble(tokens[4], "p_fo0", line_number);
  config.max_iterations = static_cast<int>(
      parseInteger(tokens[5], "max_iterations", 0, 65535, line_number));
  config.tolerance = parseDouble(tokens[6], "tolerance", line_number);
  config.threads = static_cast<unsigned>(parseInteger(tokens[7], "threads", 0, 1024, line_number));
  config.p_min = 0.0;
  config.p_max = 1.0;
  config.prior_weight = 0.0;
  config.symmetric = false;

  dog::SequenceBuilder builder;
  std::int32_t cell = 0;
  const long long step_limit = std::numeric_limits<std::int32_t>::max();
  while (nextLine(in, line_number, tokens)) {
    const long long n = parseInteger(tokens[0], "n (observations of the cell)", 1,
                                     std::numeric_limits<std::int32_t>::max(), line_number);
    if (tokens.size() != static_cast<std::size_t>(1 + 3 * n)) {
      throw InputError(where(line_number) + "a cell with n = " + std::to_string(n) +
                       " needs " + std::to_string(1 + 3 * n) + " numbers, got " +
                       std::to_string(tokens.size()));
    }
    long long previous_step = 0;
    for (long long i = 0; i < n; ++i) {
      const long long step =
          parseInteger(tokens[1 + 3 * i], "step", -step_limit - 1, step_limit, line_number);
      const long long hits = parseInteger(tokens[2 + 3 * i], "hits", 0, 65535, line_number);
      const long long misses = parseInteger(tokens[3 + 3 * i], "misses", 0, 65535, line_number);
      if (i > 0 && step <= previous_step) {
        throw InputError(where(line_number) + "steps must be strictly increasing, got " +
                         std::to_string(previous_step) + " then " + std::to_string(step));
      }
      previous_step = step;
      builder.add(cell, 0, static_cast<std::int32_t>(step), static_cast<std::uint32_t>(hits),
                  static_cast<std::uint32_t>(misses));
    }
    ++cell;
  }
  if (cell == 0) throw InputError("no cell lines after the header");
  input.sequences = builder.build();
  if (input.sequences.cellCount() != static_cast<std::size_t>(cell)) {
    throw std::logic_error("SequenceBuilder returned " +
                           std::to_string(input.sequences.cellCount()) + " cells for " +
                           std::to_string(cell) + " input lines");
  }
  return input;
}

int usage(const char* program) {
  std::fprintf(stderr, "usage: %s [--time] [--objective] < input\n(see the comment at the top of "
                       "test/tools/offline_em_cli.cpp for the format)\n", program);
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  bool print_time = false;
  bool print_objective = false;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--time") {
      print_time = true;
    } else if (arg == "--objective") {
      print_objective = true;
    } else {
      std::fprintf(stderr, "offline_em_cli: unknown argument '%s'\n", argv[i]);
      return usage(argv[0]);
    }
  }

  Input input;
  try {
    input = readInput(std::cin);
  } catch (const InputError& error) {
    std::fprintf(stderr, "offline_em_cli: malformed input: %s\n", error.what());
    return 2;
  }

  try {
    const dog::ObservationModel sensor(input.p_hit_given_occ, input.p_hit_given_free);
    const auto start = std::chrono::steady_clock::now();
    const dog::OfflineEmResult result = dog::runOfflineEm(input.sequences, sensor, input.config);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

    const std::size_t cells = input.sequences.cellCount();
    if (result.params.size() != cells || result.final_p_occ.size() != cells ||
        result.iterations.size() != cells) {
      std::fprintf(stderr, "offline_em_cli: runOfflineEm returned %zu params, %zu final_p_occ, "
                           "%zu iterations for %zu cells\n",
                   result.params.size(), result.final_p_occ.size(), result.iterations.size(),
                   cells);
      return 4;
    }
    std::string out;
    out.reserve(cells * 100);
    char buffer[256];
    for (std::size_t c = 0; c < cells; ++c) {
      const dog::TransitionParams& params = result.params[c];
      const dog::ForwardBackwardResult check =
          dog::forwardBackward(input.sequences.begin(c), input.sequences.end(c), sensor, params,
                               input.config.initial_p_occ);
      std::snprintf(buffer, sizeof buffer, "%.17g %.17g %u %.17g %.17g\n",
                    params.p_occ_given_free, params.p_free_given_occ,
                    static_cast<unsigned>(result.iterations[c]), result.final_p_occ[c],
                    check.log_likelihood);
      out += buffer;
    }
    if (print_objective) {
      for (std::size_t k = 0; k < result.objective.size(); ++k) {
        std::snprintf(buffer, sizeof buffer, "objective %zu %.17g\n", k, result.objective[k]);
        out += buffer;
      }
    }
    if (print_time) {
      std::snprintf(buffer, sizeof buffer, "time_s %.9f\n", seconds);
      out += buffer;
    }
    std::fwrite(out.data(), 1, out.size(), stdout);
    return std::fflush(stdout) == 0 ? 0 : 5;
  } catch (const std::invalid_argument& error) {
    std::fprintf(stderr, "offline_em_cli: %s\n", error.what());
    return 3;
  }
}
