#!/usr/bin/env bash
# Create the venv and install requirements.lock into it.
# Usage: tools/install_deps.sh PYTHON VENV_DIR LOCK_FILE
# pip takes ~45 s here to unpack the lock's 1.2 GB of wheels; hard links to a venv that pip made
# from the same lock take ~2 s. So the venv as pip leaves it (before the project and its
# interfaces go in) is kept in a cache beside pip's (COBOT_CALIB_VENV_CACHE, default
# ~/.cache/cobot_calib_ros/venv; set it empty for none), keyed by the lock file, this script and
# the interpreter. Its path in the venv's text files (script shebangs, activate, pyvenv.cfg) is
# put back as this venv's on restore; a restored venv that cannot import the lock's packages is
# thrown away and pip runs.
set -euo pipefail
python=$1 venv=$2 lock=$3
mkdir -p "$venv"
venv=$(cd "$venv" && pwd)
# what a restored venv must import (COBOT_CALIB_VENV_CHECK: another check, for this script's test)
check=${COBOT_CALIB_VENV_CHECK:-import numpy, scipy, cv2, rclpy, pinocchio, pytest}

cache_dir=${COBOT_CALIB_VENV_CACHE-${XDG_CACHE_HOME:-$HOME/.cache}/cobot_calib_ros/venv}
key=$({ "$python" -c 'import sys, platform; print(sys.executable, sys.version, platform.machine())'
        cat "$0" "$lock"; } | sha256sum | cut -c1-20)
cached="$cache_dir/$key"

if [ -n "$cache_dir" ] && [ -f "$cached/made_in" ] && [ ! -e "$venv/bin/python" ]; then
  made_in=$(cat "$cached/made_in")
  rm -rf "$venv"
  # hard links (2 s; a copy: 9-20 s): pip, sed -i and the interface builds replace files, they
  # never write into one, so the cache stays as pip left it; another file system: a copy
  cp -al "$cached/venv" "$venv" 2>/dev/null || { rm -rf "$venv"; cp -a "$cached/venv" "$venv"; }
  { grep -rIlF "$made_in" "$venv/bin" "$venv/pyvenv.cfg" || true; } | while read -r f; do
    sed -i "s#$made_in#$venv#g" "$f"
  done
  if "$venv/bin/python" -c "$check" 2>/dev/null; then
    echo "requirements installed into $venv from the venv cache ($cached)"
    exit 0
  fi
  echo "the cached venv $cached does not import its packages; dropped, installing with pip" >&2
  rm -rf "$venv" "$cached"
fi

fresh=0     # only a venv made here holds nothing but the lock (no project, no interfaces)
[ -x "$venv/bin/python" ] || { "$python" -m venv "$venv"; fresh=1; }
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$lock"

if [ "$fresh" = 1 ] && [ -n "$cache_dir" ] && [ ! -e "$cached" ] \
    && mkdir -p "$cache_dir" 2>/dev/null; then
  stage=$(mktemp -d "$cache_dir/.stage.XXXXXX")
  echo "$venv" >"$stage/made_in"
  if { cp -al "$venv" "$stage/venv" 2>/dev/null \
       || { rm -rf "$stage/venv"; cp -a "$venv" "$stage/venv"; }; } \
      && mv -T "$stage" "$cached" 2>/dev/null; then   # atomic
    echo "venv kept in the cache ($cached)"
    # the two newest locks' venvs are kept (a branch with another lock), older ones go
    ls -dt "$cache_dir"/*/ | tail -n +3 | xargs -r rm -rf
  else
    rm -rf "$stage"
  fi
fi
