"""Files into the core: read a configuration or data file, hand its text to the core parser.

The core never touches files (test/test_layering.py); its parsers take text or arrays and the
file's name for messages. Here: cell files (and the URDF a cell's robot may name, relative to
the cell file), camera-info files, and MUKCa sphere-socket data folders.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

from cobot_calib_ros.core.cell import Cell, CellFileError, parse_cell


def read_cell_text(path: str | Path) -> tuple[Path, str]:
    """(path, text) of a cell file; CellFileError when it cannot be read."""
    path = Path(path)
    try:
        return path, path.read_text(encoding='utf-8')
    except OSError as e:
        raise CellFileError(f'{path}: cannot read the cell file ({e.strerror}); give a path or '
                            'a name in config/cells (sawyer_close, iiwa7_close)') from None


def load_cell(path: str | Path, layout: str | None = None) -> Cell:
    """The nominal cell of a cell file, with ``layout`` (default: the file's ``layout``); a
    URDF robot's file is read too (a relative path is relative to the cell file)."""
    path, text = read_cell_text(path)
    cell = parse_cell(text, path, layout)
    if cell.urdf_robot is None:
        return cell
    urdf = Path(cell.urdf_robot.urdf_file).expanduser()
    urdf = urdf if urdf.is_absolute() else path.parent / urdf
    try:
        robot = dataclasses.replace(cell.urdf_robot, urdf=urdf.read_text(encoding='utf-8'))
    except OSError as e:
        raise CellFileError(f'{path}: cell.robot.urdf: cannot read {urdf} ({e.strerror})') \
            from None
    return dataclasses.replace(cell, urdf_robot=robot)


def load_camera_info_yaml(path: str | Path):
    """CameraModel of a camera-info file (core.landmarks.camera.parse_camera_info: ROS
    camera_calibration YAML, a CameraInfo message, OpenCV FileStorage YAML); CameraInfoError
    names the file and the key."""
    from cobot_calib_ros.core.landmarks.camera import CameraInfoError, parse_camera_info
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise CameraInfoError(f'{path}: cannot read camera info: {e}') from None
    return parse_camera_info(text, path)


def load_socket_data(folder: str | Path, distance: float | None = None):
    """SocketData of ``folder/<location>/hole_{0,1}.csv`` for every sub-folder holding both
    files (core.kinematics.identification.sockets.socket_data). ValueError for a folder without
    such sub-folders or a file that is not a numeric table with the same number of columns
    everywhere."""
    import numpy as np
    from cobot_calib_ros.core.kinematics.identification import sockets
    root = Path(folder)
    if not root.is_dir():
        raise ValueError(f'socket data folder {str(root)!r} does not exist')
    names = sorted(p.name for p in root.iterdir()
                   if p.is_dir() and all((p / f).is_file() for f in sockets.SOCKET_FILES))
    if not names:
        raise ValueError(f'no <location>/hole_0.csv + hole_1.csv under {str(root)!r}')
    tables = {name: [(str(root / name / file), _numeric_table(root / name / file))
                     for file in sockets.SOCKET_FILES] for name in names}
    return sockets.socket_data(
        tables, sockets.SOCKET_DISTANCE if distance is None else distance)


def _numeric_table(path: Path):
    """The rows of a comma-separated numeric file (2-D); ValueError naming the file when it is
    empty or not such a table (numpy's own warning for an empty file is not shown)."""
    import warnings
    import numpy as np
    expected = 'expected one row per configuration, one column per joint [rad], comma-separated'
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('error', UserWarning)     # loadtxt: "input contained no data"
            return np.loadtxt(path, delimiter=',', ndmin=2)
    except UserWarning:
        raise ValueError(f'{path}: empty; {expected}') from None
    except ValueError as exc:
        raise ValueError(f'{path}: not a numeric table ({exc}); {expected}') from None


def cell_of_urdf(urdf: str | Path, base_link: str, tip_link: str, home=None,
                 T_flange_tool=None) -> Cell:
    """A real cell given by its robot's URDF alone (no cell file): the chain from ``base_link``
    to ``tip_link``, named by the URDF's file name (as identify stores a result with no
    --cell), the tool centre ``T_flange_tool`` (4, 4) on the tip (default the tip), ``home``
    [rad] the inverse kinematics' seed (default every joint at 0), no layouts, spheres or
    camera. ValueError naming the URDF when it cannot be read or has no such chain."""
    import numpy as np
    from cobot_calib_ros.core.kinematics.robots import model_for, UrdfRobot
    path = Path(urdf).expanduser()
    try:
        text = path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f'--urdf {path}: cannot read ({e})') from None
    robot = UrdfRobot(path.stem, str(path), base_link, tip_link, urdf=text)
    try:
        joints = len(model_for(robot).joint_names)
    except ValueError as e:
        raise ValueError(f'--urdf {path}: {e}') from None
    home = np.zeros(joints) if home is None else np.asarray(home, dtype=float)
    if home.shape != (joints,):
        raise ValueError(f'--home: give {joints} joint values [rad] (the chain {base_link} -> '
                         f'{tip_link} has {joints} joints), got {home.size}')
    return Cell(name=path.stem, robot=path.stem, base_frame=base_link, tool_frame=tip_link,
                user_frame='user_frame',
                T_flange_tool=np.eye(4) if T_flange_tool is None else np.asarray(T_flange_tool),
                home=home, layout='', layouts=(), markers=(), urdf_robot=robot)
