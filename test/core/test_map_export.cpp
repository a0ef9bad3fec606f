// Tests of the map_server export (core/layers/map_export.h): the binary PGM (P5) and its YAML,
// pixel values (occupied 0, free 254, unknown 205), the north-up row flip, the YAML fields,
// map_server's own reading of the pair, and the atomic-write guarantees (no temporary file
// left, failures throw std::runtime_error and leave older files intact); the .npy values
// (npyFloat32, writeNpyLayer): header, shape, exact values with NaN, row order, atomicity.
//
// Every test works in its own fresh directory under the system temporary directory.

#include "dynamic_occupancy_grid/core/layers/map_export.h"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/layers/layers.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"

namespace dog = dynamic_occupancy_grid::core;
namespace fs = std::filesystem;

namespace {

class TempDir {
 public:
  TempDir() {
    std::string pattern = (fs::temp_directory_path() / "dog_map_export_XXXXXX").string();
    char* made = mkdtemp(pattern.data());
    if (made == nullptr) throw std::runtime_error("mkdtemp failed");
    path_ = made;
  }
  ~TempDir() {
    std::error_code ignored;
    fs::remove_all(path_, ignored);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const fs::path& path() const { return path_; }
  std::string str() const { return path_.string(); }

 private:
  fs::path path_;
};

std::string readFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

std::set<std::string> listDir(const fs::path& dir) {
  std::set<std::string> names;
  for (const auto& entry : fs::directory_iterator(dir)) names.insert(entry.path().filename().string());
  return names;
}

struct Pgm {
  std::int64_t width = -1;
  std::int64_t height = -1;
  int maxval = -1;
  std::vector<unsigned char> pixels;
};

// A strict-enough P5 reader: magic, then width, height, maxval separated by whitespace with
// '#' comments allowed, exactly one whitespace character, then width * height bytes and
// nothing after them.
Pgm parsePgm(const std::string& data) {
  Pgm pgm;
  if (data.compare(0, 2, "P5") != 0) {
    ADD_FAILURE() << "not a binary PGM";
    return pgm;
  }
  std::size_t pos = 2;
  std::int64_t fields[3];
  for (int f = 0; f < 3; ++f) {
    while (pos < data.size()) {
      if (std::isspace(static_cast<unsigned char>(data[pos]))) {
        ++pos;
      } else if (data[pos] == '#') {
        while (pos < data.size() && data[pos] != '\n') ++pos;
      } else {
        break;
      }
    }
    std::int64_t value = 0;
    const std::size_t start = pos;
    while (pos < data.size() && std::isdigit(static_cast<unsigned char>(data[pos]))) {
      value = value * 10 + (data[pos] - '0');
      ++pos;
    }
    if (pos == start) {
      ADD_FAILURE() << "PGM header field " << f << " missing";
      return pgm;
    }
    fields[f] = value;
  }
  if (pos >= data.size() || !std::isspace(static_cast<unsigned char>(data[pos]))) {
    ADD_FAILURE() << "no whitespace after maxval";
    return pgm;
  }
  ++pos;
  pgm.width = fields[0];
  pgm.height = fields[1];
  pgm.maxval = static_cast<int>(fields[2]);
  pgm.pixels.assign(data.begin() + static_cast<std::ptrdiff_t>(pos), data.end());
  return pgm;
}

std::map<std::string, std::string> parseYaml(const std::string& text) {
  std::map<std::string, std::string> fields;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    const auto colon = line.find(':');
    if (colon == std::string::npos) continue;
    std::string value = line.substr(colon + 1);
    while (!value.empty() && value.front() == ' ') value.erase(0, 1);
    while (!value.empty() && (value.back() == ' ' || value.back() == '\r')) value.pop_back();
    fields[line.substr(0, colon)] = value;
  }
  return fields;
}

std::vector<double> parseList(const std::string& value) {
  std::vector<double> numbers;
  std::string inner = value;
  if (!inner.empty() && inner.front() == '[') inner.erase(0, 1);
  if (!inner.empty() && inner.back() == ']') inner.pop_back();
  std::istringstream in(inner);
  std::string item;
  while (std::getline(in, item, ',')) numbers.push_back(std::stod(item));
  return numbers;
}

dog::MapWindow makeWindow(std::int32_t min_x, std::int32_t min_y, std::int32_t max_x,
                          std::int32_t max_y, double resolution, double origin_x, double origin_y) {
  dog::MapWindow w;
  w.resolution_m = resolution;
  w.origin_x_m = origin_x;
  w.origin_y_m = origin_y;
  w.cells.min_x = min_x;
  w.cells.min_y = min_y;
  w.cells.max_x = max_x;
  w.cells.max_y = max_y;
  return w;
}

// map_saver's trinary convention with thresholds in percent.
unsigned char expectedPixel(int value, int occupied_percent, int free_percent) {
  if (value < 0) return 205;
  if (value >= occupied_percent) return 0;
  if (value <= free_percent) return 254;
  return 205;
}

}  // namespace

