#pragma once
// Storage of the per-cell state: square tiles of 64 x 64 cells, allocated only where
// something was observed, each a struct of arrays (a field of all cells is contiguous).
// Cells are addressed by lattice coordinates (x, y): cell (0, 0) has its lower-left
// corner at the anchor point, x grows with the world x axis, y with the world y axis.
// The map window handed to publishers is row-major like nav_msgs/OccupancyGrid.

#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <vector>

#include "dynamic_occupancy_grid/core/cell/cell_kinds.h"
#include "dynamic_occupancy_grid/core/grid/traversal.h"

namespace dynamic_occupancy_grid {
namespace core {

/// Floats of a cell's learner state: online EM's eight statistics S(i, j, m)
/// (TransitionLearner::kCellEm), or the joint posterior over (kind, state) (kKinds).
constexpr int kLearnerStateSize = 2 * kKindCount > 8 ? 2 * kKindCount : 8;

/// last_step of a cell that was never observed.
constexpr std::int32_t kNeverObserved = std::numeric_limits<std::int32_t>::min();

/// An axis-aligned, inclusive box of cells; empty() when nothing is in it.
struct CellBox {
  std::int32_t min_x = std::numeric_limits<std::int32_t>::max();
  std::int32_t min_y = std::numeric_limits<std::int32_t>::max();
  std::int32_t max_x = std::numeric_limits<std::int32_t>::min();
  std::int32_t max_y = std::numeric_limits<std::int32_t>::min();

  bool empty() const { return min_x > max_x || min_y > max_y; }
  std::int64_t width() const { return empty() ? 0 : std::int64_t{max_x} - min_x + 1; }
  std::int64_t height() const { return empty() ? 0 : std::int64_t{max_y} - min_y + 1; }
  bool contains(std::int32_t x, std::int32_t y) const {
    return x >= min_x && x <= max_x && y >= min_y && y <= max_y;
  }
  void include(std::int32_t x, std::int32_t y);
  void include(const CellBox& other);
};

/// The world placement of a rectangular block of cells, as in nav_msgs/MapMetaData:
/// origin = world position of the lower-left corner of cell (0, 0) of the block,
/// index of cell (col, row) = row * width + col.
struct MapWindow {
  double resolution_m = 0.0;
  double origin_x_m = 0.0;
  double origin_y_m = 0.0;
  CellBox cells;  ///< lattice cells covered; width/height of the block are its extent
};

/// The state of one cell (THEORY.md §1–6). Floats keep a cell at 64 bytes; the filter
/// and EM math runs in double and rounds once per stored step.
struct CellState {
  float p_occ;                   ///< belief p(occ) at last_step
  std::int32_t last_step;        ///< step of the last update, kNeverObserved if none
  float log_odds;                ///< standard occupancy grid baseline (clamped log-odds)
  float p_occ_given_free;        ///< p_of the filter uses, per step
  float p_free_given_occ;        ///< p_fo the filter uses, per step
  /// The learner's state: online EM statistics S(i, j, m) in TransitionStats order (the
  /// first 8), or p(kind, state) at index 2 kind + state.
  std::array<float, kLearnerStateSize> em_stats;
  std::uint16_t observed_steps;  ///< steps with an observation (saturating)
  /// The evidence of the cell's last step (hits, misses; saturating at 255): online
  /// sensor-model learning weighs it by the cell's state once the next step is seen.
  std::uint8_t last_hits;
  std::uint8_t last_misses;
};

class CellGrid {
 public:
  static constexpr int kTileBits = 6;
  static constexpr std::int32_t kTileSize = 1 << kTileBits;  // cells per tile side
  static constexpr int kTileCells = kTileSize * kTileSize;

  /// Struct of arrays for the cells of one tile; index = (y & 63) * 64 + (x & 63).
  struct Tile {
    std::array<float, kTileCells> p_occ;
    std::array<std::int32_t, kTileCells> last_step;
    std::array<float, kTileCells> log_odds;
    std::array<float, kTileCells> p_occ_given_free;
    std::array<float, kTileCells> p_free_given_occ;
    // The learner's state (CellState::em_stats), one array per float.
    std::array<std::array<float, kTileCells>, kLearnerStateSize> em_stats;
    std::array<std::uint16_t, kTileCells> observed_steps;
    std::array<std::uint8_t, kTileCells> last_hits;    ///< evidence of the cell's last step
    std::array<std::uint8_t, kTileCells> last_misses;
    // A beam's visit reads and writes this one word (ScanRecord): which scan last touched
    // the cell and how, so that one scan counts a cell once and a hit wins over a miss of
    // the same scan, and the hits and misses gathered in the current time step.
    std::array<std::uint64_t, kTileCells> scan_record;
    std::int32_t tile_x;  ///< lattice coordinates of the tile (cell x >> kTileBits)
    std::int32_t tile_y;
    /// The Mapper's bookkeeping of the step being gathered: this tile's index among the
    /// tiles touched in it, -1 if none.
    std::int32_t touched_slot = -1;

    std::int32_t cellX(int offset) const { return (tile_x * kTileSize) + (offset & (kTileSize - 1)); }
    std::int32_t cellY(int offset) const { return (tile_y * kTileSize) + (offset >> kTileBits); }
  };

