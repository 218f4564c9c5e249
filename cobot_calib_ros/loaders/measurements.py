"""Measurement files into the core: a CSV and its YAML sidecar, MUKCa folders, DH tables.

A measurement file is ``NAME.csv`` (a header row, one sample per row) with ``NAME.yaml`` beside
it, which says what the columns are (README, "Measurement files"):

    measurement: pose              # spheres | points | pose | plane
    units: {length: m, angle: rad} # of every length / angle in the CSV and here (m|mm, rad|deg);
                                   # a prismatic joint's column is a length
    joints: [j1, j2, ...]          # the joint-angle columns
    frames: {measured_in: camera, base: base_link, tip: wrist_3_link, target: board}
    # pose:    position: [x, y, z]; rotation: [a, b, c] (rpy | rotvec) or [qw, qx, qy, qz]
    #          (quaternion_wxyz); rotation_format; camera: fixed | on_arm; rotation_weight [m/rad]
    #          or auto (each by its own scatter on the training rows)
    # points:  markers: {m1: [x1, y1, z1], m2: [x2, y2, z2]}  (an empty cell: not seen; NaN
    #          or inf is refused)
    # spheres: sphere: COLUMN; distances: [[i, j, D], ...]; ball: [x, y, z] (in the tip)
    # plane:   plane: COLUMN (optional, one plane without); ball: [x, y, z]
    noise: 0.05                    # optional: one row's RMS error (units.length), the floor
                                   # below which a held-out error is degenerate

Every other column may name groups (``--leave-out COLUMN``). Errors are ValueError with one
line naming the file and the problem.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from cobot_calib_ros.core.kinematics.identification.measurements import (
    DEFAULT_ROTATION_WEIGHT, KINDS, Measurements)

LENGTH = {'m': 1.0, 'mm': 1e-3}
ANGLE = {'rad': 1.0, 'deg': np.pi / 180.0}
ROTATION_FORMATS = {'rpy': 3, 'rotvec': 3, 'quaternion_wxyz': 4}


@dataclass(frozen=True)
class MeasurementFile:
    """What a measurement file holds, in SI units, one Measurements row per measured item.

    ``sample`` (rows,): the CSV data row (0-based) of each measurement row (several markers of
    one sample are several rows); ``columns``: every CSV column as text, per data row (groups);
    ``joints``: the joint names in q's column order; ``frames``: the sidecar's frame names.
    """

    source: str
    measurements: Measurements
    sample: np.ndarray
    joints: tuple[str, ...]
    columns: dict
    frames: dict
    samples: int
    noise_m: float = 0.0      # the sidecar's noise [m]: one row's RMS error (0: not given)
    length_per_angle: float = 1.0   # units.length / units.angle: q is read as angles

    def in_joint_order(self, names: tuple[str, ...],
                       prismatic=None) -> 'MeasurementFile':
        """The same file with q's columns in ``names`` order, the ``prismatic`` ones (flags in
        that order) read in units.length; ValueError naming the missing."""
        missing = [n for n in names if n not in self.joints]
        if missing:
            raise ValueError(f'{self.source}: the model\'s joints {missing} are not among the '
                             f'file\'s joints {list(self.joints)}; name them in the sidecar\'s '
                             '"joints"')
        order = [self.joints.index(n) for n in names]
        m = self.measurements
        q = m.q[:, order]
        if prismatic is not None and np.size(prismatic):
            q = np.where(np.asarray(prismatic, dtype=bool), q * self.length_per_angle, q)
        data = Measurements(m.kind, q, m.target, m.values, m.distances, m.ball,
                            m.rotation_weight)
        return MeasurementFile(self.source, data, self.sample, tuple(names), self.columns,
                               self.frames, self.samples, self.noise_m,
                               self.length_per_angle if prismatic is None else 1.0)

    def groups(self, column: str) -> np.ndarray:
        """The group label of every measurement row from ``column``."""
        if column not in self.columns:
            raise ValueError(f'{self.source}: --leave-out {column}: no such column; columns: '
                             f'{sorted(self.columns)}')
        return np.asarray(self.columns[column])[self.sample]


def sidecar_of(path: Path) -> Path:
    return path.with_suffix('.yaml')


def _fail(source: Path, message: str) -> ValueError:
    return ValueError(f'{source}: {message}')


def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    try:
        with path.open(newline='', encoding='utf-8') as f:
            rows = [r for r in csv.reader(f) if r and any(c.strip() for c in r)]
    except (OSError, UnicodeDecodeError) as e:
        raise _fail(path, f'cannot read ({getattr(e, "strerror", None) or e})') from None
    if len(rows) < 2:
        raise _fail(path, 'needs a header row and at least one data row')
    header = [h.strip() for h in rows[0]]
    bad = [i + 2 for i, r in enumerate(rows[1:]) if len(r) != len(header)]
    if bad:
        raise _fail(path, f'lines {bad[:5]} do not have {len(header)} fields like the header')
    return header, [[c.strip() for c in r] for r in rows[1:]]


def _numbers(path: Path, header: list[str], rows: list[list[str]], names: list[str],
             what: str, blank_ok: bool = False) -> np.ndarray:
    missing = [n for n in names if n not in header]
    if missing:
        raise _fail(path, f'missing columns {missing} ({what}); the header has {header}')
    idx = [header.index(n) for n in names]
    out = np.empty((len(rows), len(idx)))
    for i, r in enumerate(rows):
        for j, k in enumerate(idx):
            text = r[k]
            if text == '' and blank_ok:
                out[i, j] = np.nan
                continue
            try:
                out[i, j] = float(text)
            except ValueError:
                raise _fail(path, f'line {i + 2}, column {names[j]!r}: {text!r} is not a '
                                  'number') from None
            if not np.isfinite(out[i, j]):
                blank = '; leave the cell empty for a marker not seen' if blank_ok else ''
                raise _fail(path, f'line {i + 2}, column {names[j]!r}: {text!r} is not a '
                                  f'finite number{blank}')
    return out


def _names(side: dict, key: str, sidecar: Path, count: int | None = None) -> list[str]:
    value = side.get(key)
    if not isinstance(value, list) or not value or (count and len(value) != count):
        need = f'{count} column names' if count else 'a list of column names'
        raise _fail(sidecar, f'"{key}" must be {need}, got {value!r}')
    return [str(v) for v in value]


def _sidecar(path: Path) -> dict:
    sidecar = sidecar_of(path)
    try:
        side = yaml.safe_load(sidecar.read_text(encoding='utf-8'))
    except OSError as e:
        raise _fail(sidecar, f'cannot read the sidecar of {path.name} ({e.strerror}); write '
                             'one naming the measurement, units, joints and columns') from None
    except yaml.YAMLError as e:
        raise _fail(sidecar, f'not YAML ({str(e).splitlines()[0]})') from None
    if not isinstance(side, dict) or side.get('measurement') not in KINDS:
        got = side.get('measurement') if isinstance(side, dict) else side
        raise _fail(sidecar, f'"measurement" must be one of {KINDS}, got {got!r}')
    return side


def _units(side: dict, sidecar: Path) -> tuple[float, float]:
    units = side.get('units') or {}
    length, angle = units.get('length', 'm'), units.get('angle', 'rad')
    if length not in LENGTH or angle not in ANGLE:
        raise _fail(sidecar, f'units: length must be one of {list(LENGTH)} and angle one of '
                             f'{list(ANGLE)}, got {length!r} and {angle!r}')
    return LENGTH[length], ANGLE[angle]


def _vector(side: dict, key: str, sidecar: Path, scale: float) -> np.ndarray:
    value = side.get(key, [0.0, 0.0, 0.0])
    try:
        v = np.array(value, dtype=float) * scale
    except (TypeError, ValueError):
        v = np.empty(0)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise _fail(sidecar, f'"{key}" must be 3 numbers (x, y, z), got {value!r}')
    return v


def _poses(path: Path, side: dict, header, rows, length: float, angle: float) -> np.ndarray:
    sidecar = sidecar_of(path)
    fmt = side.get('rotation_format', 'rpy')
    if fmt not in ROTATION_FORMATS:
        raise _fail(sidecar, f'rotation_format must be one of {list(ROTATION_FORMATS)}, got '
                             f'{fmt!r}')
    p = _numbers(path, header, rows, _names(side, 'position', sidecar, 3), 'position') * length
    r = _numbers(path, header, rows, _names(side, 'rotation', sidecar, ROTATION_FORMATS[fmt]),
                 'rotation')
    from scipy.spatial.transform import Rotation
    if fmt == 'rpy':       # R = Rz(yaw) Ry(pitch) Rx(roll), the URDF convention
        R = Rotation.from_euler('xyz', r * angle)
    elif fmt == 'rotvec':
        R = Rotation.from_rotvec(r * angle)
    else:
        norms = np.linalg.norm(r, axis=1)
        if np.any(np.abs(norms - 1.0) > 1e-3):
            line = int(np.flatnonzero(np.abs(norms - 1.0) > 1e-3)[0]) + 2
            raise _fail(path, f'line {line}: the quaternion is not unit ({norms[line - 2]:.4f})')
        R = Rotation.from_quat(r[:, [1, 2, 3, 0]])
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R.as_matrix(), p
    camera = side.get('camera', 'fixed')
    if camera not in ('fixed', 'on_arm'):
        raise _fail(sidecar, f'camera must be fixed or on_arm, got {camera!r}')
    if camera == 'on_arm':        # T_camera_board -> T_board_camera
        from cobot_calib_ros.core.kinematics.identification.measurements import invert_all
        T = invert_all(T)
    return T


def load_measurements(path: str | Path) -> MeasurementFile:
    """The measurements of ``path`` (CSV) and its sidecar (module docstring)."""
    path = Path(path).expanduser()
    side = _sidecar(path)
    sidecar = sidecar_of(path)
    header, rows = _read_csv(path)
    length, angle = _units(side, sidecar)
    kind = side['measurement']
    joints = _names(side, 'joints', sidecar)
    q = _numbers(path, header, rows, joints, 'joint') * angle
    sample = np.arange(len(rows))
    target, values, distances = None, None, ()
    ball = _vector(side, 'ball', sidecar, length)
    weight = _rotation_weight(side, sidecar)
    if kind == 'pose':
        values = _poses(path, side, header, rows, length, angle)
    elif kind == 'points':
        markers = side.get('markers')
        if not isinstance(markers, dict) or not markers:
            raise _fail(sidecar, '"markers" must map each marker to its 3 columns, e.g. '
                                 '{m1: [x1, y1, z1]}')
        per = [_numbers(path, header, rows, _names(markers, k, sidecar, 3), f'marker {k}',
                        blank_ok=True) * length for k in markers]
        seen = [np.isfinite(p).all(axis=1) for p in per]
        sample = np.concatenate([np.flatnonzero(s) for s in seen])
        target = np.concatenate([np.full(int(s.sum()), k) for k, s in enumerate(seen)])
        values = np.concatenate([p[s] for p, s in zip(per, seen)])
        order = np.lexsort((target, sample))
        sample, target, values = sample[order], target[order], values[order]
        q = q[sample]
    elif kind in ('spheres', 'plane'):
        column = side.get('sphere' if kind == 'spheres' else 'plane')
        if kind == 'spheres' and column is None:
            raise _fail(sidecar, '"sphere" must name the column of the sphere ids')
        target = np.zeros(len(rows), dtype=int) if column is None else _numbers(
            path, header, rows, [str(column)], 'id').astype(int)[:, 0]
        if kind == 'spheres':
            try:
                distances = tuple((int(i), int(j), float(d) * length)
                                  for i, j, d in side.get('distances') or ())
            except (TypeError, ValueError):
                raise _fail(sidecar, '"distances" must be [[i, j, D], ...]') from None
    try:
        data = Measurements(kind, q, target, values, distances, ball, weight)
    except ValueError as e:
        raise _fail(path, str(e)) from None
    columns = {h: [r[k] for r in rows] for k, h in enumerate(header)}
    return MeasurementFile(str(path), data, sample, tuple(joints), columns,
                           dict(side.get('frames') or {}), len(rows),
                           _noise(side, sidecar, length), length / angle)


def _rotation_weight(side: dict, sidecar: Path) -> float | None:
    """The sidecar's rotation_weight [m/rad]; None for ``auto``."""
    value = side.get('rotation_weight', DEFAULT_ROTATION_WEIGHT)
    if value == 'auto':
        return None
    try:
        weight = float(value)
    except (TypeError, ValueError):
        weight = -1.0
    if not (weight > 0.0 and np.isfinite(weight)):
        raise _fail(sidecar, f'"rotation_weight" must be a number > 0 [m/rad] or auto, got '
                             f'{value!r}')
    return weight


