// Tests of the file helpers every user-given path goes through (core/layers/file_io.h): only
// regular files are read, never blocking on a FIFO or opening a device; reads are as long
// as the caller asks; writes never replace anything but a regular file, go through unique
// temporaries that every failure removes; stale temporaries of killed writers are cleaned,
// nothing else; paths confined to a directory stay in it after `..` and symbolic links.
//
// Every test works in its own fresh directory under the system temporary directory. Some
// failures need another user (permissions do not bind root): run as root, those tests act
// as the user nobody for the call; run as another user, the ones that need root skip.

#include "dynamic_occupancy_grid/core/layers/file_io.h"

#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace dog = dynamic_occupancy_grid::core;
namespace fs = std::filesystem;

namespace {

class TempDir {
 public:
  TempDir() {
    std::string pattern = (fs::temp_directory_path() / "dog_file_io_XXXXXX").string();
    char* made = ::mkdtemp(pattern.data());
    if (made == nullptr) throw std::runtime_error("mkdtemp failed");
    path_ = made;
  }
  ~TempDir() {
    std::error_code ignored;
    fs::permissions(path_, fs::perms::owner_all, fs::perm_options::add, ignored);
    fs::remove_all(path_, ignored);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  std::string str() const { return path_.string(); }
  std::string file(const std::string& name) const { return (path_ / name).string(); }
  std::set<std::string> entries() const {
    std::set<std::string> names;
    for (const auto& entry : fs::directory_iterator(path_)) names.insert(entry.path().filename().string());
    return names;
  }

 private:
  fs::path path_;
};

std::string readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void writeFile(const std::string& path, const std::string& contents) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << contents;
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

std::string writeErrorOf(const std::string& path, const std::string& contents = "new") {
  try {
    dog::writeFileAtomically(path, contents);
  } catch (const std::runtime_error& error) {
    return error.what();
  }
  return "NO EXCEPTION";
}

std::string readErrorOf(const std::string& path) {
  try {
    dog::RegularFileReader reader(path, "cannot read " + path);
  } catch (const std::runtime_error& error) {
    return error.what();
  }
  return "NO EXCEPTION";
}

template <class Fn>
double secondsOf(Fn&& fn) {
  const auto start = std::chrono::steady_clock::now();
  fn();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

bool isTemporaryLeft(const std::set<std::string>& names) {
  return std::any_of(names.begin(), names.end(), [](const std::string& name) { return dog::isTemporaryName(name); });
}

// While it lives, the effective user is nobody (when the test runs as root).
class AsNobody {
 public:
  AsNobody() : root_(::geteuid() == 0) {
    if (root_ && ::seteuid(65534) != 0) throw std::runtime_error("seteuid(nobody) failed");
  }
  ~AsNobody() {
    if (root_) static_cast<void>(::seteuid(0));
  }
  AsNobody(const AsNobody&) = delete;
  AsNobody& operator=(const AsNobody&) = delete;

 private:
  bool root_;
};

}  // namespace

// ---- names -------------------------------------------------------------------------------------

TEST(FileIoNames, TemporaryNamesAreRecognisedAndNothingElse) {
  EXPECT_EQ(dog::temporaryName("model.dogm", "Ab12Cd"), ".model.dogm.dogtmp.Ab12Cd");
  EXPECT_TRUE(dog::isTemporaryName(".model.dogm.dogtmp.Ab12Cd"));
  EXPECT_TRUE(dog::isTemporaryName(".a.dogtmp.000000"));
  EXPECT_TRUE(dog::isTemporaryName(dog::temporaryName("x.dogtmp.Ab12Cd", "zzzzzz")));
  for (const char* other : {"model.dogm", "model.dogm.tmp", ".model.dogm.tmp", "model.dogm.dogtmp.Ab12Cd",
                            ".model.dogm.dogtmp.Ab12C", ".model.dogm.dogtmp.Ab12Cde", ".model.dogm.dogtmp.Ab-2Cd",
                            ".model.dogm.dogtmp.Ab12Cd.bak", ".dogtmp.Ab12Cd", "..dogtmp.Ab12Cd", ".", ".."}) {
    EXPECT_FALSE(dog::isTemporaryName(other)) << other;
  }
  // A long name still gives a temporary name a file system takes (NAME_MAX 255).
  const std::string long_name(255, 'n');
  EXPECT_LE(dog::temporaryName(long_name, "Ab12Cd").size(), 255u);
  EXPECT_TRUE(dog::isTemporaryName(dog::temporaryName(long_name, "Ab12Cd")));
}

// ---- reading -----------------------------------------------------------------------------------

TEST(FileIoRead, ReadsWhatIsAskedAndNoMore) {
  TempDir dir;
  const std::string path = dir.file("data");
  writeFile(path, "0123456789");
  dog::RegularFileReader reader(path, "cannot read it");
  EXPECT_EQ(reader.size(), 10u);
  std::string bytes;
  EXPECT_EQ(reader.read(4, &bytes), 4u);
  EXPECT_EQ(bytes, "0123");
  EXPECT_EQ(reader.read(100, &bytes), 6u);
  EXPECT_EQ(bytes, "0123456789");
  EXPECT_EQ(bytes.capacity() < 200, true);
  EXPECT_FALSE(reader.hasMore());
  dog::RegularFileReader again(path, "cannot read it");
  std::string first;
  again.read(10, &first);
  EXPECT_FALSE(again.hasMore());
}

TEST(FileIoRead, OnlyRegularFilesAreOpened) {
  TempDir dir;
  const std::string fifo = dir.file("fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::string message;
  // No writer: a plain open() would wait for one forever.
  EXPECT_LT(secondsOf([&] { message = readErrorOf(fifo); }), 2.0);
  EXPECT_EQ(message, "cannot read " + fifo + ": it is a FIFO (named pipe), not a regular file");
  EXPECT_EQ(readErrorOf("/dev/zero"), "cannot read /dev/zero: it is a character device, not a regular file");
  EXPECT_EQ(readErrorOf(dir.str()), "cannot read " + dir.str() + ": it is a directory, not a regular file");
  EXPECT_EQ(readErrorOf(dir.file("missing")), "cannot read " + dir.file("missing") + ": No such file or directory");
  EXPECT_EQ(readErrorOf(""), "cannot read : the path is empty");
  // A socket.
  const std::string socket_path = dir.file("socket");
  const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
  ASSERT_GE(fd, 0);
  sockaddr_un address{};
  address.sun_family = AF_UNIX;
  std::strncpy(address.sun_path, socket_path.c_str(), sizeof(address.sun_path) - 1);
  if (socket_path.size() < sizeof(address.sun_path) &&
      ::bind(fd, reinterpret_cast<const sockaddr*>(&address), sizeof(address)) == 0) {
    EXPECT_EQ(readErrorOf(socket_path), "cannot read " + socket_path + ": it is a socket, not a regular file");
  }
  ::close(fd);
  // A link to a regular file reads it.
  writeFile(dir.file("real"), "abc");
  fs::create_symlink(dir.file("real"), dir.file("link"));
  dog::RegularFileReader reader(dir.file("link"), "x");
  std::string bytes;
  EXPECT_EQ(reader.read(3, &bytes), 3u);
  EXPECT_EQ(bytes, "abc");
  fs::create_symlink("/dev/zero", dir.file("zero_link"));
  EXPECT_EQ(readErrorOf(dir.file("zero_link")),
            "cannot read " + dir.file("zero_link") + ": it is a character device, not a regular file");
}

TEST(FileIoRead, AFileUnderAnotherProcesssLeaseFailsAtOnce) {
  // A process holding a write lease (fcntl F_SETLEASE) makes every other open wait for it
  // (up to /proc/sys/fs/lease-break-time, 45 s) -- except a non-blocking one.
  TempDir dir;
  const std::string path = dir.file("leased");
  writeFile(path, "data");
  const int fd = ::open(path.c_str(), O_RDONLY);
  ASSERT_GE(fd, 0);
  const auto saved = ::signal(SIGIO, SIG_IGN);  // the kernel's "give it back" notice
  if (::fcntl(fd, F_SETLEASE, F_WRLCK) != 0) {
    ::close(fd);
    ::signal(SIGIO, saved);
    GTEST_SKIP() << "no lease: " << std::strerror(errno);
  }
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    const std::string message = readErrorOf(path);
    ::_exit(contains(message, "another process holds a lease on it") ? 0 : 1);
  }
  int status = 0;
  double seconds = secondsOf([&] { ::waitpid(child, &status, 0); });
  ::fcntl(fd, F_SETLEASE, F_UNLCK);
  ::close(fd);
  ::signal(SIGIO, saved);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "the child's open did not fail with the lease text";
  EXPECT_LT(seconds, 10.0);
}

TEST(FileIoRead, RequireRegularFileDoesNotOpen) {
  TempDir dir;
  const std::string fifo = dir.file("fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const auto error_of = [](const std::string& path) {
    try {
      dog::requireRegularFile(path, "cannot use " + path);
    } catch (const std::runtime_error& error) {
      return std::string(error.what());
    }
    return std::string("NO EXCEPTION");
  };
  EXPECT_EQ(error_of(fifo), "cannot use " + fifo + ": it is a FIFO (named pipe), not a regular file");
  EXPECT_EQ(error_of("/dev/zero"), "cannot use /dev/zero: it is a character device, not a regular file");
  EXPECT_EQ(error_of(dir.str()), "cannot use " + dir.str() + ": it is a directory, not a regular file");
  EXPECT_EQ(error_of(dir.file("missing")), "cannot use " + dir.file("missing") + ": No such file or directory");
  writeFile(dir.file("bag"), "x");
  EXPECT_EQ(error_of(dir.file("bag")), "NO EXCEPTION");
}

// ---- writing -----------------------------------------------------------------------------------

TEST(FileIoWrite, NonRegularTargetsAreLeftAlone) {
  TempDir dir;
  const std::string fifo = dir.file("fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::string message;
  EXPECT_LT(secondsOf([&] { message = writeErrorOf(fifo); }), 2.0);
  EXPECT_EQ(message, "cannot write " + fifo + ": it is a FIFO (named pipe), not a regular file; it is left as it is");
  EXPECT_TRUE(fs::is_fifo(fifo));
  const std::string directory = dir.file("directory");
  fs::create_directory(directory);
  EXPECT_EQ(writeErrorOf(directory),
            "cannot write " + directory + ": it is a directory, not a regular file; it is left as it is");
  EXPECT_EQ(writeErrorOf(directory + "/"),
            "cannot write " + directory + "/: it is a directory, not a regular file; it is left as it is");
  EXPECT_EQ(writeErrorOf("/dev/null"),
            "cannot write /dev/null: it is a character device, not a regular file; it is left as it is");
  EXPECT_EQ(writeErrorOf("/dev/full"),
            "cannot write /dev/full: it is a character device, not a regular file; it is left as it is");
  struct stat status {};
  ASSERT_EQ(::lstat("/dev/null", &status), 0);
  EXPECT_TRUE(S_ISCHR(status.st_mode));
  EXPECT_EQ(writeErrorOf(""), "cannot write : the path is empty");
  EXPECT_EQ(dir.entries(), (std::set<std::string>{"directory", "fifo"}));
  EXPECT_TRUE(fs::is_empty(directory));
}

TEST(FileIoWrite, ReplacesKeepingThePermissionsAndFollowsLinks) {
  TempDir dir;
  const std::string path = dir.file("data");
  dog::writeFileAtomically(path, "one");
  EXPECT_EQ(readFile(path), "one");
  fs::permissions(path, fs::perms::owner_read | fs::perms::owner_write);
  dog::writeFileAtomically(path, "two");
  EXPECT_EQ(readFile(path), "two");
  EXPECT_EQ(fs::status(path).permissions() & fs::perms::all, fs::perms::owner_read | fs::perms::owner_write);
  const std::string link = dir.file("link");
  fs::create_symlink("data", link);  // relative: resolved against the link's directory
  dog::writeFileAtomically(link, "three");
  EXPECT_TRUE(fs::is_symlink(link));
  EXPECT_EQ(readFile(path), "three");
  EXPECT_EQ(dir.entries(), (std::set<std::string>{"data", "link"}));
  fs::create_symlink("missing", dir.file("dangling"));
  EXPECT_TRUE(contains(writeErrorOf(dir.file("dangling")), "it is a symbolic link that cannot be followed"));
  EXPECT_FALSE(fs::exists(dir.file("missing")));
}

TEST(FileIoWrite, TemporariesAreUniqueAndNeverLeft) {
  // Writers of one file and of several files in one directory at the same time: each
  // writes through its own temporary; every write lands whole; nothing is left behind.
  TempDir dir;
  constexpr int kWriters = 6;
  constexpr int kRounds = 25;
  std::vector<std::thread> writers;
  std::vector<std::string> errors(kWriters);
  for (int w = 0; w < kWriters; ++w) {
    writers.emplace_back([&dir, &errors, w] {
      const std::string own = dir.file("own_" + std::to_string(w));
      const std::string shared = dir.file("shared");
      const std::string contents(10000 + w, static_cast<char>('a' + w));
      try {
        for (int round = 0; round < kRounds; ++round) {
          dog::writeFileAtomically(own, contents);
          dog::writeFileAtomically(shared, contents);
        }
      } catch (const std::exception& error) {
        errors[w] = error.what();
      }
    });
  }
  for (std::thread& writer : writers) writer.join();
  for (const std::string& error : errors) EXPECT_EQ(error, "");
  const std::string shared = readFile(dir.file("shared"));
  ASSERT_GE(shared.size(), 10000u);
  EXPECT_EQ(shared, std::string(shared.size(), shared[0]));  // one writer's, whole
  std::set<std::string> expected{"shared"};
  for (int w = 0; w < kWriters; ++w) expected.insert("own_" + std::to_string(w));
  EXPECT_EQ(dir.entries(), expected);
}

TEST(FileIoWrite, AFailedWriteRemovesItsTemporary) {
  // A full disk, simulated with a file size limit (RLIMIT_FSIZE binds root too): the
  // temporary exists and fails part way; the old file stays, the temporary goes.
  TempDir dir;
  const std::string path = dir.file("data");
  dog::writeFileAtomically(path, "old");
  rlimit saved_limit{};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &saved_limit), 0);
  if (saved_limit.rlim_max != RLIM_INFINITY && saved_limit.rlim_max < 20000) GTEST_SKIP() << "file size limit too low";
  const auto saved_handler = ::signal(SIGXFSZ, SIG_IGN);  // the write then fails with EFBIG
  rlimit small_limit = saved_limit;
  small_limit.rlim_cur = 10000;
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &small_limit), 0);
  const std::string message = writeErrorOf(path, std::string(50000, 'x'));
  ::setrlimit(RLIMIT_FSIZE, &saved_limit);
  ::signal(SIGXFSZ, saved_handler);
  EXPECT_TRUE(contains(message, "cannot write " + path + ": writing " + dir.str() + "/.data.dogtmp.")) << message;
  EXPECT_TRUE(contains(message, "File too large")) << message;
  EXPECT_EQ(readFile(path), "old");
  EXPECT_EQ(dir.entries(), std::set<std::string>{"data"});
}

