// offline_em: learns every cell's transition probabilities by offline EM (Baum-Welch,
// THEORY.md §5) over one or more bags and writes the model file. The bags are mapped in
// the order given, by one mapper, as one timeline (each bag continues where the previous
// one ended, whatever its stamps). See README.md, "offline_em".

#include <chrono>
#include <cstdio>
#include <exception>
#include <memory>
#include <string>
#include <vector>

#include "bag_tools.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "dynamic_occupancy_grid/core/cell/offline_em.h"
#include "dynamic_occupancy_grid/ros/bag_offline_em.h"
#include "dynamic_occupancy_grid/ros/bag_scan_source.h"

namespace dog = dynamic_occupancy_grid;

namespace {

struct Options {
  dog::bag_tools::SharedOptions shared;
  std::vector<std::string> bags;
  std::string model_path;
};

Options parseArguments(int argc, char** argv) {
  namespace cl = dog::command_line;
  Options options;
  cl::CommandLine line("offline_em", "usage: offline_em BAG [BAG...] --out MODEL [options]\n");
  line.options().add_options()
      ("out", cl::nonEmpty(&options.model_path, "a file name")->value_name("MODEL")->required(),
       "model file to write (required)");
  dog::bag_tools::addMappingOptions(line, &options.shared);
  dog::bag_tools::addEmOptions(line, &options.shared);
  line.hidden().add_options()("bag", boost::program_options::value(&options.bags));
  line.positional("bag");
  line.parse(argc, argv);
  if (options.bags.empty()) line.fail("no bag given");
  // Only the observations matter while mapping: EM learns the transitions afterwards.
  options.shared.mapper.learn_transitions = false;
  dog::bag_tools::validateSharedOptions(line, &options.shared);
  return options;
}

int run(const Options& options) {
  // Every bag is opened (and checked) before the long work starts.
  std::vector<std::unique_ptr<dog::ros_layer::BagScanSource>> sources;
  for (const std::string& bag : options.bags) {
    dog::ros_layer::BagScanSourceOptions source_options = options.shared.source;
    source_options.bag_path = bag;
    sources.push_back(std::make_unique<dog::ros_layer::BagScanSource>(source_options));
  }

  dog::core::Mapper mapper(options.shared.mapper);
  dog::core::SequenceBuilder recorder;
  mapper.recordObservations(&recorder);
  dog::bag_tools::ProgressBar bar;
  double bag_seconds = 0.0;
  const auto start = std::chrono::steady_clock::now();
  for (std::size_t i = 0; i < sources.size(); ++i) {
    const std::string phase = sources.size() > 1 ? "bag " + std::to_string(i + 1) + "/" + std::to_string(sources.size())
                                                 : "reading";
    const dog::ros_layer::BagMappingStats mapping = dog::ros_layer::mapBag(*sources[i], mapper, true, [&](double fraction) {
      bar.show(phase, fraction);
      return true;
    });
    const dog::ros_layer::BagScanStats& stats = mapping.source;
    std::printf("%s: %.1f s, scans read: %zu, integrated: %zu, rejected: %zu, without a pose: %zu\n",
                options.bags[i].c_str(), stats.bag_duration_s, stats.scans_read, mapping.scans_integrated,
                mapping.scans_rejected, stats.scans_without_pose);
    if (mapping.scans_integrated == 0) {
      std::fprintf(stderr, "offline_em: %s\n", dog::ros_layer::describeUnusableBag(options.bags[i], mapping).c_str());
      return 1;
    }
    bag_seconds += stats.bag_duration_s;
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("time steps: %lld of %.3f s; %.1f s of bags read in %.2f s (%.0fx real time)\n",
              static_cast<long long>(*mapper.lastAppliedStep() + 1), options.shared.mapper.time_step_s, bag_seconds,
              seconds, seconds > 0.0 ? bag_seconds / seconds : 0.0);

  dog::bag_tools::runOfflineEmAndApply(mapper, recorder, options.shared.em, bar);
  dog::core::saveModel(mapper, options.model_path);
  std::printf("model -> %s\n", options.model_path.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const Options options = parseArguments(argc, argv);
  try {
    return run(options);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "offline_em: %s\n", e.what());
    return 1;
  }
}
