// A fuzz target's scratch file, in a directory of its own made by mkdtemp from the first
// pattern that works. The file and its directory go when the fuzzer exits normally (-runs,
// -max_total_time); a crash leaves them, the input is kept in the artifacts anyway. One per
// process.
#pragma once

#include <unistd.h>

#include <cstdlib>
#include <cstring>
#include <initializer_list>
#include <string>

namespace fuzz_scratch {

inline char directory[64] = "";
inline const char* file_name = "";

inline void remove() {
  ::unlink((std::string(directory) + "/" + file_name).c_str());
  ::rmdir(directory);
}

/// The scratch file's path ("<directory>/<name>"), or "" when no pattern gave a directory.
/// Patterns end in "XXXXXX" and are shorter than 64 characters.
inline std::string makeFile(std::initializer_list<const char*> patterns, const char* name) {
  for (const char* pattern : patterns) {
    std::strcpy(directory, pattern);
    if (::mkdtemp(directory) != nullptr) {
      file_name = name;
      std::atexit(remove);
      return std::string(directory) + "/" + name;
    }
  }
  return "";
}

}  // namespace fuzz_scratch
