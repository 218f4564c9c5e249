"""The cell as the user knows it: robot model, frame names, tool, home pose, marker layouts.

Everything here is nominal, what an integrator measures or configures; what only a simulator
knows (the true user frame, kinematic errors, the uneven table, noise) is in
:mod:`cobot_calib_ros.sim`. The probe's calibration table belongs to ``proximity_sensor``.

A cell file is YAML with a ``cell:`` mapping (read here) and, for the mock robot, a
``simulation:`` mapping (read by :mod:`cobot_calib_ros.sim.scenario`). Lengths in metres,
angles in radians. A file that does not fit raises :class:`CellFileError` naming the file, the
line, the key and what is expected.
"""
from __future__ import annotations

from dataclasses import dataclass
import difflib
import math
from pathlib import Path
from typing import Any
import warnings

import numpy as np
from numpy.typing import NDArray
import yaml

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.kinematics.robots import ROBOTS, UrdfRobot
from cobot_calib_ros.core.units import MAX_CELL_LENGTH
from cobot_calib_ros.core.yaml_c import compose_and_load

Array = NDArray[np.float64]
FRAME_ID_CHARS = frozenset('abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_/')

_POSE = {'xyz': None, 'rpy': None}
CELL_KEYS: dict[str, Any] = {
    'name': None, 'robot': {'urdf': None, 'name': None, 'base_link': None, 'tip_link': None,
                               'model': None},
    'base_frame': None, 'tool_frame': None, 'user_frame': None, 'home': None,
    'T_flange_tool': _POSE, 'markers': {'size': None}, 'layout': None, 'layouts': None,
    'spheres': {'diameter': None, 'centres': None, 'plate': _POSE, 'T_flange_coupling': _POSE,
                'approach_rpy': None},
    'camera': {'frame_id': None, 'T_flange_optical': _POSE, 'resolution': None, 'intrinsics': None,
               'distortion_model': None, 'distortion': None},
    'landmarks': {'dictionary': None, 'marker_length': None, 'markers': None,
                  'board': {'spec': None, 'pose': None}},
}
"""The keys of a cell file's ``cell:`` mapping, nested; None: any value (a mapping there holds
the user's names: layouts, points, spheres, marker ids)."""

RENAMED_KEYS: dict[str, dict[tuple[str, ...], str]] = {
    'cell': {('tool_offset',): 'T_flange_tool',                       # legacy name
             ('spheres', 'coupling_offset'): 'T_flange_coupling',     # legacy name
             ('camera', 'hand_eye'): 'T_flange_optical'},             # legacy name
    'simulation': {('tool_offset_true',): 'T_flange_tool_true',       # legacy name
                   ('spheres', 'coupling_offset_true'): 'p_flange_coupling_true',  # legacy name
                   ('camera', 'hand_eye_true'): 'T_flange_optical_true'},  # legacy name
}
"""Per section, a key's path before issue 39.3 (one name per transform) -> its name now; the
old key still reads, with a FutureWarning."""


class CellFileError(ValueError):
    """A cell file that cannot be used; the message names file, line, key and the fix."""


@dataclass(frozen=True)
class Marker:
    """An aluminium block on the table, axis-aligned in the user frame (nominal geometry)."""

    name: str
    xy: tuple[float, float]            # centre in the user frame [m]
    size: tuple[float, float, float]   # x, y, z extent [m] (50 x 30 x 20 mm in the paper)

    @property
    def nominal_top(self) -> Array:
        """Top-face centre on a flat table at nominal height, user frame [m]."""
        return np.array([self.xy[0], self.xy[1], self.size[2]])


