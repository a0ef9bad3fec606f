// Files named by users: regular files only, reads in pieces the caller sizes, atomic and
// durable writes through unique temporaries (core/layers/file_io.h). POSIX: open, fstat, fsync,
// rename, flock; the C++17 standard library cannot express them.

#include "dynamic_occupancy_grid/core/layers/file_io.h"

#include <dirent.h>
#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <random>
#include <stdexcept>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

namespace dynamic_occupancy_grid {
namespace core {
namespace {

constexpr std::size_t kSuffixLength = 6;
// Room for the dot, the infix and the suffix within NAME_MAX (255).
constexpr std::size_t kMaxNameInTemporary = 200;
constexpr char kSuffixAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789";

std::string errnoText(int error) { return std::strerror(error); }

bool isSuffixCharacter(char c) {
  return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9');
}

std::string randomSuffix() {
  static std::atomic<std::uint64_t> counter{0};
  thread_local std::mt19937_64 generator = [] {
    std::random_device device;
    std::seed_seq seed{static_cast<std::uint64_t>(device()), static_cast<std::uint64_t>(::getpid()),
                       static_cast<std::uint64_t>(std::chrono::steady_clock::now().time_since_epoch().count()),
                       counter.fetch_add(1)};
    return std::mt19937_64(seed);
  }();
  std::string suffix(kSuffixLength, 'X');
  std::uniform_int_distribution<std::size_t> pick(0, sizeof(kSuffixAlphabet) - 2);
  for (char& c : suffix) c = kSuffixAlphabet[pick(generator)];
  return suffix;
}

// "dir/name" -> "dir"; "name" -> "."; "/name" -> "/".
std::string directoryOf(const std::string& path) {
  const std::size_t slash = path.find_last_of('/');
  if (slash == std::string::npos) return ".";
  if (slash == 0) return "/";
  return path.substr(0, slash);
}

std::string baseNameOf(const std::string& path) {
  const std::size_t slash = path.find_last_of('/');
  return slash == std::string::npos ? path : path.substr(slash + 1);
}

std::string joinPath(const std::string& directory, const std::string& name) {
  return directory == "/" ? "/" + name : directory + "/" + name;
}

class FileDescriptor {
 public:
  explicit FileDescriptor(int fd = -1) : fd_(fd) {}
  FileDescriptor(const FileDescriptor&) = delete;
  FileDescriptor& operator=(const FileDescriptor&) = delete;
  ~FileDescriptor() {
    if (fd_ >= 0) ::close(fd_);
  }
  int get() const { return fd_; }
  void reset(int fd) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = fd;
  }
  /// Closes now; false (errno set) if closing failed (a delayed write error).
  bool close() {
    const int fd = fd_;
    fd_ = -1;
    return fd < 0 || ::close(fd) == 0;
  }

 private:
  int fd_;
};

}  // namespace

std::string temporaryName(const std::string& name, const std::string& suffix) {
  return "." + name.substr(0, kMaxNameInTemporary) + kTemporaryInfix + suffix;
}

bool isTemporaryName(const std::string& name) {
  const std::string infix = kTemporaryInfix;
  if (name.size() < 1 + 1 + infix.size() + kSuffixLength || name.front() != '.') return false;
  const std::size_t suffix_start = name.size() - kSuffixLength;
  if (name.compare(suffix_start - infix.size(), infix.size(), infix) != 0) return false;
  for (std::size_t i = suffix_start; i < name.size(); ++i) {
    if (!isSuffixCharacter(name[i])) return false;
  }
  return true;
}

std::string fileKind(unsigned int st_mode) {
  const mode_t mode = static_cast<mode_t>(st_mode);
  if (S_ISREG(mode)) return "a regular file";
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISFIFO(mode)) return "a FIFO (named pipe)";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISSOCK(mode)) return "a socket";
  if (S_ISLNK(mode)) return "a symbolic link";
  return "a special file";
}

// ---- reading ---------------------------------------------------------------------------