TEST(FileIoWrite, AFailedRenameRemovesItsTemporary) {
  // The temporary is written, but the rename over the target is refused: in a sticky
  // directory (as /tmp) only the owner of a file may replace it, and the writer (nobody)
  // does not own it.
  if (::geteuid() != 0) GTEST_SKIP() << "needs root (a file owned by another user)";
  TempDir dir;
  const std::string path = dir.file("data");
  dog::writeFileAtomically(path, "old");
  fs::permissions(dir.str(), fs::perms::all | fs::perms::sticky_bit);
  std::string message;
  {
    AsNobody nobody;
    message = writeErrorOf(path, "new");
  }
  EXPECT_TRUE(contains(message, "cannot write " + path + ": cannot rename " + dir.str() + "/.data.dogtmp.")) << message;
  EXPECT_TRUE(contains(message, "Operation not permitted")) << message;
  EXPECT_EQ(readFile(path), "old");
  EXPECT_EQ(dir.entries(), std::set<std::string>{"data"});
}

TEST(FileIoWrite, AReadOnlyDirectoryIsNamed) {
  TempDir dir;
  const std::string path = dir.file("data");
  fs::permissions(dir.str(), fs::perms::owner_read | fs::perms::owner_exec | fs::perms::group_read |
                                 fs::perms::group_exec | fs::perms::others_read | fs::perms::others_exec);
  std::string message;
  {
    AsNobody nobody;
    message = writeErrorOf(path);
  }
  EXPECT_EQ(message, "cannot write " + path + ": cannot create a temporary file in " + dir.str() +
                         ": Permission denied");
  EXPECT_TRUE(dir.entries().empty());
}

