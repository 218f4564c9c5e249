"""Tool centre point from flange poses: position, orientation, and the gate.

Position. With the tool tip on one fixed point c (base frame) at every approach i, the flange
pose (R_i, p_i) gives R_i t + p_i = c, t the tip in the flange frame: stacked,
[R_i | -I] [t; c] = -p_i (3N x 6), solved by SVD. It has rank 6 only when the rotations differ
about at least two non-parallel axes; its condition number is the factor by which the touch
noise grows into t, so approaches too alike (condition above :data:`MAX_CONDITION`) are refused
naming the pairs that are (a core.errors.Refusal, DEGENERATE_POINTS: :func:`too_alike`).
The algebraic solution already is the least squares of the tip residuals R_i t + p_i - c
(they are linear in t and c); the refinement (scipy least_squares, soft-L1 at the touch
noise) keeps one slipped touch from pulling the others.

Orientation (ABB's 5- and 6-point methods): at the reference approach (the first), the tip is
moved without turning the tool onto an elongator point along the tool's z (and one along its
x); z = normalise(tip_Z - tip_ref) (its sign flipped when the point lies back up the tool's
axis, a negative distance), x = tip_X - tip_ref made orthogonal to z (else the flange x),
y = z x x, all in the flange frame of the reference approach.

Units: metres and radians throughout (reports convert to mm where they print).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal

Array = NDArray[np.float64]
MIN_APPROACHES = 3
MAX_CONDITION = 20.0    # [1] a cone of ~10 deg tilts; the touch noise grows by this into t
ALIKE_DEG = 10.0        # approaches closer than this [deg] are named in a refusal
MIN_ELONGATION = 0.005  # [m] an elongator point nearer the reference gives no direction
ORIENTATION_METHODS = ('none', 'z', 'zx')


def too_alike(message: str) -> Refusal:
    """The refusal of approaches that do not determine the tool (DEGENERATE_POINTS); the
    message names those too alike."""
    return Refusal(Failure(ErrorCode.DEGENERATE_POINTS, message))


@dataclass(frozen=True)
class TcpPosition:
    """The solved tip: ``t`` in the flange frame, ``c`` the fixed point in the base frame."""

    t: Array                 # (3,) [m]
    c: Array                 # (3,) [m]
    residuals: Array         # (N, 3) tips R_i t + p_i minus c, base frame [m]
    condition: float         # of the stacked system [1]
    covariance: Array        # (6, 6) of [t; c] from the residuals' scatter [m^2] (nan: N = 2)
    linear: Array            # (6,) the algebraic solution [t; c] before the refinement [m]

    @property
    def distances(self) -> Array:
        """(N,) each approach's tip distance from the fixed point [m]."""
        return np.linalg.norm(self.residuals, axis=1)

    @property
    def mean_residual_m(self) -> float:
        return float(self.distances.mean())

    @property
    def max_residual_m(self) -> float:
        return float(self.distances.max())

    @property
    def rms_per_axis(self) -> float:
        """RMS of the residual components [m] (the touch noise per axis, if that explains it)."""
        return float(np.sqrt(np.mean(self.residuals ** 2)))


@dataclass(frozen=True)
class TcpSolution:
    """Position and orientation of one tool: T_flange_tool, and how it was found."""

    position: TcpPosition
    R_flange_tool: Array     # (3, 3) identity when no orientation method was used
    method: str              # one of ORIENTATION_METHODS
    turn_rad: float = 0.0    # largest turn of the flange between the reference and an
    #                          elongator touch (they must keep the orientation) [rad]

    @property
    def T_flange_tool(self) -> Array:
        return frames.make_transform(self.R_flange_tool, self.position.t)


def _system(R: Array, p: Array) -> tuple[Array, Array]:
    n = len(R)
    A = np.concatenate([R, np.broadcast_to(-np.eye(3), (n, 3, 3))], axis=2).reshape(3 * n, 6)
    return A, -p.reshape(3 * n)


def _check_poses(T: ArrayLike) -> Array:
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f'expected (N, 4, 4) finite flange poses, got shape {T.shape}')
    if len(T) < MIN_APPROACHES:
        raise ValueError(f'{len(T)} approaches: at least {MIN_APPROACHES} (better 4 to 8) '
                         'are needed to determine the tool')
    return T


