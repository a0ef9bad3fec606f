// MappingNode: the map topics — the cell HMM's layers (latched full grids and their
// updates), the best particle's map, the memory model's layers and map hypotheses — on the
// publish timer.
#include "dynamic_occupancy_grid/ros/mapping_node.h"

#include <cmath>
#include <cstdint>
#include <optional>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/layers/map_export.h"
#include "mapping_node_internal.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {
namespace {

using mapping_node_internal::toRosTime;
using mapping_node_internal::horizonSteps;

bool sameBox(const core::CellBox& a, const core::CellBox& b) {
  return (a.empty() && b.empty()) ||
         (a.min_x == b.min_x && a.min_y == b.min_y && a.max_x == b.max_x && a.max_y == b.max_y);
}

}  // namespace

void MappingNode::publishTimer(const ros::TimerEvent&) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (memory_) publishMemory(false);
  if (!mapper_) return;
  // A re-mapping after a correction is otherwise taken at the next scan: once the scans
  // stop (the robot switched off, a bag ended) the layers would never show it.
  if (correction_) correction_->takeFinishedRemap();
  // Apply the step being gathered once no scan of it can still come (scans of a later step
  // apply it anyway). Only when ROS time (on the scans' clock) and the scans' stamps agree:
  // not after stamps jumped back while ROS time ran on.
  const std::optional<std::int64_t> gathering = mapper_->gatheringStep();
  if (gathering && newest_stamp_s_) {
    const double now_s = scanClockNow().toSec();
    const double step_end_s = mapper_->clock().stepStart(*gathering + 1);
    const bool clocks_agree = std::abs(now_s - *newest_stamp_s_) < 10.0 * mapper_->config().time_step_s + 10.0;
    if (clocks_agree && now_s >= step_end_s + parameters_.max_scan_latency_s) mapper_->finishStep();
  }
  publishLayers(false);
  if (correction_) publishBestParticle(false);
}

void MappingNode::publishBestParticle(bool force) {
  const std::size_t updates = correction_->filter().updates();
  const bool belief_wanted = best_particle_belief_.getNumSubscribers() > 0;
  const bool predicted_wanted = best_particle_predicted_.getNumSubscribers() > 0;
  if (updates == 0 || !(belief_wanted || predicted_wanted)) return;
  if (!force && updates == best_particle_published_updates_) return;
  best_particle_published_updates_ = updates;
  // Stamped as the layers are: the end of the last update's step, the predicted one too (the
  // filter's steps are the Mapper's moved by whole steps: its own clock gives the time).
  const core::StepClock& clock = correction_->filter().clock();
  const std::int64_t last = correction_->filter().lastUpdateStep();
  const auto publish = [&](ros::Publisher& publisher, std::int64_t horizon_steps) {
    const core::ParticleBelief belief = correction_->bestParticleBelief(horizon_steps);
    std::vector<std::int8_t> occupancy;
    core::toOccupancyValues(belief.values, 1.0f, &occupancy);
    const double stamp_s = clock.origin() ? clock.stepStart(last + 1) : scanClockNow().toSec();
    publisher.publish(toOccupancyGrid(belief.window, std::move(occupancy), parameters_.fixed_frame, toRosTime(stamp_s)));
  };
  if (belief_wanted) publish(best_particle_belief_, 0);
  if (predicted_wanted) {
    publish(best_particle_predicted_, horizonSteps(parameters_.prediction_horizon_s, mapper_->config().time_step_s));
  }
}

void MappingNode::publishLayers(bool force_full) {
  const ros::Time now = ros::Time::now();
  const std::optional<std::int64_t> step = mapper_->lastAppliedStep();
  const core::CellBox bounds = step ? mapper_->grid().bounds() : core::CellBox{};
  const core::CellBox changed = mapper_->takeChangedCells();
  const bool full_due = force_full || !sameBox(bounds, published_bounds_) || parameters_.full_map_period_s == 0.0 ||
                        (now - last_full_publish_).toSec() >= parameters_.full_map_period_s;
  const ros::Time stamp = step ? toRosTime(mapper_->clock().stepStart(*step + 1)) : scanClockNow();
  bool sent_full = false;
  for (Output& output : outputs_) {
    if (full_due || output.needs_full) {
      if (output.full.getNumSubscribers() == 0) {
        output.needs_full = true;  // evaluated when someone listens
        continue;
      }
      publishFull(output);
      sent_full = true;
    } else if (step && !changed.empty() && output.updates.getNumSubscribers() > 0) {
      output.updates.publish(toOccupancyGridUpdate(bounds, changed, outputValues(output, *step, changed),
                                                   parameters_.fixed_frame, stamp));
    }
  }
  if (full_due || sent_full) {
    published_bounds_ = bounds;
    if (full_due) last_full_publish_ = now;
  }
}

