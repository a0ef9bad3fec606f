// sharded_em: offline EM over many bags in independent tasks (scripts/dask_offline_em.py runs
// them on Dask), giving the model file that offline_em gives for the same bags, bit for bit.
// Four steps, each a process that any machine sharing the work directory can run:
//
//   extract  one bag -> the per-cell observations of each block of the map (shard files)
//            and the bag's scan stamps (meta); bags in any order, on any worker
//   plan     the metas in bag order -> where each bag's steps fall on the one timeline
//            offline_em would make of them (bags continue each other), checked stamp by
//            stamp; a bag whose steps would round differently is named for a re-extract
//            with --anchor-step
//   em       one block: its shards of every bag, shifted onto the timeline and concatenated
//            per cell, replayed into a mapper (Mapper::replayObservations), offline EM,
//            applied -> a part model holding that block's cells
//   reduce   with --em-learn-sensor-model, after each round of em over all blocks: their
//            exact sums of the sensor model's E-step added, the emission M-step -> the
//            next round's sensor model, or the end
//   assemble the parts -> the model file (written atomically)
//
//   mrf-step with --mrf-temperature, after iteration K's E-step of every block (em
//            --iteration K): the MRF's joint M-step over all cells, in offline_em's cell
//            order -> the next iteration's transitions, or the end
//
// Cells are independent given the sensor model, so the blocks' EM runs are the single
// process's, cell for cell; the sensor model's sums are exact (core::FixedPointSum), so
// adding them over blocks gives the single process's; the MRF's M-step (core::MrfEm) runs
// on all cells in the single process's order, so it is the single process's.
// File formats: docs/sharded_em.md.

#include <algorithm>
#include <array>
#include <cinttypes>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "bag_tools.h"
#include "dynamic_occupancy_grid/core/layers/file_io.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "dynamic_occupancy_grid/core/cell/offline_em.h"
#include "dynamic_occupancy_grid/core/grid/step_clock.h"
#include "dynamic_occupancy_grid/ros/bag_offline_em.h"
#include "dynamic_occupancy_grid/ros/bag_scan_source.h"

namespace dog = dynamic_occupancy_grid;
namespace fs = std::filesystem;

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "shard files are written in the host's (little-endian) order");

namespace {

constexpr char kShardMagic[8] = {'D', 'O', 'G', 'S', 'H', 'R', 'D', '1'};
constexpr const char* kMetaHeader = "dog_shard_meta 1";
constexpr const char* kPlanHeader = "dog_shard_plan 1";
/// plan's exit status when bags must be extracted again (named in <work>/plan.redo).
constexpr int kExitRedo = 3;

struct Options {
  std::string command;
  dog::bag_tools::SharedOptions shared;
  std::string work_dir;
  std::string bag;
  int index = -1;
  std::int64_t anchor_step = 0;
  std::int32_t block_cells = 1024;
  int bags = 0;
  std::string block;
  int round = -1;
  int iteration = -1;
  bool finish = false;
  std::string out;
};

// ---- small helpers --------------------------------------------------------------------

/// FNV-1a 64 of `bytes`.
std::uint64_t fingerprint(const std::string& bytes) {
  std::uint64_t hash = 1469598103934665603ULL;
  for (const char c : bytes) {
    hash ^= static_cast<unsigned char>(c);
    hash *= 1099511628211ULL;
  }
  return hash;
}

std::string hex(std::uint64_t value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%016" PRIx64, value);
  return text;
}

std::string exact(double value) {
  char text[40];
  std::snprintf(text, sizeof(text), "%.17g", value);
  return text;
}

/// The mapping configuration's fingerprint: the header of an empty model with it (the
/// MapperConfig as the model file stores it) and the field the file leaves out that changes
/// what a scan records, the sensor model's mixed-step probability (how a step's beams are read).
std::uint64_t configFingerprint(const dog::core::MapperConfig& config) {
  return fingerprint(dog::core::serializeModel(dog::core::Mapper(config)) + "mixed_step_probability " +
                     exact(config.sensor_model_mixed_step_probability));
}

/// The offline EM options' fingerprint (all but the thread count, which changes nothing).
std::uint64_t emFingerprint(const dog::core::OfflineEmConfig& em) {
  std::ostringstream text;
  for (const double v : {em.initial_p_occ, em.initial_params.p_occ_given_free, em.initial_params.p_free_given_occ,
                         em.prior.p_occ_given_free, em.prior.p_free_given_occ, em.prior_weight, em.p_min, em.p_max,
                         em.tolerance, em.mrf_temperature, em.sensor_model_p_min}) {
    text << exact(v) << " ";
  }
  text << em.symmetric << " " << em.max_iterations << " " << em.learn_sensor_model << " " << em.sensor_model_rounds;
  return fingerprint(text.str());
}

std::string readWholeFile(const std::string& path, const std::string& what) {
  dog::core::RegularFileReader reader(path, "cannot read " + what + " " + path);
  std::string bytes;
  reader.read(static_cast<std::size_t>(reader.size()), &bytes);
  return bytes;
}

std::string bagDir(const std::string& work, int index) { return work + "/bags/" + std::to_string(index); }
std::string blockName(std::int32_t bx, std::int32_t by) {
  return "block_" + std::to_string(bx) + "_" + std::to_string(by);
}

/// "key value" lines; the first line must be `header`.
class KeyValues {
 public:
  KeyValues(const std::string& path, const std::string& what, const char* header) : path_(path) {
    std::istringstream in(readWholeFile(path, what));
    std::string line;
    if (!std::getline(in, line) || line != header) fail("does not start with '" + std::string(header) + "'");
    while (std::getline(in, line)) lines_.push_back(line);
  }
  const std::vector<std::string>& lines() const { return lines_; }
  std::string value(const std::string& key) const {
    for (const std::string& line : lines_) {
      if (line.compare(0, key.size() + 1, key + " ") == 0) return line.substr(key.size() + 1);
    }
    fail("has no '" + key + "'");
  }
  double number(const std::string& key) const { return parse(value(key), key); }
  std::int64_t integer(const std::string& key) const {
    const double v = number(key);
    if (!(std::abs(v) < 9.0e15) || v != std::floor(v)) fail("'" + key + "' is not an integer of at most 9e15");
    return static_cast<std::int64_t>(v);
  }
  double parse(const std::string& text, const std::string& key) const {
    char* end = nullptr;
    const double v = std::strtod(text.c_str(), &end);
    if (text.empty() || *end != '\0' || !std::isfinite(v)) fail("'" + key + "' is not a number: '" + text + "'");
    return v;
  }
  [[noreturn]] void fail(const std::string& message) const {
    throw std::runtime_error(path_ + ": " + message);
  }