TEST(MapExport, PgmHeaderPixelsAndRowFlip) {
  TempDir dir;
  // 5 wide, 3 high; row 0 = bottom (OccupancyGrid order).
  const dog::MapWindow window = makeWindow(-2, 3, 2, 5, 0.05, -1.1, 2.15);
  const std::vector<std::int8_t> occupancy{
      -1, 0,  25, 26,  64,   // row 0 (bottom)
      65, 100, 50, -1, 1,    // row 1
      24, 66, 99, 0,  -1,    // row 2 (top)
  };
  dog::writeMapServerFiles(dir.str(), "map", window, occupancy);
  EXPECT_EQ(listDir(dir.path()), (std::set<std::string>{"map.pgm", "map.yaml"}));
  const std::string data = readFile(dir.path() / "map.pgm");
  const Pgm pgm = parsePgm(data);
  EXPECT_EQ(pgm.width, 5);
  EXPECT_EQ(pgm.height, 3);
  EXPECT_EQ(pgm.maxval, 255);
  ASSERT_EQ(pgm.pixels.size(), 15u);
  // Image row 0 is the top: the grid's last row.
  const std::vector<unsigned char> expected{
      254, 0,   0,   254, 205,  // grid row 2
      0,   0,   205, 205, 254,  // grid row 1
      205, 254, 254, 205, 205,  // grid row 0
  };
  for (std::size_t i = 0; i < expected.size(); ++i) {
    EXPECT_EQ(static_cast<int>(pgm.pixels[i]), static_cast<int>(expected[i])) << "pixel " << i;
  }
}

TEST(MapExport, YamlFields) {
  TempDir dir;
  const dog::MapWindow window = makeWindow(-2, 3, 2, 5, 0.05, -1.1, 2.15);
  dog::writeMapServerFiles(dir.str(), "floor_1", window, std::vector<std::int8_t>(15, 0));
  const auto yaml = parseYaml(readFile(dir.path() / "floor_1.yaml"));
  ASSERT_EQ(yaml.count("image"), 1u);
  EXPECT_EQ(yaml.at("image"), "floor_1.pgm");  // relative to the YAML, as map_saver writes it
  ASSERT_EQ(yaml.count("resolution"), 1u);
  EXPECT_NEAR(std::stod(yaml.at("resolution")), 0.05, 1e-9);
  ASSERT_EQ(yaml.count("origin"), 1u);
  const std::vector<double> origin = parseList(yaml.at("origin"));
  ASSERT_EQ(origin.size(), 3u);
  EXPECT_NEAR(origin[0], -1.1, 1e-9);
  EXPECT_NEAR(origin[1], 2.15, 1e-9);
  EXPECT_NEAR(origin[2], 0.0, 1e-12);
  ASSERT_EQ(yaml.count("negate"), 1u);
  EXPECT_EQ(std::stoi(yaml.at("negate")), 0);
  ASSERT_EQ(yaml.count("occupied_thresh"), 1u);
  ASSERT_EQ(yaml.count("free_thresh"), 1u);
  EXPECT_NEAR(std::stod(yaml.at("occupied_thresh")), 0.65, 1e-9);
}

