// The tables and the summary section of Murphy's corridor experiment (murphy_corridor.h), as
// `evaluate` writes them: t and cells 1-based, as in the paper.
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/evaluation/murphy_corridor.h"
#include "dynamic_occupancy_grid/evaluation/path_planning.h"  // MeanStd

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

std::string fixed(double value, int digits) {
  if (std::isnan(value)) return "";
  std::ostringstream text;
  text << std::fixed << std::setprecision(digits) << value;
  return text.str();
}

std::size_t indexOf(CorridorEstimator estimator) {
  return static_cast<std::size_t>(std::find(kAllCorridorEstimators.begin(), kAllCorridorEstimators.end(), estimator) -
                                  kAllCorridorEstimators.begin());
}

const CorridorPosterior& estimate(const MurphyExperimentResult& result, CorridorEstimator estimator) {
  return result.paper_estimates[indexOf(estimator)];
}

// "01010101": the labels of cells 1..N of map `map` (bit i = cell i + 1).
std::string mapLabels(std::uint32_t map, int cells) {
  std::string labels;
  for (int i = 0; i < cells; ++i) labels += ((map >> i) & 1U) != 0 ? '1' : '0';
  return labels;
}

std::size_t modeOf(const std::vector<double>& p) {
  return static_cast<std::size_t>(std::max_element(p.begin(), p.end()) - p.begin());
}

std::string fig2Maps(const MurphyExperimentResult& result) {
  std::ostringstream csv;
  csv << "t,map,labels,probability\n";
  const int cells = static_cast<int>(result.paper_exact.filtered.position.front().size());
  for (std::size_t t = 0; t < result.paper_exact.maps.size(); ++t) {
    for (std::size_t m = 0; m < result.paper_exact.maps[t].size(); ++m) {
      // map: 0-based (bit i = cell i + 1); the paper's numbering is map + 1.
      csv << t + 1 << ',' << m << ',' << mapLabels(static_cast<std::uint32_t>(m), cells) << ','
          << fixed(result.paper_exact.maps[t][m], 8) << '\n';
    }
  }
  return csv.str();
}

std::string fig2Cells(const MurphyExperimentResult& result) {
  std::ostringstream csv;
  csv << "t,cell,truth,exact,online_em,online_em_no_smoothing,offline_em,offline_em_smoothed,rbpf,rbpf_optimal\n";
  const CorridorEpisode& episode = result.paper_episode;
  const std::vector<CorridorEstimator> shown{CorridorEstimator::kExact,     CorridorEstimator::kOnlineEm,
                                             CorridorEstimator::kOnlineEmNoSmoothing, CorridorEstimator::kOfflineEm,
                                             CorridorEstimator::kOfflineEmSmoothed, CorridorEstimator::kRbpf,
                                             CorridorEstimator::kRbpfOptimal};
  for (std::size_t t = 0; t < episode.steps(); ++t) {
    const std::size_t cells = result.paper_exact.filtered.map_one[t].size();
    for (std::size_t i = 0; i < cells; ++i) {
      csv << t + 1 << ',' << i + 1 << ',' << ((episode.maps[t] >> i) & 1U);
      for (const CorridorEstimator e : shown) csv << ',' << fixed(estimate(result, e).map_one[t][i], 6);
      csv << '\n';
    }
  }
  return csv.str();
}

std::string fig3Position(const MurphyExperimentResult& result) {
  std::ostringstream csv;
  csv << "t,cell,truth,exact,dead_reckoning,online_em,online_em_no_smoothing,offline_em,rbpf,rbpf_optimal,"
         "exact_smoothed,offline_em_smoothed\n";
  const CorridorEpisode& episode = result.paper_episode;
  const std::vector<CorridorEstimator> shown{CorridorEstimator::kExact,     CorridorEstimator::kDeadReckoning,
                                             CorridorEstimator::kOnlineEm,  CorridorEstimator::kOnlineEmNoSmoothing,
                                             CorridorEstimator::kOfflineEm, CorridorEstimator::kRbpf,
                                             CorridorEstimator::kRbpfOptimal};
  for (std::size_t t = 0; t < episode.steps(); ++t) {
    const std::size_t cells = result.paper_exact.filtered.position[t].size();
    for (std::size_t i = 0; i < cells; ++i) {
      csv << t + 1 << ',' << i + 1 << ',' << (episode.positions[t] == static_cast<int>(i) ? 1 : 0);
      for (const CorridorEstimator e : shown) csv << ',' << fixed(estimate(result, e).position[t][i], 6);
      csv << ',' << fixed(result.paper_exact.smoothed.position[t][i], 6) << ','
          << fixed(estimate(result, CorridorEstimator::kOfflineEmSmoothed).position[t][i], 6) << '\n';
    }
  }
  return csv.str();
}

