// map_server export: PGM pixels, row order, YAML fields, atomic replacement, clear errors.

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/map_export.h"

namespace dog = dynamic_occupancy_grid::core;
namespace fs = std::filesystem;

namespace {

std::string readFile(const fs::path& path) {
  std::ifstream file(path, std::ios::binary);
  std::stringstream contents;
  contents << file.rdbuf();
  return contents.str();
}

class MapExport : public ::testing::Test {
 protected:
  void SetUp() override {
    directory_ = fs::temp_directory_path() /
                 ("dog_map_export_" + std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()));
    fs::remove_all(directory_);
    fs::create_directories(directory_);
  }
  void TearDown() override { fs::remove_all(directory_); }

  // A 3 x 2 window: row 0 (bottom) = {occupied, free, unknown}, row 1 = {64, 65, 25}.
  static dog::MapWindow window() {
    dog::MapWindow window;
    window.resolution_m = 0.05;
    window.origin_x_m = -1.5;
    window.origin_y_m = 2.25;
    window.cells = dog::CellBox{10, 20, 12, 21};
    return window;
  }
  static std::vector<std::int8_t> values() { return {100, 0, -1, 64, 65, 25}; }

  fs::path directory_;
};

TEST_F(MapExport, WritesTrinaryPgmNorthUp) {
  dog::writeMapServerFiles(directory_.string(), "belief", window(), values());
  const std::string image = readFile(directory_ / "belief.pgm");
  const std::string header = "P5\n# dynamic_occupancy_grid belief\n3 2\n255\n";
  ASSERT_EQ(image.substr(0, header.size()), header);
  const std::string pixels = image.substr(header.size());
  ASSERT_EQ(pixels.size(), 6u);
  // Top image row = the grid's last row: 64 -> unknown, 65 -> occupied, 25 -> free.
  const std::vector<unsigned char> expected{205, 0, 254, 0, 254, 205};
  for (std::size_t i = 0; i < expected.size(); ++i) {
    EXPECT_EQ(static_cast<unsigned char>(pixels[i]), expected[i]) << i;
  }
}

TEST_F(MapExport, WritesTheYamlMapServerReads) {
  dog::writeMapServerFiles(directory_.string(), "static_map", window(), values());
  const std::string yaml = readFile(directory_ / "static_map.yaml");
  EXPECT_NE(yaml.find("image: static_map.pgm\n"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("resolution: 0.05\n"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("origin: [-1.5, 2.25, 0.0]\n"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("negate: 0\n"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("occupied_thresh: 0.65\n"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("free_thresh: 0.196\n"), std::string::npos) << yaml;
}

TEST_F(MapExport, ReplacesAnOlderExportAndLeavesNoTemporaryFile) {
  std::ofstream(directory_ / "belief.pgm") << "old";
  dog::writeMapServerFiles(directory_.string(), "belief", window(), values());
  EXPECT_NE(readFile(directory_ / "belief.pgm"), "old");
  for (const auto& entry : fs::directory_iterator(directory_)) {
    EXPECT_NE(entry.path().extension(), ".tmp") << entry.path();
  }
}

TEST_F(MapExport, MissingDirectoryThrowsNamingTheFileAndWritesNothing) {
  const fs::path missing = directory_ / "does_not_exist";
  try {
    dog::writeMapServerFiles(missing.string(), "belief", window(), values());
    FAIL() << "no error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("belief.pgm"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(missing));
}

TEST_F(MapExport, FailedWriteKeepsTheOlderFile) {
  // The target is a directory: rename fails, the temporary file is removed.
  fs::create_directories(directory_ / "belief.pgm" / "inside");
  EXPECT_THROW(dog::writeMapServerFiles(directory_.string(), "belief", window(), values()),
               std::runtime_error);
  EXPECT_TRUE(fs::is_directory(directory_ / "belief.pgm" / "inside"));
  EXPECT_FALSE(fs::exists(directory_ / "belief.pgm.tmp"));
}

TEST_F(MapExport, ValueCountMustMatchTheWindow) {
  EXPECT_THROW(dog::writeMapServerFiles(directory_.string(), "belief", window(), {1, 2, 3}),
               std::invalid_argument);
}

}  // namespace