TEST(MapExport, MapServerReadsBackTheTrinaryClasses) {
  // map_server with negate 0: p = (255 - pixel) / 255; occupied if p > occupied_thresh, free
  // if p < free_thresh, unknown otherwise. The pair must reproduce the input's classes.
  for (const dog::MapServerThresholds& t :
       {dog::MapServerThresholds{}, dog::MapServerThresholds{80, 10}, dog::MapServerThresholds{51, 49}}) {
    SCOPED_TRACE(std::to_string(t.occupied_percent) + "/" + std::to_string(t.free_percent));
    TempDir dir;
    std::vector<std::int8_t> occupancy;
    for (int v = -1; v <= 100; ++v) occupancy.push_back(static_cast<std::int8_t>(v));  // 102 values
    const dog::MapWindow window = makeWindow(0, 0, 16, 5, 0.1, 0.0, 0.0);               // 17 x 6
    dog::writeMapServerFiles(dir.str(), "m", window, occupancy, t);
    const Pgm pgm = parsePgm(readFile(dir.path() / "m.pgm"));
    ASSERT_EQ(pgm.pixels.size(), 102u);
    const auto yaml = parseYaml(readFile(dir.path() / "m.yaml"));
    const double occ_th = std::stod(yaml.at("occupied_thresh"));
    const double free_th = std::stod(yaml.at("free_thresh"));
    EXPECT_NEAR(occ_th, t.occupied_percent / 100.0, 1e-9);
    for (std::int64_t row = 0; row < 6; ++row) {
      for (std::int64_t col = 0; col < 17; ++col) {
        const int value = occupancy[static_cast<std::size_t>(row * 17 + col)];
        const unsigned char pixel = pgm.pixels[static_cast<std::size_t>((5 - row) * 17 + col)];
        ASSERT_EQ(static_cast<int>(pixel),
                  static_cast<int>(expectedPixel(value, t.occupied_percent, t.free_percent)))
            << "value " << value;
        const double p = (255.0 - pixel) / 255.0;
        const int cls = p > occ_th ? 100 : (p < free_th ? 0 : -1);
        const int expected_cls = value < 0 ? -1
                                 : value >= t.occupied_percent ? 100
                                 : value <= t.free_percent    ? 0
                                                              : -1;
        ASSERT_EQ(cls, expected_cls) << "value " << value;
      }
    }
  }
}

TEST(MapExport, ExportOfALayerFromTheMapper) {
  // A mapped row exported through evaluateLayer + toOccupancyValues: the PGM is the window of
  // the grid, flipped, with hits occupied and misses free.
  dog::MapperConfig config;
  config.resolution_m = 0.25;
  config.origin_x_m = -3.0;
  config.origin_y_m = 1.0;
  config.prior_transitions = dog::TransitionParams{0.0, 0.0};
  dog::Mapper mapper(config);
  dog::Scan scan;
  scan.laser_pose.x_m = -3.0 + 0.125;  // centre of cell (0, 0)
  scan.laser_pose.y_m = 1.0 + 0.125;
  scan.angle_increment_rad = 0.1;
  scan.range_max_m = 10.0;
  scan.ranges_m = {1.0f};
  for (int step = 0; step < 3; ++step) {
    scan.stamp_s = step;
    mapper.integrate(scan);
  }
  mapper.finishStep();
  dog::CellBox box;
  box.include(0, 0);
  box.include(5, 1);
  std::vector<float> values;
  dog::evaluateLayer(mapper.grid(), dog::Layer::kBelief, 2, 0, box, &values);
  std::vector<std::int8_t> occupancy;
  dog::toOccupancyValues(values, 1.0f, &occupancy);
  TempDir dir;
  const dog::MapWindow window = mapper.grid().window(box);
  dog::writeMapServerFiles(dir.str(), "belief", window, occupancy);
  const Pgm pgm = parsePgm(readFile(dir.path() / "belief.pgm"));
  ASSERT_EQ(pgm.width, 6);
  ASSERT_EQ(pgm.height, 2);
  // Top image row = grid row 1 (unknown); bottom = row 0: 4 free, hit, unknown.
  const std::vector<unsigned char> expected{205, 205, 205, 205, 205, 205, 254, 254, 254, 254, 0, 205};
  ASSERT_EQ(pgm.pixels, expected);
  const auto yaml = parseYaml(readFile(dir.path() / "belief.yaml"));
  const std::vector<double> origin = parseList(yaml.at("origin"));
  ASSERT_EQ(origin.size(), 3u);
  EXPECT_NEAR(origin[0], -3.0, 1e-9);
  EXPECT_NEAR(origin[1], 1.0, 1e-9);
  EXPECT_NEAR(std::stod(yaml.at("resolution")), 0.25, 1e-12);
}