void MappingNode::publishFull(Output& output) {
  const std::optional<std::int64_t> step = mapper_->lastAppliedStep();
  const core::CellBox bounds = step ? mapper_->grid().bounds() : core::CellBox{};
  const ros::Time stamp = step ? toRosTime(mapper_->clock().stepStart(*step + 1)) : scanClockNow();
  std::vector<std::int8_t> values = step ? outputValues(output, *step, bounds) : std::vector<std::int8_t>{};
  output.full.publish(toOccupancyGrid(mapper_->grid().window(bounds), std::move(values), parameters_.fixed_frame, stamp));
  output.needs_full = false;
}

std::vector<std::int8_t> MappingNode::outputValues(Output& output, std::int64_t step, const core::CellBox& box) {
  const core::Layer layer = output.view.layer;
  if (layer == core::Layer::kBelief || layer == core::Layer::kPredicted) {
    return layerValues(mapper_->grid(), output.view, step, box);  // they change with the step
  }
  if (!output.cache) output.cache.emplace(layer, core::OccupancyScaling{output.view.full_scale, output.view.thresholds});
  std::vector<std::int8_t> values;
  output.cache->occupancy(mapper_->grid(), mapper_->tileVersions(), box, &values);
  return values;
}

void MappingNode::publishMemory(bool force_full) {
  if (!force_full && !memory_updated_) return;  // the grids change at updates only
  memory_updated_ = false;
  const ros::Time now = ros::Time::now();
  const core::CellBox bounds = memory_->bounds();
  const core::CellBox changed = memory_->takeChangedCells();
  const bool full_due = force_full || !sameBox(bounds, memory_published_bounds_) ||
                        parameters_.full_map_period_s == 0.0 ||
                        (now - memory_last_full_publish_).toSec() >= parameters_.full_map_period_s;
  bool sent_full = false;
  for (MemoryOutput& output : memory_outputs_) {
    if (full_due || output.needs_full) {
      if (output.full.getNumSubscribers() == 0) {
        output.needs_full = true;  // rendered when someone listens
        continue;
      }
      publishMemoryFull(output);
      sent_full = true;
    } else if (!changed.empty() && output.updates.getNumSubscribers() > 0) {
      std::vector<std::int8_t> values = output.long_term ? memory_->ltmGrid(changed) : memory_->stmGrid(changed);
      output.updates.publish(
          toOccupancyGridUpdate(bounds, changed, std::move(values), parameters_.fixed_frame, memoryStamp()));
    }
  }
  if (full_due || sent_full) {
    memory_published_bounds_ = bounds;
    if (full_due) memory_last_full_publish_ = now;
  }
  if (hypotheses_.getNumSubscribers() > 0) {
    publishHypotheses();
  } else {
    hypotheses_need_publish_ = true;
  }
}

void MappingNode::publishMemoryFull(MemoryOutput& output) {
  const core::CellBox bounds = memory_->bounds();
  std::vector<std::int8_t> values = output.long_term ? memory_->ltmGrid(bounds) : memory_->stmGrid(bounds);
  output.full.publish(toOccupancyGrid(memory_->window(bounds), std::move(values), parameters_.fixed_frame, memoryStamp()));
  output.needs_full = false;
}

void MappingNode::publishHypotheses() {
  hypotheses_.publish(toMapHypotheses(*memory_, static_cast<std::size_t>(parameters_.max_published_hypotheses),
                                      parameters_.fixed_frame, memoryStamp()));
  hypotheses_need_publish_ = false;
}

ros::Time MappingNode::memoryStamp() const { return memory_stamp_.value_or(scanClockNow()); }

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