 private:
  std::string path_;
  std::vector<std::string> lines_;
};

// ---- shard files: one block's observations from one bag -------------------------------

void put(std::string* out, const void* data, std::size_t size) { out->append(static_cast<const char*>(data), size); }

using BlockCells = std::vector<std::pair<dog::core::CellXY, std::vector<dog::core::StepObservation>>>;

std::string encodeShard(std::uint64_t config, const BlockCells& cells) {
  std::string out(kShardMagic, sizeof(kShardMagic));
  put(&out, &config, 8);
  const std::uint64_t count = cells.size();
  put(&out, &count, 8);
  for (const auto& [xy, observations] : cells) {
    const auto n = static_cast<std::uint32_t>(observations.size());
    put(&out, &xy.x, 4);
    put(&out, &xy.y, 4);
    put(&out, &n, 4);
    for (const dog::core::StepObservation& o : observations) {
      put(&out, &o.step, 4);
      put(&out, &o.hits, 2);
      put(&out, &o.misses, 2);
    }
  }
  const std::uint64_t check = fingerprint(out);
  put(&out, &check, 8);
  return out;
}

/// Adds the shard's observations at `path`, steps + `shift`, to `builder`.
void decodeShard(const std::string& path, std::uint64_t config, std::uint64_t listed, std::int64_t shift,
                 dog::core::SequenceBuilder* builder) {
  const std::string bytes = readWholeFile(path, "shard");
  const auto bad = [&path](const std::string& why) { return std::runtime_error("shard " + path + ": " + why); };
  if (bytes.size() < 32 || std::memcmp(bytes.data(), kShardMagic, sizeof(kShardMagic)) != 0) {
    throw bad("not a shard file (bad magic or too short)");
  }
  std::uint64_t check = 0;
  std::memcpy(&check, bytes.data() + bytes.size() - 8, 8);
  if (fingerprint(bytes.substr(0, bytes.size() - 8)) != check) throw bad("checksum mismatch (corrupt or truncated)");
  if (check != listed) throw bad("not the shard its bag's meta lists (written by another extraction)");
  std::size_t at = 8;
  const auto take = [&](void* data, std::size_t size) {
    if (at + size > bytes.size() - 8) throw bad("truncated");
    std::memcpy(data, bytes.data() + at, size);
    at += size;
  };
  std::uint64_t shard_config = 0;
  std::uint64_t count = 0;
  take(&shard_config, 8);
  if (shard_config != config) throw bad("written with another mapping configuration");
  take(&count, 8);
  for (std::uint64_t c = 0; c < count; ++c) {
    std::int32_t x = 0;
    std::int32_t y = 0;
    std::uint32_t n = 0;
    take(&x, 4);
    take(&y, 4);
    take(&n, 4);
    for (std::uint32_t k = 0; k < n; ++k) {
      dog::core::StepObservation o{};
      take(&o.step, 4);
      take(&o.hits, 2);
      take(&o.misses, 2);
      const std::int64_t step = std::int64_t{o.step} + shift;
      if (step < 0 || step > std::numeric_limits<std::int32_t>::max() - 1) throw bad("step out of range");
      builder->add(x, y, static_cast<std::int32_t>(step), o.hits, o.misses);
    }
  }
  if (at != bytes.size() - 8) throw bad("trailing bytes");
}

// ---- checked binary files: an 8-byte magic, the payload, FNV-1a 64 of both ----------

void writeChecked(const std::string& path, const char* magic, const std::string& payload) {
  std::string bytes(magic, 8);
  bytes += payload;
  const std::uint64_t check = fingerprint(bytes);
  put(&bytes, &check, 8);
  dog::core::writeFileAtomically(path, bytes);
}

/// Reads a payload written by writeChecked; `take` pulls bytes from it in order.
class CheckedReader {
 public:
  CheckedReader(const std::string& path, const char* magic, const std::string& what) : path_(path) {
    bytes_ = readWholeFile(path, what);
    if (bytes_.size() < 16 || std::memcmp(bytes_.data(), magic, 8) != 0) fail("bad magic or too short");
    std::uint64_t check = 0;
    std::memcpy(&check, bytes_.data() + bytes_.size() - 8, 8);
    if (fingerprint(bytes_.substr(0, bytes_.size() - 8)) != check) fail("checksum mismatch (corrupt or truncated)");
    at_ = 8;
  }
  template <class T>
  T take() {
    T value{};
    if (at_ + sizeof(T) > bytes_.size() - 8) fail("truncated");
    std::memcpy(&value, bytes_.data() + at_, sizeof(T));
    at_ += sizeof(T);
    return value;
  }
  void finish() const {
    if (at_ != bytes_.size() - 8) fail("trailing bytes");
  }
  [[noreturn]] void fail(const std::string& why) const { throw std::runtime_error(path_ + ": " + why); }

 private:
  std::string path_;
  std::string bytes_;
  std::size_t at_ = 0;
};

constexpr char kCellsMagic[8] = {'D', 'O', 'G', 'C', 'E', 'L', 'L', '1'};
constexpr char kStampsMagic[8] = {'D', 'O', 'G', 'S', 'T', 'M', 'P', '1'};

void writeCells(const std::string& path, const std::vector<dog::core::CellXY>& cells) {
  std::string payload;
  const std::uint64_t count = cells.size();
  put(&payload, &count, 8);
  for (const dog::core::CellXY& xy : cells) {
    put(&payload, &xy.x, 4);
    put(&payload, &xy.y, 4);
  }
  writeChecked(path, kCellsMagic, payload);
}

std::vector<dog::core::CellXY> readCells(const std::string& path) {
  CheckedReader in(path, kCellsMagic, "cell list");
  std::vector<dog::core::CellXY> cells(in.take<std::uint64_t>());
  for (dog::core::CellXY& xy : cells) {
    xy.x = in.take<std::int32_t>();
    xy.y = in.take<std::int32_t>();
  }
  in.finish();
  return cells;
}

std::uint64_t cellKey(const dog::core::CellXY& xy) {
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(xy.x)) << 32) | static_cast<std::uint32_t>(xy.y);
}

// ---- extract --------------------------------------------------------------------------

