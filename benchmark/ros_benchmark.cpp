// Google Benchmark for publishing (issues 6 and 18): a map layer of a fully observed 4000 x 4000
// map (200 m x 200 m at 0.05 m) turned into a nav_msgs/OccupancyGrid by the node's own
// conversion (src/ros/grid_messages.cpp: core::layerOccupancy + toOccupancyGrid), the same by
// the reference conversion it replaced (core::evaluateLayer into a float buffer +
// toOccupancyValues: BM_FullLayerMessageReference, the "before" in the same run), the floor
// of reading the cell arrays a layer needs (BM_LayerMemoryFloor), and the serialization
// ros::Publisher does for a remote subscriber. Results and the command are in BENCHMARKS.md.
//   The map: every cell restored with a random belief, random transitions and a last update
//   0 to 99 steps before "now", so the belief layer really predicts over a gap per cell.

#include <benchmark/benchmark.h>

#include <ros/serialization.h>

#include <atomic>
#include <cstdint>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "dynamic_occupancy_grid/core/common/parallel.h"

#include "dynamic_occupancy_grid/core/cell/cell_kinds.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/ros/grid_messages.h"

namespace dog = dynamic_occupancy_grid::core;
namespace rl = dynamic_occupancy_grid::ros_layer;

namespace {

constexpr std::int32_t kSide = 4000;
constexpr std::int64_t kNow = 1000;

// Built once, shared by every benchmark (about 1 GB: 16 M cells x 64 bytes).
const dog::Mapper& fullMap() {
  static const std::unique_ptr<dog::Mapper> mapper = [] {
    dog::MapperConfig config;
    config.resolution_m = 0.05;
    config.fixed_bounds = true;
    config.width_m = kSide * config.resolution_m;
    config.height_m = config.width_m;
    config.origin_x_m = -config.width_m / 2.0;
    config.origin_y_m = -config.height_m / 2.0;
    auto m = std::make_unique<dog::Mapper>(config);
    m->restoreTime(0.0, kNow);
    std::mt19937 rng(5);
    std::uniform_real_distribution<float> p(0.0f, 1.0f);
    std::uniform_real_distribution<float> transition(0.001f, 0.2f);
    std::uniform_int_distribution<std::int32_t> age(0, 99);
    dog::CellState state{};
    for (std::int32_t y = 0; y < kSide; ++y) {
      for (std::int32_t x = 0; x < kSide; ++x) {
        state.p_occ = p(rng);
        state.last_step = static_cast<std::int32_t>(kNow) - age(rng);
        state.log_odds = 4.0f * p(rng) - 2.0f;
        state.p_occ_given_free = transition(rng);
        state.p_free_given_occ = transition(rng);
        // The default learner's state: p(kind, state) at 2 kind + state, summing to 1
        // (restoreCell refuses anything else), spread evenly over the kinds.
        state.em_stats.fill(0.0f);
        for (int k = 0; k < dog::kKindCount; ++k) {
          state.em_stats[2 * k] = state.p_occ / dog::kKindCount;
          state.em_stats[2 * k + 1] = (1.0f - state.p_occ) / dog::kKindCount;
        }
        state.observed_steps = 10;
        m->restoreCell(x, y, state);
      }
    }
    m->takeChangedCells();
    return m;
  }();
  return *mapper;
}

rl::LayerView view(std::int64_t layer) {
  rl::LayerView v;
  v.layer = static_cast<dog::Layer>(layer);
  v.horizon_steps = 10;
  return v;
}

// The conversion before issue 18 (what rl::layerValues did): the layer as floats over the
// box, then scaled to int8 in a second pass, one thread.
std::vector<std::int8_t> referenceLayerValues(const dog::CellGrid& grid, const rl::LayerView& view, std::int64_t step,
                                              const dog::CellBox& box) {
  std::vector<float> values;
  dog::evaluateLayer(grid, view.layer, step, view.horizon_steps, box, &values);
  std::vector<std::int8_t> occupancy;
  if (view.thresholds) {
    dog::toThresholdedOccupancyValues(values, *view.thresholds, &occupancy);
  } else {
    dog::toOccupancyValues(values, view.full_scale, &occupancy);
  }
  return occupancy;
}

// One full layer message: evaluate the layer over the whole map at step "now", scale to
// 0..100 / -1, build the OccupancyGrid (the values are moved in, not copied). Argument = the
// core::Layer (0 belief, 1 predicted, 2 stationary, 3 p_occ_given_free, 5 static_map).
void BM_FullLayerMessage(benchmark::State& state) {
  const dog::Mapper& mapper = fullMap();
  const dog::CellBox bounds = mapper.grid().bounds();
  const rl::LayerView layer_view = view(state.range(0));
  const ros::Time stamp(1000.0);
  for (auto _ : state) {
    nav_msgs::OccupancyGrid msg = rl::toOccupancyGrid(mapper.grid().window(bounds),
                                                      rl::layerValues(mapper.grid(), layer_view, kNow, bounds),
                                                      "map", stamp);
    benchmark::DoNotOptimize(msg.data.data());
  }
  state.SetItemsProcessed(state.iterations() * bounds.width() * bounds.height());  // cells per second
  state.SetLabel(dog::layerName(layer_view.layer) + ", 4000 x 4000 cells");
}
BENCHMARK(BM_FullLayerMessage)->Arg(0)->Arg(1)->Arg(2)->Arg(3)->Arg(5)->Unit(benchmark::kMillisecond);

// The same message by the reference conversion (before issue 18), in the same binary.
void BM_FullLayerMessageReference(benchmark::State& state) {
  const dog::Mapper& mapper = fullMap();
  const dog::CellBox bounds = mapper.grid().bounds();
  const rl::LayerView layer_view = view(state.range(0));
  const ros::Time stamp(1000.0);
  for (auto _ : state) {
    nav_msgs::OccupancyGrid msg = rl::toOccupancyGrid(mapper.grid().window(bounds),
                                                      referenceLayerValues(mapper.grid(), layer_view, kNow, bounds),
                                                      "map", stamp);
    benchmark::DoNotOptimize(msg.data.data());
  }
  state.SetItemsProcessed(state.iterations() * bounds.width() * bounds.height());
  state.SetLabel(dog::layerName(layer_view.layer) + ", reference conversion");
}
BENCHMARK(BM_FullLayerMessageReference)->Arg(0)->Arg(5)->Unit(benchmark::kMillisecond);

// The `map` topic's message: the belief thresholded as map_server reads an image (argument
// 0 trinary, 1 scale), new conversion.
void BM_FullMapMessage(benchmark::State& state) {
  const dog::Mapper& mapper = fullMap();
  const dog::CellBox bounds = mapper.grid().bounds();
  rl::LayerView layer_view = view(0);
  layer_view.thresholds = dog::OccupancyThresholds{};
  layer_view.thresholds->mode = state.range(0) == 0 ? dog::ThresholdMode::kTrinary : dog::ThresholdMode::kScale;
  const ros::Time stamp(1000.0);
  for (auto _ : state) {
    nav_msgs::OccupancyGrid msg = rl::toOccupancyGrid(mapper.grid().window(bounds),
                                                      rl::layerValues(mapper.grid(), layer_view, kNow, bounds),
                                                      "map", stamp);
    benchmark::DoNotOptimize(msg.data.data());
  }
  state.SetItemsProcessed(state.iterations() * bounds.width() * bounds.height());
  state.SetLabel(state.range(0) == 0 ? "belief, trinary thresholds" : "belief, scale thresholds");
}
BENCHMARK(BM_FullMapMessage)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// core::layerOccupancy on one thread (argument = layer), for the per-core cost.
void BM_FullLayerOneThread(benchmark::State& state) {
  const dog::Mapper& mapper = fullMap();
  const dog::CellBox bounds = mapper.grid().bounds();
  const auto layer = static_cast<dog::Layer>(state.range(0));
  std::vector<std::int8_t> occupancy;
  for (auto _ : state) {
    dog::layerOccupancy(mapper.grid(), layer, kNow, 10, bounds, dog::OccupancyScaling{}, &occupancy, 1);
    benchmark::DoNotOptimize(occupancy.data());
  }
  state.SetItemsProcessed(state.iterations() * bounds.width() * bounds.height());
  state.SetLabel(dog::layerName(layer) + ", one thread, into a reused vector");
}
BENCHMARK(BM_FullLayerOneThread)->Arg(0)->Arg(5)->Unit(benchmark::kMillisecond);

// Issue 18's int8 tile cache (core::LayerTileCache) for the layers that change only where
// cells are written: a full message from a warm cache (argument = layer; nothing written
// since the last message: a copy of one byte per cell), and (AfterScan) the same after the
// tiles of a 30 m scan's box (1200 x 1200 cells around the sensor, 400 tiles) were bumped,
// as the mapper would bump them in a step of that scan. The node does not use the cache yet:
// the mapper has no TileVersions hook (BENCHMARKS.md).
void fullLayerCached(benchmark::State& state, bool after_scan) {
  const dog::Mapper& mapper = fullMap();
  const dog::CellBox bounds = mapper.grid().bounds();
  const auto layer = static_cast<dog::Layer>(state.range(0));
  dog::TileVersions versions;
  dog::LayerTileCache cache(layer, dog::OccupancyScaling{});
  std::vector<std::int8_t> warm;
  cache.occupancy(mapper.grid(), versions, bounds, &warm);
  const ros::Time stamp(1000.0);
  std::size_t computed = 0;
  for (auto _ : state) {
    if (after_scan) {
      state.PauseTiming();
      for (std::int32_t ty = (kSide / 2 - 600) >> 6; ty <= (kSide / 2 + 599) >> 6; ++ty) {
        for (std::int32_t tx = (kSide / 2 - 600) >> 6; tx <= (kSide / 2 + 599) >> 6; ++tx) versions.bump(tx, ty);
      }
      state.ResumeTiming();
    }
    std::vector<std::int8_t> values;
    cache.occupancy(mapper.grid(), versions, bounds, &values);
    computed += cache.lastComputed();
    nav_msgs::OccupancyGrid msg = rl::toOccupancyGrid(mapper.grid().window(bounds), std::move(values), "map", stamp);
    benchmark::DoNotOptimize(msg.data.data());
  }
  state.counters["tiles_computed"] = static_cast<double>(computed) / static_cast<double>(state.iterations());
  state.SetItemsProcessed(state.iterations() * bounds.width() * bounds.height());
  state.SetLabel(dog::layerName(layer) + (after_scan ? ", tile cache, a scan's 400 tiles bumped" : ", warm tile cache"));
}
void BM_FullLayerCached(benchmark::State& state) { fullLayerCached(state, false); }
void BM_FullLayerCachedAfterScan(benchmark::State& state) { fullLayerCached(state, true); }
BENCHMARK(BM_FullLayerCached)->Arg(5)->Arg(3)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FullLayerCachedAfterScan)->Arg(5)->Arg(3)->Unit(benchmark::kMillisecond);

