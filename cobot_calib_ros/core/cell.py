"""The simulated cell: true user frame, uneven table, aluminium markers, proximity probe.

Everything here is ground truth that a real cell never tells; the mock robot node uses it to
decide where the tool really is and what the probe really reads. All lengths in metres.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
import yaml

from cobot_calib_ros.core import frames

Array = NDArray[np.float64]


@dataclass(frozen=True)
class HeightField:
    """Table height error dz(x, y) [m] over the user-frame xy plane [m]."""

    amplitude: float = 3.0e-4
    wavelength: float = 0.8
    tilt: tuple[float, float] = (0.0, 0.0)  # dz/dx, dz/dy [m/m]
    phase: tuple[float, float] = (0.0, 0.0)  # [rad]

    def __call__(self, x: Array | float, y: Array | float) -> Array:
        k = 2.0 * math.pi / self.wavelength
        wave = np.sin(k * np.asarray(x) + self.phase[0]) * np.sin(k * np.asarray(y) + self.phase[1])
        return self.amplitude * wave + self.tilt[0] * np.asarray(x) + self.tilt[1] * np.asarray(y)


@dataclass(frozen=True)
class Marker:
    """An aluminium block glued on the table; axis-aligned in the user frame."""

    name: str
    xy: tuple[float, float]       # nominal centre in the user frame [m]
    size: tuple[float, float, float]  # x, y, z extent [m] (50 x 30 x 20 mm in the paper)
    base_z: float                 # true z of the table under it, user frame [m]
    height_error: float           # true height minus nominal size[2] [m]

    @property
    def top_z(self) -> float:
        return self.base_z + self.size[2] + self.height_error

    @property
    def nominal_top(self) -> Array:
        """Top-face centre as the user knows it (flat table, nominal height)."""
        return np.array([self.xy[0], self.xy[1], self.size[2]])

    @property
    def true_top(self) -> Array:
        return np.array([self.xy[0], self.xy[1], self.top_z])

    def box(self) -> tuple[Array, Array]:
        half = np.array(self.size[:2]) / 2.0
        lo = np.array([self.xy[0] - half[0], self.xy[1] - half[1], self.base_z])
        hi = np.array([self.xy[0] + half[0], self.xy[1] + half[1], self.top_z])
        return lo, hi


def ray_box_distance(origin: Array, direction: Array, lo: Array, hi: Array) -> float:
    """Distance along a unit ray to where it enters an axis-aligned box; inf if it misses."""
    with np.errstate(divide='ignore', invalid='ignore'):
        t1 = (lo - origin) / direction
        t2 = (hi - origin) / direction
    t1 = np.where(np.isnan(t1), -np.inf, t1)
    t2 = np.where(np.isnan(t2), np.inf, t2)
    t_near = float(np.max(np.minimum(t1, t2)))
    t_far = float(np.min(np.maximum(t1, t2)))
    if t_near > t_far or t_far < 0.0 or t_near < 0.0:
        return math.inf
    return t_near


@dataclass(frozen=True)
class World:
    """The true cell: where the user frame is and what stands on the table."""

    T_base_user: Array
    markers: tuple[Marker, ...]
    height_field: HeightField

    def marker(self, name: str) -> Marker | None:
        return next((m for m in self.markers if m.name == name), None)

    @property
    def point_names(self) -> list[str]:
        return [m.name for m in self.markers]

    def true_points_base(self) -> Array:
        """(N, 3) true marker top-face centres in the base frame [m]."""
        return frames.apply(self.T_base_user, np.array([m.true_top for m in self.markers]))

    def nominal_points_user(self) -> Array:
        return np.array([m.nominal_top for m in self.markers])

    def probe_gap(self, T_base_tool: Array) -> float:
        """Gap [m] along the tool z axis from the probe tip to the nearest marker face."""
        T_user_tool = frames.invert(self.T_base_user) @ T_base_tool
        origin, direction = T_user_tool[:3, 3], T_user_tool[:3, 2]
        gaps = [ray_box_distance(origin, direction, *m.box()) for m in self.markers]
        return min(gaps, default=math.inf)


@dataclass(frozen=True)
class ProbeCurve:
    """Calibration table of the inductive probe: voltage [V] against gap [m]."""

    distance: tuple[float, ...]   # increasing [m]
    voltage: tuple[float, ...]    # [V], monotonic

    @property
    def min_range(self) -> float:
        return self.distance[0]

    @property
    def max_range(self) -> float:
        return self.distance[-1]

    def to_voltage(self, gap: float) -> float:
        """Sensor output for a gap; saturates at the range ends like the real probe."""
        g = min(max(gap, self.min_range), self.max_range)
        return float(np.interp(g, self.distance, self.voltage))

    def to_distance(self, voltage: float) -> float:
        """Gap for a voltage by linear interpolation in the table (voltage may decrease)."""
        v = np.asarray(self.voltage)
        d = np.asarray(self.distance)
        if v[0] > v[-1]:
            v, d = v[::-1], d[::-1]
        return float(np.interp(voltage, v, d))


@dataclass(frozen=True)
class Noise:
    repeatability_sigma: float = 3.0e-5  # unidirectional tool repeatability, per axis, at
    #                                      repeatability_centre [m]
    repeatability_centre: tuple[float, float] = (0.0, 0.0)  # user x, y where it is best [m]
    repeatability_growth: float = 0.0    # sigma * (1 + growth d^2), d from the centre [1/m^2]
    encoder_sigma: float = 2.0e-6        # joint encoder noise per sample [rad]
    touch_sigma: float = 2.0e-5          # operator centring error when touching a marker [m]
    probe_voltage_sigma: float = 4.0e-3  # [V] (8 V/mm sensitivity: 0.5 um)


@dataclass(frozen=True)
class Cell:
    """A whole scenario, from one cell YAML file."""

    name: str
    robot: str
    seed: int
    base_frame: str
    tool_frame: str
    user_frame: str
    tool_offset: Array          # (4, 4) flange -> probe tip
    home: Array                 # (n,) joint positions [rad]
    parameter_errors: dict[str, float]
    random_errors: tuple[float, float]  # sigma of random (length [m], angle [rad]) errors
    world: World
    layout: str
    layouts: dict[str, dict[str, tuple[float, float]]]
    noise: Noise
    probe: ProbeCurve
    joint_states_hz: float
    probe_hz: float
    time_scale: float
    approach_gap: float
    raw: dict = field(repr=False, default_factory=dict)


def repeatability_sigma_at(cell: Cell, p_base: Array) -> float:
    """Tool repeatability sigma per axis [m] with the tool at ``p_base``.

    Best at the cell's repeatability centre, growing with the squared horizontal distance
    from it (user frame): the paper's robot repeated 2-3 times worse at the corners of the
    "wide" set-up than at its centre or in the "close" one (Tables 4-5, reference rows).
    """
    x, y, _ = frames.apply(frames.invert(cell.world.T_base_user), p_base)
    cx, cy = cell.noise.repeatability_centre
    return cell.noise.repeatability_sigma * (
        1.0 + cell.noise.repeatability_growth * ((x - cx) ** 2 + (y - cy) ** 2))


def layout_repeatability_sigma(cell: Cell) -> float:
    """RMS of :func:`repeatability_sigma_at` over the layout's marker tops [m]."""
    sigmas = [repeatability_sigma_at(cell, p) for p in cell.world.true_points_base()]
    return float(np.sqrt(np.mean(np.square(sigmas))))