int extract(const Options& options) {
  const std::uint64_t config = configFingerprint(options.shared.mapper);
  dog::ros_layer::BagScanSourceOptions source_options = options.shared.source;
  source_options.bag_path = options.bag;
  dog::ros_layer::BagScanSource source(source_options);
  dog::core::Mapper mapper(options.shared.mapper);
  dog::core::SequenceBuilder recorder;
  mapper.recordObservations(&recorder);
  // The timeline as offline_em makes it: the first bag's clock starts at its first accepted
  // scan; a later bag's clock is restarted (Mapper::restartClockAt) at its first scan, in the
  // step after the last one applied, which is step `anchor_step` here (0: steps counted
  // from the bag's start; plan shifts them onto the timeline).
  const bool restart = options.index > 0;
  std::vector<double> stamps;
  dog::ros_layer::BagMappingStats stats;
  stats.source = source.forEachScan([&](const dog::core::Scan& scan) {
    if (restart && stamps.empty()) {
      // A clock restarted after step anchor_step - 1, as offline_em's mapper is.
      const std::optional<std::int64_t> before =
          options.anchor_step > 0 ? std::optional<std::int64_t>(options.anchor_step - 1) : std::nullopt;
      mapper.restoreTime(scan.stamp_s, before);
      mapper.restartClockAt(scan.stamp_s);
    }
    stamps.push_back(scan.stamp_s);
    const dog::core::ScanResult result = mapper.integrate(scan);
    if (result.status == dog::core::ScanStatus::kIntegrated) {
      ++stats.scans_integrated;
    } else {
      ++stats.scans_rejected;
      stats.last_rejection = result.error;
    }
  });
  mapper.finishStep();
  mapper.recordObservations(nullptr);
  if (stats.scans_integrated == 0) throw std::runtime_error(dog::ros_layer::describeUnusableBag(options.bag, stats));

  // Per block, its cells with their observations.
  const dog::core::ObservationSequences sequences = recorder.build();
  std::map<std::pair<std::int32_t, std::int32_t>, BlockCells> blocks;
  const int shift = __builtin_ctz(static_cast<unsigned>(options.block_cells));
  for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
    const dog::core::CellXY xy = sequences.cell(c);
    blocks[{xy.x >> shift, xy.y >> shift}].emplace_back(
        xy, std::vector<dog::core::StepObservation>(sequences.begin(c), sequences.end(c)));
  }
  const std::string dir = bagDir(options.work_dir, options.index);
  fs::create_directories(dir);
  std::ostringstream meta;
  meta << kMetaHeader << "\n"
       << "config " << hex(config) << "\n"
       << "index " << options.index << "\n"
       << "bag " << options.bag << "\n"
       << "anchor_step " << options.anchor_step << "\n"
       << "block_cells " << options.block_cells << "\n"
       << "origin " << exact(*mapper.clock().origin()) << "\n"
       << "last_step " << *mapper.lastAppliedStep() << "\n"
       << "scans_integrated " << stats.scans_integrated << "\n"
       << "observations " << sequences.observationCount() << "\n"
       << "blocks " << blocks.size() << "\n";
  for (const auto& [block, cells] : blocks) {
    const std::string name = blockName(block.first, block.second);
    const std::string shard = encodeShard(config, cells);
    dog::core::writeFileAtomically(dir + "/" + name + ".obs", shard);
    std::uint64_t check = 0;
    std::memcpy(&check, shard.data() + shard.size() - 8, 8);
    meta << "block " << name << " " << hex(check) << "\n";
  }
  // The cells in the order the bag's recorder first saw them (the MRF's cell order).
  std::vector<dog::core::CellXY> cells(sequences.cellCount());
  for (std::size_t c = 0; c < cells.size(); ++c) cells[c] = sequences.cell(c);
  writeCells(dir + "/cells", cells);
  // Every stamp handed to the mapper, for plan alone (the metas stay small for em).
  std::string stamp_payload;
  const std::uint64_t stamp_count = stamps.size();
  put(&stamp_payload, &stamp_count, 8);
  for (const double stamp : stamps) put(&stamp_payload, &stamp, 8);
  writeChecked(dir + "/stamps", kStampsMagic, stamp_payload);
  meta << "stamps " << stamps.size() << "\n";
  // Written last: a bag is extracted once its meta exists.
  dog::core::writeFileAtomically(dir + "/meta", meta.str());
  std::printf("%s: scans read %zu, integrated %zu, rejected %zu, without a pose %zu; %zu cells, %zu observed cell "
              "steps, %zu blocks -> %s\n",
              options.bag.c_str(), stats.source.scans_read, stats.scans_integrated, stats.scans_rejected,
              stats.source.scans_without_pose, sequences.cellCount(), sequences.observationCount(), blocks.size(),
              dir.c_str());
  return 0;
}

// ---- the MRF (--mrf-temperature): its state between iterations ------------------------

/// With the MRF, iteration K's files: the state its E-steps use (mrf/state.K: the objective
/// of every earlier iteration, each cell's transitions and logits, cells in mrf/cells'
/// order, which is offline_em's), each block's E-step (mrf/estep.K/B) and part model
/// (parts/mrf.K/B.dogm); mrf-step K writes mrf/state.K+1 or mrf/final.
constexpr char kMrfStateMagic[8] = {'D', 'O', 'G', 'M', 'R', 'F', 'S', '1'};
constexpr char kMrfEStepMagic[8] = {'D', 'O', 'G', 'M', 'R', 'F', 'E', '1'};
constexpr const char* kMrfFinalHeader = "dog_shard_mrf_final 1";

std::string mrfPath(const Options& options, const std::string& name) { return options.work_dir + "/mrf/" + name; }

struct MrfState {
  std::vector<double> objectives;  ///< of iterations 0 .. K - 1
  std::vector<dog::core::TransitionParams> params;
  std::vector<double> logit_occ;
  std::vector<double> logit_free;
};

void writeMrfState(const Options& options, int iteration, const MrfState& state) {
  std::string payload;
  const std::uint64_t history = state.objectives.size();
  const std::uint64_t cells = state.params.size();
  put(&payload, &history, 8);
  for (const double v : state.objectives) put(&payload, &v, 8);
  put(&payload, &cells, 8);
  for (std::size_t c = 0; c < cells; ++c) {
    put(&payload, &state.params[c].p_occ_given_free, 8);
    put(&payload, &state.params[c].p_free_given_occ, 8);
    put(&payload, &state.logit_occ[c], 8);
    put(&payload, &state.logit_free[c], 8);
  }
  writeChecked(mrfPath(options, "state." + std::to_string(iteration)), kMrfStateMagic, payload);
}

MrfState readMrfState(const Options& options, int iteration, std::size_t cells) {
  CheckedReader in(mrfPath(options, "state." + std::to_string(iteration)), kMrfStateMagic,
                   "MRF state (iteration run?)");
  MrfState state;
  state.objectives.resize(in.take<std::uint64_t>());
  if (state.objectives.size() != static_cast<std::size_t>(iteration)) in.fail("not the state of this iteration");
  for (double& v : state.objectives) v = in.take<double>();
  if (in.take<std::uint64_t>() != cells) in.fail("not of the " + std::to_string(cells) + " cells of mrf/cells");
  state.params.resize(cells);
  state.logit_occ.resize(cells);
  state.logit_free.resize(cells);
  for (std::size_t c = 0; c < cells; ++c) {
    state.params[c].p_occ_given_free = in.take<double>();
    state.params[c].p_free_given_occ = in.take<double>();
    state.logit_occ[c] = in.take<double>();
    state.logit_free[c] = in.take<double>();
  }
  in.finish();
  return state;
}

