#!/usr/bin/env bash
# Installs what dynamic_occupancy_grid needs (only what is missing) and builds it in a
# catkin workspace outside the package, so rosrun/roslaunch find its executables.
#
#   scripts/setup.sh            install + build
#   DOG_WORKSPACE=DIR           workspace to build in (default: ~/dog_ws)
#   DOG_SKIP_INSTALL=1          do not look at packages at all
#
# On Debian 12 it uses Debian's own ROS 1 packages; where /opt/ros/noetic exists it sources
# it and installs the ros-noetic-* names instead.
set -euo pipefail

package_dir=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
workspace=${DOG_WORKSPACE:-$HOME/dog_ws}
# Debian's catkin and CMake's FindPython3 take python3 from PATH: use the system one (a
# pyenv or venv python3 lacks catkin_pkg).
export PATH=/usr/bin:/bin:$PATH

# Packages: build, tests (gtest, rostest, python message modules, pomegranate for the
# cross-check, clang with libFuzzer and its sanitizer runtimes for test/fuzz, Dask for
# scripts/dask_offline_em.py), benchmarks
# (Google Benchmark; OctoMap as the peer of issue 6, optional in CMake; Debian/Ubuntu names
# on both branches, like libbenchmark-dev), demo (rviz under Xvfb, tf2 tools).
common_packages=(
  build-essential cmake libeigen3-dev libgtest-dev googletest libbenchmark-dev liboctomap-dev
  zlib1g-dev libboost-program-options-dev clang
  python3-numpy python3-matplotlib python3-pomegranate xvfb python3-distributed python3-dask
)
debian_ros_packages=(
  catkin python3-catkin-pkg ros-core-dev ros-message-generation ros-message-runtime
  libroscpp-dev librosbag-dev libtf2-dev libtf2-ros-dev libtf2-msgs-dev libtf2-geometry-msgs-dev
  libsensor-msgs-dev libnav-msgs-dev libmap-msgs-dev libgeometry-msgs-dev libstd-srvs-dev
  libnodelet-dev libnodeletlib-dev pluginlib-dev librostest-dev
  python3-rostest python3-roslaunch python3-rosbag python3-rostopic python3-rosservice
  python3-sensor-msgs python3-nav-msgs python3-map-msgs python3-tf2-msgs python3-geometry-msgs
  python3-std-srvs python3-rospy python3-rosgraph-msgs python3-tf2-ros python3-roslib python3-rospkg
  python3-yaml libnodeletlib-tools rosbash rviz tf2-tools
  libdiagnostic-updater-dev libdiagnostic-msgs-dev python3-diagnostic-msgs
  libdynamic-reconfigure-config-init-mutex-dev python3-dynamic-reconfigure
  # not ROS: Debian 12's clang 14 runtimes for test/fuzz (libFuzzer, ASan, UBSan)
  libclang-rt-14-dev libfuzzer-14-dev
)
noetic_ros_packages=(
  ros-noetic-catkin ros-noetic-roscpp ros-noetic-rosbag ros-noetic-tf2 ros-noetic-tf2-ros
  ros-noetic-tf2-msgs ros-noetic-tf2-geometry-msgs ros-noetic-sensor-msgs ros-noetic-nav-msgs
  ros-noetic-map-msgs ros-noetic-geometry-msgs ros-noetic-std-srvs ros-noetic-nodelet
  ros-noetic-pluginlib ros-noetic-rostest ros-noetic-rosbash ros-noetic-rviz
  ros-noetic-message-generation ros-noetic-message-runtime ros-noetic-rospy ros-noetic-rosgraph-msgs
  ros-noetic-diagnostic-updater ros-noetic-diagnostic-msgs ros-noetic-dynamic-reconfigure
  python3-catkin-pkg python3-yaml
)

if [ -f /opt/ros/noetic/setup.bash ]; then
  ros_packages=("${noetic_ros_packages[@]}")
  set +u
  # shellcheck disable=SC1091
  source /opt/ros/noetic/setup.bash
  set -u
else
  ros_packages=("${debian_ros_packages[@]}")
fi

if [ "${DOG_SKIP_INSTALL:-0}" != 1 ]; then
  missing=()
  for package in "${common_packages[@]}" "${ros_packages[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q 'install ok installed'; then
      missing+=("$package")
    fi
  done
  if [ ${#missing[@]} -gt 0 ]; then
    echo "setup: installing ${#missing[@]} missing packages: ${missing[*]}"
    if [ "$(id -u)" -ne 0 ]; then
      if command -v sudo >/dev/null; then sudo=sudo; else
        echo "setup: run as root (or install sudo) to install: ${missing[*]}" >&2; exit 1
      fi
    else
      sudo=
    fi
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  fi
fi

# The workspace holds a link to this checkout; build and devel spaces live beside it.
mkdir -p "$workspace/src"
link="$workspace/src/dynamic_occupancy_grid"
if [ -e "$link" ] && [ ! -L "$link" ]; then
  echo "setup: $link exists and is not a link to this checkout; set DOG_WORKSPACE to another directory" >&2
  exit 1
fi
ln -sfn "$package_dir" "$link"
echo "setup: building in $workspace"
(cd "$workspace" && catkin_make -DCMAKE_BUILD_TYPE=Release -DCATKIN_ENABLE_TESTING=ON -j2 "$@")
echo "setup: built. Use it with: source $workspace/devel/setup.bash"
