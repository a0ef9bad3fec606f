#!/usr/bin/env bash
# Runs every test of dynamic_occupancy_grid from a fresh clone: installs what is missing,
# builds, runs the catkin tests (GoogleTest, rostest), the plain-CMake core build with its
# include audit and the fuzz targets for a bounded time (test/fuzz), then prints one summary
# line "N passed, N failed" computed from the JUnit XML results. Exits non-zero if anything
# failed or did not run.
#   DOG_FUZZ_SECONDS=N   seconds per fuzz target (default 15)
#   DOG_SANITIZED=0      skip the core's tests and the node's rostests again in an ASan + UBSan
#                        build (test/sanitizers), which run by default (docs/reliability.md)
set -uo pipefail

package_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
workspace=${DOG_WORKSPACE:-$HOME/dog_ws}
export DOG_WORKSPACE=$workspace
export PATH=/usr/bin:/bin:$PATH
results_dir=$workspace/build/test_results/dynamic_occupancy_grid
status=0
broken=()  # steps that failed outside any JUnit file: each counts as a failure

"$package_dir/scripts/setup.sh" || { echo "test: setup/build failed"; echo "0 passed, 1 failed"; exit 1; }
if [ -f /opt/ros/noetic/setup.bash ]; then set +u; source /opt/ros/noetic/setup.bash; set -u; fi

rm -rf "$results_dir"
mkdir -p "$results_dir"
(cd "$workspace" && catkin_make run_tests -j2) || { status=1; broken+=("catkin_make run_tests exited non-zero"); }

# The rviz config in a real rviz under Xvfb, and the launch files through roslaunch's loader
# (test/rviz/). Each writes its JUnit file; one that exits without it crashed or timed out.
for check in check_rviz_config check_launch_files; do
  result="$results_dir/${check#check_}.xml"
  if ! timeout -k 30 600 "$package_dir/test/rviz/$check.sh" "$result"; then
    status=1
    [ -s "$result" ] || broken+=("test/rviz/$check.sh crashed or timed out (no $result)")
  fi
done

# The core alone, built by plain CMake with no ROS anywhere, plus its include audit.
standalone="$workspace/build/core_standalone"
# A build made from another checkout (the workspace outlives clones) names that source tree
# in its cache, and CMake refuses it: start that build afresh.
if [ -f "$standalone/CMakeCache.txt" ] &&
   ! grep -qxF "CMAKE_HOME_DIRECTORY:INTERNAL=$package_dir/test/core_standalone" "$standalone/CMakeCache.txt"; then
  rm -rf "$standalone"
fi
if cmake -S "$package_dir/test/core_standalone" -B "$standalone" -DCMAKE_BUILD_TYPE=Release >/dev/null &&
   cmake --build "$standalone" -j2 >/dev/null; then
  (cd "$standalone" && ctest --output-on-failure --output-junit "$results_dir/core_standalone.xml") || status=1
else
  status=1
  broken+=("the plain-CMake build of the core failed")
fi

# Each fuzz target for a bounded time from its committed corpus (docs/reliability.md): one
# testcase per target, failed by a crash, a sanitizer finding, a leak or a hang.
start=$(date +%s)
if ! "$package_dir/test/fuzz/run_fuzz.sh" "$workspace/build/fuzz" "$results_dir/fuzz.xml" "${DOG_FUZZ_SECONDS:-15}"; then
  status=1
  [ -s "$results_dir/fuzz.xml" ] || broken+=("test/fuzz/run_fuzz.sh wrote no $results_dir/fuzz.xml")
fi
echo "test: fuzzing took $(($(date +%s) - start)) s"

# The GoogleTest binaries and the rostests again, built with ASan + UBSan in a workspace of
# their own: their results under sanitized/, and every sanitizer report a failing testcase.
if [ "${DOG_SANITIZED:-1}" != 0 ]; then
  start=$(date +%s)
  if ! "$package_dir/test/sanitizers/run_sanitized.sh" "$workspace/build/sanitized_ws" "$results_dir"; then
    status=1
    [ -s "$results_dir/sanitized/sanitizer_reports.xml" ] ||
      broken+=("test/sanitizers/run_sanitized.sh failed before any result (log: $workspace/build/sanitized_ws/build.log)")
  fi
  echo "test: the sanitized build and tests took $(($(date +%s) - start)) s"
fi

# One line from the real results: every <testcase> of every JUnit file.
/usr/bin/python3 - "$results_dir" "${broken[@]}" <<'PY' || status=1
import glob, os, sys
import xml.etree.ElementTree as ET
passed = failed = skipped = 0


def reason(problem):
    """A failure's gist for the log: its message's first line, at most 300 characters."""
    text = (problem.get("message") or problem.text or "").strip()
    return text.splitlines()[0][:300] if text else "(no message)"


failures = list(sys.argv[2:])
failed += len(failures)
for path in sorted(glob.glob(os.path.join(sys.argv[1], "**", "*.xml"), recursive=True)):
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as error:
        failed += 1
        failures.append(f"{os.path.relpath(path, sys.argv[1])}: unreadable result file ({error})")
        continue
    where = os.path.relpath(path, sys.argv[1])
    for case in root.iter("testcase"):
        name = f"{case.get('classname', '')}.{case.get('name', '')}"
        problem = case.find("failure") if case.find("failure") is not None else case.find("error")
        if problem is not None:
            failed += 1
            failures.append(f"{where}: {name}: {reason(problem)}")
        elif case.find("skipped") is not None or case.get("status") == "notrun":
            skipped += 1
        else:
            passed += 1
    # Errors outside any testcase (a Python test whose setUpClass raised: rosunit writes a
    # suite with errors="1" and no testcase) count too, one failure each.
    for suite in root.iter("testsuite"):
        declared = sum(int(suite.get(key, "0") or 0) for key in ("errors", "failures"))
        inside = sum(1 for case in suite.findall("testcase")
                     if case.find("failure") is not None or case.find("error") is not None)
        if declared > inside:
            failed += declared - inside
            failures.append(f"{where}: {suite.get('name', '')}: {declared - inside} error(s) outside "
                            "any testcase (setUpClass?)")
for line in failures:
    print("FAILED:", line)
if passed + failed == 0:
    print("test: no test results found in", sys.argv[1])
    failed = 1
print(f"{passed} passed, {failed} failed" + (f", {skipped} skipped" if skipped else ""))
sys.exit(1 if failed else 0)
PY
exit $status
