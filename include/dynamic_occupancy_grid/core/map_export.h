#pragma once
// map_server-compatible export: a PGM image plus the YAML map_server loads it with, in the
// convention of map_saver (trinary: occupied 0, free 254, unknown 205). Both files are
// written atomically (temporary file, then rename), so a failed export leaves any older
// files intact.

#include <cstdint>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/cell_grid.h"

namespace dynamic_occupancy_grid {
namespace core {

struct MapServerThresholds {
  int occupied_percent = 65;  ///< values >= this are written as occupied
  int free_percent = 25;      ///< values in [0, this] are written as free
};

/// Writes `<directory>/<name>.pgm` and `<directory>/<name>.yaml` for row-major occupancy
/// values (-1 unknown, 0..100) over `window` (row 0 = bottom row, as in OccupancyGrid; the
/// image is flipped so that it shows north up, as map_server expects). Throws
/// std::runtime_error naming the file on any I/O failure.
void writeMapServerFiles(const std::string& directory, const std::string& name,
                         const MapWindow& window, const std::vector<std::int8_t>& occupancy,
                         const MapServerThresholds& thresholds = MapServerThresholds{});

/// Writes `contents` to `path` through `path.tmp` + rename; throws std::runtime_error.
void writeFileAtomically(const std::string& path, const std::string& contents);

}  // namespace core
}  // namespace dynamic_occupancy_grid