def _noise(side: dict, sidecar: Path, length: float) -> float:
    """The sidecar's ``noise`` [m]: one row's RMS error as the held-out errors count it."""
    value = side.get('noise', 0.0)
    try:
        noise = float(value) * length
    except (TypeError, ValueError):
        noise = -1.0
    if not (noise >= 0.0 and np.isfinite(noise)):
        raise _fail(sidecar, f'"noise" must be a length >= 0 (one row\'s RMS error, in '
                             f'units.length), got {value!r}')
    return noise


def load_socket_measurements(folder: str | Path, ball=(0.0, 0.0, 0.04)) -> MeasurementFile:
    """A MUKCa folder (loaders.load_socket_data) as spheres: sphere 2 k + socket of the k-th
    location, the known distance between a location's two sockets, a 'location' column."""
    from cobot_calib_ros.loaders import load_socket_data
    sockets = load_socket_data(folder)
    obs = sockets.observations()
    data = Measurements('spheres', obs.q, obs.sphere, distances=obs.known_distances,
                        ball=np.asarray(ball, dtype=float))
    names = [f'joint_a{i + 1}' for i in range(obs.q.shape[1])]
    location = [sockets.locations[i] for i in sockets.location]
    return MeasurementFile(str(folder), data, np.arange(len(obs.q)), tuple(names),
                           {'location': location, 'socket': [str(s) for s in sockets.socket]},
                           {'tip': 'tool0', 'target': 'ball'}, len(obs.q))


