#!/usr/bin/env bash
# Checks every launch file of the package without starting anything, and writes one JUnit
# testcase per check:
#   xml    well-formed, <launch> root
#   args   every $(arg)/arg() used is declared (also in branches roslaunch skips), every arg
#          is used and has a doc, <include> passes only declared args, $(find) resolves
#   load   roslaunch's own loader with each set of args below (so every if/unless branch
#          is taken once): substitutions, includes, rosparam files; then, as roslaunch-check
#          does, each node's package is found and declared in package.xml and its
#          executable exists; nodelet classes are declared; package files given exist
# followed by negative controls: broken copies of the files that these checks must reject.
# The node's executable must be built (scripts/setup.sh) for the load checks to pass.
#   test/rviz/check_launch_files.sh RESULT.xml
set -uo pipefail
output=${1:?usage: check_launch_files.sh JUNIT_RESULT_XML}
output=$(realpath -m "$output")
# shellcheck source=test/rviz/common.sh source-path=SCRIPTDIR/../..
source "$(dirname "${BASH_SOURCE[0]}")/common.sh"
trap 'rm -rf "$work"' EXIT
trap 'exit 130' INT TERM

launch_dir="$package_dir/launch"
bag="$package_dir/data/example/stationary_laser_people.bag"

# Argument sets per launch file, one per line (words are name:=value, | separates words).
# Every launch file must be listed: the checks fail for one that is not.
declare -A variants=(
  [mapping.launch]="
    defaults|
    nodelet_model_odom|use_nodelet:=true|model:=/tmp/model.yaml|fixed_frame:=odom|scan_topic:=/front/scan|output:=log
    memory_model|mapping_model:=memory"
  [replay.launch]="
    bag|bag:=$bag
    static_pose_nodelet_norviz|bag:=$bag|static_laser_pose:=1.5 -2 0.5|laser_frame:=base_laser|rviz:=false|use_nodelet:=true|model:=/tmp/model.yaml|rate:=2|start:=10"
  [demo.launch]="
    defaults|
    nodelet_norviz|rviz:=false|use_nodelet:=true|rate:=4"
)

# load_variants CHECKED_DIR FILE: one load testcase per argument set of FILE.
load_variants() {
  local dir=$1 file=$2 line name
  local -a words
  if [ -z "${variants[$file]:-}" ]; then
    echo "FAIL: $file has no argument sets in check_launch_files.sh: add them" > "$work/none.log"
    record "load/$file" fail 0 "$work/none.log"
    return
  fi
  while IFS= read -r line; do
    read -r line <<< "$line"  # trims the indentation
    [ -z "$line" ] && continue
    IFS='|' read -r -a words <<< "$line"
    name=${words[0]}
    check "load/$file/$name" python3 "$checks" launch load "$dir" "$dir/launch/$file" "${words[@]:1}"
  done <<< "${variants[$file]}"
}

shopt -s nullglob
files=("$launch_dir"/*.launch)
if [ ${#files[@]} -eq 0 ]; then
  echo "FAIL: no launch files in $launch_dir" > "$work/none.log"
  record "launch_files_exist" fail 0 "$work/none.log"
fi
for path in "${files[@]}"; do
  file=$(basename "$path")
  for kind in xml args; do
    check "$kind/$file" python3 "$checks" launch "$kind" "$package_dir" "$path"
  done
  load_variants "$package_dir" "$file"
done

# Negative controls: each breaks a copy of the files in one way and runs the check that
# must catch it (the copy comes first on ROS_PACKAGE_PATH, so $(find) resolves to it).
broken_root="$work/broken"
copy=$(overlay_copy "$broken_root")
run_on_copy() { ROS_PACKAGE_PATH="$broken_root:$ROS_PACKAGE_PATH" "$@"; }
restore() { rm -rf "$copy/launch"; cp -rL "$launch_dir" "$copy/launch"; }

sed -i 's/type="mapping_node"/type="mapping_nod"/' "$copy/launch/mapping.launch"
expect_failure "negative_control/node_type_typo" "no executable mapping_nod" \
  run_on_copy python3 "$checks" launch load "$copy" "$copy/launch/mapping.launch"
restore

# In the nodelet branch only, which roslaunch does not read when use_nodelet is false.
# shellcheck disable=SC2016  # $(arg ...) is roslaunch's, not the shell's
sed -i 's/MappingNodelet $(arg nodelet_manager)/MappingNodelet $(arg nodelet_manger)/' "$copy/launch/mapping.launch"
expect_failure "negative_control/undeclared_arg_in_skipped_branch" 'arg nodelet_manger\) is used but not declared' \
  run_on_copy python3 "$checks" launch args "$copy" "$copy/launch/mapping.launch"
restore

sed -i 's#load dynamic_occupancy_grid/MappingNodelet#load dynamic_occupancy_grid/MapingNodelet#' "$copy/launch/mapping.launch"
expect_failure "negative_control/nodelet_class_typo" "nodelet dynamic_occupancy_grid/MapingNodelet is not declared" \
  run_on_copy python3 "$checks" launch load "$copy" "$copy/launch/mapping.launch" use_nodelet:=true
restore

sed -i 's/<arg name="static_laser_pose" value=/<arg name="static_laser_pos" value=/' "$copy/launch/demo.launch"
expect_failure "negative_control/include_arg_typo" "static_laser_pos" \
  run_on_copy python3 "$checks" launch load "$copy" "$copy/launch/demo.launch"
restore

sed -i 's#config/dynamic_occupancy_grid.yaml#config/dynamic_occupancy_grid.yml#' "$copy/launch/mapping.launch"
expect_failure "negative_control/missing_config_file" "dynamic_occupancy_grid.yml" \
  run_on_copy python3 "$checks" launch load "$copy" "$copy/launch/mapping.launch"
restore

sed -i 's#</launch>##' "$copy/launch/replay.launch"
expect_failure "negative_control/broken_xml" "not well-formed" \
  run_on_copy python3 "$checks" launch xml "$copy" "$copy/launch/replay.launch"
restore

sed -i 's#pkg="rosbag"#pkg="rosbag_typo"#' "$copy/launch/replay.launch"
expect_failure "negative_control/unknown_package" "package not found: rosbag_typo" \
  run_on_copy python3 "$checks" launch load "$copy" "$copy/launch/replay.launch" "bag:=$bag"
restore

sed -i 's#pkg="rviz" type="rviz"#pkg="rosout" type="rosout"#' "$copy/launch/replay.launch"
expect_failure "negative_control/undeclared_dependency" "package rosout is not a dependency" \
  run_on_copy python3 "$checks" launch load "$copy" "$copy/launch/replay.launch" "bag:=$bag"
restore

# Not a broken file: a pose that is not "x y yaw" must stop roslaunch.
expect_failure "negative_control/static_laser_pose_not_x_y_yaw" "static_laser_pose is not x y yaw" \
  python3 "$checks" launch load "$package_dir" "$launch_dir/replay.launch" "bag:=$bag" "static_laser_pose:=1 2"

python3 "$checks" junit launch_files "$results" "$output"
