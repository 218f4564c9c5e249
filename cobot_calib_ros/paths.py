"""Where the package's config and the user's results live."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping

PACKAGE = 'cobot_calib_ros'


def share_dir() -> Path:
    """The package's share directory (ament index when sourced, else the source tree)."""
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory(PACKAGE))
    except (ImportError, LookupError, OSError, ValueError):
        return Path(__file__).resolve().parent.parent


DEFAULT_CELL = 'sawyer_close'     # the cell every command and node uses unless told


def config_dir() -> Path:
    return share_dir() / 'config'


def cell_file(name_or_path: str = DEFAULT_CELL) -> Path:
    """A cell YAML by path, or by name from config/cells/."""
    path = Path(name_or_path)
    if path.suffix in ('.yaml', '.yml') or path.exists():
        return path.expanduser().resolve()
    return config_dir() / 'cells' / f'{name_or_path}.yaml'


def data_dir(given: str | None = None, environ: Mapping[str, str] | None = None) -> Path:
    """Results root: ``given`` (a data_dir parameter or --data-dir) when not empty, else
    $COBOT_CALIB_DATA (of ``environ``, default this process's), else ~/.ros/cobot_calib."""
    if given:
        return Path(given)
    env = (os.environ if environ is None else environ).get('COBOT_CALIB_DATA')
    return Path(env).expanduser() if env else Path.home() / '.ros' / 'cobot_calib'
