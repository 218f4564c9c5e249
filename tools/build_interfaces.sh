#!/usr/bin/env bash
# Build an ament_cmake interface package with rosidl and install it into the venv prefix.
# Usage: tools/build_interfaces.sh [--if-missing] VENV_DIR [PACKAGE_DIR]
#   PACKAGE_DIR defaults to msg_defs (cobot_calib_msgs).
#   --if-missing: build only where no ROS install provides the package already; for packages the
#   project rebuilds from upstream definitions (interfaces/tf2_msgs: tf2_msgs is not on PyPI).
#   tools/interface_provider.py decides; a copy we built before is rebuilt.
# A build is kept in a cache beside pip's (COBOT_CALIB_BUILD_CACHE, default
# ~/.cache/cobot_calib_ros/interfaces; set it empty for none), keyed by the package's files, this
# script, requirements.lock and the Python version: another clone or venv on this machine then
# installs the same build in seconds instead of building it again (~85 s for cobot_calib_msgs).
set -euo pipefail
if_missing=0
if [ "${1:-}" = --if-missing ]; then if_missing=1; shift; fi
venv=$(cd "$1" && pwd)
here=$(cd "$(dirname "$0")/.." && pwd)
src=$(cd "$here" && cd "${2:-msg_defs}" && pwd)
py="$venv/bin/python"
pkg=$(sed -n 's#.*<name>\(.*\)</name>.*#\1#p' "$src/package.xml" | head -1)
[ -n "$pkg" ] || { echo "no <name> in $src/package.xml" >&2; exit 1; }

if [ "$if_missing" = 1 ]; then
  provider=$("$py" "$here/tools/interface_provider.py" "$venv" "$pkg")
  case "$provider" in
    foreign*)
      echo "$pkg: using the installed one (${provider#foreign }), not building $src"
      exit 0 ;;
    index-only*)
      echo "$pkg: listed in the ament index of ${provider#index-only } but not importable by $py;" \
           "building this project's copy into the venv" ;;
  esac
fi

# The ROS wheels' exported CMake targets hard-code the wheel builder's include paths
# (/opt/python/cp311-cp311/...): point them at this interpreter's (ros2-from-pypi notes).
py_inc=$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')
np_inc=$("$py" -c 'import numpy; print(numpy.get_include())')
{ grep -rl '/opt/python/cp311-cp311' "$venv/share" --include='*.cmake' 2>/dev/null || true; } | while read -r f; do
  sed -i -e "s#/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include#$np_inc#g" \
         -e "s#/opt/python/cp311-cp311/include/python3.11#$py_inc#g" "$f"
done

build="$here/build/$pkg"
mkdir -p "$build"
# One checkout, several `make setup` at once (parallel make, or two shells): one build per package
# at a time, or their `make install` runs trip over each other's files.
exec 9>"$build.lock"
flock 9

cache_dir=${COBOT_CALIB_BUILD_CACHE-${XDG_CACHE_HOME:-$HOME/.cache}/cobot_calib_ros/interfaces}
key=$({ echo "$pkg"; "$py" -c 'import sys, platform; print(sys.version, platform.machine())'
        cat "$0" "$here/requirements.lock"
        (cd "$src" && find . -type f | LC_ALL=C sort | xargs sha256sum); } | sha256sum | cut -c1-20)
cached="$cache_dir/$pkg-$key.tar.gz"

# The installed package's bytecode, written once here: `make test` sets PYTHONDONTWRITEBYTECODE, so
# without it every node and command process compiles the generated message modules again (0.14 s
# of CPU a process for cobot_calib_msgs, session 28).
compile_installed() {
  "$py" -c "import compileall, os, sys, $pkg
sys.exit(not compileall.compile_dir(os.path.dirname($pkg.__file__), quiet=1))"
}

# The build's files, as `make install` wrote them into the venv, with the venv's path in its text
# files (cmake exports, local_setup.sh) put back as this venv's.
if [ -n "$cache_dir" ] && [ -f "$cached" ]; then
  restore=$(mktemp -d)
  if tar -xzf "$cached" -C "$restore" && [ -f "$restore/built_in" ]; then
    built_in=$(cat "$restore/built_in")
    (cd "$restore/venv" && grep -rIlF "$built_in" . || true) | while read -r f; do
      sed -i "s#$built_in#$venv#g" "$restore/venv/$f"
    done
    cp -a "$restore/venv/." "$venv/"
    rm -rf "$restore"
    if "$py" -c "import $pkg.msg" 2>/dev/null; then
      compile_installed
      echo "$pkg installed into $venv from the build cache ($cached)"
      exit 0
    fi
    echo "$pkg: the cached build $cached does not import; building it" >&2
  else
    rm -rf "$restore"
  fi
fi

cd "$build"
PATH="$venv/bin:$PATH" cmake "$src" -DCMAKE_INSTALL_PREFIX="$venv" \
  -DCMAKE_PREFIX_PATH="$venv" -DPython3_EXECUTABLE="$py" -DBUILD_TESTING=OFF >cmake.log 2>&1 \
  || { cat cmake.log; exit 1; }
PATH="$venv/bin:$PATH" make -j2 install >make.log 2>&1 || { tail -50 make.log; exit 1; }
"$py" -c "import $pkg.msg; print('$pkg installed into $venv')"
compile_installed

if [ -n "$cache_dir" ] && mkdir -p "$cache_dir" 2>/dev/null; then
  stage=$(mktemp -d)
  mkdir "$stage/venv"
  echo "$venv" >"$stage/built_in"
  sed "s#^$venv/##" install_manifest.txt | (cd "$venv" && xargs cp --parents -a -t "$stage/venv")
  tar -czf "$cached.$$" -C "$stage" built_in venv && mv "$cached.$$" "$cached"    # atomic
  rm -rf "$stage"
fi
