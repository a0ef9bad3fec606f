// write_npy_cli: a small test tool that writes two layers through the core's export
// (core::writeMapServerFiles + core::writeNpyLayer) with values of a fixed formula, so that
// test/python/test_render_layers.py can check that numpy reads the .npy files exactly and
// that scripts/render_layers.py renders them. Not installed; built by test/core_standalone.
//
// Usage: write_npy_cli DIR
//   a window of 7 columns x 5 rows, 0.1 m cells, origin (-0.3, 1.2); cell (row r, column c)
//   of the bottom-up, row-major values (i = r * 7 + c):
//     NaN (never observed) when (r + c) % 5 == 0, otherwise
//     belief            i / 35 (rounded to float)
//     p_occ_given_free  2^-(1 + i % 16) (exact in float)
//
// Exit status: 0 done, 2 usage, 3 a library error (message on stderr).

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <limits>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/layers/layers.h"
#include "dynamic_occupancy_grid/core/layers/map_export.h"

namespace dog = dynamic_occupancy_grid::core;

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: write_npy_cli DIR\n");
    return 2;
  }
  constexpr int kCols = 7;
  constexpr int kRows = 5;
  dog::MapWindow window;
  window.resolution_m = 0.1;
  window.origin_x_m = -0.3;
  window.origin_y_m = 1.2;
  window.cells.min_x = -3;
  window.cells.min_y = 12;
  window.cells.max_x = window.cells.min_x + kCols - 1;
  window.cells.max_y = window.cells.min_y + kRows - 1;
  std::vector<float> belief;
  std::vector<float> transitions;
  for (int r = 0; r < kRows; ++r) {
    for (int c = 0; c < kCols; ++c) {
      const int i = r * kCols + c;
      const bool unknown = (r + c) % 5 == 0;
      const float nan = std::numeric_limits<float>::quiet_NaN();
      belief.push_back(unknown ? nan : static_cast<float>(i / 35.0));
      transitions.push_back(unknown ? nan : std::ldexp(1.0f, -(1 + i % 16)));
    }
  }
  try {
    const std::string directory = argv[1];
    std::vector<std::int8_t> occupancy;
    dog::toOccupancyValues(belief, 1.0f, &occupancy);
    dog::writeMapServerFiles(directory, "belief", window, occupancy);
    dog::writeNpyLayer(directory, "belief", window, belief);
    dog::toOccupancyValues(transitions, 0.1f, &occupancy);
    dog::writeMapServerFiles(directory, "p_occ_given_free", window, occupancy);
    dog::writeNpyLayer(directory, "p_occ_given_free", window, transitions);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "write_npy_cli: %s\n", e.what());
    return 3;
  }
  return 0;
}