// The per-cell cost without the memory traffic: a 256 x 256 box of the map (16 tiles, 1 MB of
// the arrays the belief reads: stays in L2 between iterations), one thread. Argument = layer.
void BM_LayerInCache(benchmark::State& state) {
  const dog::Mapper& mapper = fullMap();
  dog::CellBox box;
  box.include(1024, 1024);
  box.include(1024 + 255, 1024 + 255);
  const auto layer = static_cast<dog::Layer>(state.range(0));
  std::vector<std::int8_t> occupancy;
  for (auto _ : state) {
    dog::layerOccupancy(mapper.grid(), layer, kNow, 10, box, dog::OccupancyScaling{}, &occupancy, 1);
    benchmark::DoNotOptimize(occupancy.data());
  }
  state.SetItemsProcessed(state.iterations() * box.width() * box.height());
  state.SetLabel(dog::layerName(layer) + ", 256 x 256 cells in cache, one thread");
}
BENCHMARK(BM_LayerInCache)->Arg(0)->Arg(2)->Arg(3)->Arg(5)->Unit(benchmark::kMicrosecond);

// The floor of a full layer on this machine: read the cell arrays a layer needs (argument 4:
// p_occ, last_step, p_of, p_fo as the belief does; 2: last_step and log_odds as static_map
// does) tile by tile in the same order and threads as layerOccupancy, and write one byte
// per cell into a fresh 16 MB message vector. No arithmetic worth the name.
void BM_LayerMemoryFloor(benchmark::State& state) {
  const dog::Mapper& mapper = fullMap();
  const dog::CellGrid& grid = mapper.grid();
  const dog::CellBox box = grid.bounds();
  const bool four = state.range(0) == 4;
  const std::int64_t width = box.width();
  const std::int64_t blocks = (box.height() + dog::CellGrid::kTileSize - 1) / dog::CellGrid::kTileSize;
  const unsigned threads = std::max(1U, std::thread::hardware_concurrency());
  for (auto _ : state) {
    std::vector<std::int8_t> out(static_cast<std::size_t>(width * box.height()));
    std::atomic<std::int64_t> next{0};
    dog::runOnThreads(threads, [&] {
      for (std::int64_t b = next++; b < blocks; b = next++) {
        const std::int32_t y0 = static_cast<std::int32_t>(box.min_y + b * dog::CellGrid::kTileSize);
        const std::int32_t y1 = std::min<std::int32_t>(box.max_y + 1, y0 + dog::CellGrid::kTileSize);
        for (std::int32_t x = box.min_x; x <= box.max_x; x = (x | (dog::CellGrid::kTileSize - 1)) + 1) {
          const std::int32_t run_end = std::min<std::int32_t>(box.max_x, x | (dog::CellGrid::kTileSize - 1));
          for (std::int32_t y = y0; y < y1; ++y) {
            const dog::CellGrid::Tile* tile = grid.findTile(x, y);
            std::int8_t* o = out.data() + (static_cast<std::int64_t>(y - box.min_y) * width) + (x - box.min_x);
            const int i0 = dog::CellGrid::offsetOf(x, y);
            for (int j = 0; j <= run_end - x; ++j) {
              std::uint32_t bits = static_cast<std::uint32_t>(tile->last_step[i0 + j]);
              std::uint32_t f;
              if (four) {
                std::memcpy(&f, &tile->p_occ[i0 + j], 4);
                bits ^= f;
                std::memcpy(&f, &tile->p_occ_given_free[i0 + j], 4);
                bits ^= f;
                std::memcpy(&f, &tile->p_free_given_occ[i0 + j], 4);
                bits ^= f;
              } else {
                std::memcpy(&f, &tile->log_odds[i0 + j], 4);
                bits ^= f;
              }
              o[j] = static_cast<std::int8_t>(bits & 0x7F);
            }
          }
        }
      }
    });
    benchmark::DoNotOptimize(out.data());
  }
  state.SetItemsProcessed(state.iterations() * width * box.height());
  state.SetBytesProcessed(state.iterations() * width * box.height() * (four ? 17 : 9));
  state.SetLabel(four ? "4 arrays (belief's), 2 threads" : "2 arrays (static_map's), 2 threads");
}
BENCHMARK(BM_LayerMemoryFloor)->Arg(4)->Arg(2)->Unit(benchmark::kMillisecond);