/// The cells in offline_em's order (each bag's new cells in the order its recorder saw
/// them, bags in timeline order) and the state of iteration 0.
void startMrf(const Options& options) {
  std::vector<dog::core::CellXY> order;
  std::unordered_set<std::uint64_t> seen;
  for (int i = 0; i < options.bags; ++i) {
    for (const dog::core::CellXY& xy : readCells(bagDir(options.work_dir, i) + "/cells")) {
      if (seen.insert(cellKey(xy)).second) order.push_back(xy);
    }
  }
  fs::create_directories(options.work_dir + "/mrf");
  writeCells(mrfPath(options, "cells"), order);
  const dog::core::MrfEm mrf(order, options.shared.em);
  writeMrfState(options, 0, MrfState{{}, mrf.params(), mrf.logitOcc(), mrf.logitFree()});
}

// ---- plan -----------------------------------------------------------------------------

int plan(const Options& options) {
  const std::uint64_t config = configFingerprint(options.shared.mapper);
  const double time_step = options.shared.mapper.time_step_s;
  std::ostringstream out;
  std::vector<std::pair<int, std::int64_t>> redo;
  std::int64_t last_global = -1;
  double origin = 0.0;
  std::vector<std::int64_t> shifts;
  for (int i = 0; i < options.bags; ++i) {
    const KeyValues meta(bagDir(options.work_dir, i) + "/meta", "shard meta (extracted?)", kMetaHeader);
    if (meta.value("config") != hex(config)) meta.fail("extracted with another mapping configuration");
    if (meta.integer("block_cells") != options.block_cells) meta.fail("extracted with another --block-cells");
    const std::int64_t anchor = meta.integer("anchor_step");
    const std::int64_t last_local = meta.integer("last_step");
    if (i == 0) {
      if (anchor != 0) meta.fail("the first bag has no --anchor-step");
      origin = meta.number("origin");
      shifts.push_back(0);
      last_global = last_local;
      continue;
    }
    const std::int64_t offset = last_global + 1;
    CheckedReader stamp_file(bagDir(options.work_dir, i) + "/stamps", kStampsMagic, "scan stamps");
    std::vector<double> stamps(stamp_file.take<std::uint64_t>());
    for (double& stamp : stamps) stamp = stamp_file.take<double>();
    stamp_file.finish();
    if (stamps.empty() || static_cast<std::int64_t>(stamps.size()) != meta.integer("stamps")) {
      meta.fail("its stamps file does not hold its " + meta.value("stamps") + " stamps");
    }
    dog::core::StepClock extracted(time_step);
    dog::core::StepClock timeline(time_step);
    extracted.anchor(stamps.front(), anchor);
    timeline.anchor(stamps.front(), offset);
    bool same = true;
    for (const double stamp : stamps) {
      same = same && timeline.stepOf(stamp) == extracted.stepOf(stamp) - anchor + offset;
    }
    if (!same) {
      // Its steps would round differently on the timeline: extracted again right there.
      redo.emplace_back(i, offset);
      break;
    }
    shifts.push_back(offset - anchor);
    last_global = last_local - anchor + offset;
    origin = *timeline.origin();
  }
  if (last_global > std::numeric_limits<std::int32_t>::max() - 1) {
    throw std::runtime_error("the bags span " + std::to_string(last_global + 1) + " steps, more than the map's clock "
                             "counts (2^31 - 1): use a longer --time-step");
  }
  if (!redo.empty()) {
    std::string lines;
    for (const auto& [bag, offset] : redo) lines += std::to_string(bag) + " " + std::to_string(offset) + "\n";
    dog::core::writeFileAtomically(options.work_dir + "/plan.redo", lines);
    std::printf("plan: bag %d must be extracted again with --anchor-step %" PRId64 " (its stamps round differently "
                "on the timeline) -> %s/plan.redo\n",
                redo.front().first, redo.front().second, options.work_dir.c_str());
    return kExitRedo;
  }
  out << kPlanHeader << "\n"
      << "config " << hex(config) << "\n"
      << "em " << hex(emFingerprint(options.shared.em)) << "\n"
      << "block_cells " << options.block_cells << "\n"
      << "origin " << exact(origin) << "\n"
      << "last_step " << last_global << "\n"
      << "bags " << options.bags << "\n";
  for (int i = 0; i < options.bags; ++i) out << "shift " << i << " " << shifts[i] << "\n";
  if (options.shared.em.mrf_temperature > 0.0) startMrf(options);
  dog::core::writeFileAtomically(options.work_dir + "/plan", out.str());
  std::printf("plan: %d bags, steps 0..%" PRId64 " -> %s/plan\n", options.bags, last_global,
              options.work_dir.c_str());
  return 0;
}

struct Plan {
  double origin = 0.0;
  std::int64_t last_step = 0;
  std::vector<std::int64_t> shifts;  ///< per bag
};

Plan readPlan(const Options& options) {
  const KeyValues file(options.work_dir + "/plan", "plan (planned?)", kPlanHeader);
  if (file.value("config") != hex(configFingerprint(options.shared.mapper))) {
    file.fail("planned with another mapping configuration");
  }
  if (file.integer("block_cells") != options.block_cells) file.fail("planned with another --block-cells");
  if (file.value("em") != hex(emFingerprint(options.shared.em))) file.fail("planned with other offline EM options");
  Plan plan;
  plan.origin = file.number("origin");
  plan.last_step = file.integer("last_step");
  const std::int64_t bags = file.integer("bags");
  for (const std::string& line : file.lines()) {
    if (line.compare(0, 6, "shift ") != 0) continue;
    std::istringstream fields(line.substr(6));
    std::int64_t bag = -1;
    std::int64_t shift = 0;
    if (!(fields >> bag >> shift) || bag != static_cast<std::int64_t>(plan.shifts.size())) file.fail("bad shift line");
    plan.shifts.push_back(shift);
  }
  if (static_cast<std::int64_t>(plan.shifts.size()) != bags) file.fail("has not one shift per bag");
  return plan;
}

// ---- em, reduce: per block, and with --em-learn-sensor-model in rounds -----------------

