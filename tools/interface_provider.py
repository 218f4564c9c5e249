"""Who provides interface package PKG to this venv: nobody, our own build, or a ROS install.

Run it with the venv's Python (it imports PKG.msg the way the project will). Prints one line:
  none                  PKG is neither importable nor in an ament index
  ours PATH             importable from the copy tools/build_interfaces.sh built into the venv
                        (it carries share/PKG/cobot_calib_ros.vendored)
  foreign WHERE         importable from anything else: a sourced ROS install, a wheel
  index-only WHERE      an ament index outside the venv lists PKG but this Python cannot import it
                        (e.g. a ROS install for another Python): the project cannot use that copy
Usage: VENV/bin/python tools/interface_provider.py VENV_DIR PKG
"""
from __future__ import annotations

import importlib
import os
from pathlib import Path
import sys

MARKER = 'cobot_calib_ros.vendored'


def _prefixes(venv: Path) -> list[Path]:
    paths = [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    out: list[Path] = []
    for p in [*paths, venv]:
        p = p.resolve()
        if p not in out:
            out.append(p)
    return out


def provider(venv: Path, pkg: str) -> str:
    venv = venv.resolve()
    try:
        module = importlib.import_module(f'{pkg}.msg')
    except ImportError:
        module = None
    if module is not None:
        where = Path(module.__file__).resolve().parent.parent
        if where.is_relative_to(venv) and (venv / 'share' / pkg / MARKER).is_file():
            return f'ours {where}'
        return f'foreign {where}'
    listed = [p for p in _prefixes(venv)
              if (p / 'share' / 'ament_index' / 'resource_index' / 'packages' / pkg).is_file()
              and not (p / 'share' / pkg / MARKER).is_file()]
    if listed:
        return f'index-only {os.pathsep.join(map(str, listed))}'
    return 'none'


def main() -> None:
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    print(provider(Path(sys.argv[1]), sys.argv[2]))


if __name__ == '__main__':
    main()
