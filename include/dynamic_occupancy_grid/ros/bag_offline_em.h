#pragma once
// Bags into a mapper, and offline EM over a recorded bag: the bag's scans are ray-traced
// with a mapper's geometry (so its cells are the same lattice cells as the map's), every
// cell's observed steps are recorded, and Baum-Welch runs on them (core/cell/offline_em.h).
// Shared by process_bag, the offline_em tool and the node's ~run_offline_em service.

#include <cstddef>
#include <functional>
#include <string>

#include "dynamic_occupancy_grid/core/pose/corrected_mapping.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/cell/offline_em.h"
#include "dynamic_occupancy_grid/ros/bag_scan_source.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {

/// What mapBag did.
struct BagMappingStats {
  BagScanStats source;                  ///< scans read, without a pose, time span, cancelled
  std::size_t scans_integrated = 0;
  std::size_t scans_rejected = 0;       ///< malformed scans or time going backwards
  std::string last_rejection;
  std::size_t beams_hit = 0;
  std::size_t beams_no_return = 0;
  std::size_t beams_ignored = 0;
};

/// Integrates every scan of `source` into `mapper` and applies the last step gathered
/// (unless cancelled). With `continue_timeline` and a mapper that has seen scans before
/// (an earlier bag), the mapper's clock is restarted at this bag's first scan
/// (Mapper::restartClockAt), so bags recorded at any times continue one timeline.
/// `after_scan` (optional) runs after each integrated scan, e.g. to write snapshots. With
/// `correction` (on `mapper`), the scans' poses are read as odometry and the scans go
/// through it (pose correction; not with continue_timeline); a scan its filter refuses
/// counts as rejected. Errors as BagScanSource::forEachScan.
BagMappingStats mapBag(BagScanSource& source, core::Mapper& mapper, bool continue_timeline,
                       const BagReadProgress& progress = {},
                       const std::function<void(const core::Scan&)>& after_scan = {},
                       core::CorrectedMapping* correction = nullptr);

/// One line saying why no scan of a bag could be used (for error messages).
std::string describeUnusableBag(const std::string& bag_path, const BagMappingStats& stats);

/// Offline EM prior weight of the tools and the node (the core's own default is 0 = maximum
/// likelihood): a cell seen only free has no evidence about p_free_given_occ, which maximum
/// likelihood leaves drifting to p_max (0.47 per step on average on the Neato bag); two
/// pseudo-transitions of the prior per state bring it to 0.035.
constexpr double kDefaultOfflinePriorWeight = 2.0;

struct BagOfflineEmOptions {
  BagScanSourceOptions source;   ///< bag, scan topic, fixed frame, time range
  /// Its initial_p_occ is replaced by the geometry's, so that the EM chain starts where the
  /// mapper's cells start.
  core::OfflineEmConfig em;
};

struct BagOfflineEmRun {
  core::ObservationSequences sequences;  ///< per cell, on the mapper's lattice
  core::OfflineEmResult result;          ///< result.cancelled if progress said stop
  BagScanStats stats;
  std::size_t scans_integrated = 0;
  std::size_t scans_rejected = 0;        ///< malformed scans or time going backwards
  std::string last_rejection;
  double reading_s = 0.0;                ///< wall time of reading and ray-tracing the bag
  double em_s = 0.0;                     ///< wall time of the EM iterations
};

/// Progress: phase "reading" (the bag) or "em" (the EM iterations) with a fraction in
/// [0, 1]; return false to stop (the run then returns at once with result.cancelled).
/// Called from the calling thread while reading, from an EM worker thread (never
/// concurrently) during EM.
using BagOfflineEmProgress = std::function<bool(const std::string& phase, double fraction)>;

/// Reads the bag (errors as BagScanSource: std::runtime_error naming the file), maps it with
/// `geometry` (its resolution, origin, bounds, time step and sensor model; transitions are
/// not learned while reading), then runs offline EM. Throws std::runtime_error if no scan of
/// the bag could be used, std::invalid_argument for a bad EM or mapper configuration.
BagOfflineEmRun runOfflineEmOnBag(const BagOfflineEmOptions& options, const core::MapperConfig& geometry,
                                  const BagOfflineEmProgress& progress = {});

/// The same on a bag opened already (e.g. checked synchronously by a service before the run
/// goes to a background thread); `options.source` is not used, the source's own options are.
BagOfflineEmRun runOfflineEmOnBag(BagScanSource& source, const core::OfflineEmConfig& em,
                                  const core::MapperConfig& geometry, const BagOfflineEmProgress& progress = {});

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
