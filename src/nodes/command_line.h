#pragma once
// The tools' command lines (process_bag, offline_em, check_bag, simulate, evaluate) on
// boost::program_options. What is left here: values checked as they are read (a number in
// its range, a pose, a list), so that the error names the option, and the form of a usage
// error every tool shares (message, usage, exit status 2). ROS-free: evaluate uses it too.
// Header-only: each tool stays one .cpp file.

#include <boost/any.hpp>
#include <boost/lexical_cast.hpp>
#include <boost/program_options.hpp>

#include <cmath>
#include <cstdlib>
#include <functional>
#include <iostream>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

namespace dynamic_occupancy_grid {
namespace command_line {

/// An option's value read by `convert`, which throws std::invalid_argument with what is
/// wrong (the text after "--name: ") for a bad one. Stored as `Value`, or appended when
/// `Stored` is std::vector<Value>: then the option may be repeated.
template <class Value, class Stored = Value>
class Checked : public boost::program_options::typed_value<Stored> {
 public:
  using Convert = std::function<Value(const std::string&)>;
  Checked(Stored* target, Convert convert)
      : boost::program_options::typed_value<Stored>(target), convert_(std::move(convert)) {}

  void xparse(boost::any& store, const std::vector<std::string>& tokens) const override {
    namespace po = boost::program_options;
    if constexpr (std::is_same_v<Stored, Value>) po::validators::check_first_occurrence(store);
    const std::string& text = po::validators::get_single_string(tokens);
    Value value;
    try {
      value = convert_(text);
    } catch (const std::invalid_argument& error) {
      // program_options fills in the option's name as given on the command line.
      throw po::error_with_option_name(std::string("%canonical_option%: ") + error.what());
    }
    if constexpr (std::is_same_v<Stored, Value>) {
      store = std::move(value);
    } else {
      if (store.empty()) store = Stored();
      boost::any_cast<Stored&>(store).push_back(std::move(value));
    }
  }

 private:
  Convert convert_;
};

/// Where a number option's value must lie: [min, max], or (min, max] with exclusive_min.
template <class T>
struct Range {
  T min = std::numeric_limits<T>::lowest();
  T max = std::numeric_limits<T>::max();
  bool exclusive_min = false;

  bool contains(T value) const { return (exclusive_min ? value > min : value >= min) && value <= max; }
  std::string text() const {
    std::ostringstream text;
    if (max == std::numeric_limits<T>::max()) {
      text << (exclusive_min ? "> " : ">= ") << min;
    } else {
      text << "in " << (exclusive_min ? "(" : "[") << min << ", " << max << "]";
    }
    return text.str();
  }
};
template <class T>
Range<T> between(T min, T max) { return Range<T>{min, max, false}; }
template <class T>
Range<T> atLeast(T min) { return Range<T>{min, std::numeric_limits<T>::max(), false}; }
template <class T>
Range<T> above(T min) { return Range<T>{min, std::numeric_limits<T>::max(), true}; }

/// `text` as a T in `range` (finite, for floating point); throws std::invalid_argument
/// saying what was expected.
template <class T>
T toNumber(const std::string& text, const Range<T>& range) {
  static_assert(std::is_arithmetic_v<T>, "a number option");
  T value{};
  // lexical_cast reads "-1" as a huge unsigned number instead of refusing it.
  const bool converted = boost::conversion::try_lexical_convert(text, value) &&
                         !(std::is_unsigned_v<T> && !text.empty() && text[0] == '-');
  bool finite = true;
  if constexpr (std::is_floating_point_v<T>) finite = std::isfinite(value);
  if (!converted || !finite || !range.contains(value)) {
    throw std::invalid_argument(std::string(std::is_integral_v<T> ? "needs a whole number " : "needs a number ") +
                                range.text() + ", got '" + text + "'");
  }
  return value;
}

/// A number option read into *target; repeatable when target is a std::vector.
template <class T>
Checked<T>* number(T* target, Range<T> range) {
  return new Checked<T>(target, [range](const std::string& text) { return toNumber(text, range); });
}
template <class T>
Checked<T, std::vector<T>>* numbers(std::vector<T>* target, Range<T> range) {
  return new Checked<T, std::vector<T>>(target, [range](const std::string& text) { return toNumber(text, range); });
}

/// A text option that must not be empty; `what` names what it is ("a file name").
inline Checked<std::string>* nonEmpty(std::string* target, std::string what) {
  return new Checked<std::string>(target, [what](const std::string& text) {
    if (text.empty()) throw std::invalid_argument("needs " + what + ", got ''");
    return text;
  });
}

/// An option whose text `convert` turns into a value (throwing std::invalid_argument for
/// a bad one) that `apply` then takes: for values program_options cannot hold itself (it
/// reads what it holds from a stream), such as a pose or a scenario. The text is checked
/// as it is read, so the error names the option.
template <class Convert, class Apply>
Checked<std::string>* converted(Convert convert, Apply apply) {
  auto* value = new Checked<std::string>(nullptr, [convert](const std::string& text) {
    convert(text);
    return text;
  });
  value->notifier([convert, apply](const std::string& text) { apply(convert(text)); });
  return value;
}

/// A command line: the tool's usage (its first lines, then the generated option list),
/// parsed by program_options; -h/--help prints the usage, a bad command line is a usage
/// error.
class CommandLine {
 public:
  /// `usage`: "usage: TOOL ..." and any lines that explain the tool.
  CommandLine(std::string tool, std::string usage)
      : tool_(std::move(tool)), usage_(std::move(usage)), options_("options") {
    options_.add_options()("help,h", "print this help and exit");
  }

  /// The listed options (add to them with options().add_options()).
  boost::program_options::options_description& options() { return options_; }
  /// Options read but not listed in the usage.
  boost::program_options::options_description& hidden() { return hidden_; }
  /// Arguments without an option name go to the option `name` (a std::vector).
  void positional(const std::string& name) { positional_.add(name.c_str(), -1); }

  /// Parses argv; prints the usage and exits 0 on --help, exits 2 on an error. The targets
  /// of the options are set when this returns.
  boost::program_options::variables_map parse(int argc, char** argv) const {
    boost::program_options::variables_map values;
    try {
      values = read(argc, argv);
    } catch (const boost::program_options::error& error) {
      fail(error.what());
    }
    if (values.count("help") > 0) {
      std::cout << usageText();
      std::exit(0);
    }
    return values;
  }

  /// parse() without leaving the process: throws boost::program_options::error for a bad
  /// command line; with --help the map holds "help" and no target is set.
  boost::program_options::variables_map read(int argc, const char* const* argv) const {
    namespace po = boost::program_options;
    po::options_description all;
    all.add(options_).add(hidden_);
    po::variables_map values;
    // Only the full names: a prefix is no abbreviation of an option (--res is unknown).
    const int style = po::command_line_style::unix_style & ~po::command_line_style::allow_guessing;
    po::store(po::command_line_parser(argc, argv).options(all).positional(positional_).style(style).run(), values);
    if (values.count("help") == 0) po::notify(values);
    return values;
  }

  /// A usage error: "TOOL: message", the usage, exit status 2.
  [[noreturn]] void fail(const std::string& message) const {
    std::cerr << tool_ << ": " << message << "\n" << usageText();
    std::exit(2);
  }

  std::string usageText() const {
    std::ostringstream text;
    text << usage_ << options_;
    return text.str();
  }

 private:
  std::string tool_;
  std::string usage_;
  boost::program_options::options_description options_;
  boost::program_options::options_description hidden_;
  boost::program_options::positional_options_description positional_;
};

}  // namespace command_line
}  // namespace dynamic_occupancy_grid