/// Learning the sensor model, round R's files: the sensor model it uses (rounds/R.sensor,
/// written by reduce R - 1), each block's transitions after it (parts/B.R.params, where
/// round R + 1 starts) and its sums of the sensor model's E-step (parts/B.R.sums).
constexpr const char* kSensorHeader = "dog_shard_sensor 1";
constexpr const char* kSumsHeader = "dog_shard_sums 1";
constexpr const char* kFinalHeader = "dog_shard_final 1";
constexpr char kParamsMagic[8] = {'D', 'O', 'G', 'P', 'A', 'R', 'M', '1'};
const char* const kSumNames[4] = {"trials_occ", "trials_free", "hits_occ", "hits_free"};

using Sums = std::array<dog::core::FixedPointSum, 4>;  // trials occ, free; hits occ, free

std::string roundPath(const Options& options, const std::string& name) {
  return options.work_dir + "/rounds/" + name;
}
std::string partsPath(const Options& options, const std::string& name) {
  return options.work_dir + "/parts/" + name;
}

std::string encodeSums(const Sums& sums) {
  std::string text = std::string(kSumsHeader) + "\n";
  for (int k = 0; k < 4; ++k) {
    text += std::string(kSumNames[k]) + " " + hex(sums[k].high()) + " " + hex(sums[k].low()) + "\n";
  }
  return text;
}

Sums readSums(const std::string& path, const char* header) {
  const KeyValues file(path, "sums (round run?)", header);
  Sums sums;
  for (int k = 0; k < 4; ++k) {
    std::istringstream fields(file.value(kSumNames[k]));
    std::string high;
    std::string low;
    if (!(fields >> high >> low) || high.size() != 16 || low.size() != 16 ||
        high.find_first_not_of("0123456789abcdef") != std::string::npos ||
        low.find_first_not_of("0123456789abcdef") != std::string::npos) {
      file.fail("bad '" + std::string(kSumNames[k]) + "'");
    }
    sums[k] = dog::core::FixedPointSum::fromHalves(std::stoull(high, nullptr, 16), std::stoull(low, nullptr, 16));
  }
  return sums;
}

/// The sensor model round `round` uses.
dog::core::ObservationModel roundSensor(const Options& options, int round) {
  // Steps are read as the one-process run reads them (mapper.sensor()): with the mapper's
  // mixed-step probability.
  const double mixed = options.shared.mapper.sensor_model_mixed_step_probability;
  if (round == 0) return {options.shared.mapper.p_hit_given_occ, options.shared.mapper.p_hit_given_free, mixed};
  const KeyValues file(roundPath(options, std::to_string(round) + ".sensor"), "sensor model (reduced?)", kSensorHeader);
  try {
    return {file.number("p_hit_given_occ"), file.number("p_hit_given_free"), mixed};
  } catch (const std::invalid_argument& e) {
    file.fail(e.what());
  }
}

std::string encodeParams(const std::vector<dog::core::TransitionParams>& params) {
  std::string out(kParamsMagic, sizeof(kParamsMagic));
  const std::uint64_t count = params.size();
  put(&out, &count, 8);
  for (const dog::core::TransitionParams& p : params) {
    put(&out, &p.p_occ_given_free, 8);
    put(&out, &p.p_free_given_occ, 8);
  }
  const std::uint64_t check = fingerprint(out);
  put(&out, &check, 8);
  return out;
}

std::vector<dog::core::TransitionParams> decodeParams(const std::string& path, std::size_t cells) {
  const std::string bytes = readWholeFile(path, "transitions");
  std::uint64_t count = 0;
  std::uint64_t check = 0;
  if (bytes.size() < 24 || std::memcmp(bytes.data(), kParamsMagic, 8) != 0) {
    throw std::runtime_error("transitions " + path + ": bad magic or too short");
  }
  std::memcpy(&count, bytes.data() + 8, 8);
  std::memcpy(&check, bytes.data() + bytes.size() - 8, 8);
  if (count != cells || bytes.size() != 24 + 16 * count || fingerprint(bytes.substr(0, bytes.size() - 8)) != check) {
    throw std::runtime_error("transitions " + path + ": corrupt, or not of this block's " + std::to_string(cells) +
                             " cells");
  }
  std::vector<dog::core::TransitionParams> params(count);
  for (std::uint64_t c = 0; c < count; ++c) {
    std::memcpy(&params[c].p_occ_given_free, bytes.data() + 16 + 16 * c, 8);
    std::memcpy(&params[c].p_free_given_occ, bytes.data() + 24 + 16 * c, 8);
  }
  return params;
}

/// The shards bag `index` wrote (its meta's list: block names and the shards' checksums),
/// sorted by block.
std::vector<std::pair<std::string, std::uint64_t>> bagShards(const Options& options, std::size_t index) {
  const KeyValues meta(bagDir(options.work_dir, static_cast<int>(index)) + "/meta", "shard meta", kMetaHeader);
  std::vector<std::pair<std::string, std::uint64_t>> shards;
  for (const std::string& line : meta.lines()) {
    if (line.compare(0, 6, "block ") != 0) continue;
    std::istringstream fields(line.substr(6));
    std::string name;
    std::string check;
    if (!(fields >> name >> check) || check.size() != 16 ||
        check.find_first_not_of("0123456789abcdef") != std::string::npos) {
      meta.fail("bad block line '" + line + "'");
    }
    shards.emplace_back(name, std::stoull(check, nullptr, 16));
  }
  std::sort(shards.begin(), shards.end());
  return shards;
}

std::vector<std::string> bagBlocks(const Options& options, std::size_t index) {
  std::vector<std::string> blocks;
  for (const auto& shard : bagShards(options, index)) blocks.push_back(shard.first);
  return blocks;
}