// ---- stale temporaries -----------------------------------------------------------------------

TEST(FileIoStale, OnlyUnlockedTemporariesOfOurOwnPatternAreRemoved) {
  TempDir dir;
  const std::string stale = ".model.dogm.dogtmp.Ab12Cd";
  const std::string busy = ".model.dogm.dogtmp.Zz99Yy";
  writeFile(dir.file(stale), "left by a killed writer");
  writeFile(dir.file(busy), "being written");
  // Someone else's files, and ours: names that only look alike, other kinds of files.
  for (const char* name : {"model.dogm", "model.dogm.tmp", ".model.dogm.tmp", "notes.dogtmp.Ab12Cd",
                           ".model.dogm.dogtmp.Ab12Cd.bak", ".model.dogm.dogtmp.short"}) {
    writeFile(dir.file(name), "keep");
  }
  fs::create_directory(dir.file(".d.dogtmp.Ab12Cd"));
  ASSERT_EQ(::mkfifo(dir.file(".f.dogtmp.Ab12Cd").c_str(), 0600), 0);
  TempDir outside;
  writeFile(outside.file("target"), "keep");
  fs::create_symlink(outside.file("target"), dir.file(".l.dogtmp.Ab12Cd"));
  // The busy one is locked as writeFileAtomically locks its temporary while writing.
  const int fd = ::open(dir.file(busy).c_str(), O_WRONLY);
  ASSERT_GE(fd, 0);
  ASSERT_EQ(::flock(fd, LOCK_EX), 0);

  const std::set<std::string> before = dir.entries();
  const std::vector<std::string> removed = dog::removeStaleTemporaries(dir.str());
  ::close(fd);
  EXPECT_EQ(removed, std::vector<std::string>{stale});
  std::set<std::string> expected = before;
  expected.erase(stale);
  EXPECT_EQ(dir.entries(), expected);
  EXPECT_EQ(readFile(outside.file("target")), "keep");
  // Once its writer is gone, the other one goes too; a missing directory is nothing to do.
  EXPECT_EQ(dog::removeStaleTemporaries(dir.str()), std::vector<std::string>{busy});
  EXPECT_TRUE(dog::removeStaleTemporaries(dir.file("missing")).empty());
}