// An _updates message for the box one 30 m scan changes (1200 x 1200 cells around the
// sensor, what Mapper::takeChangedCells returns after a step of that scan), belief layer.
void BM_UpdateMessage(benchmark::State& state) {
  const dog::Mapper& mapper = fullMap();
  const dog::CellBox bounds = mapper.grid().bounds();
  dog::CellBox changed;
  changed.include(kSide / 2 - 600, kSide / 2 - 600);
  changed.include(kSide / 2 + 599, kSide / 2 + 599);
  const rl::LayerView layer_view = view(0);
  const ros::Time stamp(1000.0);
  for (auto _ : state) {
    map_msgs::OccupancyGridUpdate msg = rl::toOccupancyGridUpdate(
        bounds, changed, rl::layerValues(mapper.grid(), layer_view, kNow, changed), "map", stamp);
    benchmark::DoNotOptimize(msg.data.data());
  }
  state.SetItemsProcessed(state.iterations() * changed.width() * changed.height());
  state.SetLabel("belief, 1200 x 1200 changed cells");
}
BENCHMARK(BM_UpdateMessage)->Unit(benchmark::kMillisecond);

// What ros::Publisher::publish adds for a subscriber in another process: serializing the
// 16 MB message into one buffer (ros::serialization::serializeMessage).
void BM_SerializeFullLayer(benchmark::State& state) {
  const dog::Mapper& mapper = fullMap();
  const dog::CellBox bounds = mapper.grid().bounds();
  const nav_msgs::OccupancyGrid msg = rl::toOccupancyGrid(
      mapper.grid().window(bounds), rl::layerValues(mapper.grid(), view(0), kNow, bounds), "map", ros::Time(1000.0));
  for (auto _ : state) {
    ros::SerializedMessage serialized = ros::serialization::serializeMessage(msg);
    benchmark::DoNotOptimize(serialized.buf.get());
  }
  state.SetBytesProcessed(state.iterations() * static_cast<std::int64_t>(msg.data.size()));
  state.SetLabel("nav_msgs/OccupancyGrid, 16 M cells");
}
BENCHMARK(BM_SerializeFullLayer)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
