#!/usr/bin/env bash
# The tests again in an ASan + UBSan build (docs/reliability.md): the package built by gcc
# with -fsanitize=address,undefined in a catkin workspace of its own, then the core's
# GoogleTest binaries and the node's rostests (the node, the nodelet and the tools they
# launch are sanitized executables). Not again: the evaluation library's tests (experiments
# on the simulator, on the core the core's tests cover) and the rostests of the offline tools
# (TOOL_ROSTESTS: they run the same core on bags; each runs once, unsanitized), nor are the
# tools those need built. Any sanitizer report fails: each one stops its process
# (halt_on_error, -fno-sanitize-recover) and is written to a report directory that
# collect_results.py turns into a failing testcase, also when the process was a node whose
# test went on.
#
#   run_sanitized.sh WORKSPACE RESULTS_DIR
#     WORKSPACE    the sanitized catkin workspace (created; its src links this checkout)
#     RESULTS_DIR  where the JUnit files go (RESULTS_DIR/sanitized/*.xml)
#
# nodelet.test loads the sanitized nodelet library into Debian's nodelet manager, which is
# not built with ASan: the manager gets the ASan runtime through LD_PRELOAD
# (DOG_NODELET_PRELOAD, read by nodelet.test).
set -uo pipefail

package_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
workspace=$1
results_dir=$2
export PATH=/usr/bin:/bin:$PATH

flags="-O1 -g1 -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=all"
mkdir -p "$workspace/src"
ln -sfn "$package_dir" "$workspace/src/dynamic_occupancy_grid"
# A workspace configured from another checkout names it in its cache: start afresh.
if [ -f "$workspace/build/CMakeCache.txt" ] &&
   ! grep -q "^dynamic_occupancy_grid_SOURCE_DIR:STATIC=$workspace/src/dynamic_occupancy_grid$" "$workspace/build/CMakeCache.txt"; then
  rm -rf "$workspace/build" "$workspace/devel"
fi
# The benchmarks are not tests: not built here.
configure=(-DCMAKE_BUILD_TYPE=None "-DCMAKE_CXX_FLAGS=$flags" "-DCMAKE_C_FLAGS=$flags"
           -DCMAKE_EXE_LINKER_FLAGS=-fsanitize=address,undefined
           -DCMAKE_SHARED_LINKER_FLAGS=-fsanitize=address,undefined
           -DCATKIN_ENABLE_TESTING=ON -DCMAKE_DISABLE_FIND_PACKAGE_benchmark=ON)
# The offline tools' rostests: CMakeLists.txt's DOG_TOOL_ROSTESTS.
TOOL_ROSTESTS=" $(sed -n 's/^ *set(DOG_TOOL_ROSTESTS \(.*\))$/\1/p' "$package_dir/CMakeLists.txt") "
if [ "$TOOL_ROSTESTS" = "  " ]; then
  echo "run_sanitized: no set(DOG_TOOL_ROSTESTS ...) line in $package_dir/CMakeLists.txt" >&2
  exit 1
fi
binaries=(mapping_node dynamic_occupancy_grid_nodelet simulate dynamic_occupancy_grid_generate_messages_py)
targets=()
for test_file in "$package_dir"/test/core/test_*.cpp; do
  binaries+=("$(basename "$test_file" .cpp)")
  targets+=("run_tests_dynamic_occupancy_grid_gtest_$(basename "$test_file" .cpp)")
done
for test_file in "$package_dir"/test/ros/*.test; do
  [[ "$TOOL_ROSTESTS" == *" $(basename "$test_file" .test) "* ]] && continue
  targets+=("run_tests_dynamic_occupancy_grid_rostest_test_ros_$(basename "$test_file")")
done
# What those tests run (the rostests' nodes and tools, the core's test binaries), not all.
if ! (cd "$workspace" && catkin_make "${configure[@]}" --make-args "${binaries[@]}" -j2 >"$workspace/build.log" 2>&1); then
  tail -30 "$workspace/build.log"
  echo "run_sanitized: the sanitized build failed (log: $workspace/build.log)" >&2
  exit 1
fi

reports="$workspace/sanitizer_reports"
rm -rf "$reports" "$workspace/build/test_results"
mkdir -p "$reports"
# Leak detection on for every process, without suppressions: the ROS libraries the tests
# reach reported no leak of their own (docs/reliability.md).
export ASAN_OPTIONS="halt_on_error=1:abort_on_error=1:detect_leaks=1:log_path=$reports/asan"
# The rostests' waits for a node's answer (test/ros/wall_scene.py), 15 s, times 3: the
# sanitized nodes are slower, and a CI machine may be busy.
export DOG_TEST_TIMEOUT_SCALE=3
export UBSAN_OPTIONS="halt_on_error=1:abort_on_error=1:print_stacktrace=1:log_path=$reports/ubsan"
DOG_NODELET_PRELOAD=$(gcc -print-file-name=libasan.so)
export DOG_NODELET_PRELOAD

status=0
(cd "$workspace" && catkin_make "${targets[@]}" -j2) >"$workspace/test.log" 2>&1 || status=1

/usr/bin/python3 "$package_dir/test/sanitizers/collect_results.py" \
  "$workspace/build/test_results" "$reports" "$results_dir/sanitized" || status=1
exit $status
