#pragma once
// A particle's map for the pose filter (pose_filter.h; Murphy 1999, §4): each cell's
// p(occ) and the step of its last update, given the particle's trajectory. The cells are
// the package's cell HMMs: a cell is predicted across the steps it was not seen in closed
// form (THEORY.md §3) with transition probabilities that all particles share
// (TransitionSource), and updated with a scan's evidence by Bayes (THEORY.md §2).
//
// Storage: square tiles of 32 x 32 cells, shared between maps until one of them writes to
// a tile (copy on write, as gmapping shares its map patches). Copying a map copies tile
// pointers, so resampling costs no cell copies, and a scan copies only the shared tiles it
// writes to.
//
// ROS-free: standard library only.

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <unordered_map>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/cell/cell_model.h"

namespace dynamic_occupancy_grid {
namespace core {

class Mapper;

/// The per-step transition probabilities of the cells, one source for every particle.
/// Cells are lattice cells of the particle maps: cell (x, y) covers [x r, (x + 1) r) x
/// [y r, (y + 1) r) for the maps' resolution r (the lattice's corner at the origin).
class TransitionSource {
 public:
  virtual ~TransitionSource() = default;
  virtual TransitionParams at(std::int32_t x, std::int32_t y) const = 0;
};

/// The same transitions for every cell: {0, 0} is a static map (the gmapping-like
/// baseline), a prior's values a map that forgets at one rate.
class UniformTransitions final : public TransitionSource {
 public:
  /// Throws std::invalid_argument for invalid params.
  explicit UniformTransitions(const TransitionParams& params);
  TransitionParams at(std::int32_t, std::int32_t) const override { return params_; }

 private:
  TransitionParams params_;
};

/// The transitions a Mapper has learned (the package's learners, on the scans the pose
/// filter corrected): the Mapper's cell holding the centre of the particle maps' cell. A
/// cell the Mapper has observed in fewer than `min_observed_steps` steps (or never) is
/// static ({0, 0}) until then: the learner's prior forgets a wall within a loop of a
/// patrol, before the learner has seen it often enough to call it a wall. The Mapper must
/// outlive this and not change while particles read it.
class MapperTransitions final : public TransitionSource {
 public:
  /// Throws std::invalid_argument unless resolution_m > 0.
  MapperTransitions(const Mapper& mapper, double resolution_m, std::uint32_t min_observed_steps);
  TransitionParams at(std::int32_t x, std::int32_t y) const override;

 private:
  const Mapper& mapper_;
  double resolution_m_;
  std::uint32_t min_observed_steps_;
};

class ParticleMap {
 public:
  static constexpr int kTileBits = 5;
  static constexpr std::int32_t kTileSize = 1 << kTileBits;  // cells per tile side
  static constexpr int kTileCells = kTileSize * kTileSize;

  struct Tile {
    std::array<float, kTileCells> p_occ;            ///< at last_step
    std::array<std::int32_t, kTileCells> last_step;  ///< kNeverObserved: never updated
  };

  /// p(occ) of cell (x, y) predicted to `step` (>= its last update) in closed form; for a
  /// cell never updated, `unknown_p_occ` one transition on (the Mapper's convention: the
  /// prior is the belief just before the step's transition).
  double predicted(std::int32_t x, std::int32_t y, std::int64_t step, const TransitionSource& transitions,
                   double unknown_p_occ) const;
  /// The step of the cell's last update; kNeverObserved if none.
  std::int32_t lastStep(std::int32_t x, std::int32_t y) const;
  /// One filter step of cell (x, y) at `step` (>= its last update, < 2^31): the prediction
  /// to it, then Bayes with the evidence's log-likelihood ratio log p(z|occ)/p(z|free). A
  /// cell never updated starts from `unknown_p_occ` (one transition before `step`).
  void update(std::int32_t x, std::int32_t y, std::int64_t step, double log_likelihood_ratio,
              const TransitionSource& transitions, double unknown_p_occ);

  /// Reads cells remembering the tile of the last one (the cells of a beam mostly share a
  /// tile). Valid while the map is not changed.
  class Reader {
   public:
    explicit Reader(const ParticleMap& map) : map_(map) {}
    double predicted(std::int32_t x, std::int32_t y, std::int64_t step, const TransitionSource& transitions,
                     double unknown_p_occ);
    std::int32_t lastStep(std::int32_t x, std::int32_t y);

   private:
    const Tile* tile(std::int32_t x, std::int32_t y);
    const ParticleMap& map_;
    std::optional<std::uint64_t> key_;  ///< of tile_; none before the first cell (every key is some tile's)
    const Tile* tile_ = nullptr;
  };
  /// update() remembering the tile of the last cell (copied, if shared, at its first write).
  /// The only writer of the map while it lives.
  class Writer {
   public:
    explicit Writer(ParticleMap& map) : map_(map) {}
    void update(std::int32_t x, std::int32_t y, std::int64_t step, double log_likelihood_ratio,
                const TransitionSource& transitions, double unknown_p_occ);

   private:
    ParticleMap& map_;
    std::optional<std::uint64_t> key_;  ///< of tile_; none before the first cell
    Tile* tile_ = nullptr;
  };

  std::size_t tileCount() const { return tiles_.size(); }
  /// Tiles this map shares with another map (none written since the copy).
  std::size_t sharedTileCount() const;
  /// Whether this map and `other` hold the same storage for the tile of cell (x, y).
  bool sharesTileWith(const ParticleMap& other, std::int32_t x, std::int32_t y) const;
  /// The box of the tiles allocated (empty without any).
  CellBox bounds() const;
  /// Bytes of the distinct tiles of `maps` (a tile shared by several maps counts once).
  static std::size_t distinctTileBytes(const std::vector<const ParticleMap*>& maps);

 private:
  static std::uint64_t keyOf(std::int32_t x, std::int32_t y);
  static double predictedIn(const Tile* tile, std::int32_t x, std::int32_t y, std::int64_t step,
                            const TransitionSource& transitions, double unknown_p_occ);
  static void updateIn(Tile& tile, std::int32_t x, std::int32_t y, std::int64_t step, double log_likelihood_ratio,
                       const TransitionSource& transitions, double unknown_p_occ);
  const Tile* find(std::int32_t x, std::int32_t y) const;
  /// The cell's tile, copied first if another map shares it, created if missing.
  Tile& writable(std::int32_t x, std::int32_t y);

  std::unordered_map<std::uint64_t, std::shared_ptr<Tile>> tiles_;
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