def too_alike_message(R: Array, null_vector: Array, condition: float) -> str:
    """Why rotations ``R`` (N, 3, 3) do not determine the tool: the pairs closer than
    ALIKE_DEG (numbered from 1), else the one axis they all turn about."""
    pairs = sorted((frames.rotation_angle(R[i] @ R[j].T), i, j)
                   for i in range(len(R)) for j in range(i + 1, len(R)))
    close = [f'approaches {i + 1} and {j + 1} differ by {math.degrees(a):.1f} deg'
             for a, i, j in pairs if math.degrees(a) < ALIKE_DEG]
    head = f'the approaches are too alike to determine the tool (condition {condition:.0f} > ' \
           f'{MAX_CONDITION:.0f}): '
    advice = f'; tilt them >= {2 * ALIKE_DEG:.0f} deg apart about different axes'
    if close:
        return head + ', '.join(close) + advice
    axis = null_vector[3:] / (np.linalg.norm(null_vector[3:]) or 1.0)
    return head + (f'they all turn about one axis (base direction '
                   f'{np.round(axis, 2).tolist()})' + advice)


def check_determined(R: ArrayLike) -> float:
    """The condition number of the system of rotations ``R`` (N, 3, 3) (flange or tool
    orientations alike: a constant tool rotation does not change it); a :func:`too_alike`
    Refusal when it is above MAX_CONDITION. A plan is checked before anything moves."""
    R = np.asarray(R, dtype=float)
    A, _ = _system(R, np.zeros((len(R), 3)))
    _, s, Vt = np.linalg.svd(A, full_matrices=False)
    condition = float(s[0] / s[-1]) if s[-1] > 0 else math.inf
    if condition > MAX_CONDITION:
        raise too_alike(too_alike_message(R, Vt[-1], condition))
    return condition


def solve_position(T_base_flange: ArrayLike, robust_scale: float = 5e-5) -> TcpPosition:
    """The tip and the fixed point from (N, 4, 4) flange poses in the base frame.

    Refusal (DEGENERATE_POINTS) when the approaches do not determine them; ValueError for
    bad input.
    ``robust_scale`` [m]: where the refinement's soft-L1 loss turns linear (the touch noise).
    """
    T = _check_poses(T_base_flange)
    condition = check_determined(T[:, :3, :3])
    A, b = _system(T[:, :3, :3], T[:, :3, 3])
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    linear = Vt.T @ ((U.T @ b) / s)
    from scipy.optimize import least_squares    # here: importing it takes 0.3 s
    refined = least_squares(lambda x: A @ x - b, linear, loss='soft_l1',
                            f_scale=robust_scale, method='trf', x_scale=1.0).x
    residuals = (A @ refined - b).reshape(-1, 3)
    dof = A.shape[0] - 6
    sigma2 = float(np.sum(residuals ** 2) / dof) if dof > 0 else math.nan
    covariance = sigma2 * (Vt.T @ np.diag(1.0 / s ** 2) @ Vt)
    return TcpPosition(refined[:3], refined[3:], residuals, condition, covariance, linear)


def _direction(T_ref: Array, t: Array, elongator: tuple[ArrayLike, float], axis: str) -> Array:
    """The unit direction of ``axis`` in the reference flange frame from an elongator touch
    (pose, signed distance along the axis [m]: only its sign is used, the operator's
    distance need not be exact). ValueError when the tip barely moved."""
    T, distance = elongator
    d = frames.apply(np.asarray(T, dtype=float), t) - frames.apply(T_ref, t)
    moved = float(np.linalg.norm(d))
    if moved < MIN_ELONGATION:
        raise ValueError(f'the {axis} elongator point is {moved * 1e3:.1f} mm from the '
                         f'reference: at least {MIN_ELONGATION * 1e3:.0f} mm are needed')
    return math.copysign(1.0, distance) * (T_ref[:3, :3].T @ d) / moved


def tool_orientation(T_ref: ArrayLike, t: ArrayLike, z: tuple[ArrayLike, float],
                     x: tuple[ArrayLike, float] | None = None) -> Array:
    """(3, 3) R_flange_tool from the reference flange pose (4, 4, base frame), the tip ``t``
    and the elongator touches along z (and x): each (flange pose, signed distance along that
    tool axis [m]). Without x, the flange x made orthogonal to z. ValueError when an
    elongator point is too near the reference or x lies along z."""
    T_ref = np.asarray(T_ref, dtype=float)
    t = np.asarray(t, dtype=float)
    z_dir = _direction(T_ref, t, z, 'z')
    x_dir = np.array([1.0, 0.0, 0.0]) if x is None else _direction(T_ref, t, x, 'x')
    x_dir = x_dir - (x_dir @ z_dir) * z_dir
    if np.linalg.norm(x_dir) < 0.1:
        raise ValueError('the x elongator point lies along the tool z: it must be off the '
                         'tool axis' if x is not None else
                         'the tool z is along the flange x: give an x elongator point')
    x_dir /= np.linalg.norm(x_dir)
    return np.column_stack([x_dir, np.cross(z_dir, x_dir), z_dir])


