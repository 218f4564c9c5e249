"""The simulation part of a cell file (``simulation:``): truth, noise, rates, the true probe.

Read only by the mock robot and tests. The nominal part (``cell:``) is core.cell's.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import math
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.cell import Cell, CellReader
from cobot_calib_ros.loaders import load_cell, read_cell_text
from cobot_calib_ros.core.kinematics import KinematicModel
from cobot_calib_ros.core.sensors.probe import ProbeCurve
from cobot_calib_ros.sim.spheres import LaserTracker, SphereTruth
from cobot_calib_ros.sim.world import HeightField, TrueMarker, World

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Noise:
    repeatability_sigma: float = 3.0e-5  # unidirectional tool repeatability per axis, at
    #                                      repeatability_centre [m]
    repeatability_centre: tuple[float, float] = (0.0, 0.0)  # user x, y where it is best [m]
    repeatability_growth: float = 0.0    # sigma * (1 + growth d^2), d from the centre [1/m^2]
    encoder_sigma: float = 2.0e-6        # joint encoder noise per sample [rad]
    touch_sigma: float = 2.0e-5          # operator centring error when touching a marker [m]
    probe_voltage_sigma: float = 4.0e-3  # [V] (8 V/mm sensitivity: 0.5 um)


@dataclass(frozen=True)
class CameraTruth:
    """The real wrist camera (``simulation: camera:``): true hand-eye, true intrinsics and
    image quality; sim.camera renders with it. ``K`` (3, 3) [px] / ``D`` / ``distortion_model``
    are the true lens (``intrinsics: [fx, fy, cx, cy]``, ``distortion_model``, ``distortion``,
    as in ``cell: camera:``); None: the lens is the nominal one the cell gives the suite."""

    T_flange_optical: Array              # (4, 4) true flange -> optical frame
    noise_sigma: float = 1.5             # [grey levels]
    blur_sigma: float = 0.6              # [px]
    light_gradient: tuple[float, float] = (0.0, 0.0)  # gain change left->right, top->bottom [1]
    vignetting: float = 0.0              # gain lost at the image corners [1]
    K: Array | None = None               # (3, 3) true camera matrix at the cell's resolution
    D: Array | None = None               # true distortion coefficients
    distortion_model: str = 'plumb_bob'

    def true_camera(self, nominal):
        """The true lens (a CameraModel) on the nominal one's sensor (size, name): the nominal
        itself when the truth gives none."""
        if self.K is None:
            return nominal
        from cobot_calib_ros.core.landmarks.camera import CameraModel
        return CameraModel(nominal.width, nominal.height, self.K,
                           np.zeros(0) if self.D is None else self.D, self.distortion_model,
                           nominal.name)


@dataclass(frozen=True)
class Simulation:
    """Everything the mock robot knows and the calibration path must not."""

    cell: Cell                  # the nominal cell this simulation is of
    seed: int
    time_scale: float           # simulated motion time = real motion time * time_scale
    parameter_errors: dict[str, float]
    random_errors: tuple[float, float]  # sigma of random (length [m], angle [rad]) errors
    world: World
    noise: Noise
    probe: ProbeCurve           # the probe's true curve
    joint_states_hz: float
    probe_hz: float
    spheres: SphereTruth | None = None   # the sphere plate, if the cell has one
    camera: CameraTruth | None = None    # the wrist camera, if the cell has one
    T_flange_tool_true: Array | None = None   # (4, 4) where the tool tip really is on the
    #                                           flange (what a TCP calibration finds); given
    #                                           None: the cell's T_flange_tool is exact

    def __post_init__(self) -> None:
        if self.T_flange_tool_true is None:
            object.__setattr__(self, 'T_flange_tool_true', self.cell.T_flange_tool)

    def true_parameters(self, model: KinematicModel) -> Array:
        """Nominal parameters plus the explicit and seeded random kinematic errors."""
        rng = np.random.default_rng(self.seed + 1)
        names = model.parameter_names
        length_sigma, angle_sigma = self.random_errors
        is_angle = np.array([n.split('_')[0] in ('alpha', 'theta', 'roll', 'pitch', 'yaw')
                             for n in names])
        true = model.nominal + rng.normal(0.0, 1.0, len(names)) * np.where(
            is_angle, angle_sigma, length_sigma)
        for name, delta in self.parameter_errors.items():
            if name not in names:
                raise ValueError(f'kinematic error for unknown parameter {name!r}')
            true[names.index(name)] += delta
        return true

    def repeatability_sigma_at(self, p_base: Array) -> float:
        """Tool repeatability sigma per axis [m] with the tool at ``p_base``.

        Best at the repeatability centre, growing with the squared horizontal distance from
        it (user frame): the paper's robot repeated 2-3 times worse at the corners of the
        "wide" set-up than at its centre or in the "close" one (Tables 4-5, reference rows).
        """
        x, y, _ = frames.apply(frames.invert(self.world.T_base_user), p_base)
        cx, cy = self.noise.repeatability_centre
        return self.noise.repeatability_sigma * (
            1.0 + self.noise.repeatability_growth * ((x - cx) ** 2 + (y - cy) ** 2))

    def layout_repeatability_sigma(self) -> float:
        """RMS of :meth:`repeatability_sigma_at` over the layout's marker tops [m]."""
        sigmas = [self.repeatability_sigma_at(p) for p in self.world.true_points_base()]
        return float(np.sqrt(np.mean(np.square(sigmas))))


