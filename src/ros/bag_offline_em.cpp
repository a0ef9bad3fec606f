#include "dynamic_occupancy_grid/ros/bag_offline_em.h"

#include <chrono>
#include <stdexcept>

namespace dynamic_occupancy_grid {
namespace ros_layer {
namespace {

double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

BagMappingStats mapBag(BagScanSource& source, core::Mapper& mapper, bool continue_timeline,
                       const BagReadProgress& progress, const std::function<void(const core::Scan&)>& after_scan,
                       core::CorrectedMapping* correction) {
  if (correction != nullptr && (continue_timeline || &correction->mapper() != &mapper)) {
    throw std::invalid_argument("mapBag: a pose correction needs its own mapper and one timeline");
  }
  BagMappingStats stats;
  // Only an earlier bag's scans make a restart necessary; the first scan of all starts step 0.
  bool restart_clock = continue_timeline && mapper.clock().origin().has_value();
  stats.source = source.forEachScan(
      [&](const core::Scan& scan) {
        if (restart_clock) {
          mapper.restartClockAt(scan.stamp_s);
          restart_clock = false;
        }
        core::ScanResult result;
        if (correction == nullptr) {
          result = mapper.integrate(scan);
        } else {
          try {
            result = correction->integrate(scan).mapped;
          } catch (const std::invalid_argument& e) {
            result.status = core::ScanStatus::kRejectedInvalid;
            result.error = e.what();
          }
        }
        if (result.status != core::ScanStatus::kIntegrated) {
          ++stats.scans_rejected;
          stats.last_rejection = result.error;
          return;
        }
        ++stats.scans_integrated;
        stats.beams_hit += result.beams_hit;
        stats.beams_no_return += result.beams_no_return;
        stats.beams_ignored += result.beams_ignored;
        if (after_scan) after_scan(scan);
      },
      progress);
  if (!stats.source.cancelled) {
    if (correction != nullptr) correction->finish();
    mapper.finishStep();
  }
  return stats;
}

std::string describeUnusableBag(const std::string& bag_path, const BagMappingStats& stats) {
  const BagScanStats& source = stats.source;
  std::string message = "no scan of bag " + bag_path + " could be used: " + std::to_string(source.scans_read) +
                        " read";
  if (source.scans_outside_time_range > 0) {
    message += ", " + std::to_string(source.scans_outside_time_range) + " outside the time range";
  }
  if (source.scans_without_pose > 0) {
    message += ", " + std::to_string(source.scans_without_pose) + " without a pose (" + source.last_pose_error + ")";
  }
  if (stats.scans_rejected > 0) {
    message += ", " + std::to_string(stats.scans_rejected) + " rejected (" + stats.last_rejection + ")";
  }
  return message;
}

BagOfflineEmRun runOfflineEmOnBag(const BagOfflineEmOptions& options, const core::MapperConfig& geometry,
                                  const BagOfflineEmProgress& progress) {
  BagScanSource source(options.source);
  return runOfflineEmOnBag(source, options.em, geometry, progress);
}

BagOfflineEmRun runOfflineEmOnBag(BagScanSource& source, const core::OfflineEmConfig& em,
                                  const core::MapperConfig& geometry, const BagOfflineEmProgress& progress) {
  core::MapperConfig config = geometry;
  // Only the observations matter here; learning would cost time for nothing.
  config.learn_transitions = false;
  core::OfflineEmConfig em_config = em;
  em_config.initial_p_occ = config.initial_p_occ;
  em_config.validate();
  core::Mapper mapper(config);
  core::SequenceBuilder recorder;
  mapper.recordObservations(&recorder);

  BagOfflineEmRun run;
  const auto reading_start = std::chrono::steady_clock::now();
  BagReadProgress reading_progress;
  if (progress) reading_progress = [&progress](double fraction) { return progress("reading", fraction); };
  const BagMappingStats mapping = mapBag(source, mapper, false, reading_progress);
  mapper.recordObservations(nullptr);
  run.stats = mapping.source;
  run.scans_integrated = mapping.scans_integrated;
  run.scans_rejected = mapping.scans_rejected;
  run.last_rejection = mapping.last_rejection;
  run.reading_s = secondsSince(reading_start);
  if (mapping.source.cancelled) {
    run.result.cancelled = true;
    return run;
  }
  if (!mapper.lastAppliedStep()) throw std::runtime_error(describeUnusableBag(source.options().bag_path, mapping));

  run.sequences = recorder.build();
  const auto em_start = std::chrono::steady_clock::now();
  core::OfflineEmProgress em_progress;
  if (progress) {
    em_progress = [&progress](std::size_t done, std::size_t total) {
      return progress("em", total > 0 ? static_cast<double>(done) / static_cast<double>(total) : 1.0);
    };
  }
  run.result = core::runOfflineEm(run.sequences, mapper.sensor(), em_config, em_progress);
  run.em_s = secondsSince(em_start);
  return run;
}

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
