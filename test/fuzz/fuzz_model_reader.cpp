// libFuzzer target: the model-file reader (core/layers/model_io.h) on arbitrary bytes.
//
// Every input is read twice: as it is (almost always refused by the checksum), and with its
// last four bytes replaced by the CRC-32 of the rest, so that mutations reach the header and
// cell checks behind the checksum. The checksummed bytes are also written to a file and read
// by loadModel, which must agree with deserializeModel. A model that loads must save, load
// and save again to the same bytes (model_io.h: "saving it again gives the same bytes"),
// and must map on (one scan) without a sanitizer finding.

#include <zlib.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "scratch_file.h"

namespace core = dynamic_occupancy_grid::core;

namespace {

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_model_reader: %s\n", what);
  std::abort();
}

std::unique_ptr<core::Mapper> deserialized(const std::string& bytes, std::string* error) {
  try {
    return core::deserializeModel(bytes);
  } catch (const std::runtime_error& refused) {
    *error = refused.what();
    return nullptr;
  }
}

std::unique_ptr<core::Mapper> loaded(const std::string& path, std::string* error) {
  try {
    return core::loadModel(path);
  } catch (const std::runtime_error& refused) {
    *error = refused.what();
    return nullptr;
  }
}

const std::string& modelPath() {
  static const std::string path = [] {
    std::string file = fuzz_scratch::makeFile({"/tmp/fuzz_model_reader.XXXXXX"}, "model.dogm");
    if (file.empty()) fail("cannot create a temporary directory");
    return file;
  }();
  return path;
}

void writeFile(const std::string& path, const std::string& bytes) {
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) fail("cannot write the model file");
  const bool written = std::fwrite(bytes.data(), 1, bytes.size(), file) == bytes.size();
  if (std::fclose(file) != 0 || !written) fail("cannot write the model file");
}

// One scan whose beams cross at most about 64 cells, whatever the model's resolution: a
// beam allocates every 64 x 64-cell tile it crosses (280 kB each), so at the finest
// resolutions a file may name a 2 m beam would allocate gigabytes (docs/reliability.md).
void mapOn(core::Mapper& mapper) {
  const float range_m = static_cast<float>(std::min(2.0, 64.0 * mapper.config().resolution_m));
  core::Scan scan;
  const auto step = mapper.lastAppliedStep();
  const double origin_s = mapper.clock().origin().value_or(0.0);
  scan.stamp_s = origin_s + (static_cast<double>(step.value_or(0)) + 1.0) * mapper.config().time_step_s;
  scan.laser_pose = core::Pose2D{mapper.config().origin_x_m, mapper.config().origin_y_m, 0.3};
  scan.angle_min_rad = -1.5;
  scan.angle_increment_rad = 0.25;
  scan.range_min_m = 0.05 * range_m;
  scan.range_max_m = range_m;
  // Hits, no returns (beyond range_max) and ignored readings (below range_min).
  for (const float fraction : {0.5f, 1.25f, 0.01f, 0.25f, 0.75f, 0.95f, 0.35f, 0.6f, 1.5f, 0.55f, 0.45f, 0.7f, 0.8f}) {
    scan.ranges_m.push_back(fraction * range_m);
  }
  mapper.integrate(scan);
  mapper.finishStep();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::string error;
  deserialized(std::string(reinterpret_cast<const char*>(data), size), &error);
  if (size < 4) return 0;

  std::string bytes(reinterpret_cast<const char*>(data), size);
  const std::uint32_t crc = static_cast<std::uint32_t>(
      ::crc32_z(::crc32_z(0L, nullptr, 0), reinterpret_cast<const unsigned char*>(bytes.data()), size - 4));
  for (int k = 0; k < 4; ++k) bytes[size - 4 + k] = static_cast<char>((crc >> (8 * k)) & 0xff);

  std::string read_error;
  std::unique_ptr<core::Mapper> mapper = deserialized(bytes, &read_error);
  writeFile(modelPath(), bytes);
  std::string load_error;
  const std::unique_ptr<core::Mapper> from_file = loaded(modelPath(), &load_error);
  if ((mapper == nullptr) != (from_file == nullptr)) fail("loadModel and deserializeModel disagree");
  if (mapper == nullptr) return 0;

  const std::string saved = core::serializeModel(*mapper);
  std::string reload_error;
  const std::unique_ptr<core::Mapper> reloaded = deserialized(saved, &reload_error);
  if (reloaded == nullptr) fail(("a saved model does not load: " + reload_error).c_str());
  if (core::serializeModel(*reloaded) != saved) fail("a model saved, loaded and saved again changed");
  if (core::serializeModel(*from_file) != saved) fail("loadModel and deserializeModel read different models");

  mapOn(*mapper);
  return 0;
}