int emBlock(const Options& options) {
  const Plan plan = readPlan(options);
  const std::uint64_t config = configFingerprint(options.shared.mapper);
  const bool rounds = options.shared.em.learn_sensor_model;
  dog::core::SequenceBuilder builder;
  // Bags in timeline order: each cell's steps keep increasing. Only the shards a bag's meta
  // lists are its own (a work directory may hold older files).
  for (std::size_t i = 0; i < plan.shifts.size(); ++i) {
    const std::vector<std::pair<std::string, std::uint64_t>> shards = bagShards(options, i);
    const auto found = std::lower_bound(shards.begin(), shards.end(), std::make_pair(options.block, std::uint64_t{0}));
    if (found == shards.end() || found->first != options.block) continue;
    decodeShard(bagDir(options.work_dir, static_cast<int>(i)) + "/" + options.block + ".obs", config, found->second,
                plan.shifts[i], &builder);
  }
  const dog::core::ObservationSequences sequences = builder.build();
  if (sequences.cellCount() == 0) throw std::runtime_error("no bag has observations in " + options.block);
  // The part is a model of its own (the timeline's clock, its block's cells).
  dog::core::Mapper mapper(options.shared.mapper);
  mapper.restoreTime(plan.origin, std::nullopt);
  dog::core::OfflineEmResult result;
  std::string dir = options.work_dir + "/parts";
  if (rounds) {
    const std::vector<dog::core::TransitionParams> start =
        options.round == 0
            ? std::vector<dog::core::TransitionParams>{}
            : decodeParams(partsPath(options, options.block + "." + std::to_string(options.round - 1) + ".params"),
                           sequences.cellCount());
    result = dog::core::runOfflineEmRound(sequences, roundSensor(options, options.round), options.shared.em, start);
    fs::create_directories(dir);
    const std::string name = options.block + "." + std::to_string(options.round);
    dog::core::writeFileAtomically(partsPath(options, name + ".params"), encodeParams(result.params));
    dog::core::writeFileAtomically(partsPath(options, name + ".sums"),
                                   encodeSums({result.sensor_trials_sum[0], result.sensor_trials_sum[1],
                                               result.sensor_hits_sum[0], result.sensor_hits_sum[1]}));
    dir += "/" + std::to_string(options.round);
  } else if (options.shared.em.mrf_temperature > 0.0) {
    // The MRF's iteration K: this block's E-step with the transitions of mrf/state.K. Its
    // cells' places in offline_em's order (mrf/cells).
    std::unordered_map<std::uint64_t, std::size_t> local;
    for (std::size_t c = 0; c < sequences.cellCount(); ++c) local.emplace(cellKey(sequences.cell(c)), c);
    const std::vector<dog::core::CellXY> order = readCells(mrfPath(options, "cells"));
    std::vector<std::uint32_t> global(sequences.cellCount(), std::numeric_limits<std::uint32_t>::max());
    for (std::size_t g = 0; g < order.size(); ++g) {
      const auto found = local.find(cellKey(order[g]));
      if (found != local.end()) global[found->second] = static_cast<std::uint32_t>(g);
    }
    const MrfState state = readMrfState(options, options.iteration, order.size());
    std::vector<dog::core::TransitionParams> params(sequences.cellCount());
    for (std::size_t c = 0; c < params.size(); ++c) {
      if (global[c] == std::numeric_limits<std::uint32_t>::max()) {
        throw std::runtime_error("cell of " + options.block + " missing from mrf/cells (planned with other bags?)");
      }
      params[c] = state.params[global[c]];
    }
    const std::string estep_dir = mrfPath(options, "estep." + std::to_string(options.iteration));
    std::vector<double> final_p_occ(sequences.cellCount());
    if (!options.finish) {
      const dog::core::OfflineEStep e = dog::core::offlineEStep(
          sequences, mapper.sensor(), params, options.shared.em.initial_p_occ, options.shared.em.threads);
      std::string payload;
      const std::uint64_t count = sequences.cellCount();
      put(&payload, &count, 8);
      for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
        put(&payload, &global[c], 4);
        for (const auto& row : e.counts[c]) put(&payload, row.data(), 16);
        put(&payload, &e.log_likelihood[c], 8);
        put(&payload, &e.final_p_occ[c], 8);
      }
      fs::create_directories(estep_dir);
      writeChecked(estep_dir + "/" + options.block, kMrfEStepMagic, payload);
      std::printf("%s: %zu cells, %zu observed cell steps, E-step of iteration %d\n", options.block.c_str(),
                  sequences.cellCount(), sequences.observationCount(), options.iteration);
      return 0;
    }
    // --finish: EM stopped after this iteration's E-step; its final beliefs make the part.
    CheckedReader in(estep_dir + "/" + options.block, kMrfEStepMagic, "E-step (iteration run?)");
    if (in.take<std::uint64_t>() != sequences.cellCount()) in.fail("not of this block's cells");
    for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
      if (in.take<std::uint32_t>() != global[c]) in.fail("not of this block's cells");
      for (int k = 0; k < 5; ++k) in.take<double>();  // counts, log-likelihood
      final_p_occ[c] = in.take<double>();
    }
    in.finish();
    result.params = params;
    result.final_p_occ = final_p_occ;
    result.final_step.resize(sequences.cellCount());
    for (std::size_t c = 0; c < sequences.cellCount(); ++c) result.final_step[c] = (sequences.end(c) - 1)->step;
    result.iterations.assign(sequences.cellCount(), static_cast<std::uint16_t>(options.iteration));
    dir += "/mrf." + std::to_string(options.iteration);
  } else {
    result = dog::core::runOfflineEm(sequences, mapper.sensor(), options.shared.em);
  }
  mapper.replayObservations(sequences);
  mapper.applyOfflineEm(sequences, result, true);
  fs::create_directories(dir);
  const std::string path = dir + "/" + options.block + ".dogm";
  dog::core::saveModel(mapper, path);
  if (result.objective.empty()) {
    std::printf("%s: %zu cells, %zu observed cell steps, the MRF's iteration %d -> %s\n", options.block.c_str(),
                sequences.cellCount(), sequences.observationCount(), options.iteration, path.c_str());
  } else {
    std::printf("%s: %zu cells, %zu observed cell steps, %zu converged, objective %.6f -> %.6f -> %s\n",
                options.block.c_str(), sequences.cellCount(), sequences.observationCount(), result.cells_converged,
                result.objective.front(), result.objective.back(), path.c_str());
  }
  return 0;
}

/// The blocks of the plan's bags (from their metas), sorted.
std::vector<std::string> allBlocks(const Options& options, std::size_t bags) {
  std::vector<std::string> blocks;
  for (std::size_t i = 0; i < bags; ++i) {
    const std::vector<std::string> own = bagBlocks(options, i);
    blocks.insert(blocks.end(), own.begin(), own.end());
  }
  std::sort(blocks.begin(), blocks.end());
  blocks.erase(std::unique(blocks.begin(), blocks.end()), blocks.end());
  return blocks;
}

