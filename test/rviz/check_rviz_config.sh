#!/usr/bin/env bash
# Checks the rviz configuration in a real rviz under Xvfb, headless, and writes one JUnit
# testcase per check:
#   static/config               YAML readable; fixed frame map, the default fixed_frame of
#                               replay.launch and the config; a top-down view that follows
#                               base_link and fits the map demo.launch builds; a Map display per layer with
#                               its topic, _updates topic, color scheme and enabled state;
#                               LaserScan /scan, TF, Grid; every class declared by a plugin
#   rviz/loads_without_errors   rviz (own roscore on a free port) comes up with it, is still
#                               running when stopped, and logs no error
#   rviz/subscribes_to_enabled_displays
#                               rviz subscribes to belief, static_map (+ _updates), /scan,
#                               /tf: those displays really loaded; none to a disabled layer
#   rviz/keeps_every_key        rviz saves the config back (save_config service) with every
#                               key and value: rviz silently ignores keys it does not know
# and negative controls: broken copies of the config that these checks must reject.
# rviz has no "load and exit", so the check starts it, asks it over ROS what it loaded,
# then stops it. Everything it starts is killed on exit, also on failure or Ctrl-C.
#   test/rviz/check_rviz_config.sh RESULT.xml [CONFIG]
set -uo pipefail
output=${1:?usage: check_rviz_config.sh JUNIT_RESULT_XML [RVIZ_CONFIG]}
output=$(realpath -m "$output")
# shellcheck source=test/rviz/common.sh source-path=SCRIPTDIR/../..
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
config=$(realpath "${2:-$package_dir/rviz/dynamic_occupancy_grid.rviz}")

