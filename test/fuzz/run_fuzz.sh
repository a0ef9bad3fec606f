#!/usr/bin/env bash
# Builds the fuzz targets (CMakeLists.txt here, clang) and runs each for a bounded time from
# its committed corpus (corpus/<target>/), writing one JUnit testcase per target: a crash, a
# sanitizer finding, a leak, a timeout or running out of memory fails it, with the input
# that did it kept (docs/reliability.md says how to replay one).
#
#   run_fuzz.sh BUILD_DIR RESULT_XML [SECONDS]   (default 15 s per target)
set -uo pipefail

fuzz_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
build_dir=$1
result=$2
seconds=${3:-15}
targets=(model_reader scan_integrate bag_scan_source command_line)
export PATH=/usr/bin:/bin:$PATH

mkdir -p "$(dirname "$result")"
cases=()
failures=0
xml_escape() { sed -e 's/&/\&amp;/g' -e 's/</\&lt;/g' -e 's/>/\&gt;/g' -e 's/"/\&quot;/g'; }
add_case() {  # name, seconds, failure text (empty: passed)
  if [ -n "$3" ]; then
    failures=$((failures + 1))
    cases+=("<testcase classname=\"fuzz\" name=\"$1\" time=\"$2\"><failure message=\"$1 failed\">$(printf '%s' "$3" | xml_escape)</failure></testcase>")
  else
    cases+=("<testcase classname=\"fuzz\" name=\"$1\" time=\"$2\"/>")
  fi
}
write_result() {
  {
    echo '<?xml version="1.0" encoding="UTF-8"?>'
    echo "<testsuite name=\"fuzz\" tests=\"${#cases[@]}\" failures=\"$failures\">"
    printf '%s\n' "${cases[@]}"
    echo '</testsuite>'
  } >"$result"
}

# A build made from another checkout names that source tree in its cache: start afresh.
if [ -f "$build_dir/CMakeCache.txt" ] &&
   ! grep -qxF "CMAKE_HOME_DIRECTORY:INTERNAL=$fuzz_dir" "$build_dir/CMakeCache.txt"; then
  rm -rf "$build_dir"
fi
if ! cmake -S "$fuzz_dir" -B "$build_dir" -DCMAKE_CXX_COMPILER=clang++ >"$build_dir.log" 2>&1 ||
   ! cmake --build "$build_dir" -j2 >>"$build_dir.log" 2>&1; then
  add_case build 0 "$(tail -40 "$build_dir.log")"
  write_result
  exit 1
fi

status=0
for target in "${targets[@]}"; do
  work="$build_dir/work/$target"      # what this run adds; the committed corpus stays as it is
  artifacts="$build_dir/artifacts/$target/"
  rm -rf "$work" "$artifacts"
  mkdir -p "$work" "$artifacts"
  log="$build_dir/$target.log"
  start=$(date +%s)
  # -timeout: an input taking over 60 s is a hang (a model asking for a tile index near the
  # reader's 256 MiB limit takes 7 s here, four of them built per input); -rss_limit_mb:
  # libFuzzer's default.
  if timeout -k 10 $((seconds + 120)) "$build_dir/fuzz_$target" -max_total_time="$seconds" -timeout=60 \
       -rss_limit_mb=2048 -print_final_stats=1 -artifact_prefix="$artifacts" "$work" "$fuzz_dir/corpus/$target" \
       >"$log" 2>&1; then
    add_case "$target" $(($(date +%s) - start)) ""
  else
    status=1
    add_case "$target" $(($(date +%s) - start)) "$(grep -m1 -A30 -E 'ERROR|SUMMARY|Test unit written' "$log" | head -60)
inputs kept in $artifacts; log $log"
  fi
  grep -E '^stat::(number_of_executed_units|average_exec_per_sec)' "$log" | sed "s/^/fuzz $target: /"
done
write_result
exit $status
