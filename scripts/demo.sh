#!/usr/bin/env bash
# The main job: installs what is missing, builds, then on simulated changing worlds
#   1. writes an example run (the parking lot: cars come and go every "hour") to a bag and
#      maps it with process_bag: the six layers as images,
#   2. runs the evaluation of the papers (accuracy of static / online / offline / oracle maps
#      over time, 10 repetitions per scenario; the path planning experiment, Table 1) and
#      draws its figures,
#   3. maps the bundled real recording (people walking past a stationary laser),
# all into one output directory, and says where everything is.
#   scripts/demo.sh [OUTPUT_DIR] [--rviz]
#     OUTPUT_DIR  default ./dynamic_occupancy_grid_output
#     --rviz      afterwards replay the example bag in rviz (needs a display)
set -euo pipefail
package_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
out_arg=""
open_rviz=false
for arg in "$@"; do
  case "$arg" in
    --rviz) open_rviz=true ;;
    -*) echo "demo: unknown option $arg (usage: scripts/demo.sh [OUTPUT_DIR] [--rviz])" >&2; exit 2 ;;
    *) out_arg=$arg ;;
  esac
done
out_dir=$(realpath -m "${out_arg:-dynamic_occupancy_grid_output}")
export DOG_WORKSPACE=${DOG_WORKSPACE:-$HOME/dog_ws}
export PATH=/usr/bin:/bin:$PATH

"$package_dir/scripts/setup.sh"
set +u
# shellcheck disable=SC1091
source "$DOG_WORKSPACE/devel/setup.bash"
set -u
mkdir -p "$out_dir/example" "$out_dir/evaluation" "$out_dir/real"
start=$(date +%s)

# 1. The example: a simulated parking lot, mapped like any recording. The sensor model is
# the scenario's (evaluation/simulator.cpp: no more certain than the simulated laser).
echo "demo: simulating the parking lot example ..."
rosrun dynamic_occupancy_grid simulate --scenario parking_lot --seed 1 --out "$out_dir/example/parking_lot.bag"
rosrun dynamic_occupancy_grid process_bag "$out_dir/example/parking_lot.bag" --out "$out_dir/example" \
  --resolution 0.25 --p-hit-given-occ 0.9 --p-hit-given-free 0.05 --prediction-horizon 108
/usr/bin/python3 "$package_dir/scripts/plot_evaluation.py" --layers "$out_dir/example"

# 2. The papers' experiments.
rosrun dynamic_occupancy_grid evaluate --out "$out_dir/evaluation"
/usr/bin/python3 "$package_dir/scripts/plot_evaluation.py" "$out_dir/evaluation"

# 3. The bundled real recording (no tf: the laser stands at the origin).
rosrun dynamic_occupancy_grid process_bag "$package_dir/data/example/stationary_laser_people.bag" \
  --laser-pose 0,0,0 --out "$out_dir/real"
/usr/bin/python3 "$package_dir/scripts/plot_evaluation.py" --layers "$out_dir/real"

echo
echo "demo: done in $(( $(date +%s) - start )) s. Everything is in $out_dir:"
echo "  evaluation/summary.md           accuracy, path planning, MRF, memory navigation and learning tables, targets (also printed above)"
echo "  evaluation/*.png, *.csv         the papers' figures (fig4.png, fig5.png, accuracy_parking_lot.png, path_planning.png, mrf_maps.png, ...)"
echo "  example/layers.png              the simulated parking lot's six map layers (example/*.pgm + .yaml for map_server)"
echo "  example/parking_lot.bag         the simulated run (scans, tf, ground truth) to replay"
echo "  real/layers.png                 the same layers for the bundled real recording"
if $open_rviz; then
  roslaunch dynamic_occupancy_grid replay.launch bag:="$out_dir/example/parking_lot.bag" fixed_frame:=odom rate:=10
fi