# Process groups started here (setsid) and the pids of rosmaster and rosout (roslaunch puts
# them in sessions of their own): stopped with SIGINT (roscore shuts its nodes down on it),
# then SIGKILL whatever is left after 3 s.
process_groups=()
core_pids=()
any_alive() {
  local group pid
  for group in "${process_groups[@]}"; do
    if kill -0 -- "-$group" 2>/dev/null; then return 0; fi
  done
  for pid in "${core_pids[@]}"; do
    if kill -0 "$pid" 2>/dev/null; then return 0; fi
  done
  return 1
}
cleanup() {
  local group pid _
  for group in "${process_groups[@]}"; do kill -INT -- "-$group" 2>/dev/null; done
  for _ in $(seq 12); do any_alive || break; sleep 0.25; done
  for group in "${process_groups[@]}"; do kill -KILL -- "-$group" 2>/dev/null; done
  for pid in "${core_pids[@]}"; do kill -KILL "$pid" 2>/dev/null; done
  rm -rf "$work"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

# A roscore of our own on a free port, in its own process group.
port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI="http://localhost:$port"
# (timeout stops it cleanly even if this script is killed before its trap can run.)
setsid timeout -s INT -k 10 900 roscore -p "$port" > "$work/roscore.log" 2>&1 < /dev/null &
process_groups+=($!)
disown  # no "Killed" report from bash when it is stopped
master_up() {
  python3 -c 'import rosgraph, sys; sys.exit(0 if rosgraph.is_master_online() else 1)' 2>/dev/null
}
for _ in $(seq 60); do master_up && break; sleep 0.5; done
if ! master_up; then
  { echo "FAIL: roscore did not start on port $port"; cat "$work/roscore.log"; } > "$work/core.log"
  record "rviz/roscore_starts" fail 30 "$work/core.log"
  # A view that stays at the fixed frame's origin: a robot driving away leaves it.
sed 's/^      Target Frame: base_link$/      Target Frame: <Fixed Frame>/' "$config" > "$broken/fixed_view.rviz"
expect_failure "negative_control/view_does_not_follow_the_robot/static" "expected 'base_link'" \
  python3 "$checks" static-rviz "$broken/fixed_view.rviz"

python3 "$checks" junit rviz_config "$results" "$output"
  exit 1
fi
read -r -a core_pids < <(python3 - <<'PY'
import time, xmlrpc.client, rosgraph
master = rosgraph.Master("/config_checks")
pids = [master.getPid()]
for _ in range(20):  # rosout registers a moment after the master is up
    try:
        api = master.lookupNode("/rosout")
        pids.append(xmlrpc.client.ServerProxy(api).getPid("/config_checks")[2])
        break
    except Exception:
        time.sleep(0.25)
print(*pids)
PY
)

# One virtual screen for every rviz run. Xvfb itself rather than xvfb-run: -displayfd
# picks a free display and tells which, and xauth (which xvfb-run needs) is not required.
setsid timeout -s KILL 900 Xvfb -displayfd 3 -screen 0 1400x1000x24 -nolisten tcp \
  3> "$work/display" > "$work/xvfb.log" 2>&1 < /dev/null &
process_groups+=($!)
disown
for _ in $(seq 40); do [ -s "$work/display" ] && break; sleep 0.25; done
if [ ! -s "$work/display" ]; then
  { echo "FAIL: Xvfb did not start"; cat "$work/xvfb.log"; } > "$work/xvfb_failed.log"
  record "rviz/xvfb_starts" fail 10 "$work/xvfb_failed.log"
  # A view that stays at the fixed frame's origin: a robot driving away leaves it.
sed 's/^      Target Frame: base_link$/      Target Frame: <Fixed Frame>/' "$config" > "$broken/fixed_view.rviz"
expect_failure "negative_control/view_does_not_follow_the_robot/static" "expected 'base_link'" \
  python3 "$checks" static-rviz "$broken/fixed_view.rviz"

python3 "$checks" junit rviz_config "$results" "$output"
  exit 1
fi
DISPLAY=":$(head -n 1 "$work/display")"
export DISPLAY

# run_rviz NAME CONFIG: rviz with CONFIG on that screen until the probe has what it needs
# (at most ~75 s), then stopped. Leaves rviz.out, rviz.err, rosout.log, probe.yaml,
# saved.rviz and, if rviz was still running when stopped, "alive" in $work/NAME.
run_rviz() {
  local rviz_config=$2 dir="$work/$1" node="rviz_check_$1"
  mkdir -p "$dir"
  setsid timeout -s KILL 120 rviz -d "$rviz_config" "__name:=$node" \
    > "$dir/rviz.out" 2> "$dir/rviz.err" < /dev/null &
  local group=$!
  process_groups+=("$group")
  timeout -s KILL 90 python3 "$checks" probe-rviz "$node" "$dir" > "$dir/probe.out" 2>&1
  if kill -0 "$group" 2>/dev/null; then touch "$dir/alive"; fi
  kill -TERM -- "-$group" 2>/dev/null
  for _ in $(seq 20); do kill -0 "$group" 2>/dev/null || break; sleep 0.25; done
  kill -KILL -- "-$group" 2>/dev/null
  wait "$group" 2>/dev/null
  # rosout's log of this run (written by the roscore above).
  cat "$ROS_HOME"/log/latest/rosout.log > "$dir/rosout.log" 2>/dev/null || true
}

check "static/config" python3 "$checks" static-rviz "$config"

run_rviz good "$config"
check "rviz/loads_without_errors" python3 "$checks" rviz-loaded rviz_check_good "$work/good"
check "rviz/subscribes_to_enabled_displays" python3 "$checks" rviz-subscriptions "$work/good"
check "rviz/keeps_every_key" python3 "$checks" compare-rviz "$config" "$work/good/saved.rviz"

# Negative controls: each breaks a copy of the config in one way; the check that must catch
# it has to fail, naming the breakage.
broken="$work/broken"
mkdir -p "$broken"

# A display class no plugin declares: rviz logs an ERROR and shows a failed display.
sed '0,/Class: rviz\/Map/s//Class: rviz\/NoSuchMapDisplay/' "$config" > "$broken/unknown_class.rviz"
expect_failure "negative_control/unknown_display_class/static" "NoSuchMapDisplay" \
  python3 "$checks" static-rviz "$broken/unknown_class.rviz"
run_rviz unknown_class "$broken/unknown_class.rviz"
expect_failure "negative_control/unknown_display_class/rviz_log" "ERROR.*NoSuchMapDisplay" \
  python3 "$checks" rviz-loaded rviz_check_unknown_class "$work/unknown_class"

# A misspelled property: rviz ignores it without a word; only the round trip sees it.
sed '0,/Color Scheme: costmap/s//Colour Scheme: costmap/' "$config" > "$broken/misspelled.rviz"
run_rviz misspelled "$broken/misspelled.rviz"
expect_failure "negative_control/misspelled_property/round_trip" "Colour Scheme: rviz does not know this key" \
  python3 "$checks" compare-rviz "$broken/misspelled.rviz" "$work/misspelled/saved.rviz"

# Invalid YAML: rviz says nothing and starts empty; the subscriptions show it.
sed 's/^Visualization Manager:$/Visualization Manager: [/' "$config" > "$broken/invalid_yaml.rviz"
expect_failure "negative_control/invalid_yaml/static" "cannot read" \
  python3 "$checks" static-rviz "$broken/invalid_yaml.rviz"
run_rviz invalid_yaml "$broken/invalid_yaml.rviz"
expect_failure "negative_control/invalid_yaml/rviz_subscriptions" "rviz did not subscribe" \
  python3 "$checks" rviz-subscriptions "$work/invalid_yaml"

# A layer on the wrong topic (the static check compares with the node's interface).
sed 's#Topic: /dynamic_occupancy_grid/stationary$#Topic: /dynamic_occupancy_grid/stationnary#' \
  "$config" > "$broken/wrong_topic.rviz"
expect_failure "negative_control/wrong_layer_topic/static" "stationnary" \
  python3 "$checks" static-rviz "$broken/wrong_topic.rviz"

# A view zoomed in too far to show the map the demo builds.
sed 's/^      Scale: [0-9.]*$/      Scale: 200/' "$config" > "$broken/zoomed_in.rviz"
expect_failure "negative_control/view_misses_the_map/static" "does not show the demo map" \
  python3 "$checks" static-rviz "$broken/zoomed_in.rviz"

# A view that stays at the fixed frame's origin: a robot driving away leaves it.
sed 's/^      Target Frame: base_link$/      Target Frame: <Fixed Frame>/' "$config" > "$broken/fixed_view.rviz"
expect_failure "negative_control/view_does_not_follow_the_robot/static" "expected 'base_link'" \
  python3 "$checks" static-rviz "$broken/fixed_view.rviz"

python3 "$checks" junit rviz_config "$results" "$output"