def solve_tcp(approaches: ArrayLike,
              elongators: Mapping[str, tuple[ArrayLike, float]] | None = None,
              robust_scale: float = 5e-5) -> TcpSolution:
    """Position from the approaches' (N, 4, 4) flange poses, orientation from ``elongators``
    {'z': (pose, signed distance)[, 'x': ...]} touched from the first approach's orientation
    (none: position only)."""
    position = solve_position(approaches, robust_scale)
    elongators = dict(elongators or {})
    if not elongators:
        return TcpSolution(position, np.eye(3), 'none')
    if 'z' not in elongators or set(elongators) - {'z', 'x'}:
        raise ValueError(f'elongator points {sorted(elongators)}: give z, or z and x')
    T_ref = np.asarray(approaches, dtype=float)[0]
    R = tool_orientation(T_ref, position.t, elongators['z'], elongators.get('x'))
    turn = max(frames.rotation_angle(T_ref[:3, :3].T @ np.asarray(T, dtype=float)[:3, :3])
               for T, _ in elongators.values())
    return TcpSolution(position, R, 'zx' if 'x' in elongators else 'z', float(turn))


@dataclass(frozen=True)
class GateLimits:
    """What a TCP must satisfy to become active."""

    touch_sigma: float = 5e-5        # [m] per axis: the operator's centring and the arm
    confidence: float = 0.999        # of the chi-square test of the residuals
    max_tool_length: float = 1.0     # [m] no cobot tool reaches further from the flange
    max_nominal_difference: float = 0.02   # [m] from the cell's T_flange_tool (its own tool)
    max_turn_rad: float = math.radians(1.0)  # elongator touches keep the orientation


def gate_problem(solution: TcpSolution, limits: GateLimits = GateLimits(),
                 nominal: ArrayLike | None = None) -> Failure | None:
    """None when ``solution`` may become the tool's active TCP, else an IMPLAUSIBLE_FIT
    Failure saying why not (and what to do).
    ``nominal``: the cell's (4, 4) T_flange_tool when this is the cell's tool."""
    pos = solution.position
    dof = pos.residuals.size - 6
    if dof > 0:
        from scipy.stats import chi2        # here: importing scipy.stats takes 0.35 s
        bound = limits.touch_sigma * math.sqrt(chi2.ppf(limits.confidence, dof) / dof)
        rms = math.sqrt(float(np.sum(pos.residuals ** 2)) / dof)
        if rms > bound:
            return Failure(ErrorCode.IMPLAUSIBLE_FIT,
                           f'residual {rms * 1e3:.3f} mm per axis (mean '
                    f'{pos.mean_residual_m * 1e3:.3f} mm, max {pos.max_residual_m * 1e3:.3f} '
                    'mm) is more than the touch noise '
                    f'({limits.touch_sigma * 1e3:.3f} mm) explains (<= {bound * 1e3:.3f} mm): '
                    'a touch slipped, or the tool moved on the flange; touch again')
    length = float(np.linalg.norm(pos.t))
    if length > limits.max_tool_length:
        return Failure(ErrorCode.IMPLAUSIBLE_FIT,
                       f'tool length {length * 1e3:.1f} mm is beyond '
                       f'{limits.max_tool_length * 1e3:.0f}'
                ' mm: not a tool on this flange (check the fixed point stayed put)')
    if nominal is not None:
        off = float(np.linalg.norm(pos.t - np.asarray(nominal, dtype=float)[:3, 3]))
        if off > limits.max_nominal_difference:
            return Failure(ErrorCode.IMPLAUSIBLE_FIT,
                           f'the TCP is {off * 1e3:.1f} mm from the cell\'s T_flange_tool (more '
                           'than '
                    f'{limits.max_nominal_difference * 1e3:.0f} mm): another tool? calibrate '
                    'it under its own name, or correct T_flange_tool in the cell file')
    if solution.turn_rad > limits.max_turn_rad:
        return Failure(ErrorCode.IMPLAUSIBLE_FIT,
                       f'the tool turned {math.degrees(solution.turn_rad):.2f} deg between the '
                f'reference and an elongator touch (<= {math.degrees(limits.max_turn_rad):.1f}'
                ' deg): move onto the elongator points without turning the tool')
    return None