  /// The fields of Tile::scan_record: bits 0-30 the id of the scan that last touched the
  /// cell, bit 31 set if that scan hit it, bits 32-47 this step's hits, 48-63 its misses.
  struct ScanRecord {
    static constexpr std::uint64_t kIdMask = 0x7fffffffULL;
    static constexpr std::uint64_t kHitBit = 0x80000000ULL;
    static constexpr std::uint64_t kMarkMask = kIdMask | kHitBit;
    static constexpr std::uint32_t kMaxCount = 0xffff;
    static std::uint32_t scanId(std::uint64_t record) { return static_cast<std::uint32_t>(record & kIdMask); }
    static bool hit(std::uint64_t record) { return (record & kHitBit) != 0; }
    static std::uint32_t hits(std::uint64_t record) { return static_cast<std::uint32_t>(record >> 32) & kMaxCount; }
    static std::uint32_t misses(std::uint64_t record) { return static_cast<std::uint32_t>(record >> 48); }
    static bool gathered(std::uint64_t record) { return (record >> 32) != 0; }
    static std::uint64_t make(std::uint32_t scan_id, bool hit, std::uint32_t hits, std::uint32_t misses) {
      return (std::uint64_t{misses} << 48) | (std::uint64_t{hits} << 32) | (hit ? kHitBit : 0) | scan_id;
    }
  };

  /// Initial values of a freshly allocated cell.
  struct CellDefaults {
    float p_occ_given_free;
    float p_free_given_occ;
  };

  /// A grid anchored at world point (anchor_x_m, anchor_y_m). With `fixed_cells` set, only
  /// those lattice cells exist and nothing ever grows; otherwise the covered area grows in
  /// whole tiles, up to max_cells_per_side along each axis.
  CellGrid(double resolution_m, double anchor_x_m, double anchor_y_m,
           std::optional<CellBox> fixed_cells, std::int32_t max_cells_per_side,
           CellDefaults defaults);
  /// A deep copy: every allocated tile is copied (a checkpoint of the map).
  CellGrid(const CellGrid& other);
  CellGrid& operator=(const CellGrid& other);
  CellGrid(CellGrid&&) noexcept = default;
  CellGrid& operator=(CellGrid&&) noexcept = default;
  ~CellGrid() = default;

  double resolution() const { return resolution_m_; }
  double anchorX() const { return anchor_x_m_; }
  double anchorY() const { return anchor_y_m_; }
  /// World coordinate -> continuous lattice coordinate (in cells).
  double toLatticeX(double x_m) const { return (x_m - anchor_x_m_) * inverse_resolution_; }
  double toLatticeY(double y_m) const { return (y_m - anchor_y_m_) * inverse_resolution_; }

  /// Cells that may hold data: the fixed box, or the tiles allocated so far (empty box for a
  /// growing grid that has seen nothing).
  CellBox bounds() const;
  MapWindow window() const { return window(bounds()); }
  MapWindow window(const CellBox& cells) const;
  bool isFixed() const { return fixed_cells_.has_value(); }

  /// Makes every cell of `box` addressable (growing the tile index if allowed) and returns
  /// the part of `box` that is inside the grid's limits.
  CellBox reserve(const CellBox& box);
  /// The tile holding (x, y), allocating it on first use; nullptr outside the grid.
  /// Call reserve() first for the area: this only allocates inside the reserved index.
  Tile* tileForWriting(std::int32_t x, std::int32_t y);
  /// The tile holding (x, y) if it was ever allocated.
  const Tile* findTile(std::int32_t x, std::int32_t y) const;
  Tile* findTile(std::int32_t x, std::int32_t y) {
    return const_cast<Tile*>(static_cast<const CellGrid&>(*this).findTile(x, y));
  }
  /// The cell (x, y), or std::nullopt if it was never observed.
  std::optional<CellState> cell(std::int32_t x, std::int32_t y) const;

  /// Calls fn(Tile&) for every allocated tile.
  template <class Fn>
  void forEachTile(Fn&& fn) {
    for (auto& tile : tiles_) {
      if (tile) fn(*tile);
    }
  }
  template <class Fn>
  void forEachTile(Fn&& fn) const {
    for (const auto& tile : tiles_) {
      if (tile) fn(static_cast<const Tile&>(*tile));
    }
  }

  bool insideLimits(std::int32_t x, std::int32_t y) const;
  /// Every cell of tile (tile_x, tile_y) is inside the limits (no per-cell check needed).
  bool tileInsideLimits(std::int32_t tile_x, std::int32_t tile_y) const {
    return insideLimits(tile_x * kTileSize, tile_y * kTileSize) &&
           insideLimits((tile_x * kTileSize) + kTileSize - 1, (tile_y * kTileSize) + kTileSize - 1);
  }
  static int offsetOf(std::int32_t x, std::int32_t y) {
    return ((y & (kTileSize - 1)) << kTileBits) | (x & (kTileSize - 1));
  }

  std::size_t allocatedTiles() const { return allocated_tiles_; }
  /// Bytes of cell storage per allocated cell (the tile struct over its cell count).
  static constexpr double bytesPerCell() { return static_cast<double>(sizeof(Tile)) / kTileCells; }

 private:
  std::unique_ptr<Tile>* slot(std::int32_t tile_x, std::int32_t tile_y);
  const std::unique_ptr<Tile>* slot(std::int32_t tile_x, std::int32_t tile_y) const;

  double resolution_m_;
  double inverse_resolution_;
  double anchor_x_m_;
  double anchor_y_m_;
  std::optional<CellBox> fixed_cells_;
  std::int32_t max_cells_per_side_;
  CellDefaults defaults_;
  // Tile index: a dense row-major array of tile pointers over the tile box
  // [tile_min_x_, tile_min_x_ + tiles_w_) x [tile_min_y_, tile_min_y_ + tiles_h_).
  // Growing moves pointers only; cells never move.
  std::int32_t tile_min_x_ = 0;
  std::int32_t tile_min_y_ = 0;
  std::int32_t tiles_w_ = 0;
  std::int32_t tiles_h_ = 0;
  std::vector<std::unique_ptr<Tile>> tiles_;
  std::size_t allocated_tiles_ = 0;
  CellBox allocated_cells_;
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