std::string fig4Rbpf(const MurphyExperimentResult& result) {
  std::ostringstream csv;
  csv << "t,cell,true_position,exact_position,rbpf_position,rbpf_optimal_position,true_label,exact_p_one,rbpf_p_one,"
         "rbpf_optimal_p_one\n";
  const CorridorEpisode& episode = result.paper_episode;
  const CorridorPosterior& exact = result.paper_exact.filtered;
  const CorridorPosterior& rbpf = estimate(result, CorridorEstimator::kRbpf);
  const CorridorPosterior& optimal = estimate(result, CorridorEstimator::kRbpfOptimal);
  for (std::size_t t = 0; t < episode.steps(); ++t) {
    for (std::size_t i = 0; i < exact.position[t].size(); ++i) {
      csv << t + 1 << ',' << i + 1 << ',' << (episode.positions[t] == static_cast<int>(i) ? 1 : 0) << ','
          << fixed(exact.position[t][i], 6) << ',' << fixed(rbpf.position[t][i], 6) << ','
          << fixed(optimal.position[t][i], 6) << ',' << ((episode.maps[t] >> i) & 1U) << ','
          << fixed(exact.map_one[t][i], 6) << ',' << fixed(rbpf.map_one[t][i], 6) << ','
          << fixed(optimal.map_one[t][i], 6) << '\n';
    }
  }
  return csv.str();
}

// Mean and std over the runs of one series at step t; NaN without the series.
MeanStd acrossRuns(const MurphyVariant& variant, std::size_t e, std::vector<double> CorridorErrors::*series,
                   std::size_t t) {
  std::vector<double> values;
  for (const auto& run : variant.runs) {
    const std::vector<double>& s = run[e].*series;
    if (s.empty()) return MeanStd{std::nan(""), std::nan("")};
    values.push_back(s[t]);
  }
  return meanStd(values);
}

std::string errors(const MurphyExperimentResult& result) {
  std::ostringstream csv;
  csv << "variant,estimator,t,position_tv_mean,position_tv_std,truth_mass_mean,map_error_mean,map_truth_error_mean,"
         "runs\n";
  for (const MurphyVariant& variant : result.variants) {
    const std::size_t steps = variant.runs.front().front().position_tv.size();
    for (std::size_t e = 0; e < kAllCorridorEstimators.size(); ++e) {
      for (std::size_t t = 0; t < steps; ++t) {
        const MeanStd tv = acrossRuns(variant, e, &CorridorErrors::position_tv, t);
        csv << variant.name << ',' << corridorEstimatorName(kAllCorridorEstimators[e]) << ',' << t + 1 << ','
            << fixed(tv.mean, 6) << ',' << fixed(tv.std, 6) << ','
            << fixed(acrossRuns(variant, e, &CorridorErrors::truth_mass, t).mean, 6) << ','
            << fixed(acrossRuns(variant, e, &CorridorErrors::map_error, t).mean, 6) << ','
            << fixed(acrossRuns(variant, e, &CorridorErrors::map_truth_error, t).mean, 6) << ','
            << variant.runs.size() << '\n';
      }
    }
  }
  return csv.str();
}

std::string particles(const MurphyExperimentResult& result) {
  std::ostringstream csv;
  csv << "particles,mean_tv_mean,mean_tv_std,max_tv_mean,map_error_mean,sampling_floor_tv_mean,seeds\n";
  for (const MurphyParticleSweepRow& row : result.particle_sweep) {
    const MeanStd tv = meanStd(row.mean_tv);
    csv << row.particles << ',' << fixed(tv.mean, 6) << ',' << fixed(tv.std, 6) << ','
        << fixed(meanStd(row.max_tv).mean, 6) << ',' << fixed(meanStd(row.map_error).mean, 6) << ','
        << fixed(meanStd(row.sampling_floor_tv).mean, 6) << ',' << row.mean_tv.size() << '\n';
  }
  return csv.str();
}