@dataclass(frozen=True)
class Cell:
    """The nominal cell of one file, with one layout of markers chosen."""

    name: str
    robot: str                  # the robot's model name (a built-in one, or the URDF's)
    base_frame: str
    tool_frame: str
    user_frame: str
    T_flange_tool: Array        # (4, 4) flange -> tool centre point (the probe tip)
    home: Array                 # (n,) joint positions [rad]
    layout: str
    layouts: tuple[str, ...]
    markers: tuple[Marker, ...]
    spheres: SpherePlate | None = None   # kinematic calibration plate, if the cell has one
    camera: WristCamera | None = None    # the wrist camera, if the cell has one
    landmarks: Landmarks | None = None   # fiducials on the table, if the cell has them
    urdf_robot: UrdfRobot | None = None  # the robot's URDF chain, when not a built-in model

    def require(self, verb: str, *sections: str) -> None:
        """CellFileError naming ``verb`` and the first of ``sections`` ('layouts', 'spheres',
        'camera', 'landmarks') this cell lacks: a real cell may have none of them (robot,
        tool, frames and home are enough for identify, filter, move, export, tcp and
        user-frame from files)."""
        present = {'layouts': bool(self.markers), 'spheres': self.spheres is not None,
                   'camera': self.camera is not None, 'landmarks': self.landmarks is not None}
        for section in sections:
            if not present[section]:
                raise CellFileError(
                    f'{verb} needs the cell\'s {section}: section, which cell {self.name!r} '
                    f'has not; add it to the cell file (README "Configuration")')

    def marker(self, name: str) -> Marker | None:
        return next((m for m in self.markers if m.name == name), None)

    @property
    def point_names(self) -> list[str]:
        return [m.name for m in self.markers]

    def nominal_points_user(self) -> Array:
        """(N, 3) nominal top-face centres in the user frame [m]."""
        return np.array([m.nominal_top for m in self.markers])


@dataclass(frozen=True)
class SpherePlate:
    """Kinematic calibration plate (second paper): precision spheres and a magnetic coupling.

    The sphere centres relative to each other are known precisely (CMM, the paper's Table 1);
    where the plate stands in the base frame is only roughly known (taught by hand-guiding):
    the coupling self-centres on contact under impedance control.
    """

    names: tuple[str, ...]
    centres_plate: Array       # (k, 3) sphere centres in the plate frame [m]
    diameter: float            # [m] (50.8 mm)
    T_base_plate: Array        # (4, 4) nominal (taught) plate pose in the base frame
    T_flange_coupling: Array   # (4, 4) flange -> coupling centre when mated (the sphere centre)
    approach_rpy: Array        # (3,) coupling orientation at a sphere, base frame rpy [rad]

    def centres_base(self) -> Array:
        """(k, 3) nominal sphere centres in the base frame [m]."""
        return frames.apply(self.T_base_plate, self.centres_plate)

    def known_distances(self) -> tuple[tuple[int, int, float], ...]:
        """Centre-to-centre distances (i, j, metres) for every pair of spheres."""
        c = self.centres_plate
        return tuple((i, j, float(np.linalg.norm(c[i] - c[j])))
                     for i in range(len(c)) for j in range(i + 1, len(c)))


@dataclass(frozen=True)
class WristCamera:
    """The wrist camera as configured: nominal hand-eye and intrinsics of the raw image."""

    frame_id: str              # optical frame (x right, y down, z along the lens axis)
    T_flange_optical: Array    # (4, 4) nominal hand-eye: the optical frame on the flange
    width: int                 # [px]
    height: int                # [px]
    K: Array                   # (3, 3) [px]
    D: Array                   # distortion coefficients (plumb_bob: k1 k2 p1 p2 k3)
    distortion_model: str = 'plumb_bob'

    def camera_model(self):
        """core.landmarks.camera.CameraModel of these intrinsics (imports OpenCV)."""
        from cobot_calib_ros.core.landmarks.camera import CameraModel
        return CameraModel(self.width, self.height, self.K, self.D, self.distortion_model,
                           self.frame_id)