TEST(MapExport, ExistingFilesAreReplacedWithoutTemporaryFilesLeft) {
  TempDir dir;
  const dog::MapWindow big = makeWindow(0, 0, 9, 9, 0.1, 0.0, 0.0);
  dog::writeMapServerFiles(dir.str(), "map", big, std::vector<std::int8_t>(100, 100));
  const dog::MapWindow small = makeWindow(0, 0, 1, 0, 0.5, 4.0, -2.0);
  dog::writeMapServerFiles(dir.str(), "map", small, std::vector<std::int8_t>{0, -1});
  EXPECT_EQ(listDir(dir.path()), (std::set<std::string>{"map.pgm", "map.yaml"}));
  const Pgm pgm = parsePgm(readFile(dir.path() / "map.pgm"));
  EXPECT_EQ(pgm.width, 2);
  EXPECT_EQ(pgm.height, 1);
  EXPECT_EQ(pgm.pixels, (std::vector<unsigned char>{254, 205}));  // nothing of the old file left
  const auto yaml = parseYaml(readFile(dir.path() / "map.yaml"));
  EXPECT_NEAR(std::stod(yaml.at("resolution")), 0.5, 1e-12);
  EXPECT_NEAR(parseList(yaml.at("origin"))[0], 4.0, 1e-12);
}

TEST(MapExport, MissingDirectoryThrowsAndLeavesNothingBehind) {
  TempDir dir;
  const fs::path missing = dir.path() / "does" / "not" / "exist";
  const dog::MapWindow window = makeWindow(0, 0, 1, 1, 0.1, 0.0, 0.0);
  try {
    dog::writeMapServerFiles(missing.string(), "map", window, std::vector<std::int8_t>(4, 0));
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("map"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(dir.path() / "does"));
  EXPECT_TRUE(listDir(dir.path()).empty());
}

TEST(MapExport, FailedWriteKeepsTheOlderFile) {
  TempDir dir;
  const dog::MapWindow window = makeWindow(0, 0, 1, 1, 0.1, 0.0, 0.0);
  dog::writeMapServerFiles(dir.str(), "map", window, std::vector<std::int8_t>(4, 100));
  const std::string old_pgm = readFile(dir.path() / "map.pgm");
  const std::string old_yaml = readFile(dir.path() / "map.yaml");
  // A read-only directory: no temporary can be created (as root, whom permissions do not
  // bind, the export runs as the user nobody).
  fs::permissions(dir.path(), fs::perms::owner_read | fs::perms::owner_exec | fs::perms::group_read |
                                  fs::perms::group_exec | fs::perms::others_read | fs::perms::others_exec);
  const bool root = ::geteuid() == 0;
  if (root) ASSERT_EQ(::seteuid(65534), 0);
  std::string message = "NO EXCEPTION";
  try {
    dog::writeMapServerFiles(dir.str(), "map", window, std::vector<std::int8_t>(4, 0));
  } catch (const std::runtime_error& e) {
    message = e.what();
  }
  if (root) ASSERT_EQ(::seteuid(0), 0);
  fs::permissions(dir.path(), fs::perms::owner_all, fs::perm_options::add);
  EXPECT_NE(message.find("cannot write " + (dir.path() / "map.pgm").string()), std::string::npos) << message;
  EXPECT_EQ(readFile(dir.path() / "map.pgm"), old_pgm);
  EXPECT_EQ(readFile(dir.path() / "map.yaml"), old_yaml);
  EXPECT_EQ(listDir(dir.path()), (std::set<std::string>{"map.pgm", "map.yaml"}));
}

TEST(MapExport, OnlyRegularFilesAreReplaced) {
  // A FIFO where an export file goes is refused (not replaced, not blocked on); the files
  // before it are written.
  TempDir dir;
  const dog::MapWindow window = makeWindow(0, 0, 1, 1, 0.1, 0.0, 0.0);
  const fs::path fifo = dir.path() / "map.yaml";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  try {
    dog::writeMapServerFiles(dir.str(), "map", window, std::vector<std::int8_t>(4, 0));
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()),
              "cannot write " + fifo.string() + ": it is a FIFO (named pipe), not a regular file; it is left as it is");
  }
  EXPECT_TRUE(fs::is_fifo(fifo));
  EXPECT_EQ(listDir(dir.path()), (std::set<std::string>{"map.pgm", "map.yaml"}));
  const fs::path directory = dir.path() / "belief.npy";
  fs::create_directory(directory);
  EXPECT_THROW(dog::writeNpyLayer(dir.str(), "belief", window, std::vector<float>(4, 0.5f)), std::runtime_error);
  EXPECT_TRUE(fs::is_directory(directory));
}