const MurphyVariant& variantNamed(const MurphyExperimentResult& result, const std::string& name) {
  for (const MurphyVariant& variant : result.variants) {
    if (variant.name == name) return variant;
  }
  throw std::logic_error("formatMurphySummary: no variant " + name);
}

}  // namespace

std::vector<std::pair<std::string, std::string>> murphyCsvTables(const MurphyExperimentResult& result) {
  return {{"murphy_corridor_fig2_maps.csv", fig2Maps(result)},
          {"murphy_corridor_fig2_cells.csv", fig2Cells(result)},
          {"murphy_corridor_fig3_position.csv", fig3Position(result)},
          {"murphy_corridor_fig4_rbpf.csv", fig4Rbpf(result)},
          {"murphy_corridor_errors.csv", errors(result)},
          {"murphy_corridor_particles.csv", particles(result)}};
}

std::string formatMurphySummary(const MurphyExperimentConfig& config, const MurphyExperimentResult& result,
                                std::vector<MurphyTarget>* targets) {
  const CorridorModel model = murphyModel();
  const ExactCorridorPosterior& exact = result.paper_exact;
  const int last = static_cast<int>(result.paper_episode.steps()) - 1;
  const int back = kMurphyReturnStep;
  std::ostringstream text;
  text << "\n## Murphy's 1D corridor (Murphy 1999, Sections 3–4)\n\n"
       << "The corridor of " << model.cells << " cells, p_o = " << model.p_observation << ", p_a = " << model.p_action
       << ", p_c = " << model.p_change << ", and the paper's run (16 steps, true map 01010101, the slip after t = 4; "
       << "docs/murphy_corridor.md). Every estimator against exact Bayes (enumeration over 2^8 maps x 8 cells): "
       << "position error is the total variation distance of p(L_t | y_{1:t}) to the exact one (offline EM "
          "smoothed: of p(L_t | y_{1:T})), map error the mean over cells of |p(M_t(i) = 1) - exact|. The RBPF has "
       << config.rbpf.particles << " particles, residual resampling when N_eff < " << config.rbpf.resample_below
       << " N; " << config.repetitions << " seeds (seed " << config.seed << "); online EM decay d = "
       << config.online_em.decay << ", window " << (config.online_em.window < 0 ? std::string("W_t = t")
                                                                                 : std::to_string(config.online_em.window))
       << ". " << fixed(result.seconds, 1) << " s.\n\n";

  // The paper's checkpoints.
  const double p_cell8_t9 = exact.filtered.position[8][7];
  const std::size_t mode_t8 = modeOf(exact.maps[7]);
  const std::size_t mode_end = modeOf(exact.maps[static_cast<std::size_t>(last)]);
  const double online_m5 = estimate(result, CorridorEstimator::kOnlineEm).map_one[static_cast<std::size_t>(last)][4];
  const std::vector<double>& offline_map = estimate(result, CorridorEstimator::kOfflineEmSmoothed).map_one.back();
  std::uint32_t offline_labels = 0;
  for (std::size_t i = 0; i < offline_map.size(); ++i) {
    if (offline_map[i] > 0.5) offline_labels |= 1U << i;
  }
  text << "The paper's checkpoints: exact p(L_9 = 8) = " << fixed(p_cell8_t9, 3)
       << " (paper: \"almost 70 %\"); the mode of p(M | y_{1:t}) at t = 8 is " << mapLabels(static_cast<std::uint32_t>(mode_t8), model.cells)
       << " (M(5) = " << ((mode_t8 >> 4) & 1U) << "), at t = 16 " << mapLabels(static_cast<std::uint32_t>(mode_end), model.cells)
       << " with p = " << fixed(exact.maps[static_cast<std::size_t>(last)][mode_end], 3) << " (the paper's map "
       << mode_end + 1 << " in its 1-based numbering; paper: 171); online EM's p(M(5) = 1) at t = 16: "
       << fixed(online_m5, 3) << " (paper: stuck with M(5) = 1); offline EM's map " << mapLabels(offline_labels, model.cells)
       << ".\n\n";

  text << "| run | estimator | position TV, all steps | TV, t = 10–16 | p(true cell), t = 10–16 | map error vs exact | "
          "max TV |\n|---|---|---|---|---|---|---|\n";
  for (const MurphyVariant& variant : result.variants) {
    for (const CorridorEstimator e : kAllCorridorEstimators) {
      if (e == CorridorEstimator::kExact && variant.name != "paper") continue;
      text << "| " << variant.name << " | " << corridorEstimatorName(e) << " | " << fixed(variant.meanPositionTv(e), 3)
           << " | " << fixed(variant.meanPositionTv(e, back), 3) << " | " << fixed(variant.meanTruthMass(e, back), 3)
           << " | " << (e == CorridorEstimator::kDeadReckoning ? "-" : fixed(variant.meanMapError(e), 3)) << " | "
           << fixed(variant.maxPositionTv(e), 3) << " |\n";
    }
  }
  text << "\nRuns: `paper` is the paper's run (deterministic estimators identical across the seeds); "
       << "`simulated_static` are runs drawn from the model with the paper's actions (a random map, slips and "
          "sensor errors); `simulated_dynamic` the same with p_c = "
       << config.dynamic_p_change
       << " (exact and RBPF model the changes; EM keeps a static map). Offline EM: one batch EM per prefix y_{1:t}; "
          "offline_em_smoothed: EM on the whole run, against exact smoothing.\n\n";

  text << "The RBPF against the number of particles on the paper's run (mean over " << config.repetitions
       << " seeds); the sampling floor is the TV of that many independent draws from the exact posterior itself.\n\n"
       << "| particles | position TV | max TV | map error | sampling floor |\n|---|---|---|---|---|\n";
  for (const MurphyParticleSweepRow& row : result.particle_sweep) {
    const MeanStd tv = meanStd(row.mean_tv);
    text << "| " << row.particles << " | " << fixed(tv.mean, 4) << " ± " << fixed(tv.std, 4) << " | "
         << fixed(meanStd(row.max_tv).mean, 3) << " | " << fixed(meanStd(row.map_error).mean, 4) << " | "
         << fixed(meanStd(row.sampling_floor_tv).mean, 4) << " |\n";
  }

  if (targets != nullptr) {
    const MurphyVariant& paper = variantNamed(result, "paper");
    targets->push_back({"Murphy: exact p(L_9 = cell 8) \"almost 70 %\" (0.6–0.7)", fixed(p_cell8_t9, 3),
                        p_cell8_t9 >= 0.6 && p_cell8_t9 <= 0.7});
    targets->push_back({"Murphy: exact map mode wrong (M(5) = 1) at t = 8, 01010101 (the paper's 171) at t = 16",
                        mapLabels(static_cast<std::uint32_t>(mode_t8), model.cells) + " → " +
                            mapLabels(static_cast<std::uint32_t>(mode_end), model.cells),
                        ((mode_t8 >> 4) & 1U) == 1 && mode_end == 0xAA});
    const double rbpf_tv = paper.meanPositionTv(CorridorEstimator::kRbpf);
    targets->push_back({"Murphy: RBPF (" + std::to_string(config.rbpf.particles) +
                            " particles) close to exact: mean position TV ≤ 0.12 on the paper's run",
                        fixed(rbpf_tv, 3), rbpf_tv <= 0.12});
    const double online_mass = paper.meanTruthMass(CorridorEstimator::kOnlineEm, back);
    const double exact_mass = paper.meanTruthMass(CorridorEstimator::kExact, back);
    targets->push_back({"Murphy: online EM lost on the way back (p(true cell), t = 10–16, ≤ 0.35; exact ≥ 0.6) and "
                        "stuck with M(5) = 1",
                        fixed(online_mass, 3) + " vs exact " + fixed(exact_mass, 3) + "; p(M(5) = 1) " +
                            fixed(online_m5, 3),
                        online_mass <= 0.35 && exact_mass >= 0.6 && online_m5 > 0.5});
    targets->push_back({"Murphy: offline EM learns 01010101", mapLabels(offline_labels, model.cells),
                        offline_labels == 0xAA});
  }
  return text.str();
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