def load_dh_table(path: str | Path):
    """KinematicModel (kind 'mdh', core.kinematics.model.dh_model) of a DH table YAML:
    name, joints, rows [[d, theta, r, alpha], ...] (m, rad), limits [[lower, upper], ...]."""
    from cobot_calib_ros.core.kinematics.model import dh_model
    path = Path(path).expanduser()
    try:
        doc = yaml.safe_load(path.read_text(encoding='utf-8'))
        return dh_model(str(doc['name']), tuple(doc['joints']), doc['rows'], doc['limits'])
    except OSError as e:
        raise _fail(path, f'cannot read ({e.strerror})') from None
    except (yaml.YAMLError, KeyError, TypeError, ValueError) as e:
        raise _fail(path, f'not a DH table (name, joints, rows [[d, theta, r, alpha]], '
                          f'limits): {e}') from None


def robot_model(source: Path, frames: dict, urdf: str | None, base_link: str | None,
                tip_link: str | None, dh: str | None):
    """The arm of a measurement source: a DH table, or a URDF's chain from ``base_link`` to
    ``tip_link`` (default the sidecar's frames; a MUKCa folder: iiwa14.urdf beside it)."""
    from cobot_calib_ros.core.kinematics.urdf import model_from_urdf
    if dh:
        return load_dh_table(dh)
    robot = robot_description(source, frames, urdf, base_link, tip_link)
    try:
        return model_from_urdf(robot.urdf, robot.base_link, robot.tip_link, robot.name,
                               free_pitch=True)
    except ValueError as e:
        raise ValueError(f'--urdf {robot.urdf_file}: {e}') from None


def robot_description(source: Path, frames: dict, urdf: str | None, base_link: str | None,
                      tip_link: str | None):
    """The URDF of a measurement source's arm (core UrdfRobot with its text: what the
    calibrated URDF is written back into), as :func:`robot_model` chooses it."""
    from cobot_calib_ros.core.kinematics.robots import UrdfRobot
    if urdf:
        path = Path(urdf).expanduser()
    elif source.is_dir() and (source.parent / 'iiwa14.urdf').is_file():
        path = source.parent / 'iiwa14.urdf'              # MUKCa's layout
    else:
        raise ValueError('give the robot: --urdf FILE --base-link L --tip-link L, or --dh FILE')
    base = base_link or frames.get('base') or 'base_link'
    tip = tip_link or frames.get('tip')
    if not tip:
        raise ValueError('give --tip-link (the sidecar names no frames.tip)')
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as e:
        raise ValueError(f'--urdf {path}: cannot read ({e.strerror})') from None
    return UrdfRobot(path.stem, str(path), base, tip, urdf=text)