def with_true_lens(sim: Simulation, K: ArrayLike, D: ArrayLike,
                   distortion_model: str = 'plumb_bob') -> Simulation:
    """``sim`` with the wrist camera's true lens K (3, 3) [px] and D (as ``simulation:
    camera: intrinsics / distortion`` gives it); the suite keeps the nominal one."""
    camera = dataclasses.replace(sim.camera, K=np.asarray(K, dtype=float),
                                 D=np.asarray(D, dtype=float), distortion_model=distortion_model)
    return dataclasses.replace(sim, camera=camera)


def load_simulation(path: str | Path, layout: str | None = None) -> Simulation:
    """The simulation of a cell file (both its ``cell:`` and ``simulation:`` parts)."""
    cell = load_cell(path, layout)
    path, text = read_cell_text(path)
    r = CellReader(path, text, 'simulation')
    seed = int(r.number('seed', default=0))
    rng = np.random.default_rng(seed)
    field = _height_field(r, rng)
    world = World(frames.from_xyz_rpy(r.vector('user_frame_true', 'xyz', length=3),
                                      r.vector('user_frame_true', 'rpy', length=3)),
                  _true_markers(r, cell, field, rng), field)
    errors = r.get('kinematic_errors', default={})
    return Simulation(
        cell=cell, seed=seed, time_scale=r.number('time_scale', default=1.0),
        parameter_errors={k: float(v) for k, v in (errors.get('explicit') or {}).items()},
        random_errors=(r.number('kinematic_errors', 'random_length_sigma', default=0.0),
                       r.number('kinematic_errors', 'random_angle_sigma', default=0.0)),
        world=world, noise=_noise(r), probe=_probe(r),
        joint_states_hz=r.number('rates', 'joint_states_hz', default=1000.0),
        probe_hz=r.number('rates', 'probe_hz', default=200.0),
        spheres=_spheres(r, cell), camera=_camera(r, cell), T_flange_tool_true=_tool(r))


def _tool(r: CellReader) -> Array | None:
    """The real tool (``T_flange_tool_true: {xyz, rpy}``), None: the nominal one is exact."""
    if r.get('T_flange_tool_true', default=None) is None:
        return None
    return frames.from_xyz_rpy(r.vector('T_flange_tool_true', 'xyz', length=3),
                               r.vector('T_flange_tool_true', 'rpy', length=3))


