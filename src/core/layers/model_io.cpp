// The model file (docs/model_format.md). Byte order is written out explicitly, so the file
// is the same on any host; the file I/O uses POSIX (open, fsync, rename) for a durable,
// atomic replace, which the C++17 standard library cannot express; the checksum is zlib's.

#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "dynamic_occupancy_grid/core/layers/file_io.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <new>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace dynamic_occupancy_grid {
namespace core {
namespace {

// ---- layout (docs/model_format.md) ----------------------------------------------------

constexpr char kMagic[8] = {'D', 'O', 'G', 'M', 'O', 'D', 'E', 'L'};
constexpr std::size_t kMagicSize = sizeof(kMagic);
constexpr std::size_t kVersionEnd = kMagicSize + 4;
// Version 1: magic, version, configuration (19 doubles, 3 flags, 1 uint32), time (2
// flags, a double, an int64), cell count.
constexpr std::size_t kHeaderSizeV1 = kMagicSize + 4 + (19 * 8 + 3 * 1 + 4) + (1 + 8 + 1 + 8) + 8;
static_assert(kHeaderSizeV1 == 197, "docs/model_format.md documents a 197-byte version 1 header");
// Where version 1's time ends and version 2's learner block begins.
constexpr std::size_t kTimeEnd = kHeaderSizeV1 - 8;
// Version 2 adds, before the cell count, the learners' configuration (2 flags, 1 byte of
// schedule, 5 doubles, 1 uint32) and the sensor model's sums (4 doubles).
constexpr std::size_t kHeaderSizeV2 = kTimeEnd + (2 * 1 + 1 + 5 * 8 + 4) + 4 * 8 + 8;
static_assert(kHeaderSizeV2 == 276, "docs/model_format.md documents a 276-byte version 2 header");
// Version 3 adds, before the cell count, the transition learner and the kinds of cells:
// learner and kind count (2 bytes), per kind its initial transitions (2 doubles) and share,
// 4 doubles of options, 3 bytes of choices, the number of distance bins (u16), and the
// sums: per kind and bin 4 pairs, per kind a membership, the number of cells; then the
// kinds' transitions learned so far (2 doubles each).
constexpr std::size_t kKindsSumsSize = (kKindCount * kGapBins * 4 + kKindCount + 1) * 8;
constexpr std::size_t kHeaderSizeV3 = kHeaderSizeV2 - 8 + 2 + kKindCount * (2 + 1) * 8 + 4 * 8 + 3 + 2 +
                                      kKindsSumsSize + kKindCount * 2 * 8 + 8;
static_assert(kHeaderSizeV3 == 20403, "docs/model_format.md documents a 20403-byte version 3 header");
// x, y, p_occ, last_step, log_odds, p_occ_given_free, p_free_given_occ, em_stats[8],
// observed_steps; version 2 adds last_hits and last_misses; version 3 stores the learner's
// state in kLearnerStateSize floats instead of 8.
constexpr std::size_t kCellSizeV1 = 4 * 7 + 4 * 8 + 2;
// What the empirical-Bayes prior's population weight, an option removed after a9ed7d5, was
// by default: written where files hold it, so that a file is as it was.
constexpr double kDefaultPriorPopulationWeight = 10.0;
// The kinds' summary and counting, choices removed after a9ed7d5, as files number them:
// the geometric mean and the most probable kind, the ones left.
constexpr std::uint8_t kGeometricMeanSummary = 0;
constexpr std::uint8_t kMostProbableCounting = 1;
// What the online EM's step-size exponent and offset, options removed after a9ed7d5, were
// by default: written where files hold them, so that a file is as it was.
constexpr double kHarmonicStepSizeExponent = 0.6;
constexpr double kHarmonicStepSizeOffset = 2.0;
static_assert(kCellSizeV1 == 62, "docs/model_format.md documents 62-byte version 1 cell records");
constexpr std::size_t kCellSizeV2 = kCellSizeV1 + 2;
constexpr std::size_t kCellSizeV3 = kCellSizeV2 + 4 * (kLearnerStateSize - 8);
static_assert(kCellSizeV3 == 72, "docs/model_format.md documents 72-byte version 3 cell records");
// Version 1 and 2 files hold 8 learner floats per cell.
constexpr std::size_t kLearnerStateSizeV2 = 8;

struct Layout {
  std::size_t header;
  std::size_t cell;
  std::size_t learner_floats;
};
Layout layoutOf(std::uint32_t version) {
  if (version == 1) return Layout{kHeaderSizeV1, kCellSizeV1, kLearnerStateSizeV2};
  if (version == 2) return Layout{kHeaderSizeV2, kCellSizeV2, kLearnerStateSizeV2};
  return Layout{kHeaderSizeV3, kCellSizeV3, kLearnerStateSize};
}
bool readableVersion(std::uint32_t version) { return version >= 1 && version <= kModelFormatVersion; }
constexpr std::size_t kChecksumSize = 4;

// ---- CRC-32: zlib's own, the one the format promises and Python's zlib.crc32 computes ----

std::uint32_t checksum(const unsigned char* data, std::size_t size) {
  // crc32_z takes a size_t length (crc32 takes an unsigned int), so a map file over 4 GiB
  // needs no chunking.
  return static_cast<std::uint32_t>(::crc32_z(::crc32_z(0L, nullptr, 0), data, size));
}

// ---- little-endian encoding, whatever the host's byte order ----------------------------

template <class Unsigned>
void putUnsigned(unsigned char*& out, Unsigned value) {
  for (std::size_t k = 0; k < sizeof(Unsigned); ++k) *out++ = static_cast<unsigned char>(value >> (8 * k));
}

template <class Unsigned>
Unsigned getUnsigned(const unsigned char*& in) {
  Unsigned value = 0;
  for (std::size_t k = 0; k < sizeof(Unsigned); ++k) value |= static_cast<Unsigned>(Unsigned{*in++} << (8 * k));
  return value;
}

// Bit patterns: floats and doubles are stored exactly (IEEE 754 binary32 / binary64).
template <class To, class From>
To bitCast(From from) {
  static_assert(sizeof(To) == sizeof(From), "bitCast needs equal sizes");
  To to;
  std::memcpy(&to, &from, sizeof(To));
  return to;
}

class Writer {
 public:
  explicit Writer(unsigned char* out) : out_(out) {}
  void bytes(const char* data, std::size_t size) {
    std::memcpy(out_, data, size);
    out_ += size;
  }
  void u8(std::uint8_t value) { *out_++ = value; }
  void flag(bool value) { u8(value ? 1 : 0); }
  void u16(std::uint16_t value) { putUnsigned(out_, value); }
  void u32(std::uint32_t value) { putUnsigned(out_, value); }
  void i32(std::int32_t value) { putUnsigned(out_, bitCast<std::uint32_t>(value)); }
  void u64(std::uint64_t value) { putUnsigned(out_, value); }
  void i64(std::int64_t value) { putUnsigned(out_, bitCast<std::uint64_t>(value)); }
  void f32(float value) { putUnsigned(out_, bitCast<std::uint32_t>(value)); }
  void f64(double value) { putUnsigned(out_, bitCast<std::uint64_t>(value)); }
  unsigned char* position() const { return out_; }