// ---- confined paths ----------------------------------------------------------------------------

TEST(FileIoPaths, PathsStayInTheirDirectory) {
  TempDir dir;
  const std::string root = dir.file("root");
  fs::create_directories(root + "/sub");
  const std::string canonical_root = fs::canonical(root).string();
  EXPECT_EQ(dog::resolveWithin("model.dogm", root), canonical_root + "/model.dogm");
  EXPECT_EQ(dog::resolveWithin("sub/../sub/./x", root), canonical_root + "/sub/x");
  EXPECT_EQ(dog::resolveWithin(canonical_root + "/sub/new/deeper", root), canonical_root + "/sub/new/deeper");
  EXPECT_EQ(dog::resolveWithin(".", root + "/"), canonical_root);
  EXPECT_EQ(dog::resolveWithin(root, root), canonical_root);
  const auto refused = [&root](const std::string& path) {
    try {
      return "NOT REFUSED: " + dog::resolveWithin(path, root);
    } catch (const std::runtime_error& error) {
      return std::string(error.what());
    }
  };
  const std::string parent = fs::canonical(dir.str()).string();
  EXPECT_EQ(refused("../escaped"), parent + "/escaped is outside " + canonical_root);
  EXPECT_EQ(refused("sub/../../escaped"), parent + "/escaped is outside " + canonical_root);
  EXPECT_EQ(refused("/etc/passwd"), "/etc/passwd is outside " + canonical_root);
  // A sibling whose name starts like the root's is outside too.
  fs::create_directory(root + "2");
  EXPECT_EQ(refused(root + "2/x"), parent + "/root2/x is outside " + canonical_root);
  // A link inside that leads out.
  fs::create_symlink(parent, root + "/out");
  EXPECT_EQ(refused("out/x"), parent + "/x is outside " + canonical_root);
  fs::create_symlink("sub", root + "/in");
  EXPECT_EQ(dog::resolveWithin("in/x", root), canonical_root + "/sub/x");
}