@dataclass(frozen=True)
class Landmarks:
    """Fiducials lying on the table: single markers and an optional ChArUco board.

    Placements are (x, y, yaw) in the user frame [m, m, rad]: a marker's centre and the
    direction of its x axis, the board's grid centre and the direction of its x axis (its
    columns), both printed face up. Frames as core.landmarks: marker z out of the face (up),
    board z into the board (down), board origin at the grid's top-left outer corner.
    """

    dictionary: str                                   # canonical cv2.aruco name
    marker_length: float                              # [m]
    markers: dict[int, tuple[float, float, float]]    # id -> (x, y, yaw)
    board: str = ''                                   # ChArUco spec (targets.BoardSpec), '' none
    board_pose: tuple[float, float, float] | None = None

    def T_user_marker(self, marker_id: int, T_user_surface: Array | None = None) -> Array:
        """(4, 4) marker frame in the user frame; ``T_user_surface``: the table surface at the
        marker (its z and tilt), default the flat table (z = 0)."""
        x, y, yaw = self.markers[marker_id]
        return _on_surface(x, y, T_user_surface) @ frames.make_transform(frames.rot_z(yaw),
                                                                         np.zeros(3))

    def T_user_board(self, T_user_surface: Array | None = None) -> Array:
        """(4, 4) board frame in the user frame (surface as for T_user_marker)."""
        from cobot_calib_ros.core.landmarks.targets import BoardSpec
        x, y, yaw = self.board_pose
        width, height = BoardSpec.parse(self.board).size
        face_up = frames.make_transform(frames.rot_z(yaw) @ frames.rot_x(math.pi), np.zeros(3))
        return _on_surface(x, y, T_user_surface) @ face_up @ frames.make_transform(
            np.eye(3), [-width / 2.0, -height / 2.0, 0.0])


def _on_surface(x: float, y: float, T_user_surface: Array | None) -> Array:
    return frames.make_transform(np.eye(3), [x, y, 0.0]) if T_user_surface is None \
        else T_user_surface


def tool_down_orientation(T_base_user: Array, axis: str = 'z') -> Array:
    """(3, 3) tool orientation in base whose z axis probes a marker along the user ``axis``.

    'z': pointing down onto the top face; 'x' / 'y': pointing along +x / +y of the user frame
    at the marker's side face.
    """
    R_user = {
        'z': frames.rot_x(math.pi),
        'x': frames.rot_y(math.pi / 2.0),
        'y': frames.rot_x(-math.pi / 2.0),
    }[axis]
    return T_base_user[:3, :3] @ R_user


def check_frame_id(frame_id: str) -> Failure | None:
    """None if ``frame_id`` is a valid tf2 frame id (letters, digits, '_', '/'), else an
    INVALID_INPUT Failure saying why not."""
    if not frame_id:
        return Failure(ErrorCode.INVALID_INPUT, 'a frame id must not be empty')
    bad = sorted(set(frame_id) - FRAME_ID_CHARS)
    if bad or frame_id.startswith('/'):
        return Failure(ErrorCode.INVALID_INPUT,
                       f'frame id {frame_id!r} has characters tf2 does not accept '
                       f'({"".join(bad) or "/"}'
                       '); use letters, digits and _ (e.g. user_frame), no leading /')
    return None


# -- reading a cell file ------------------------------------------------------------------