/// After round R of every block: the sums over all blocks, the emission M-step, and either
/// the next round's sensor model ("continue") or the final round ("done"), as runOfflineEm
/// decides.
int reduce(const Options& options) {
  const Plan plan = readPlan(options);
  Sums total;
  const std::vector<std::string> blocks = allBlocks(options, plan.shifts.size());
  for (const std::string& block : blocks) {
    const Sums sums = readSums(partsPath(options, block + "." + std::to_string(options.round) + ".sums"), kSumsHeader);
    for (int k = 0; k < 4; ++k) total[k].add(sums[k]);
  }
  const dog::core::ObservationModel used = roundSensor(options, options.round);
  std::optional<dog::core::ObservationModel> next;
  if (options.round + 1 < options.shared.em.sensor_model_rounds) {
    next = dog::core::nextSensorModel({total[0], total[1]}, {total[2], total[3]}, used, options.shared.em);
  }
  fs::create_directories(options.work_dir + "/rounds");
  if (next) {
    dog::core::writeFileAtomically(roundPath(options, std::to_string(options.round + 1) + ".sensor"),
                                   std::string(kSensorHeader) + "\np_hit_given_occ " + exact(next->pHitGivenOcc()) +
                                       "\np_hit_given_free " + exact(next->pHitGivenFree()) + "\n");
    std::printf("continue: round %d over %zu blocks: p_hit_given_occ %.6f, p_hit_given_free %.6f\n", options.round + 1,
                blocks.size(), next->pHitGivenOcc(), next->pHitGivenFree());
  } else {
    std::string text = encodeSums(total);
    text.replace(0, std::strlen(kSumsHeader), kFinalHeader);
    dog::core::writeFileAtomically(roundPath(options, "final"), text + "round " + std::to_string(options.round) + "\n");
    std::printf("done: %d rounds, p_hit_given_occ %.6f, p_hit_given_free %.6f\n", options.round + 1,
                used.pHitGivenOcc(), used.pHitGivenFree());
  }
  return 0;
}

/// After iteration K's E-step of every block: the objective, EM's stopping rule, and
/// either the M-step (mrf/state.K+1, "continue") or the end (mrf/final, "done"), as
/// runOfflineEm's MRF loop decides.
int mrfStep(const Options& options) {
  const Plan plan = readPlan(options);
  const std::vector<dog::core::CellXY> order = readCells(mrfPath(options, "cells"));
  const std::size_t cells = order.size();
  MrfState state = readMrfState(options, options.iteration, cells);
  std::vector<dog::core::TransitionCounts> counts(cells);
  std::vector<double> log_likelihood(cells);
  std::vector<bool> filled(cells, false);
  const std::string estep_dir = mrfPath(options, "estep." + std::to_string(options.iteration));
  for (const std::string& block : allBlocks(options, plan.shifts.size())) {
    CheckedReader in(estep_dir + "/" + block, kMrfEStepMagic, "E-step (iteration run for " + block + "?)");
    const auto n = in.take<std::uint64_t>();
    for (std::uint64_t k = 0; k < n; ++k) {
      const auto g = in.take<std::uint32_t>();
      if (g >= cells || filled[g]) in.fail("a cell index out of range or repeated");
      filled[g] = true;
      for (auto& row : counts[g]) {
        row[0] = in.take<double>();
        row[1] = in.take<double>();
      }
      log_likelihood[g] = in.take<double>();
      in.take<double>();  // the final belief: for em --finish
    }
    in.finish();
  }
  if (std::find(filled.begin(), filled.end(), false) != filled.end()) {
    throw std::runtime_error("the blocks' E-steps of iteration " + std::to_string(options.iteration) +
                             " miss cells of mrf/cells");
  }
  dog::core::MrfEm mrf(order, options.shared.em);
  mrf.restore(state.params, state.logit_occ, state.logit_free);
  const double objective = mrf.objective(log_likelihood);
  const bool converged = options.iteration > 0 && mrf.converged(objective - state.objectives.back());
  state.objectives.push_back(objective);
  if (converged || options.iteration >= options.shared.em.max_iterations) {
    dog::core::writeFileAtomically(mrfPath(options, "final"), std::string(kMrfFinalHeader) + "\niteration " +
                                                                  std::to_string(options.iteration) + "\n");
    std::printf("done: %d iterations (%s), objective %.6f -> %.6f\n", options.iteration,
                converged ? "converged" : "the most allowed", state.objectives.front(), objective);
    return 0;
  }
  const std::array<int, 2> newton = mrf.mStep(counts);
  writeMrfState(options, options.iteration + 1, MrfState{state.objectives, mrf.params(), mrf.logitOcc(),
                                                         mrf.logitFree()});
  std::printf("continue: iteration %d, objective %.6f, Newton iterations %d/%d\n", options.iteration + 1, objective,
              newton[0], newton[1]);
  return 0;
}

// ---- assemble -------------------------------------------------------------------------

int assemble(const Options& options) {
  const Plan plan = readPlan(options);
  const std::uint64_t config = configFingerprint(options.shared.mapper);
  dog::core::Mapper model(options.shared.mapper);
  model.restoreTime(plan.origin, plan.last_step);
  std::string parts_dir = options.work_dir + "/parts";
  std::optional<Sums> sensor_sums;
  if (options.shared.em.mrf_temperature > 0.0) {
    const KeyValues final_iteration(mrfPath(options, "final"), "the MRF's end (mrf-step run?)", kMrfFinalHeader);
    parts_dir += "/mrf." + std::to_string(final_iteration.integer("iteration"));
  }
  if (options.shared.em.learn_sensor_model) {
    // The final round's parts, and the sensor model's sums over all blocks.
    const KeyValues final_round(roundPath(options, "final"), "final round (reduced?)", kFinalHeader);
    sensor_sums = readSums(roundPath(options, "final"), kFinalHeader);
    parts_dir += "/" + std::to_string(final_round.integer("round"));
  }
  // One part per block of the plan's bags, each required (a work directory may hold
  // parts of other runs: they are not read).
  const std::vector<std::string> blocks = allBlocks(options, plan.shifts.size());
  std::size_t cells = 0;
  for (const std::string& block : blocks) {
    const std::string path = parts_dir + "/" + block + ".dogm";
    if (!fs::exists(path)) throw std::runtime_error("no part of " + block + " (" + path + "): em not run for it?");
    const std::unique_ptr<dog::core::Mapper> part = dog::core::loadModel(path);
    // A model file does not hold the mixed-step probability: the part's is the run's.
    dog::core::MapperConfig part_config = part->config();
    part_config.sensor_model_mixed_step_probability = options.shared.mapper.sensor_model_mixed_step_probability;
    if (configFingerprint(part_config) != config) {
      throw std::runtime_error("part " + path + " was learned with another mapping configuration");
    }
    part->grid().forEachTile([&](const dog::core::CellGrid::Tile& tile) {
      for (int i = 0; i < dog::core::CellGrid::kTileCells; ++i) {
        if (tile.last_step[i] == dog::core::kNeverObserved) continue;
        model.restoreCell(tile.cellX(i), tile.cellY(i), *part->grid().cell(tile.cellX(i), tile.cellY(i)));
        ++cells;
      }
    });
  }
  if (sensor_sums && (*sensor_sums)[0].value() + (*sensor_sums)[1].value() > 0.0) {
    // As Mapper::applyOfflineEm: the learned sensor model's sums become the map's.
    dog::core::SensorModelStats stats;
    for (int state = 0; state < 2; ++state) {
      stats.trials[state] = (*sensor_sums)[state].value();
      stats.hits[state] = std::min((*sensor_sums)[2 + state].value(), stats.trials[state]);
    }
    model.restoreSensorModelStats(stats);
  }
  dog::core::saveModel(model, options.out);
  std::printf("assemble: %zu parts, %zu cells, steps 0..%" PRId64 "\nmodel -> %s\n", blocks.size(), cells,
              plan.last_step, options.out.c_str());
  return 0;
}

