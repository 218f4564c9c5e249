#!/usr/bin/env bash
# Build msg_defs/ (cobot_calib_msgs) with rosidl and install it into the venv prefix.
# Usage: tools/build_interfaces.sh VENV_DIR
set -euo pipefail
venv=$(cd "$1" && pwd)
here=$(cd "$(dirname "$0")/.." && pwd)
py="$venv/bin/python"

# The ROS wheels' exported CMake targets hard-code the wheel builder's include paths
# (/opt/python/cp311-cp311/...): point them at this interpreter's (ros2-from-pypi notes).
py_inc=$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
np_inc=$("$py" -c 'import numpy; print(numpy.get_include())')
{ grep -rl '/opt/python/cp311-cp311' "$venv/share" --include='*.cmake' 2>/dev/null || true; } | while read -r f; do
  sed -i -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$np_inc#g" \
         -e "s#/opt/python/cp311-cp311/include/python3.11#$py_inc#g" "$f"
done

build="$here/build/cobot_calib_msgs"
mkdir -p "$build"
cd "$build"
PATH="$venv/bin:$PATH" cmake "$here/msg_defs" -DCMAKE_INSTALL_PREFIX="$venv" \
  -DCMAKE_PREFIX_PATH="$venv" -DPython3_EXECUTABLE="$py" -DBUILD_TESTING=OFF >cmake.log 2>&1 \
  || { cat cmake.log; exit 1; }
PATH="$venv/bin:$PATH" make -j2 install >make.log 2>&1 || { tail -50 make.log; exit 1; }
"$py" -c 'from cobot_calib_msgs.srv import CalibrateUserFrame; print("cobot_calib_msgs installed")'
