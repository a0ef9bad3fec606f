#!/usr/bin/env bash
# The main job on the bundled example: installs what is missing, builds, and maps the
# bundled bag (a stationary laser watching people walk through a room) with process_bag.
#   scripts/demo.sh [OUTPUT_DIR]     (default: ./dynamic_occupancy_grid_output)
set -euo pipefail
package_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
out_dir=$(realpath -m "${1:-dynamic_occupancy_grid_output}")
export DOG_WORKSPACE=${DOG_WORKSPACE:-$HOME/dog_ws}

"$package_dir/scripts/setup.sh"
set +u
# shellcheck disable=SC1091
source "$DOG_WORKSPACE/devel/setup.bash"
set -u
rosrun dynamic_occupancy_grid process_bag "$package_dir/data/example/stationary_laser_people.bag" \
  --laser-pose 0,0,0 --out "$out_dir"
echo "demo: the six map layers (map_server PGM + YAML) and model.dogm are in $out_dir"
