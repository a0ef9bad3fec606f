# shellcheck shell=bash disable=SC2034  # the variables are for the scripts that source it
# Shared by check_rviz_config.sh and check_launch_files.sh (sourced, not run).
# Sets package_dir, checks (config_checks.py), work (a temporary directory removed on exit)
# and results; provides the ROS environment and one function per kind of testcase.

package_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
checks="$package_dir/test/rviz/config_checks.py"
export PATH=/usr/bin:/bin:$PATH  # system python3 with the ROS modules

# ROS: /opt/ros/noetic where it exists, else Debian's; the workspace scripts/setup.sh builds
# (for the node's executables); this checkout first on the package path.
if [ -f /opt/ros/noetic/setup.bash ]; then set +u; source /opt/ros/noetic/setup.bash; set -u; fi
workspace=${DOG_WORKSPACE:-$HOME/dog_ws}
if [ -f "$workspace/devel/setup.bash" ]; then
  set +u; source "$workspace/devel/setup.bash"; set -u
fi
export ROS_PACKAGE_PATH="$package_dir${ROS_PACKAGE_PATH:+:$ROS_PACKAGE_PATH}"

work=$(mktemp -d "${TMPDIR:-/tmp}/dog_checks.XXXXXX") || { echo "cannot create a temporary directory" >&2; exit 2; }
results="$work/results"
mkdir -p "$results"
export ROS_HOME="$work/ros_home"  # logs of this run only, and none in ~/.ros
case_count=0

# record NAME STATUS SECONDS LOG_FILE: one testcase for config_checks.py junit
# (results/NNN.status holds "STATUS SECONDS NAME", results/NNN.log the output).
record() {
  case_count=$((case_count + 1))
  local stem
  stem=$(printf '%s/%03d' "$results" "$case_count")
  echo "$2 $3 $1" > "$stem.status"  # the name last: it may hold spaces
  cp "$4" "$stem.log"
  printf '%-4s %s\n' "$( [ "$2" = pass ] && echo ok || echo FAIL)" "$1"
  if [ "$2" != pass ]; then sed 's/^/     /' "$4" | tail -n 20; fi
}

# check NAME COMMAND...: passes when the command exits 0.
check() {
  local name=$1 start=$SECONDS log="$work/case.log"
  shift
  if "$@" > "$log" 2>&1; then record "$name" pass $((SECONDS - start)) "$log"
  else record "$name" fail $((SECONDS - start)) "$log"; fi
}

# expect_failure NAME PATTERN COMMAND...: a negative control. Passes when the command fails
# and its output matches PATTERN (grep -E), i.e. the check does catch the breakage.
expect_failure() {
  local name=$1 pattern=$2 start=$SECONDS log="$work/case.log" rc=0
  shift 2
  "$@" > "$work/control.out" 2>&1 || rc=$?
  {
    echo "negative control: $* must fail with output matching /$pattern/"
    echo "exit status $rc; its output:"
    sed 's/^/  | /' "$work/control.out"
  } > "$log"
  if [ "$rc" -ne 0 ] && grep -Eq -- "$pattern" "$work/control.out"; then
    echo "caught as expected" >> "$log"
    record "$name" pass $((SECONDS - start)) "$log"
  else
    echo "FAIL: the check did not catch the breakage" >> "$log"
    record "$name" fail $((SECONDS - start)) "$log"
  fi
}

# overlay_copy DIR: a copy of the package's launch/rviz/config files (and package.xml) in
# DIR/dynamic_occupancy_grid, to break on purpose; put DIR first on ROS_PACKAGE_PATH to use it.
overlay_copy() {
  local copy="$1/dynamic_occupancy_grid"
  mkdir -p "$copy/data"
  cp "$package_dir/package.xml" "$copy/"
  [ -f "$package_dir/nodelet_plugins.xml" ] && cp "$package_dir/nodelet_plugins.xml" "$copy/"
  cp -rL "$package_dir/launch" "$package_dir/rviz" "$package_dir/config" "$copy/"
  ln -s "$package_dir/data/example" "$copy/data/example"
  echo "$copy"
}
