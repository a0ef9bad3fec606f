#include "dynamic_occupancy_grid/core/layers/map_export.h"

#include <cstdint>
#include <cstring>
#include <iomanip>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace dynamic_occupancy_grid {
namespace core {

std::string npyFloat32(const std::vector<float>& values, std::int64_t rows, std::int64_t cols) {
  if (rows < 0 || cols < 0 || static_cast<std::int64_t>(values.size()) != rows * cols) {
    throw std::invalid_argument("npy: " + std::to_string(values.size()) + " values for a " +
                                std::to_string(rows) + " x " + std::to_string(cols) + " array");
  }
  // Format 1.0 (numpy.lib.format): magic, version, little-endian uint16 header length, then
  // an ASCII dict padded with spaces and ended by '\n' so that the data starts at a multiple
  // of 64 bytes.
  std::string header = "{'descr': '<f4', 'fortran_order': False, 'shape': (" + std::to_string(rows) + ", " +
                       std::to_string(cols) + "), }";
  constexpr std::size_t kPreamble = 10;  // magic (6) + version (2) + header length (2)
  const std::size_t total = (kPreamble + header.size() + 1 + 63) / 64 * 64;
  header.append(total - kPreamble - header.size() - 1, ' ');
  header.push_back('\n');
  std::string bytes("\x93NUMPY\x01\x00", 8);
  bytes.push_back(static_cast<char>(header.size() & 0xFF));
  bytes.push_back(static_cast<char>((header.size() >> 8) & 0xFF));
  bytes += header;
  bytes.reserve(bytes.size() + 4 * values.size());
  for (const float value : values) {
    std::uint32_t word = 0;
    static_assert(sizeof(word) == sizeof(value) && std::numeric_limits<float>::is_iec559,
                  "'<f4' needs IEEE 754 binary32 floats");
    std::memcpy(&word, &value, sizeof(word));
    for (int shift = 0; shift < 32; shift += 8) bytes.push_back(static_cast<char>((word >> shift) & 0xFF));
  }
  return bytes;
}

void writeNpyLayer(const std::string& directory, const std::string& name, const MapWindow& window,
                   const std::vector<float>& values) {
  const std::int64_t width = window.cells.width();
  const std::int64_t height = window.cells.height();
  if (static_cast<std::int64_t>(values.size()) != width * height) {
    throw std::invalid_argument("npy export of " + name + ": " + std::to_string(values.size()) +
                                " values for a " + std::to_string(width) + " x " +
                                std::to_string(height) + " window");
  }
  writeFileAtomically(directory + "/" + name + ".npy", npyFloat32(values, height, width));
}

void writeMapServerFiles(const std::string& directory, const std::string& name,
                         const MapWindow& window, const std::vector<std::int8_t>& occupancy,
                         const MapServerThresholds& thresholds) {
  const std::int64_t width = window.cells.width();
  const std::int64_t height = window.cells.height();
  if (static_cast<std::int64_t>(occupancy.size()) != width * height) {
    throw std::invalid_argument("map export of " + name + ": " + std::to_string(occupancy.size()) +
                                " values for a " + std::to_string(width) + " x " +
                                std::to_string(height) + " window");
  }
  std::string image = "P5\n# dynamic_occupancy_grid " + name + "\n" + std::to_string(width) + " " +
                      std::to_string(height) + "\n255\n";
  const std::size_t header = image.size();
  image.resize(header + static_cast<std::size_t>(width * height));
  for (std::int64_t row = 0; row < height; ++row) {
    // Image row 0 is the top (north) row: the last row of the grid.
    const std::int8_t* source = occupancy.data() + (height - 1 - row) * width;
    char* target = &image[header + static_cast<std::size_t>(row * width)];
    for (std::int64_t col = 0; col < width; ++col) {
      const int value = source[col];
      unsigned char pixel = 205;  // unknown
      if (value >= 0 && value <= thresholds.free_percent) {
        pixel = 254;
      } else if (value >= thresholds.occupied_percent) {
        pixel = 0;
      }
      target[col] = static_cast<char>(pixel);
    }
  }
  std::ostringstream yaml;
  yaml << std::setprecision(9) << "image: " << name << ".pgm\n"
       << "resolution: " << window.resolution_m << "\n"
       << "origin: [" << window.origin_x_m << ", " << window.origin_y_m << ", 0.0]\n"
       << "negate: 0\n"
       << "occupied_thresh: " << thresholds.occupied_percent / 100.0 << "\n"
       // map_saver's value: the unknown grey 205 reads as p = 50/255 = 0.196, not free.
       << "free_thresh: 0.196\n";
  const std::string base = directory + "/" + name;
  writeFileAtomically(base + ".pgm", image);
  writeFileAtomically(base + ".yaml", yaml.str());
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
