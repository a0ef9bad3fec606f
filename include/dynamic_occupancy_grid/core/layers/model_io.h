#pragma once
// The model file: everything a Mapper knows (configuration and geometry, time, and every
// observed cell's belief, transitions, online EM statistics and static baseline) in one
// versioned binary file, so that mapping can stop and go on later, and so that offline
// tools and Python can read a map. Format: docs/model_format.md (little-endian, values as
// the grid stores them, CRC-32 at the end); Python reader: scripts/read_model.py.
//
// A saved and loaded mapper is the saved one: the same cells bit for bit, the same
// configuration and time, so it maps on exactly as the saved one would have, and saving it
// again gives the same bytes.
//
// ROS-free: standard library only.

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "dynamic_occupancy_grid/core/grid/mapper.h"

namespace dynamic_occupancy_grid {
namespace core {

/// The format version saveModel writes. loadModel reads it and versions 1 and 2: both were
/// written by each cell's online EM (TransitionLearner::kCellEm) and go on with it; version
/// 1 also lacks the learners' options, the sensor model's sums and the cells' last evidence
/// (MapperConfig's defaults and zeros).
constexpr std::uint32_t kModelFormatVersion = 3;

/// The model as bytes. The evidence of the step still being gathered is not part of it
/// (call Mapper::finishStep first to include it). Needs one buffer of the file's size
/// (72 bytes per observed cell) besides the map.
std::string serializeModel(const Mapper& mapper);
/// A belief to save for observed cell (x, y) instead of the mapper's: p(occ) at the cell's
/// own last step `last_step` (a mapper step); none keeps the mapper's.
using CellBeliefOverride =
    std::function<std::optional<float>(std::int32_t x, std::int32_t y, std::int32_t last_step)>;
/// serializeModel with each cell's belief from `belief` where it gives one (the pose filter's
/// best particle: corrected_mapping.h). The cell keeps everything else but its learner
/// state's split over the state now: each kind (kKinds, as Mapper::applyOfflineEm's final
/// beliefs do) or each past transition i -> j (kCellEm's S(i, j, m)) keeps its mass, split
/// by the new belief. Throws std::invalid_argument for a belief
/// outside [0, 1] (nothing is written).
std::string serializeModel(const Mapper& mapper, const CellBeliefOverride& belief);
/// A Mapper holding the model in `bytes`. Throws std::runtime_error with a clear message for
/// anything but a complete, intact file of versions 1 to kModelFormatVersion (bad magic, other version,
/// truncated, checksum mismatch, invalid values, trailing bytes); nothing else is affected
/// then. The returned mapper gathers no step yet: its next scan may be in any step after
/// the last applied one.
std::unique_ptr<Mapper> deserializeModel(const std::string& bytes);

/// serializeModel to `path` by writeFileAtomically (core/layers/file_io.h: a unique temporary
/// `.<name>.dogtmp.XXXXXX` beside it, fsync, rename): a failure (full disk, missing
/// directory) throws std::runtime_error "cannot save model file <path>: ..." and leaves any
/// older file at `path` intact; anything at `path` but a regular file (a device, a FIFO, a
/// directory) is refused and left alone. A symbolic link is followed (the file it points
/// to is replaced).
void saveModel(const Mapper& mapper, const std::string& path);
/// The file half of saveModel, for bytes from serializeModel (a node serializes under its
/// map's lock and writes after releasing it).
void saveModelBytes(const std::string& bytes, const std::string& path);
/// deserializeModel of the file at `path`; errors "cannot load model file <path>: ...".
/// Only a regular file is opened (core/layers/file_io.h: a FIFO or a device is refused without
/// waiting or reading), and it is read in two steps: the header, then exactly the size its
/// cell count promises; a file of another size is refused from its size, so neither an
/// endless nor a huge file makes it allocate more than the header promises.
std::unique_ptr<Mapper> loadModel(const std::string& path);

}  // namespace core
}  // namespace dynamic_occupancy_grid
