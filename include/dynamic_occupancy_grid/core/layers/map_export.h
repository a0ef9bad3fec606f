#pragma once
// map_server-compatible export: a PGM image plus the YAML map_server loads it with, in the
// convention of map_saver (trinary: occupied 0, free 254, unknown 205). Every file is
// written by writeFileAtomically (core/layers/file_io.h: a unique temporary, fsync, rename; only a
// regular file is ever replaced), so a failed export leaves any older files intact.
//
// The values themselves: a NumPy .npy file per layer (format version 1.0, float32
// little-endian '<f4', C order, shape (rows, cols)), NaN for unknown cells, row 0 the
// bottom row (min y) as in nav_msgs/OccupancyGrid -- *not* flipped like the PGM; element
// [r][c] is the cell whose lower-left corner is at origin + (c, r) * resolution of the
// YAML written next to it.

#include <cstdint>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
// writeFileAtomically, which the tools also use for their own files.
#include "dynamic_occupancy_grid/core/layers/file_io.h"

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

/// The bytes of a NumPy .npy file (version 1.0) holding `values` as a float32 array of
/// shape (rows, cols) in C order ('<f4', little-endian on any host): element [r][c] =
/// values[r * cols + c]. NaN stays NaN. Throws std::invalid_argument when the sizes differ.
std::string npyFloat32(const std::vector<float>& values, std::int64_t rows, std::int64_t cols);

/// Writes `<directory>/<name>.npy` (npyFloat32 of row-major `values` over `window`, row 0 =
/// bottom row as in OccupancyGrid, NaN = unknown), atomically. Throws std::invalid_argument
/// for a size mismatch, std::runtime_error naming the file on any I/O failure.
void writeNpyLayer(const std::string& directory, const std::string& name, const MapWindow& window,
                   const std::vector<float>& values);

}  // namespace core
}  // namespace dynamic_occupancy_grid