// ---- command line ---------------------------------------------------------------------

Options parseArguments(int argc, char** argv) {
  namespace cl = dog::command_line;
  Options options;
  cl::CommandLine line("sharded_em",
                       "usage: sharded_em extract BAG --index I --work DIR [options]\n"
                       "       sharded_em plan --work DIR --bags N [options]\n"
                       "       sharded_em em --work DIR --block NAME [--round R | --iteration K] [options]\n"
                       "       sharded_em mrf-step --work DIR --iteration K [options]   (with --mrf-temperature)\n"
                       "       sharded_em reduce --work DIR --round R [options]   (with --em-learn-sensor-model)\n"
                       "       sharded_em assemble --work DIR --out MODEL [options]\n"
                       "       sharded_em check --work DIR [options]   (checks the options, does nothing)\n"
                       "Offline EM over bags in independent steps, the model offline_em writes for the same bags in\n"
                       "the same order (scripts/dask_offline_em.py runs them on Dask; docs/sharded_em.md). Every step\n"
                       "needs the same mapping options and --block-cells.\n");
  std::vector<std::string> positional;
  line.options().add_options()
      ("work", cl::nonEmpty(&options.work_dir, "a directory")->value_name("DIR")->required(),
       "work directory shared by all steps (required)")
      ("index", cl::number(&options.index, cl::between(0, 1000000000))->value_name("I"),
       "extract: the bag's place in the timeline (0 = first)")
      ("anchor-step", cl::number(&options.anchor_step, cl::between<std::int64_t>(0, 2000000000))->value_name("K"),
       "extract: the bag's first scan starts step K (what plan asks for in plan.redo; default 0)")
      ("block-cells", cl::number(&options.block_cells, cl::between(8, 1 << 20))->value_name("N"),
       "side of a block in cells, a power of two >= 8 (default 1024); smaller blocks, smaller EM tasks")
      ("bags", cl::number(&options.bags, cl::between(1, 1000000000))->value_name("N"), "plan: the number of bags")
      ("block", cl::nonEmpty(&options.block, "a block name")->value_name("NAME"),
       "em: the block (block_X_Y, as extract names its shard files)")
      ("iteration", cl::number(&options.iteration, cl::between(0, 65535))->value_name("K"),
       "em, mrf-step: the iteration of the MRF's EM (with --mrf-temperature)")
      ("finish", boost::program_options::bool_switch(&options.finish),
       "em with --iteration K: write the block's part from iteration K's E-step (after mrf-step said done)")
      ("round", cl::number(&options.round, cl::between(0, 1000))->value_name("R"),
       "em, reduce: the round of learning the sensor model (with --em-learn-sensor-model)")
      ("out", cl::nonEmpty(&options.out, "a file name")->value_name("MODEL"), "assemble: model file to write");
  dog::bag_tools::addMappingOptions(line, &options.shared);
  dog::bag_tools::addEmOptions(line, &options.shared);
  line.hidden().add_options()("positional", boost::program_options::value(&positional));
  line.positional("positional");
  line.parse(argc, argv);
  if (positional.empty()) line.fail("no step given (extract, plan, em, reduce, mrf-step, assemble or check)");
  options.command = positional[0];
  const auto arguments = [&](std::size_t n) {
    if (positional.size() != n + 1) line.fail(options.command + " takes " + std::to_string(n) + " argument(s)");
  };
  if (options.command == "extract") {
    arguments(1);
    options.bag = positional[1];
    if (options.index < 0) line.fail("extract needs --index");
    if (options.index == 0 && options.anchor_step != 0) line.fail("the first bag (--index 0) has no --anchor-step");
  } else if (options.command == "plan") {
    arguments(0);
    if (options.bags == 0) line.fail("plan needs --bags");
  } else if (options.command == "em") {
    arguments(0);
    if (options.block.empty()) line.fail("em needs --block");
    if (options.shared.em.learn_sensor_model != (options.round >= 0)) {
      line.fail(options.round >= 0 ? "--round is for --em-learn-sensor-model"
                                   : "--em-learn-sensor-model needs --round");
    }
    if (options.finish && options.iteration < 0) line.fail("--finish needs --iteration");
    if ((options.shared.em.mrf_temperature > 0.0) != (options.iteration >= 0)) {
      line.fail(options.iteration >= 0 ? "--iteration is for --mrf-temperature"
                                       : "--mrf-temperature needs --iteration");
    }
  } else if (options.command == "assemble") {
    arguments(0);
    if (options.out.empty()) line.fail("assemble needs --out");
  } else if (options.command == "reduce") {
    arguments(0);
    if (options.round < 0) line.fail("reduce needs --round");
    if (!options.shared.em.learn_sensor_model) line.fail("reduce is for --em-learn-sensor-model");
  } else if (options.command == "mrf-step") {
    arguments(0);
    if (options.iteration < 0) line.fail("mrf-step needs --iteration");
    if (!(options.shared.em.mrf_temperature > 0.0)) line.fail("mrf-step is for --mrf-temperature");
  } else if (options.command == "check") {
    arguments(0);
  } else {
    line.fail("unknown step '" + options.command + "' (extract, plan, em, reduce, mrf-step, assemble or check)");
  }
  if ((options.block_cells & (options.block_cells - 1)) != 0) line.fail("--block-cells must be a power of two");
  // As offline_em: only the observations matter while mapping, EM learns the transitions.
  options.shared.mapper.learn_transitions = false;
  dog::bag_tools::validateSharedOptions(line, &options.shared);
  return options;
}

}  // namespace

int main(int argc, char** argv) {
  const Options options = parseArguments(argc, argv);
  try {
    if (options.command == "extract") return extract(options);
    if (options.command == "plan") return plan(options);
    if (options.command == "em") return emBlock(options);
    if (options.command == "reduce") return reduce(options);
    if (options.command == "mrf-step") return mrfStep(options);
    if (options.command == "assemble") return assemble(options);
    return 0;  // check: the options were fine
  } catch (const std::exception& e) {
    std::fprintf(stderr, "sharded_em %s: %s\n", options.command.c_str(), e.what());
    return 1;
  }
}