class CellReader:
    """Typed access to one mapping of a cell file, with errors that name the file and line."""

    def __init__(self, path: Path, text: str, section: str) -> None:
        self.path, self.section = path, section
        try:
            self._root, doc = compose_and_load(text)
        except yaml.YAMLError as e:
            raise CellFileError(f'{path}: not valid YAML: {" ".join(str(e).split())}') from None
        if not isinstance(doc, dict) or not isinstance(doc.get(section), dict):
            raise CellFileError(f'{path}: expected a mapping with a top-level "{section}:" key')
        self.data: dict = doc[section]
        for old, new in RENAMED_KEYS.get(section, {}).items():
            self._take_renamed_key(old, new)

    def _take_renamed_key(self, old: tuple[str, ...], new: str) -> None:
        """Read the key at path ``old`` as ``new`` (in the data and for line numbers)."""
        parent = self.get(*old[:-1], default=None) if old[:-1] else self.data
        if not isinstance(parent, dict) or old[-1] not in parent:
            return
        if new in parent:
            raise self.fail(old, f'give {new!r} only ({old[-1]!r} is its old name)')
        parent[new] = parent.pop(old[-1])
        node = self._root
        for key in (self.section, *old):
            name, node = next((k, v) for k, v in node.value if k.value == str(key))
        name.value = new
        where = '.'.join((self.section, *old))
        warnings.warn(f'{self.path}:{name.start_mark.line + 1}: {where} is now called {new}; '
                      'rename it (the old key still reads)', FutureWarning, stacklevel=2)

    def fail(self, keys: tuple[str, ...], expected: str) -> CellFileError:
        where = '.'.join(str(k) for k in (self.section, *keys))
        return CellFileError(f'{self.path}:{self._line(keys)}: {where}: {expected}')

    def _line(self, keys: tuple[str, ...]) -> int:
        node, line = self._root, 1
        for key in (self.section, *keys):
            found = next((v for k, v in getattr(node, 'value', [])
                          if isinstance(node, yaml.MappingNode) and k.value == str(key)), None)
            if found is None:
                break
            node, line = found, found.start_mark.line + 1
        return line

    def get(self, *keys: str, default: Any = ...) -> Any:
        value: Any = self.data
        for i, key in enumerate(keys):
            if not isinstance(value, dict) or key not in value:
                if default is not ...:
                    return default
                raise self.fail(keys[:i + 1], 'missing; see config/cells/sawyer_close.yaml')
            value = value[key]
        return value

    def number(self, *keys: str, default: Any = ...) -> float:
        value = self.get(*keys, default=default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise self.fail(keys, f'expected a finite number, got {value!r}')
        return float(value)

    def vector(self, *keys: str, length: int | None = None, default: Any = ...) -> Array:
        value = self.get(*keys, default=default)
        ok = isinstance(value, list) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        if not ok or (length is not None and len(value) != length) \
                or not np.all(np.isfinite(value)):
            size = f'{length} ' if length else ''
            raise self.fail(keys, f'expected a list of {size}finite numbers, got {value!r}')
        return np.asarray(value, dtype=float)

    def lengths(self, *keys: str, length: int, count: int | None = None,
                default: Any = ...) -> Array:
        """A vector as :meth:`vector` whose first ``count`` values (default all) are lengths
        [m] within MAX_CELL_LENGTH of the origin."""
        value = self.vector(*keys, length=length, default=default)
        far = np.abs(value[:count]).max(initial=0.0)
        if far > MAX_CELL_LENGTH:
            raise self.fail(keys, f'{value[:count].tolist()} is {far:g} m from the origin, '
                            f'beyond the {MAX_CELL_LENGTH:g} m of any cell: lengths are in '
                            'metres (millimetres given?)')
        return value

    def check_keys(self, known: dict[str, Any]) -> None:
        """Refuse a key that is not in ``known`` (nested as CELL_KEYS), naming the nearest
        known one: a misspelt key would otherwise be ignored and its default used."""
        self._check_keys((), self.data, known)

    def _check_keys(self, keys: tuple[str, ...], mapping: dict, known: dict[str, Any]) -> None:
        for key, value in mapping.items():
            if key not in known:
                near = difflib.get_close_matches(str(key), known, n=1)
                hint = f'did you mean {near[0]!r}? ' if near else ''
                raise self.fail((*keys, key), f'unknown key {key!r}; {hint}known here: '
                                f'{", ".join(known)}')
            if isinstance(known[key], dict) and isinstance(value, dict):
                self._check_keys((*keys, key), value, known[key])

    def name(self, *keys: str, default: Any = ...) -> str:
        value = self.get(*keys, default=default)
        if not isinstance(value, str) or not value:
            raise self.fail(keys, f'expected a non-empty string, got {value!r}')
        return value


def parse_cell(text: str, path: str | Path, layout: str | None = None) -> Cell:
    """The nominal cell of a cell file's text (``path`` names it in messages; loaders.load_cell
    reads the file, and the URDF of a URDF robot), with ``layout`` (default: the file's
    ``layout``)."""
    r = CellReader(Path(path), text, 'cell')
    r.check_keys(CELL_KEYS)
    robot, urdf_robot = _robot(r)
    frames_ = {k: r.name(k, default=d) for k, d in (
        ('base_frame', 'base_link'), ('tool_frame', 'tool0'), ('user_frame', 'user_frame'))}
    for key, value in frames_.items():
        if (bad_id := check_frame_id(value)) is not None:
            raise r.fail((key,), bad_id.message)
    layouts = r.get('layouts', default=None)
    if layouts is None and layout is None and r.get('layout', default=None) is None:
        chosen = ''           # a real cell: no marker layouts (Cell.require: who needs them)
    else:
        if not isinstance(layouts, dict) or not layouts:
            raise r.fail(('layouts',), 'expected a mapping of layout name -> {point: [x, y]}')
        chosen = layout or r.get('layout', default=next(iter(layouts)))
        if chosen not in layouts:
            raise r.fail(('layout',), f'layout {chosen!r} is not in the cell; choose one of '
                         f'{", ".join(layouts)}')
    return Cell(
        name=r.name('name', default=Path(path).stem), robot=robot, urdf_robot=urdf_robot,
        **frames_,
        T_flange_tool=frames.from_xyz_rpy(r.lengths('T_flange_tool', 'xyz', length=3),
                                          r.vector('T_flange_tool', 'rpy', length=3)),
        home=r.vector('home'), layout=chosen, layouts=tuple(layouts or ()),
        markers=_markers(r, chosen) if chosen else (), spheres=_spheres(r), camera=_camera(r),
        landmarks=_landmarks(r))


def _robot(r: CellReader) -> tuple[str, UrdfRobot | None]:
    """(model name, None) of a built-in robot, or (name, UrdfRobot without its text yet) of
    ``robot: {urdf: FILE, base_link: LINK, tip_link: LINK[, name: NAME]}``; with ``model:
    BUILT_IN`` the built-in model is the kinematics and the URDF the robot's description (the
    calibrated URDF is written back into it)."""
    robot = r.get('robot')
    if isinstance(robot, dict):
        urdf = r.name('robot', 'urdf')
        model = r.get('robot', 'model', default='')
        if model and model not in ROBOTS:
            raise r.fail(('robot', 'model'), f'unknown robot model {model!r}; use one of '
                         f'{", ".join(ROBOTS)}, or leave it out to take the URDF chain')
        name = model or r.name('robot', 'name', default=Path(urdf).stem)
        return name, UrdfRobot(name, urdf, r.name('robot', 'base_link'),
                               r.name('robot', 'tip_link'), model=model)
    robot = r.name('robot')
    if robot not in ROBOTS:
        raise r.fail(('robot',), f'unknown robot {robot!r}; use one of {", ".join(ROBOTS)}, or '
                     'give {urdf: FILE, base_link: LINK, tip_link: LINK}')
    return robot, None


def _spheres(r: CellReader) -> SpherePlate | None:
    if r.get('spheres', default=None) is None:
        return None
    centres = r.get('spheres', 'centres')
    if not isinstance(centres, dict) or len(centres) < 2:
        raise r.fail(('spheres', 'centres'), 'expected a mapping of at least two sphere names '
                     '-> [x, y, z] centres in the plate frame [m]')
    names = tuple(str(n) for n in centres)
    points = np.array([r.lengths('spheres', 'centres', n, length=3) for n in names])
    diameter = r.number('spheres', 'diameter')
    if not 0.001 < diameter < 0.5:
        raise r.fail(('spheres', 'diameter'), f'expected a diameter in metres, got {diameter}')
    return SpherePlate(
        names=names, centres_plate=points, diameter=diameter,
        T_base_plate=frames.from_xyz_rpy(r.lengths('spheres', 'plate', 'xyz', length=3),
                                         r.vector('spheres', 'plate', 'rpy', length=3)),
        T_flange_coupling=frames.from_xyz_rpy(
            r.lengths('spheres', 'T_flange_coupling', 'xyz', length=3),
            r.vector('spheres', 'T_flange_coupling', 'rpy', length=3)),
        approach_rpy=r.vector('spheres', 'approach_rpy', length=3))


def _markers(r: CellReader, layout: str) -> tuple[Marker, ...]:
    size = r.vector('markers', 'size', length=3)
    if np.any(size <= 0) or np.any(size > 1.0):
        raise r.fail(('markers', 'size'), f'expected x y z extents in metres, got {size}')
    points = r.get('layouts', layout)
    if not isinstance(points, dict) or not points:
        raise r.fail(('layouts', layout), 'expected a mapping of point name -> [x, y] [m]')
    return tuple(Marker(str(name), tuple(r.lengths('layouts', layout, str(name), length=2)),
                        tuple(size)) for name in points)


def _camera(r: CellReader) -> WristCamera | None:
    if r.get('camera', default=None) is None:
        return None
    frame_id = r.name('camera', 'frame_id')
    if (bad_id := check_frame_id(frame_id)) is not None:
        raise r.fail(('camera', 'frame_id'), bad_id.message)
    width, height = r.vector('camera', 'resolution', length=2)
    if width != int(width) or height != int(height) or width <= 0 or height <= 0:
        raise r.fail(('camera', 'resolution'), f'expected [width, height] in pixels, got '
                     f'{[width, height]}')
    fx, fy, cx, cy = r.vector('camera', 'intrinsics', length=4)
    model = r.name('camera', 'distortion_model', default='plumb_bob')
    D = r.vector('camera', 'distortion', default=[])
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    camera = WristCamera(frame_id, frames.from_xyz_rpy(
        r.lengths('camera', 'T_flange_optical', 'xyz', length=3),
        r.vector('camera', 'T_flange_optical', 'rpy', length=3)), int(width), int(height), K, D,
        model)
    try:
        camera.camera_model()
    except ValueError as e:
        raise r.fail(('camera',), str(e)) from None
    return camera


def _landmarks(r: CellReader) -> Landmarks | None:
    if r.get('landmarks', default=None) is None:
        return None
    from cobot_calib_ros.core.landmarks.targets import BoardSpec, canonical_dictionary_name
    keys = ('landmarks',)
    try:
        dictionary = canonical_dictionary_name(r.name(*keys, 'dictionary'))
    except ValueError as e:
        raise r.fail((*keys, 'dictionary'), str(e)) from None
    length = r.number(*keys, 'marker_length')
    if not 0.001 < length < 1.0:
        raise r.fail((*keys, 'marker_length'), f'expected a side length in metres, got {length}')
    placements = r.get(*keys, 'markers', default={})
    if not isinstance(placements, dict):
        raise r.fail((*keys, 'markers'), 'expected a mapping of marker id -> [x, y, yaw]')
    markers = {}
    for key in placements:
        if isinstance(key, bool) or not isinstance(key, int) or key < 0:
            raise r.fail((*keys, 'markers'), f'marker ids are integers >= 0, got {key!r}')
        markers[key] = tuple(float(v) for v in r.lengths(*keys, 'markers', key, length=3,
                                                          count=2))
    board, pose = '', None
    if r.get(*keys, 'board', default=None) is not None:
        board = r.name(*keys, 'board', 'spec')
        try:
            BoardSpec.parse(board)
        except ValueError as e:
            raise r.fail((*keys, 'board', 'spec'), str(e)) from None
        pose = tuple(float(v) for v in r.lengths(*keys, 'board', 'pose', length=3, count=2))
    return Landmarks(dictionary, length, markers, board, pose)