RegularFileReader::RegularFileReader(const std::string& path, std::string error_prefix)
    : error_prefix_(std::move(error_prefix)) {
  const auto fail = [this](const std::string& what) { return std::runtime_error(error_prefix_ + ": " + what); };
  if (path.empty()) throw fail("the path is empty");
  // stat first: a device is never opened (opening some has effects of its own).
  struct stat status {};
  if (::stat(path.c_str(), &status) != 0) throw fail(errnoText(errno));
  if (!S_ISREG(status.st_mode)) throw fail("it is " + fileKind(status.st_mode) + ", not a regular file");
  // O_NONBLOCK: should a FIFO have taken its place meanwhile, the open does not wait for
  // a writer; a file under another process's lease fails now instead of waiting for it.
  fd_ = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd_ < 0) {
    const int error = errno;
    if (error == EWOULDBLOCK) {
      throw fail("another process holds a lease on it (opening it would wait for that process): " +
                 errnoText(error));
    }
    throw fail(errnoText(error));
  }
  if (::fstat(fd_, &status) != 0 || !S_ISREG(status.st_mode)) {
    const int error = errno;
    const std::string what =
        S_ISREG(status.st_mode) ? errnoText(error) : "it is " + fileKind(status.st_mode) + ", not a regular file";
    ::close(fd_);
    fd_ = -1;
    throw fail(what);
  }
  size_ = static_cast<std::uint64_t>(status.st_size);
}

RegularFileReader::~RegularFileReader() {
  if (fd_ >= 0) ::close(fd_);
}

std::size_t RegularFileReader::read(std::size_t count, std::string* out) {
  const std::size_t start = out->size();
  out->resize(start + count);
  std::size_t used = 0;
  while (used < count) {
    const ssize_t got = ::read(fd_, &(*out)[start + used], count - used);
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) {
      const int error = errno;
      out->resize(start + used);
      throw std::runtime_error(error_prefix_ + ": read failed: " + errnoText(error));
    }
    if (got == 0) break;
    used += static_cast<std::size_t>(got);
  }
  out->resize(start + used);
  return used;
}

bool RegularFileReader::hasMore() {
  std::string probe;
  return read(1, &probe) == 1;
}

void requireRegularFile(const std::string& path, const std::string& error_prefix) {
  if (path.empty()) throw std::runtime_error(error_prefix + ": the path is empty");
  struct stat status {};
  if (::stat(path.c_str(), &status) != 0) throw std::runtime_error(error_prefix + ": " + errnoText(errno));
  if (!S_ISREG(status.st_mode)) {
    throw std::runtime_error(error_prefix + ": it is " + fileKind(status.st_mode) + ", not a regular file");
  }
}

// ---- writing ---------------------------------------------------------------------------

void writeFileAtomically(const std::string& path, const std::string& contents) {
  writeFileAtomically(path, contents, "cannot write " + path);
}

