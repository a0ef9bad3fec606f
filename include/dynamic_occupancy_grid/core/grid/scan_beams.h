#pragma once
// A scan's beams as segments on a cell lattice: the reading rules every map of the package
// shares (the HMM Mapper and the memory model), in one place.
//
// ROS-free: standard library only.

#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/grid/scan.h"

namespace dynamic_occupancy_grid {
namespace core {

/// Largest lattice coordinate the traversal handles (int32 with margin); a grid limited to
/// its maximum size never comes close, a wild pose or range does.
constexpr double kMaxLatticeCoordinate = 1.0e9;

/// Why `scan` cannot be integrated (no ranges, a non-finite stamp, pose or angle, a zero
/// angle increment with several beams, a beam heading that overflows to infinity, not
/// 0 <= range_min < range_max); nullopt if it can.
std::optional<std::string> scanFieldsError(const Scan& scan);

/// The end of one beam in lattice coordinates: misses up to the end cell; the end cell is a
/// hit if `hit`, otherwise a miss too.
struct BeamEnd {
  double u1 = 0.0;
  double v1 = 0.0;
  bool hit = false;
};

struct BeamCounts {
  std::size_t hit = 0;        ///< finite range in [range_min, range_max)
  std::size_t no_return = 0;  ///< range >= range_max or +inf: free space only
  std::size_t ignored = 0;    ///< NaN, -inf, < range_min
};

/// How beams become segments.
struct BeamRules {
  double cells_per_m = 1.0;
  /// Beams without return clear up to this distance (0: they are ignored); at most one cell
  /// short of the scan's range_max.
  double max_free_range_m = 0.0;
  /// No beam is walked further than this (the far part of it would be outside the map);
  /// a beam cut short ends in a miss.
  double max_beam_m = 0.0;
};

/// The beams of a scan whose fields passed scanFieldsError, from the laser at lattice
/// coordinates (u0, v0). Readings:
///   finite range in [range_min, range_max): misses up to the end cell, a hit in it;
///   range >= range_max or +inf: misses up to max_free_range (capped one cell short of
///     range_max: a surface there may read beyond it), no hit;
///   NaN, -inf, < range_min: ignored.
/// Appends to `ends` (cleared first), counts the beams, and grows `box` by the end cells.
/// Returns the index of the first beam that ends beyond kMaxLatticeCoordinate (the scan
/// must then be refused), nullopt otherwise.
std::optional<std::size_t> beamEnds(const Scan& scan, double u0, double v0, const BeamRules& rules,
                                    std::vector<BeamEnd>& ends, BeamCounts& counts, CellBox& box);

}  // namespace core
}  // namespace dynamic_occupancy_grid