TEST(MapExport, WrongNumberOfValuesIsRejectedBeforeWriting) {
  TempDir dir;
  const dog::MapWindow window = makeWindow(0, 0, 2, 2, 0.1, 0.0, 0.0);
  EXPECT_ANY_THROW(dog::writeMapServerFiles(dir.str(), "map", window, std::vector<std::int8_t>(8, 0)));
  EXPECT_TRUE(listDir(dir.path()).empty());
}

TEST(WriteFileAtomically, WritesReplacesAndCleansUp) {
  TempDir dir;
  const fs::path file = dir.path() / "data.bin";
  std::string contents("binary\0data\n", 12);
  dog::writeFileAtomically(file.string(), contents);
  EXPECT_EQ(readFile(file), contents);
  dog::writeFileAtomically(file.string(), "x");
  EXPECT_EQ(readFile(file), "x");
  dog::writeFileAtomically(file.string(), "");
  EXPECT_EQ(readFile(file), "");
  EXPECT_TRUE(fs::exists(file));
  EXPECT_EQ(listDir(dir.path()), (std::set<std::string>{"data.bin"}));
  const fs::path missing = dir.path() / "nope" / "data.bin";
  try {
    dog::writeFileAtomically(missing.string(), "abc");
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("data.bin"), std::string::npos) << e.what();
  }
  EXPECT_EQ(listDir(dir.path()), (std::set<std::string>{"data.bin"}));
}

// --- the .npy values (npyFloat32, writeNpyLayer) ------------------------------------------------

namespace {

struct Npy {
  std::string header;  ///< the dict, without padding and newline
  std::vector<float> values;
};

// Parses a version 1.0 .npy file as numpy.lib.format documents it, checking every rule of the
// preamble: magic, version, header length, padding to 64 bytes, the closing newline.
Npy parseNpy(const std::string& data) {
  Npy npy;
  if (data.size() < 10 || data.compare(0, 6, "\x93NUMPY", 6) != 0) {
    ADD_FAILURE() << "no .npy magic";
    return npy;
  }
  EXPECT_EQ(static_cast<unsigned char>(data[6]), 1u) << "major version";
  EXPECT_EQ(static_cast<unsigned char>(data[7]), 0u) << "minor version";
  const std::size_t length =
      static_cast<unsigned char>(data[8]) | (static_cast<std::size_t>(static_cast<unsigned char>(data[9])) << 8);
  if (data.size() < 10 + length) {
    ADD_FAILURE() << "header longer than the file";
    return npy;
  }
  EXPECT_EQ((10 + length) % 64, 0u) << "data not aligned to 64 bytes";
  std::string header = data.substr(10, length);
  EXPECT_EQ(header.back(), '\n');
  header.pop_back();
  while (!header.empty() && header.back() == ' ') header.pop_back();
  for (const char c : header) EXPECT_TRUE(c >= 0x20 && c < 0x7f) << "non-ASCII header";
  npy.header = header;
  const std::string body = data.substr(10 + length);
  EXPECT_EQ(body.size() % 4, 0u);
  for (std::size_t i = 0; i + 4 <= body.size(); i += 4) {
    std::uint32_t word = 0;
    for (int b = 0; b < 4; ++b) word |= std::uint32_t{static_cast<unsigned char>(body[i + b])} << (8 * b);
    float value = 0.0f;
    std::memcpy(&value, &word, sizeof(value));
    npy.values.push_back(value);
  }
  return npy;
}

std::uint32_t bitsOf(float value) {
  std::uint32_t word = 0;
  std::memcpy(&word, &value, sizeof(word));
  return word;
}

}  // namespace