void writeFileAtomically(const std::string& path, const std::string& contents, const std::string& error_prefix) {
  const auto refuse = [&error_prefix](const std::string& what) {
    return std::runtime_error(error_prefix + ": " + what);
  };
  const auto fail = [&error_prefix](const std::string& what, int error) {
    return std::runtime_error(error_prefix + ": " + what + ": " + errnoText(error));
  };
  if (path.empty()) throw refuse("the path is empty");

  // What is there now: nothing, or a regular file (through a symbolic link, the file it
  // points to). Anything else is left as it is: rename() would replace a device node or a
  // FIFO with a regular file.
  std::string target = path;
  struct stat status {};
  bool replacing = false;
  if (::lstat(target.c_str(), &status) == 0) {
    if (S_ISLNK(status.st_mode)) {
      char* resolved = ::realpath(path.c_str(), nullptr);
      if (resolved == nullptr) {
        throw fail("it is a symbolic link that cannot be followed (it is left as it is)", errno);
      }
      target = resolved;
      std::free(resolved);
      if (::lstat(target.c_str(), &status) != 0) throw fail("cannot examine " + target, errno);
    }
    if (!S_ISREG(status.st_mode)) {
      const std::string what = target == path ? "it" : "the symbolic link's target " + target;
      throw refuse(what + " is " + fileKind(status.st_mode) + ", not a regular file; it is left as it is");
    }
    replacing = true;
  } else if (errno != ENOENT) {
    throw refuse(errnoText(errno));  // e.g. "Not a directory": a file where a directory should be
  }
  const std::string directory = directoryOf(target);
  const std::string name = baseNameOf(target);
  if (name.empty() || name == "." || name == "..") throw refuse("it names a directory, not a file");

  // A unique temporary beside the target (the rename must stay in one file system).
  std::string temporary;
  FileDescriptor file;
  for (int attempt = 0; file.get() < 0; ++attempt) {
    temporary = joinPath(directory, temporaryName(name, randomSuffix()));
    // O_EXCL: a new file of this writer's own, whatever else writes into the directory.
    file.reset(::open(temporary.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC | O_NOFOLLOW, 0666));
    if (file.get() < 0 && (errno != EEXIST || attempt >= 100)) {
      throw fail("cannot create a temporary file in " + directory, errno);
    }
  }
  // Held until the file is closed: removeStaleTemporaries leaves it alone meanwhile.
  static_cast<void>(::flock(file.get(), LOCK_EX | LOCK_NB));
  const auto discard = [&temporary, &file] {
    file.close();
    ::unlink(temporary.c_str());
  };
  // The old file's permissions carry over (the new one would have the umask's).
  if (replacing) static_cast<void>(::fchmod(file.get(), status.st_mode & 07777));

  const char* data = contents.data();
  std::size_t left = contents.size();
  while (left > 0) {
    const ssize_t written = ::write(file.get(), data, left);
    if (written < 0 && errno == EINTR) continue;
    if (written <= 0) {
      const int error = written < 0 ? errno : ENOSPC;
      discard();
      throw fail("writing " + temporary + " failed", error);
    }
    data += written;
    left -= static_cast<std::size_t>(written);
  }
  // fsync before the rename: without it a crash soon after can leave an empty file in
  // place of both the old and the new one.
  if (::fsync(file.get()) != 0) {
    const int error = errno;
    discard();
    throw fail("writing " + temporary + " to disk failed", error);
  }
  if (!file.close()) {
    const int error = errno;
    ::unlink(temporary.c_str());
    throw fail("closing " + temporary + " failed", error);
  }
  if (std::rename(temporary.c_str(), target.c_str()) != 0) {
    const int error = errno;
    ::unlink(temporary.c_str());
    throw fail("cannot rename " + temporary + " to " + target, error);
  }
  // The rename is durable once the directory is; best effort (some file systems refuse
  // fsync on a directory, and the new file is in place either way).
  FileDescriptor directory_fd(::open(directory.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
  if (directory_fd.get() >= 0) static_cast<void>(::fsync(directory_fd.get()));
}

std::vector<std::string> removeStaleTemporaries(const std::string& directory) {
  std::vector<std::string> removed;
  DIR* const listing = ::opendir(directory.c_str());
  if (listing == nullptr) return removed;
  const int directory_fd = ::dirfd(listing);
  while (const dirent* entry = ::readdir(listing)) {
    const std::string name = entry->d_name;
    if (!isTemporaryName(name)) continue;
    struct stat status {};
    if (::fstatat(directory_fd, name.c_str(), &status, AT_SYMLINK_NOFOLLOW) != 0 || !S_ISREG(status.st_mode)) {
      continue;
    }
    FileDescriptor file(::openat(directory_fd, name.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOFOLLOW | O_NOCTTY));
    struct stat opened {};
    if (file.get() < 0 || ::fstat(file.get(), &opened) != 0 || opened.st_dev != status.st_dev ||
        opened.st_ino != status.st_ino) {
      continue;
    }
    // A writer holds its temporary locked until it closes it: only a dead writer's is free.
    if (::flock(file.get(), LOCK_EX | LOCK_NB) != 0) continue;
    if (::unlinkat(directory_fd, name.c_str(), 0) == 0) removed.push_back(name);
  }
  ::closedir(listing);
  return removed;
}

// ---- paths -----------------------------------------------------------------------------

std::string resolveWithin(const std::string& path, const std::string& root) {
  namespace fs = std::filesystem;
  try {
    fs::path root_path = fs::weakly_canonical(fs::absolute(fs::path(root)));
    if (root_path.filename().empty()) root_path = root_path.parent_path();  // "dir/" -> "dir"
    fs::path request(path);
    if (request.is_relative()) request = root_path / request;
    const fs::path resolved = fs::weakly_canonical(request);
    // Inside: the root's elements are the first ones of the result.
    auto inside = resolved.begin();
    for (auto part = root_path.begin(); part != root_path.end(); ++part, ++inside) {
      if (inside == resolved.end() || *inside != *part) {
        throw std::runtime_error(resolved.string() + " is outside " + root_path.string());
      }
    }
    return resolved.string();
  } catch (const fs::filesystem_error& error) {
    throw std::runtime_error("cannot resolve " + path + ": " + error.code().message());
  }
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