def _height_field(cfg: dict, rng: np.random.Generator) -> HeightField:
    phase = cfg.get('phase')
    if phase is None:
        phase = tuple(float(p) for p in rng.uniform(0.0, 2.0 * math.pi, 2))
    return HeightField(amplitude=float(cfg.get('amplitude', 3.0e-4)),
                       wavelength=float(cfg.get('wavelength', 0.8)),
                       tilt=tuple(float(t) for t in cfg.get('tilt', (0.0, 0.0))),
                       phase=tuple(float(p) for p in phase))


def _markers(layout: dict, cfg: dict, field_: HeightField,
             rng: np.random.Generator) -> tuple[Marker, ...]:
    size = tuple(float(s) for s in cfg.get('size', (0.050, 0.030, 0.020)))
    sigma = float(cfg.get('height_sigma', 5.0e-5))
    markers = []
    for name, xy in layout.items():
        x, y = float(xy[0]), float(xy[1])
        markers.append(Marker(name, (x, y), size, float(field_(x, y)),
                              float(rng.normal(0.0, sigma))))
    return tuple(markers)


def _tool_offset(cfg: dict) -> Array:
    return frames.from_xyz_rpy(cfg.get('xyz', (0.0, 0.0, 0.1)), cfg.get('rpy', (0.0, 0.0, 0.0)))


