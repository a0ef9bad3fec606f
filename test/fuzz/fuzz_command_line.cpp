// libFuzzer target: the bag tools' command line (src/nodes/command_line.h on
// boost::program_options, with bag_tools.h's shared mapping and offline EM options and a
// positional bag list, as process_bag builds it). The input is argv: arguments separated by
// NUL bytes. A bad command line must be refused with boost::program_options::error; values
// it accepts then go through the same checks the tools make (MapperConfig::validate,
// OfflineEmConfig::validate, a Mapper built from them), which refuse with
// std::invalid_argument. Any other exception is a finding (an uncaught exception aborts).

#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include <boost/program_options.hpp>

#include "../../src/nodes/bag_tools.h"
#include "../../src/nodes/command_line.h"

namespace dog = dynamic_occupancy_grid;
namespace cl = dog::command_line;

namespace {

constexpr std::size_t kMaxArguments = 40;

std::vector<std::string> argumentsOf(const std::uint8_t* data, std::size_t size) {
  std::vector<std::string> arguments{"fuzz_command_line"};
  std::string argument;
  for (std::size_t i = 0; i < size && arguments.size() < kMaxArguments; ++i) {
    if (data[i] == '\0') {
      arguments.push_back(argument);
      argument.clear();
    } else {
      argument.push_back(static_cast<char>(data[i]));
    }
  }
  if (!argument.empty() && arguments.size() < kMaxArguments) arguments.push_back(argument);
  return arguments;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::vector<std::string> arguments = argumentsOf(data, size);
  std::vector<const char*> argv;
  for (const std::string& argument : arguments) argv.push_back(argument.c_str());
  argv.push_back(nullptr);

  dog::bag_tools::SharedOptions options;
  std::string out_dir;
  double snapshot_every_s = 0.0;
  bool offline_em = false;
  std::vector<std::string> bags;
  cl::CommandLine line("fuzz_command_line", "usage: fuzz_command_line BAG [options]\n");
  line.options().add_options()
      ("out", cl::nonEmpty(&out_dir, "a directory")->value_name("DIR"), "output directory")
      ("offline-em", boost::program_options::bool_switch(&offline_em), "learn offline")
      ("snapshot-every", cl::number(&snapshot_every_s, cl::above(0.0))->value_name("S"), "snapshot period");
  dog::bag_tools::addMappingOptions(line, &options);
  dog::bag_tools::addEmOptions(line, &options);
  line.hidden().add_options()("bag", boost::program_options::value(&bags));
  line.positional("bag");

  boost::program_options::variables_map values;
  try {
    values = line.read(static_cast<int>(arguments.size()), argv.data());
  } catch (const boost::program_options::error&) {
    return 0;  // refused, with a message naming the option
  }
  if (values.count("help") > 0) {
    static_cast<void>(line.usageText());
    return 0;
  }
  // bag_tools::validateSharedOptions without its exit.
  options.em.initial_p_occ = options.mapper.initial_p_occ;
  options.em.prior = options.mapper.prior_transitions;
  try {
    options.mapper.validate();
    options.em.validate();
    const dog::core::Mapper mapper(options.mapper);
  } catch (const std::invalid_argument&) {
  }
  return 0;
}