 private:
  unsigned char* out_;
};

// Reads from a buffer whose size the caller has checked beforehand.
class Reader {
 public:
  explicit Reader(const unsigned char* in) : in_(in) {}
  std::uint8_t u8() { return *in_++; }
  std::uint16_t u16() { return getUnsigned<std::uint16_t>(in_); }
  std::uint32_t u32() { return getUnsigned<std::uint32_t>(in_); }
  std::int32_t i32() { return bitCast<std::int32_t>(getUnsigned<std::uint32_t>(in_)); }
  std::uint64_t u64() { return getUnsigned<std::uint64_t>(in_); }
  std::int64_t i64() { return bitCast<std::int64_t>(getUnsigned<std::uint64_t>(in_)); }
  float f32() { return bitCast<float>(getUnsigned<std::uint32_t>(in_)); }
  double f64() { return bitCast<double>(getUnsigned<std::uint64_t>(in_)); }
  /// A boolean byte: 0 or 1, anything else is a damaged file (and would not save back the same).
  bool flag(const char* field) {
    const std::uint8_t value = u8();
    if (value > 1) {
      throw std::runtime_error(std::string("invalid model file: ") + field + " is " + std::to_string(value) +
                               ", must be 0 or 1");
    }
    return value == 1;
  }

 private:
  const unsigned char* in_;
};

// ---- the cells, in the documented order ------------------------------------------------

// Calls fn(x, y, tile, offset) for every observed cell, by row (y ascending), then x.
template <class Fn>
void forEachObservedCell(const CellGrid& grid, Fn&& fn) {
  std::vector<const CellGrid::Tile*> tiles;
  grid.forEachTile([&tiles](const CellGrid::Tile& tile) { tiles.push_back(&tile); });
  std::sort(tiles.begin(), tiles.end(), [](const CellGrid::Tile* a, const CellGrid::Tile* b) {
    return std::make_pair(a->tile_y, a->tile_x) < std::make_pair(b->tile_y, b->tile_x);
  });
  // One row of tiles at a time, and within it one row of cells across all its tiles.
  for (std::size_t row_begin = 0; row_begin < tiles.size();) {
    std::size_t row_end = row_begin;
    while (row_end < tiles.size() && tiles[row_end]->tile_y == tiles[row_begin]->tile_y) ++row_end;
    for (int cell_row = 0; cell_row < CellGrid::kTileSize; ++cell_row) {
      for (std::size_t t = row_begin; t < row_end; ++t) {
        const CellGrid::Tile& tile = *tiles[t];
        const int row_offset = cell_row << CellGrid::kTileBits;
        for (int offset = row_offset; offset < row_offset + CellGrid::kTileSize; ++offset) {
          if (tile.last_step[offset] != kNeverObserved) fn(tile.cellX(offset), tile.cellY(offset), tile, offset);
        }
      }
    }
    row_begin = row_end;
  }
}

std::size_t countObservedCells(const CellGrid& grid) {
  std::size_t count = 0;
  grid.forEachTile([&count](const CellGrid::Tile& tile) {
    for (const std::int32_t last_step : tile.last_step) count += last_step != kNeverObserved ? 1 : 0;
  });
  return count;
}

std::string cellName(std::uint64_t index, std::int32_t x, std::int32_t y) {
  return "cell " + std::to_string(index) + " at (" + std::to_string(x) + ", " + std::to_string(y) + ")";
}

// The tile index of a loaded model is one pointer per tile of the area it covers, allocated
// (and zeroed) as the Mapper is built and its cells restored: the whole fixed bounds, or the
// box of the cells of a growing map. max_map_size allows 1e8 cells per side, so a header of a
// few hundred bytes (or two cells far apart) could ask for terabytes; no real map needs more
// than this (2^25 tiles: an 18 km square at 5 cm), so a file asking for more is refused
// before anything is allocated.
constexpr std::uint64_t kMaxTileIndexBytes = std::uint64_t{256} << 20;

// Tiles along one side of `size_m` at `resolution_m`, at least as many as CellGrid indexes.
double tilesAlong(double size_m, double resolution_m) {
  return std::floor(size_m / resolution_m / CellGrid::kTileSize) + 2.0;
}

// Tiles from cell `min` to cell `max` (inclusive), as CellGrid's index spans them.
double tilesSpanned(std::int32_t min, std::int32_t max) {
  return static_cast<double>((max >> CellGrid::kTileBits) - (min >> CellGrid::kTileBits)) + 1.0;
}

// Throws when the model in `data` (checked sizes: `cell_count` records of `cell_size` bytes
// from `cells`) would need a tile index over kMaxTileIndexBytes.
void checkTileIndex(const MapperConfig& config, const unsigned char* cells, std::uint64_t cell_count,
                    std::size_t cell_size) {
  double tiles = 0.0;
  if (config.fixed_bounds) {
    tiles = tilesAlong(config.width_m, config.resolution_m) * tilesAlong(config.height_m, config.resolution_m);
  } else if (cell_count > 0) {
    CellBox box;
    for (std::uint64_t index = 0; index < cell_count; ++index) {
      Reader reader(cells + index * cell_size);
      const std::int32_t x = reader.i32();
      box.include(x, reader.i32());
    }
    tiles = tilesSpanned(box.min_x, box.max_x) * tilesSpanned(box.min_y, box.max_y);
  }
  const double index_bytes = tiles * static_cast<double>(sizeof(std::unique_ptr<CellGrid::Tile>));
  if (index_bytes > static_cast<double>(kMaxTileIndexBytes)) {
    throw std::runtime_error("invalid model file: its map would need a tile index of " +
                             std::to_string(static_cast<std::uint64_t>(index_bytes / static_cast<double>(1 << 20))) +
                             " MiB (" + (config.fixed_bounds ? "fixed bounds" : "the box of its cells") +
                             "), more than the " + std::to_string(kMaxTileIndexBytes >> 20) + " MiB any real map needs");
  }
}

std::unique_ptr<Mapper> deserializeChecked(const std::string& bytes) {
  const auto* data = reinterpret_cast<const unsigned char*>(bytes.data());
  const std::size_t size = bytes.size();
  const auto truncated = [size](const std::string& expected) {
    return std::runtime_error("truncated model file: expected " + expected + ", " + std::to_string(size) +
                              " available");
  };

  // Magic and version first: they say what the rest is.
  const std::size_t magic_bytes = std::min(size, kMagicSize);
  if (std::memcmp(data, kMagic, magic_bytes) != 0) {
    throw std::runtime_error("not a dynamic_occupancy_grid model file (no DOGMODEL magic at its start)");
  }
  if (size < kVersionEnd) throw truncated("at least " + std::to_string(kHeaderSizeV1 + kChecksumSize) + " bytes");
  Reader reader(data + kMagicSize);
  const std::uint32_t version = reader.u32();
  if (!readableVersion(version)) {
    throw std::runtime_error("model format version " + std::to_string(version) + ", this build reads versions 1 to " +
                             std::to_string(kModelFormatVersion));
  }
  const Layout layout = layoutOf(version);
  const std::size_t header_size = layout.header;
  const std::size_t cell_size = layout.cell;
  const std::size_t minimum_size = header_size + kChecksumSize;
  if (size < minimum_size) throw truncated("at least " + std::to_string(minimum_size) + " bytes");

  // The size the cell count implies, checked before anything is allocated for the cells.
  std::uint64_t cell_count = 0;
  {
    Reader count_reader(data + header_size - 8);
    cell_count = count_reader.u64();
  }
  const std::uint64_t cell_room = (size - minimum_size) / cell_size;
  if (cell_count > cell_room) {
    const std::uint64_t max_cells = (std::numeric_limits<std::uint64_t>::max() - minimum_size) / cell_size;
    if (cell_count > max_cells) {
      throw std::runtime_error("corrupt model file: absurd cell count " + std::to_string(cell_count) + " in " +
                               std::to_string(size) + " bytes");
    }
    throw truncated(std::to_string(minimum_size + cell_count * cell_size) + " bytes for " +
                    std::to_string(cell_count) + " cells");
  }
  const std::size_t expected_size = minimum_size + static_cast<std::size_t>(cell_count) * cell_size;
  if (size > expected_size) {
    throw std::runtime_error("invalid model file: " + std::to_string(size - expected_size) +
                             " trailing bytes after the checksum (" + std::to_string(expected_size) +
                             " bytes expected for " + std::to_string(cell_count) + " cells)");
  }
  {
    Reader checksum_reader(data + size - kChecksumSize);
    const std::uint32_t stored = checksum_reader.u32();
    const std::uint32_t computed = checksum(data, size - kChecksumSize);
    if (stored != computed) {
      char message[128];
      std::snprintf(message, sizeof(message), "corrupt model file: checksum mismatch (stored %08x, computed %08x)",
                    static_cast<unsigned>(stored), static_cast<unsigned>(computed));
      throw std::runtime_error(message);
    }
  }

  // Configuration, in MapperConfig's order.
  MapperConfig config;
  config.resolution_m = reader.f64();
  config.time_step_s = reader.f64();
  config.p_hit_given_occ = reader.f64();
  config.p_hit_given_free = reader.f64();
  config.prior_transitions.p_occ_given_free = reader.f64();
  config.prior_transitions.p_free_given_occ = reader.f64();
  config.learn_transitions = reader.flag("learn_transitions");
  config.online_em.prior_weight = reader.f64();
  config.online_em.learning_rate_floor = reader.f64();
  config.online_em.p_min = reader.f64();
  config.online_em.p_max = reader.f64();
  config.online_em.symmetric = reader.flag("online_em.symmetric");
  config.online_em.min_observed_steps = reader.u32();
  config.initial_p_occ = reader.f64();
  config.static_clamp.min_log_odds = reader.f64();
  config.static_clamp.max_log_odds = reader.f64();
  config.max_free_range_m = reader.f64();
  config.origin_x_m = reader.f64();
  config.origin_y_m = reader.f64();
  config.fixed_bounds = reader.flag("fixed_bounds");
  config.width_m = reader.f64();
  config.height_m = reader.f64();
  config.max_map_size_m = reader.f64();

  // Time.
  const bool has_clock_origin = reader.flag("clock origin present");
  const double clock_origin_s = reader.f64();
  const bool has_last_applied_step = reader.flag("last applied step present");
  const std::int64_t last_applied_step = reader.i64();
  // An absent value is stored as 0: anything else would not save back the same.
  if ((!has_clock_origin && bitCast<std::uint64_t>(clock_origin_s) != 0) ||
      (!has_last_applied_step && last_applied_step != 0)) {
    throw std::runtime_error("invalid model file: an absent time value is not stored as 0");
  }
  // Version 2: the learners' configuration and the sensor model's sums (version 1 files
  // keep MapperConfig's defaults and no sums).
  SensorModelStats sensor_stats;
  if (version >= 2) {
    // learn_prior and prior_population_weight: the empirical-Bayes prior, an option removed
    // after a9ed7d5. Files still hold them; a file written with it loads, and its new cells
    // start from prior_transitions.
    reader.flag("learn_prior");
    reader.f64();
    // The online EM's step-size schedule (0 harmonic, 1 robbins_monro), its exponent and
    // offset, and the start of its averaging: options removed after a9ed7d5. Files still
    // hold them; a file written with another schedule or with averaging loads, and its
    // cells go on with the 1/t schedule and without averaging.
    const std::uint8_t schedule = reader.u8();
    if (schedule > 1) {
      throw std::runtime_error("invalid model file: online_em.schedule is " + std::to_string(schedule) +
                               ", must be 0 (harmonic) or 1 (robbins_monro)");
    }
    reader.f64();
    reader.f64();
    reader.u32();
    config.learn_sensor_model = reader.flag("learn_sensor_model");
    config.sensor_model_prior_weight = reader.f64();
    config.sensor_model_p_min = reader.f64();
    for (int state = 0; state < 2; ++state) sensor_stats.trials[state] = reader.f64();
    for (int state = 0; state < 2; ++state) sensor_stats.hits[state] = reader.f64();
  }
  // Version 3: the transition learner and the kinds of cells. Older files were written by
  // each cell's online EM, and their cells hold its statistics: they go on with it.
  CellKinds::Sums kind_sums;
  std::array<TransitionParams, kKindCount> kind_transitions{};
  if (version >= 3) {
    const std::uint8_t learner = reader.u8();
    if (learner > 1) {
      throw std::runtime_error("invalid model file: learner is " + std::to_string(learner) +
                               ", must be 0 (cell_em) or 1 (kinds)");
    }
    config.learner = learner == 0 ? TransitionLearner::kCellEm : TransitionLearner::kKinds;
    const std::uint8_t kinds = reader.u8();
    if (kinds != kKindCount) {
      throw std::runtime_error("model file with " + std::to_string(kinds) + " kinds of cells, this build has " +
                               std::to_string(kKindCount));
    }
    for (TransitionParams& start : config.kinds.initial_transitions) {
      start.p_occ_given_free = reader.f64();
      start.p_free_given_occ = reader.f64();
    }
    for (double& weight : config.kinds.initial_weights) weight = reader.f64();
    config.kinds.transition_prior_weight = reader.f64();
    config.kinds.weight_prior_cells = reader.f64();
    config.kinds.switch_probability = reader.f64();
    config.kinds.forgetting = reader.f64();
    // The kinds' summary, counting and learning from gaps: choices removed after a9ed7d5.
    // Files still hold them; a file written with another choice loads, and its kinds go on
    // with the geometric mean, the most probable kind's counting and pairs across gaps.
    const std::uint8_t summary = reader.u8();
    if (summary > 2) {
      throw std::runtime_error("invalid model file: kinds.summary is " + std::to_string(summary) +
                               ", must be 0 (geometric_mean), 1 (mean) or 2 (most_probable)");
    }
    const std::uint8_t counting = reader.u8();
    if (counting > 1) {
      throw std::runtime_error("invalid model file: kinds.counting is " + std::to_string(counting) +
                               ", must be 0 (posterior) or 1 (most_probable)");
    }
    reader.flag("kinds.learn_from_gaps");
    const std::uint16_t bins = reader.u16();
    if (bins != kGapBins) {
      throw std::runtime_error("model file with " + std::to_string(bins) + " distance bins of the kinds' pairs, this "
                               "build has " + std::to_string(kGapBins));
    }
    for (auto& kind : kind_sums.pairs) {
      for (auto& bin : kind) {
        for (double& value : bin) value = reader.f64();
      }
    }
    for (double& membership : kind_sums.membership) membership = reader.f64();
    kind_sums.cells = reader.f64();
    for (TransitionParams& learned : kind_transitions) {
      learned.p_occ_given_free = reader.f64();
      learned.p_free_given_occ = reader.f64();
    }
  } else {
    config.learner = TransitionLearner::kCellEm;
  }
  static_cast<void>(reader.u64());  // the cell count, read above

  try {
    config.validate();
  } catch (const std::invalid_argument& error) {
    throw std::runtime_error(std::string("invalid configuration in model file: ") + error.what());
  }
  checkTileIndex(config, data + header_size, cell_count, cell_size);
  std::unique_ptr<Mapper> mapper;
  try {
    mapper = std::make_unique<Mapper>(config);
  } catch (const std::invalid_argument& error) {
    throw std::runtime_error(std::string("invalid configuration in model file: ") + error.what());
  }
  try {
    mapper->restoreTime(has_clock_origin ? std::optional<double>(clock_origin_s) : std::nullopt, has_last_applied_step ? std::optional<std::int64_t>(last_applied_step)
                                                      : std::nullopt);
  } catch (const std::invalid_argument& error) {
    throw std::runtime_error(std::string("invalid time in model file: ") + error.what());
  }
  try {
    mapper->restoreSensorModelStats(sensor_stats);
  } catch (const std::invalid_argument& error) {
    throw std::runtime_error(std::string("invalid sensor model sums in model file: ") + error.what());
  }
  try {
    if (version >= 3) mapper->restoreKinds(kind_sums, kind_transitions);
  } catch (const std::invalid_argument& error) {
    throw std::runtime_error(std::string("invalid kinds of cells in model file: ") + error.what());
  }

  for (std::uint64_t index = 0; index < cell_count; ++index) {
    const std::int32_t x = reader.i32();
    const std::int32_t y = reader.i32();
    CellState state{};
    state.p_occ = reader.f32();
    state.last_step = reader.i32();
    state.log_odds = reader.f32();
    state.p_occ_given_free = reader.f32();
    state.p_free_given_occ = reader.f32();
    state.em_stats.fill(0.0f);
    for (std::size_t k = 0; k < layout.learner_floats; ++k) state.em_stats[k] = reader.f32();
    state.observed_steps = reader.u16();
    if (version >= 2) {
      state.last_hits = reader.u8();
      state.last_misses = reader.u8();
    }
    // A second record of the same cell would silently overwrite the first.
    if (mapper->grid().cell(x, y)) {
      throw std::runtime_error("invalid model file: " + cellName(index, x, y) + " appears twice");
    }
    try {
      mapper->restoreCell(x, y, state);
    } catch (const std::invalid_argument& error) {
      throw std::runtime_error("invalid model file: " + cellName(index, x, y) + ": " + error.what());
    }
  }
  return mapper;
}

// ---- files -----------------------------------------------------------------------------
// Opening, reading and writing are core/layers/file_io.h's (regular files only, an atomic and
// durable replace through a unique temporary); here: how much of a model file is read.

std::string saveError(const std::string& path) { return "cannot save model file " + path; }
std::string loadError(const std::string& path) { return "cannot load model file " + path; }

// The bytes of the model file at `path`, read in two steps so that nothing is allocated
// beyond what its header promises (whatever the file's size): first the longest header
// and a checksum, then exactly the rest the header's cell count promises. A file whose
// size differs from that promise is refused with deserializeModel's own words, without
// reading its body; a file too short for a header, without the magic or of another
// version is handed to deserializeModel whole (it is at most a header long), to say so.
std::string readModelFile(const std::string& path) {
  RegularFileReader file(path, loadError(path));
  const auto fail = [&path](const std::string& what) { return std::runtime_error(loadError(path) + ": " + what); };
  std::string bytes;
  const std::size_t first = kHeaderSizeV3 + kChecksumSize;
  if (file.read(first, &bytes) < first) return bytes;  // all of it
  const auto* data = reinterpret_cast<const unsigned char*>(bytes.data());
  if (std::memcmp(data, kMagic, kMagicSize) != 0) return bytes;
  Reader reader(data + kMagicSize);
  const std::uint32_t version = reader.u32();
  if (!readableVersion(version)) return bytes;
  const Layout layout = layoutOf(version);
  const std::size_t minimum_size = layout.header + kChecksumSize;
  Reader count_reader(data + layout.header - 8);
  const std::uint64_t cell_count = count_reader.u64();
  const std::uint64_t size = std::max<std::uint64_t>(file.size(), bytes.size());
  const std::uint64_t max_cells = (std::numeric_limits<std::uint64_t>::max() - minimum_size) / layout.cell;
  if (cell_count > max_cells) {
    throw fail("corrupt model file: absurd cell count " + std::to_string(cell_count) + " in " + std::to_string(size) +
               " bytes");
  }
  const std::uint64_t expected = minimum_size + cell_count * layout.cell;
  const auto trailing = [&](const std::string& how_many) {
    return fail("invalid model file: " + how_many + " trailing bytes after the checksum (" + std::to_string(expected) +
                " bytes expected for " + std::to_string(cell_count) + " cells)");
  };
  if (size < expected) {
    throw fail("truncated model file: expected " + std::to_string(expected) + " bytes for " +
               std::to_string(cell_count) + " cells, " + std::to_string(size) + " available");
  }
  if (size > expected) throw trailing(std::to_string(size - expected));
  if (expected > bytes.max_size()) throw std::bad_alloc();
  // Fewer bytes than that: the file shrank meanwhile, and deserializeModel says it is truncated.
  file.read(static_cast<std::size_t>(expected) - bytes.size(), &bytes);
  if (bytes.size() == expected && file.hasMore()) throw trailing("some");  // it grew meanwhile
  return bytes;
}

}  // namespace

std::string serializeModel(const Mapper& mapper) { return serializeModel(mapper, CellBeliefOverride{}); }

std::string serializeModel(const Mapper& mapper, const CellBeliefOverride& belief) {
  const MapperConfig& config = mapper.config();
  const CellGrid& grid = mapper.grid();
  const std::size_t cell_count = countObservedCells(grid);
  // The file is built in one buffer of its exact size: the only copy of the cells besides
  // the grid itself.
  std::string bytes(kHeaderSizeV3 + kChecksumSize + cell_count * kCellSizeV3, '\0');
  auto* const begin = reinterpret_cast<unsigned char*>(&bytes[0]);
  Writer writer(begin);
  writer.bytes(kMagic, kMagicSize);
  writer.u32(kModelFormatVersion);

  writer.f64(config.resolution_m);
  writer.f64(config.time_step_s);
  writer.f64(config.p_hit_given_occ);
  writer.f64(config.p_hit_given_free);
  writer.f64(config.prior_transitions.p_occ_given_free);
  writer.f64(config.prior_transitions.p_free_given_occ);
  writer.flag(config.learn_transitions);
  writer.f64(config.online_em.prior_weight);
  writer.f64(config.online_em.learning_rate_floor);
  writer.f64(config.online_em.p_min);
  writer.f64(config.online_em.p_max);
  writer.flag(config.online_em.symmetric);
  writer.u32(config.online_em.min_observed_steps);
  writer.f64(config.initial_p_occ);
  writer.f64(config.static_clamp.min_log_odds);
  writer.f64(config.static_clamp.max_log_odds);
  writer.f64(config.max_free_range_m);
  writer.f64(config.origin_x_m);
  writer.f64(config.origin_y_m);
  writer.flag(config.fixed_bounds);
  writer.f64(config.width_m);
  writer.f64(config.height_m);
  writer.f64(config.max_map_size_m);

  const std::optional<double> origin = mapper.clock().origin();
  const std::optional<std::int64_t> last_applied_step = mapper.lastAppliedStep();
  writer.flag(origin.has_value());
  writer.f64(origin.value_or(0.0));
  writer.flag(last_applied_step.has_value());
  writer.i64(last_applied_step.value_or(0));
  // The removed empirical-Bayes prior's fields, as it was by default (see the reader).
  writer.flag(false);
  writer.f64(kDefaultPriorPopulationWeight);
  // The removed step-size schedule's fields, as the harmonic schedule wrote them (see the reader).
  writer.u8(0);
  writer.f64(kHarmonicStepSizeExponent);
  writer.f64(kHarmonicStepSizeOffset);
  writer.u32(0);
  writer.flag(config.learn_sensor_model);
  writer.f64(config.sensor_model_prior_weight);
  writer.f64(config.sensor_model_p_min);
  const SensorModelStats& sensor_stats = mapper.sensorModelStats();
  for (int state = 0; state < 2; ++state) writer.f64(sensor_stats.trials[state]);
  for (int state = 0; state < 2; ++state) writer.f64(sensor_stats.hits[state]);
  writer.u8(config.learner == TransitionLearner::kCellEm ? 0 : 1);
  writer.u8(kKindCount);
  for (const TransitionParams& start : config.kinds.initial_transitions) {
    writer.f64(start.p_occ_given_free);
    writer.f64(start.p_free_given_occ);
  }
  for (const double weight : config.kinds.initial_weights) writer.f64(weight);
  writer.f64(config.kinds.transition_prior_weight);
  writer.f64(config.kinds.weight_prior_cells);
  writer.f64(config.kinds.switch_probability);
  writer.f64(config.kinds.forgetting);
  // The removed kinds' choices, as the only ones left wrote them (see the reader).
  writer.u8(kGeometricMeanSummary);
  writer.u8(kMostProbableCounting);
  writer.flag(true);  // learn_from_gaps
  writer.u16(static_cast<std::uint16_t>(kGapBins));
  const CellKinds::Sums& kind_sums = mapper.kinds().sums();
  for (const auto& kind : kind_sums.pairs) {
    for (const auto& bin : kind) {
      for (const double value : bin) writer.f64(value);
    }
  }
  for (const double membership : kind_sums.membership) writer.f64(membership);
  writer.f64(kind_sums.cells);
  for (int k = 0; k < kKindCount; ++k) {
    writer.f64(mapper.kinds().transitions(k).p_occ_given_free);
    writer.f64(mapper.kinds().transitions(k).p_free_given_occ);
  }
  writer.u64(cell_count);

  const bool kinds = config.learner == TransitionLearner::kKinds;
  forEachObservedCell(grid, [&](std::int32_t x, std::int32_t y, const CellGrid::Tile& tile, int i) {
    const std::optional<float> p_occ = belief ? belief(x, y, tile.last_step[i]) : std::nullopt;
    if (p_occ && !(*p_occ >= 0.0f && *p_occ <= 1.0f)) {
      throw std::invalid_argument("serializeModel: the belief given for cell (" + std::to_string(x) + ", " +
                                  std::to_string(y) + ") is " + std::to_string(*p_occ) + ", outside [0, 1]");
    }
    writer.i32(x);
    writer.i32(y);
    writer.f32(p_occ.value_or(tile.p_occ[i]));
    writer.i32(tile.last_step[i]);
    writer.f32(tile.log_odds[i]);
    writer.f32(tile.p_occ_given_free[i]);
    writer.f32(tile.p_free_given_occ[i]);
    if (p_occ) {
      // The learner's state is a joint with the cell's state now: each kind (kinds) or each
      // pair of states of a past transition (online EM's S(i, j, m), m last) keeps its mass,
      // split over the state now by the new belief (index 0 of each pair: occupied).
      const int pairs = kinds ? kKindCount : 4;
      for (int k = 0; k < pairs; ++k) {
        const double mass = double{tile.em_stats[2 * k][i]} + tile.em_stats[2 * k + 1][i];
        writer.f32(static_cast<float>(mass * *p_occ));
        writer.f32(static_cast<float>(mass * (1.0 - *p_occ)));
      }
      for (int k = 2 * pairs; k < kLearnerStateSize; ++k) writer.f32(tile.em_stats[k][i]);
    } else {
      for (const auto& state : tile.em_stats) writer.f32(state[i]);
    }
    writer.u16(tile.observed_steps[i]);
    writer.u8(tile.last_hits[i]);
    writer.u8(tile.last_misses[i]);
  });
  const std::size_t body = static_cast<std::size_t>(writer.position() - begin);
  if (body != bytes.size() - kChecksumSize) {
    throw std::logic_error("serializeModel: wrote " + std::to_string(body) + " bytes, expected " +
                           std::to_string(bytes.size() - kChecksumSize));
  }
  writer.u32(checksum(begin, body));
  return bytes;
}

std::unique_ptr<Mapper> deserializeModel(const std::string& bytes) {
  try {
    return deserializeChecked(bytes);
  } catch (const std::bad_alloc&) {
    // Only a model within kMaxTileIndexBytes and the cells its size allows, yet larger than
    // this machine's memory, gets here (both are checked before anything is built).
    throw std::runtime_error("model file needs more memory than is available");
  } catch (const std::length_error& error) {
    throw std::runtime_error(std::string("model file needs more memory than is available: ") + error.what());
  }
}

void saveModelBytes(const std::string& bytes, const std::string& path) {
  writeFileAtomically(path, bytes, saveError(path));
}

void saveModel(const Mapper& mapper, const std::string& path) { saveModelBytes(serializeModel(mapper), path); }

std::unique_ptr<Mapper> loadModel(const std::string& path) {
  std::string bytes;
  try {
    bytes = readModelFile(path);
  } catch (const std::bad_alloc&) {
    // Only a file that is as large as its header says, and larger than memory, gets here.
    throw std::runtime_error(loadError(path) + ": model file needs more memory than is available");
  }
  try {
    return deserializeModel(bytes);
  } catch (const std::runtime_error& error) {
    throw std::runtime_error(loadError(path) + ": " + error.what());
  }
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
