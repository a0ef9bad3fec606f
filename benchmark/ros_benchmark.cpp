// Google Benchmark for publishing (issue 6): a map layer of a fully observed 4000 x 4000 map
// (200 m x 200 m at 0.05 m) turned into a nav_msgs/OccupancyGrid by the node's own
// conversion (src/ros/grid_messages.cpp: core::evaluateLayer + toOccupancyValues +
// toOccupancyGrid), and the serialization ros::Publisher does for a remote subscriber.
// Results and the command are in BENCHMARKS.md.
//   The map: every cell restored with a random belief, random transitions and a last update
//   0 to 99 steps before "now", so the belief layer really predicts over a gap per cell.

#include <benchmark/benchmark.h>

#include <ros/serialization.h>

#include <cstdint>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/mapper.h"
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
        state.em_stats.fill(1.0f);
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

// One full layer message: evaluate the layer over the whole map at step "now", scale to
// 0..100 / -1, build the OccupancyGrid (the values are moved in, not copied). Argument = the
// core::Layer (0 belief, 1 predicted, 2 stationary, 5 static_map).
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
BENCHMARK(BM_FullLayerMessage)->Arg(0)->Arg(1)->Arg(2)->Arg(5)->Unit(benchmark::kMillisecond);

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