def _spheres(r: CellReader, cell: Cell) -> SphereTruth | None:
    """The true plate; nominal where the file gives no truth."""
    plate = cell.spheres
    if plate is None:
        return None
    keys = ('spheres',)
    if r.get(*keys, 'plate_true', default=None) is None:
        T_plate = plate.T_base_plate
    else:
        T_plate = frames.from_xyz_rpy(r.vector(*keys, 'plate_true', 'xyz', length=3),
                                      r.vector(*keys, 'plate_true', 'rpy', length=3))
    coupling = plate.T_flange_coupling.copy()
    coupling[:3, 3] = r.vector(*keys, 'p_flange_coupling_true', length=3,
                               default=plate.T_flange_coupling[:3, 3].tolist())
    tracker = LaserTracker(
        frames.from_xyz_rpy(r.vector(*keys, 'laser_tracker', 'xyz', length=3, default=[2, 0, 0]),
                            r.vector(*keys, 'laser_tracker', 'rpy', length=3, default=[0, 0, 0])),
        r.number(*keys, 'laser_tracker', 'sigma', default=2.5e-5))
    return SphereTruth(frames.apply(T_plate, plate.centres_plate), coupling,
                       r.number(*keys, 'capture_radius', default=0.008),
                       r.number(*keys, 'compliance_sigma', default=3.0e-6), tracker)


def _camera(r: CellReader, cell: Cell) -> CameraTruth | None:
    """The real wrist camera; the nominal hand-eye where the file gives no truth."""
    if cell.camera is None:
        return None
    keys = ('camera',)
    if r.get(*keys, 'T_flange_optical_true', default=None) is None:
        T = cell.camera.T_flange_optical
    else:
        T = frames.from_xyz_rpy(r.vector(*keys, 'T_flange_optical_true', 'xyz', length=3),
                                r.vector(*keys, 'T_flange_optical_true', 'rpy', length=3))
    defaults = CameraTruth(T)
    K = D = None
    model = 'plumb_bob'
    if r.get(*keys, 'intrinsics', default=None) is not None:
        fx, fy, cx, cy = r.vector(*keys, 'intrinsics', length=4)
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        D = r.vector(*keys, 'distortion', default=[])
        model = str(r.get(*keys, 'distortion_model', default='plumb_bob'))
    return CameraTruth(
        T, noise_sigma=r.number(*keys, 'noise_sigma', default=defaults.noise_sigma),
        blur_sigma=r.number(*keys, 'blur_sigma', default=defaults.blur_sigma),
        light_gradient=tuple(float(v) for v in r.vector(
            *keys, 'light_gradient', length=2, default=list(defaults.light_gradient))),
        vignetting=r.number(*keys, 'vignetting', default=defaults.vignetting),
        K=K, D=D, distortion_model=model)


def _height_field(r: CellReader, rng: np.random.Generator) -> HeightField:
    keys = ('table', 'height_field')
    phase = r.get(*keys, 'phase', default=None)
    if phase is None:
        phase = rng.uniform(0.0, 2.0 * math.pi, 2)
    return HeightField(amplitude=r.number(*keys, 'amplitude', default=3.0e-4),
                       wavelength=r.number(*keys, 'wavelength', default=0.8),
                       tilt=tuple(r.vector(*keys, 'tilt', length=2, default=[0.0, 0.0])),
                       phase=tuple(float(p) for p in phase))


def _true_markers(r: CellReader, cell: Cell, field: HeightField,
                  rng: np.random.Generator) -> tuple[TrueMarker, ...]:
    sigma = r.number('marker_height_sigma', default=5.0e-5)
    return tuple(TrueMarker(m, float(field(*m.xy)), float(rng.normal(0.0, sigma)))
                 for m in cell.markers)


def _noise(r: CellReader) -> Noise:
    defaults = Noise()
    values = {}
    for name, default in vars(defaults).items():
        if isinstance(default, tuple):
            values[name] = tuple(r.vector('noise', name, length=len(default),
                                          default=list(default)))
        else:
            values[name] = r.number('noise', name, default=default)
    return Noise(**values)


def _probe(r: CellReader) -> ProbeCurve:
    distance = r.vector('probe', 'distance')
    voltage = r.vector('probe', 'voltage', length=len(distance))
    return ProbeCurve(tuple(distance.tolist()), tuple(voltage.tolist()))