TEST(Npy, HeaderParsesAndValuesRoundTripWithNaN) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<float> values{0.0f, 0.01f, nan, 1.0f, -0.0f, 1e-30f, std::numeric_limits<float>::infinity(),
                                  0.123456789f, nan, 1e-7f, 0.5f, 3.0e38f};
  const std::string bytes = dog::npyFloat32(values, 3, 4);
  const Npy npy = parseNpy(bytes);
  EXPECT_EQ(npy.header, "{'descr': '<f4', 'fortran_order': False, 'shape': (3, 4), }");
  ASSERT_EQ(npy.values.size(), values.size());
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (std::isnan(values[i])) {
      EXPECT_TRUE(std::isnan(npy.values[i])) << "element " << i;
    } else {
      EXPECT_EQ(bitsOf(npy.values[i]), bitsOf(values[i])) << "element " << i;  // exact, -0 included
    }
  }
  // Little-endian whatever the host: 1.0f is 00 00 80 3f.
  EXPECT_EQ(bytes.substr(bytes.size() - 4 * 9, 4), std::string("\x00\x00\x80\x3f", 4));
}

TEST(Npy, EmptyAndLargeShapes) {
  const Npy empty = parseNpy(dog::npyFloat32({}, 0, 0));
  EXPECT_EQ(empty.header, "{'descr': '<f4', 'fortran_order': False, 'shape': (0, 0), }");
  EXPECT_TRUE(empty.values.empty());
  const Npy tall = parseNpy(dog::npyFloat32(std::vector<float>(123456, 0.25f), 123456, 1));
  EXPECT_EQ(tall.header, "{'descr': '<f4', 'fortran_order': False, 'shape': (123456, 1), }");
  EXPECT_EQ(tall.values, std::vector<float>(123456, 0.25f));
  EXPECT_THROW(dog::npyFloat32(std::vector<float>(5), 2, 3), std::invalid_argument);
  EXPECT_THROW(dog::npyFloat32({}, -1, 0), std::invalid_argument);
}

TEST(Npy, LayerFileHasTheWindowShapeRowZeroAtTheBottomAndIsAtomic) {
  TempDir dir;
  // 3 columns x 2 rows; values row-major from the bottom row, as evaluateLayer gives them.
  const dog::MapWindow window = makeWindow(-1, 4, 1, 5, 0.05, -0.05, 0.2);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<float> values{0.1f, 0.2f, nan, 0.4f, 0.5f, 0.6f};
  dog::writeNpyLayer(dir.str(), "p_occ_given_free", window, values);
  EXPECT_EQ(listDir(dir.path()), (std::set<std::string>{"p_occ_given_free.npy"}));
  const Npy npy = parseNpy(readFile(dir.path() / "p_occ_given_free.npy"));
  EXPECT_EQ(npy.header, "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }");
  ASSERT_EQ(npy.values.size(), 6u);
  EXPECT_EQ(npy.values[0], 0.1f);  // [0][0]: the bottom-left cell, not flipped like the PGM
  EXPECT_TRUE(std::isnan(npy.values[2]));
  EXPECT_EQ(npy.values[3], 0.4f);  // [1][0]: the row above
  // Rewriting replaces the file; a size mismatch throws before anything is written; a
  // missing directory throws naming the file.
  dog::writeNpyLayer(dir.str(), "p_occ_given_free", makeWindow(0, 0, 0, 0, 0.05, 0.0, 0.0), {0.75f});
  EXPECT_EQ(parseNpy(readFile(dir.path() / "p_occ_given_free.npy")).values, std::vector<float>{0.75f});
  EXPECT_THROW(dog::writeNpyLayer(dir.str(), "other", window, std::vector<float>(5)), std::invalid_argument);
  try {
    dog::writeNpyLayer((dir.path() / "missing").string(), "belief", window, values);
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("belief.npy"), std::string::npos) << e.what();
  }
  EXPECT_EQ(listDir(dir.path()), (std::set<std::string>{"p_occ_given_free.npy"}));
}