def _probe(cfg: dict) -> ProbeCurve:
    return ProbeCurve(tuple(float(d) for d in cfg['distance']),
                      tuple(float(v) for v in cfg['voltage']))


def cell_from_dict(raw: dict, layout: str | None = None) -> Cell:
    """Build a Cell from the parsed YAML (the `cell:` mapping); seeded and reproducible."""
    seed = int(raw.get('seed', 0))
    rng = np.random.default_rng(seed)
    layouts = {k: {n: tuple(p) for n, p in v.items()} for k, v in raw['layouts'].items()}
    layout = layout or raw.get('layout', next(iter(layouts)))
    if layout not in layouts:
        raise ValueError(f'layout {layout!r} is not in the cell; choose one of {sorted(layouts)}')
    field_ = _height_field(raw.get('table', {}).get('height_field', {}), rng)
    markers = _markers(layouts[layout], raw.get('markers', {}), field_, rng)
    uf = raw['user_frame_true']
    world = World(frames.from_xyz_rpy(uf['xyz'], uf['rpy']), markers, field_)
    errors = raw.get('kinematic_errors', {})
    noise = Noise(**{k: tuple(float(x) for x in v) if isinstance(v, list) else float(v)
                     for k, v in raw.get('noise', {}).items()})
    rates = raw.get('rates', {})
    return Cell(
        name=str(raw.get('name', 'cell')), robot=str(raw['robot']), seed=seed,
        base_frame=str(raw.get('base_frame', 'base_link')),
        tool_frame=str(raw.get('tool_frame', 'tool0')),
        user_frame=str(raw.get('user_frame', 'user_frame')),
        tool_offset=_tool_offset(raw.get('tool_offset', {})),
        home=np.asarray(raw['home'], dtype=float),
        parameter_errors={k: float(v) for k, v in errors.get('explicit', {}).items()},
        random_errors=(float(errors.get('random_length_sigma', 0.0)),
                       float(errors.get('random_angle_sigma', 0.0))),
        world=world, layout=layout, layouts=layouts, noise=noise, probe=_probe(raw['probe']),
        joint_states_hz=float(rates.get('joint_states_hz', 1000.0)),
        probe_hz=float(rates.get('probe_hz', 200.0)),
        time_scale=float(raw.get('time_scale', 1.0)),
        approach_gap=float(raw.get('approach_gap', 1.2e-3)), raw=raw)


def load_cell(path: str | Path, layout: str | None = None) -> Cell:
    """Read a cell YAML file (top-level key `cell`)."""
    with open(path, encoding='utf-8') as f:
        doc = yaml.safe_load(f)
    if not isinstance(doc, dict) or 'cell' not in doc:
        raise ValueError(f'{path}: expected a mapping with a top-level "cell" key')
    return cell_from_dict(doc['cell'], layout)


def true_parameters(cell: Cell, nominal: Array, names: tuple[str, ...]) -> Array:
    """Nominal parameters plus the cell's explicit and seeded random kinematic errors."""
    rng = np.random.default_rng(cell.seed + 1)
    length_sigma, angle_sigma = cell.random_errors
    is_angle = np.array([n.split('_')[0] in ('alpha', 'theta', 'roll', 'pitch', 'yaw')
                         for n in names])
    sigma = np.where(is_angle, angle_sigma, length_sigma)
    true = nominal + rng.normal(0.0, 1.0, len(nominal)) * sigma
    for name, delta in cell.parameter_errors.items():
        if name not in names:
            raise ValueError(f'kinematic error for unknown parameter {name!r}')
        true[names.index(name)] += delta
    return true


def tool_down_orientation(T_base_user: Array, axis: str = 'z') -> Array:
    """(3, 3) tool orientation in base whose z axis probes the marker along the user axis.

    'z': pointing down onto the top face; 'x' / 'y': pointing along +x / +y of the user frame
    at the marker's side face.
    """
    R_user = {
        'z': frames.rot_x(math.pi),
        'x': frames.rot_y(math.pi / 2.0),
        'y': frames.rot_x(-math.pi / 2.0),
    }[axis]
    return T_base_user[:3, :3] @ R_user
