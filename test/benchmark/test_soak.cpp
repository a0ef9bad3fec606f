// The short soak as a test (issue 20): `soak --quick` (20,000 scans of the office floor with
// the node's defaults and its layers) must pass its own verdict -- RSS within 2 % and the
// per-scan time at most doubled once the explored area stopped growing -- and write one CSV
// row per window. The time bound is loose because a CI run shares its cores with other tests:
// at a load of 16-21 on 2 cores, load alone moved the quick run's per-scan time by +32 %
// (BENCHMARKS.md, issue 20); the long run keeps soak's own 25 %.

#include <gtest/gtest.h>

#include <sys/wait.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace {

struct SoakRun {
  int exit_status = -1;
  std::string output;
};

SoakRun runSoak(const std::string& arguments) {
  const std::string command = std::string(DOG_SOAK_BINARY) + " " + arguments + " 2>&1";
  SoakRun run;
  FILE* pipe = popen(command.c_str(), "r");
  if (pipe == nullptr) return run;
  char buffer[4096];
  std::size_t read = 0;
  while ((read = std::fread(buffer, 1, sizeof buffer, pipe)) > 0) run.output.append(buffer, read);
  const int status = pclose(pipe);
  if (WIFEXITED(status)) run.exit_status = WEXITSTATUS(status);
  return run;
}

std::vector<std::vector<std::string>> readCsv(const std::string& path) {
  std::vector<std::vector<std::string>> rows;
  std::ifstream file(path);
  std::string line;
  while (std::getline(file, line)) {
    std::vector<std::string> fields;
    std::stringstream stream(line);
    std::string field;
    while (std::getline(stream, field, ',')) fields.push_back(field);
    rows.push_back(fields);
  }
  return rows;
}

TEST(Soak, QuickRunKeepsMemoryAndTimeFlat) {
  const std::string csv = ::testing::TempDir() + "soak_quick.csv";
  const SoakRun run = runSoak("--quick --max-time-growth 100 --csv " + csv);
  std::cout << run.output;
#if defined(__SANITIZE_ADDRESS__)
  // The ASan build (test/sanitizers): its allocator's quarantine grows RSS and the
  // instrumentation moves the per-scan time, so the verdict is not judged there; the run
  // must still end by itself with a verdict (a sanitizer report aborts it) and its CSV.
  ASSERT_TRUE(run.exit_status == 0 || run.exit_status == 1) << run.output;
  EXPECT_NE(run.output.find("verdict: "), std::string::npos) << run.output;
#else
  ASSERT_EQ(run.exit_status, 0) << run.output;
  EXPECT_NE(run.output.find("verdict: PASS"), std::string::npos) << run.output;
#endif

  const std::vector<std::vector<std::string>> rows = readCsv(csv);
  ASSERT_EQ(rows.size(), 41u) << "a header and 40 windows of 500 scans";
  ASSERT_EQ(rows[0].size(), 13u);
  EXPECT_EQ(rows[0][0], "scans");
  EXPECT_EQ(rows[0][3], "rss_mb");
  EXPECT_EQ(rows.back()[0], "20000");
  for (std::size_t i = 1; i < rows.size(); ++i) {
    ASSERT_EQ(rows[i].size(), rows[0].size()) << "row " << i;
    EXPECT_GT(std::stod(rows[i][2]), 0.0) << "cells allocated, row " << i;
    const double rss = std::stod(rows[i][3]);
    EXPECT_TRUE(std::isfinite(rss) && rss > 0.0) << "RSS, row " << i;
    EXPECT_GT(std::stod(rows[i][4]), 0.0) << "per-scan median, row " << i;
  }
}

TEST(Soak, TooShortToJudgeFails) {
  // 3,000 scans end inside the first lap: the explored area is still growing, so there is
  // nothing to call flat and the verdict must fail.
  const SoakRun run = runSoak("--scans 3000 --window 1000 --compare-windows 1");
  EXPECT_EQ(run.exit_status, 1) << run.output;
  EXPECT_NE(run.output.find("verdict: FAIL: fewer than 2 looping windows"), std::string::npos) << run.output;
}

TEST(Soak, BadOptionIsAUsageError) {
  const SoakRun run = runSoak("--scans 0");
  EXPECT_EQ(run.exit_status, 2) << run.output;
  EXPECT_NE(run.output.find("--scans"), std::string::npos) << run.output;
}

}  // namespace
