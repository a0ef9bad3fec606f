#pragma once
// Files whose paths come from users (a service request, a node parameter, a command line):
// read and written so that no path can hang, exhaust or damage the process or the system.
//
// Reading: only regular files. The path is stat()ed first, so that a device node is never
// even opened (opening some has side effects), then opened with O_NONBLOCK (a FIFO swapped
// in meanwhile cannot block the open; a file another process holds a lease on fails at
// once instead of waiting for the lease) and fstat()ed again. The caller reads what it
// needs, in pieces of the sizes it chooses (the model file: its header first, then what
// the header promises), never "until the end".
//
// Writing (writeFileAtomically): only a regular file is ever replaced (a device, FIFO,
// socket or directory at the path is refused and left alone); the data goes to a unique
// temporary file in the target's directory, `.<name>.dogtmp.XXXXXX` (exclusive create),
// is fsync()ed, renamed over the target, and the directory is fsync()ed; every failure
// removes the temporary. While it is written the temporary is flock()ed, so that
// removeStaleTemporaries (at a node's start) removes only those a killed writer left.
//
// Symbolic links are followed: reading one reads the file it points to; writing one
// replaces the file it points to (atomically, in that file's directory) and keeps the
// link. What the link points to must itself be a regular file (or, for a write, not exist
// yet in an existing directory); a dangling link is refused.
//
// ROS-free: the C++ standard library and POSIX (open, fstat, fsync, rename, flock), which
// the standard library cannot express.

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace dynamic_occupancy_grid {
namespace core {

/// What every temporary name holds between the target's name and the random suffix.
constexpr const char* kTemporaryInfix = ".dogtmp.";

/// The temporary name writeFileAtomically would use for a file named `name` with random
/// `suffix`: "." + name (at most 200 characters of it) + kTemporaryInfix + suffix.
std::string temporaryName(const std::string& name, const std::string& suffix);
/// True for names of that form with a 6-character [A-Za-z0-9] suffix (and nothing else).
bool isTemporaryName(const std::string& name);

/// A regular file opened for reading (see the top of this file). Every error is a
/// std::runtime_error "<error_prefix>: <what>", e.g. "cannot load model file /a/f: it is
/// a FIFO (named pipe), not a regular file".
class RegularFileReader {
 public:
  /// Opens `path`; refuses anything but a regular file (naming what it is) before reading.
  RegularFileReader(const std::string& path, std::string error_prefix);
  ~RegularFileReader();
  RegularFileReader(const RegularFileReader&) = delete;
  RegularFileReader& operator=(const RegularFileReader&) = delete;

  /// The file's size when it was opened.
  std::uint64_t size() const { return size_; }
  /// Appends up to `count` bytes to `out` (fewer only at the end of the file); returns
  /// how many. Grows `out` by at most `count`.
  std::size_t read(std::size_t count, std::string* out);
  /// True if the file has at least one more byte (reads it).
  bool hasMore();

 private:
  int fd_ = -1;
  std::uint64_t size_ = 0;
  std::string error_prefix_;
};

/// Refuses (std::runtime_error "<error_prefix>: <what>") anything at `path` but a regular
/// file (symbolic links followed), without opening it: for files that a library opens by
/// name itself (a bag). Does not block, whatever `path` is.
void requireRegularFile(const std::string& path, const std::string& error_prefix);

/// "a directory", "a FIFO (named pipe)", "a character device", "a block device", "a
/// socket", "a symbolic link", "a regular file" or "a special file" for a stat st_mode.
std::string fileKind(unsigned int st_mode);

/// Writes `contents` to `path` atomically and durably (see the top of this file): a
/// failure throws std::runtime_error "<error_prefix>: ..." (default "cannot write
/// <path>"), removes the temporary and leaves any older file at `path` intact. Refuses,
/// without touching it, anything at `path` but a regular file.
void writeFileAtomically(const std::string& path, const std::string& contents);
void writeFileAtomically(const std::string& path, const std::string& contents, const std::string& error_prefix);

/// Removes the regular files named like writeFileAtomically's temporaries in `directory`
/// (not in its subdirectories) that no writer holds (flock): the leftovers of a writer
/// killed mid-write. Returns the names removed; a missing or unreadable directory gives
/// none. Anything else (other names, other kinds of files, a temporary being written) is
/// left alone.
std::vector<std::string> removeStaleTemporaries(const std::string& directory);

/// `path` resolved for a request confined to `root` (an existing directory): a relative
/// `path` is taken relative to `root`; `..` and symbolic links (of the part that exists)
/// are resolved; the result, absolute, must be `root` or inside it, else
/// std::runtime_error "<resolved path> is outside <root>". `root` is resolved the same
/// way. Against mistakes (a wrong path, `..`, a link leading elsewhere), not a sandbox:
/// who can change the tree under `root` meanwhile can still redirect a later open.
std::string resolveWithin(const std::string& path, const std::string& root);

}  // namespace core
}  // namespace dynamic_occupancy_grid
