"""Identify an arm's kinematic errors from measurements (any kind), validated on held-out rows.

The one identification engine: :func:`calibrate` is the call every path ends in (a
measurement file or MUKCa folder through :func:`identify_measurements`; live collections,
bags and the suite through core.kinematics.kinematic_calibration.CalibrationJob, which turns
its observations into measurements).

Error models (``ERROR_MODELS``) over a :class:`KinematicModel` (from a URDF, or an MDH table):

- ``offsets``: one offset per joint, q_model = q + offset (``offset_<joint>``);
- ``full``: every joint origin's x, y, z, roll, pitch, yaw (kind 'origin' models: FIGAROH's
  ``full_params``);
- ``mdh``: every joint's alpha, a, theta, d (kind 'mdh' models, a DH table: the paper's);
- ``<one of them>+compliance``: and one compliance per revolute joint, a deflection in
  proportion to its gravity torque (:mod:`.compliance`), after the geometric candidates.

Unknowns are the free model parameters then the measurement's nuisance (base and target
frames, markers, sphere centres, planes: :mod:`.measurements`). Jacobians: the model
parameters' through the tip pose's twists (:mod:`.tip_jacobian`), the nuisance's from the
kind: in closed form for spheres, else by central differences of the residuals (step
``FD_STEP``, accurate to ~1e-9 relative, which the rank tolerance below is far above). The
solver (:meth:`_Problem.solve`) is scipy's trust-region least squares ('lm'), the model
parameters within the gates' deviation bounds, with a robust loss if asked (``soft_l1``, the
CLI's default: inliers within the median residual of the start, the nominal model with its
fitted frames), or Nelder-Mead on the same cost ('nelder-mead'); a callback sees every
iteration and may stop the solve (:class:`Cancelled`).

Identifiability (:func:`identifiable`) on the data's own Jacobian at the start point, columns
scaled to unit norm: the nuisance columns first, then the model's parameters in a fixed order
(joint by joint, the model's field order); a column is kept when the part of it outside the span
of those kept before is at least ``rank_tol`` of its norm, else dropped, naming the kept
columns that make it up (the largest coefficients). Deterministic: the same data give the same
set on any machine. The condition number is that of the kept columns (scaled); pairs of kept
unknowns whose estimates correlate above 0.9 (from (J^T J)^-1) are listed.

Validation (:func:`cross_validate`): every row is held out once, in k folds (row i in fold
i % k) or one group at a time; per fold the nuisance alone (``nominal``) and the nuisance with
the identifiable parameters (``calibrated``) are fitted on the other rows and the held-out
rows' errors pooled. An outlier rule (:func:`outliers`) names rows.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
import math
import time
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics.identification import compliance, gates
from cobot_calib_ros.core.kinematics.identification.gates import DeviationBounds, Verdict
from cobot_calib_ros.core.kinematics.identification.measurements import (
    DEFAULT_ROTATION_WEIGHT, Kind, make_kind, Measurements, textbook_minimum)
from cobot_calib_ros.core.kinematics.identification.tip_jacobian import (
    residual_jacobian, tip_twists)
from cobot_calib_ros.core.kinematics.model import fk_placements, KinematicModel, placement

Array = NDArray[np.float64]
GEOMETRIC_MODELS = ('offsets', 'full', 'mdh')
ERROR_MODELS = GEOMETRIC_MODELS + tuple(m + compliance.SUFFIX for m in GEOMETRIC_MODELS)
FD_STEP = 1e-6            # [m or rad] central-difference step
RANK_TOL = 1e-3           # a column is kept if >= this fraction of it is new (scaled columns)
CORRELATED = 0.9
OUTLIER_MADS = 5.0        # a row is an outlier beyond median + 5 scaled MADs of the errors
PRIOR_PASSES = 8          # the prior's data sigma: the nominal model's scatter, then each
PRIOR_SETTLED = 0.9       # pass's, each pass from the last's solution, until it settles
TOLERANCE = 1e-12         # trf's xtol, ftol and gtol
MAX_EVALUATIONS = 200     # trf's residual evaluations, both stages of a robust loss
SOLVERS = ('lm', 'nelder-mead')
# rho(z), z = (r / f_scale)^2, as scipy.optimize.least_squares defines its losses
LOSSES: dict[str, Callable[[Array], Array]] = {
    'linear': lambda z: z,
    'soft_l1': lambda z: 2.0 * (np.sqrt(1.0 + z) - 1.0),
    'huber': lambda z: np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0),
    'cauchy': np.log1p,
    'arctan': np.arctan,
}
# rho'(z): a row's weight at the solution (iteratively reweighted least squares), for the
# standard deviations at the robust loss's weights
WEIGHTS: dict[str, Callable[[Array], Array]] = {
    'linear': np.ones_like,
    'soft_l1': lambda z: 1.0 / np.sqrt(1.0 + z),
    'huber': lambda z: np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0))),
    'cauchy': lambda z: 1.0 / (1.0 + z),
    'arctan': lambda z: 1.0 / (1.0 + z * z),
}
NM_STEP = 1e-3  # Nelder-Mead initial simplex edge along each unknown: 1 mm or 1 mrad
# Nelder-Mead run to convergence (the product's setting and make bench's): the simplex within
# 0.1 um / 0.1 urad and the cost within 1e-16 m^2 (the RMS no longer moves in the 5th digit);
# a tighter xatol (1e-6) ran for over 12 CPU minutes on noisy data without changing the
# held-out error. scipy's own caps (200 iterations per unknown) stop it long before: 0.178 mm
# held-out max where LM reaches 0.083 mm (iiwa 7, 300 poses, issue 16.6)
NM_CONVERGED = {'max_iterations': 400_000, 'max_evaluations': 400_000, 'xatol': 1e-4,
                'fatol': 1e-16}
# callback(iteration, cost [m^2], rms [m]) -> False to stop (:func:`calibrate`)
Callback = Callable[[int, float, float], 'bool | None']


class Cancelled(Exception):
    """The callback asked to stop the solve; nothing is kept."""


@dataclass(frozen=True)
class ErrorModel:
    """Which parameters of ``model`` may move: names in ``candidates`` (fixed order)."""

    model: KinematicModel
    name: str

    def __post_init__(self) -> None:
        if self.name not in ERROR_MODELS:
            raise ValueError(f'unknown error model {self.name!r}; use one of {ERROR_MODELS}')
        # the parameters of each error model are fields of one kind of model: a URDF's joint
        # origins are not MDH rows (an exact conversion needs a base transform the MDH chain
        # lacks, and is not unique where consecutive axes are parallel), nor the reverse
        if self.geometric == 'mdh' and self.model.kind != 'mdh':
            raise ValueError(f'--model mdh needs a DH table (--dh FILE); {self.model.name} is '
                             'a URDF: use --model full (x, y, z, roll, pitch, yaw of every '
                             'joint origin, which covers alpha, a, theta, d) or offsets')
        if self.geometric == 'full' and self.model.kind != 'origin':
            raise ValueError(f'--model full needs a URDF (--urdf FILE); {self.model.name} is a '
                             'DH table: use --model mdh (alpha, a, theta, d of every joint) '
                             'or offsets')

    @property
    def geometric(self) -> str:
        return self.name.removesuffix(compliance.SUFFIX)

    @property
    def candidates(self) -> tuple[str, ...]:
        extra = compliance.candidates(self.model) if self.name != self.geometric else ()
        if self.geometric == 'offsets':
            return tuple(f'offset_{j}' for j in self.model.joint_names) + extra
        return self.model.parameter_names + extra

    def tip_poses(self, names: tuple[str, ...], values: Array, q: Array) -> Array:
        """(m, 4, 4) T_base_tip with the named parameters at ``values`` (others nominal)."""
        placements, offsets = self.placements(names, values)
        q_model = q + offsets
        springs = self.q_dependent(names)
        if springs:
            tau = compliance.gravity_torques(self.model, q)
            for k in springs:
                j = compliance.joint_index(self.model, names[k])
                q_model[:, j] += values[k] * tau[:, j]
        return fk_placements(placements, self.model.flange, q_model, self.model.prismatic)

    def q_dependent(self, names: tuple[str, ...]) -> list[int]:
        """Indices of ``names`` whose effect varies with the joint values (compliances)."""
        return [k for k, n in enumerate(names) if n.startswith(compliance.PREFIX)]

    def placements(self, names: tuple[str, ...], values: Array) -> tuple[Array, Array]:
        """(placements (n, 4, 4), joint offsets (n,)) with the named parameters at values."""
        params, offsets = self.parameters(names, values)
        return np.stack([placement(self.model.kind, r)
                         for r in self.model.rows(params)]), offsets

    def parameters(self, names: tuple[str, ...], values: Array) -> tuple[Array, Array]:
        """(model parameters (P,), joint offsets (n,)) with the named ones at values."""
        params = np.array(self.model.nominal, dtype=float)
        offsets = np.zeros(len(self.model.joint_names))
        for name, v in zip(names, values):
            if name.startswith('offset_'):
                offsets[self.model.joint_names.index(name[7:])] = v
            elif not name.startswith(compliance.PREFIX):
                params[self.model.parameter_names.index(name)] = v
        return params, offsets

    def start(self, names: tuple[str, ...]) -> Array:
        lookup = dict(zip(self.model.parameter_names, self.model.nominal))
        return np.array([lookup.get(n, 0.0) for n in names], dtype=float)


class _Problem:
    """Residuals and their Jacobian over x = [the named model parameters..., nuisance...]."""

    def __init__(self, errors: ErrorModel, data: Measurements, names: tuple[str, ...],
                 nuisance: Array | None = None, prior: Array | None = None) -> None:
        self.errors, self.data, self.names = errors, data, tuple(names)
        self.kind = make_kind(data, errors.tip_poses((), np.empty(0), data.q))
        start = self.kind.x0 if nuisance is None else np.asarray(nuisance, dtype=float)
        self.x0 = np.concatenate([errors.start(self.names), start])
        self.start = self.x0        # where the solve starts (:func:`fit`'s ``start``)
        self.n = len(self.names)
        # the Gaussian prior's rows, weight_i (x_i - nominal_i) = sigma_r / sigma_i (x_i -
        # nominal_i) beside the data's residuals (:func:`fit`); zeros: none
        self.prior = np.zeros(self.n) if prior is None else np.asarray(prior, dtype=float)
        self._tip_key, self._tip = b'', np.empty((0, 4, 4))
        self._columns_key, self._columns = b'', np.empty((0, 0))

    def tip(self, x: Array, q: Array | None = None) -> Array:
        if q is not None:
            return self.errors.tip_poses(self.names, x[:self.n], q)
        key = np.asarray(x[:self.n], dtype=float).tobytes()
        if key != self._tip_key or not len(self._tip):   # the solver asks for residuals
            # and the Jacobian at one point, and the nuisance moves alone in a nominal fit
            self._tip = self.errors.tip_poses(self.names, x[:self.n], self.data.q)
            self._tip_key = key
        return self._tip

    def residuals(self, x: Array) -> Array:
        return self.kind.residuals(self.tip(x), x[self.n:])

    def objective(self, x: Array) -> Array:
        """The residuals the solve minimises: the data's, then the prior's."""
        r = self.residuals(x)
        if not self.prior.any():
            return r
        return np.concatenate([r, self.prior * (x[:self.n] - self.x0[:self.n])])

    def objective_columns(self, x: Array) -> Array:
        """d :meth:`objective` / d x."""
        J = self.columns(x)
        if not self.prior.any():
            return J
        rows = np.zeros((self.n, J.shape[1]))
        rows[:, :self.n] = np.diag(self.prior)
        return np.vstack([J, rows])

    def jacobian(self, x: Array) -> Array:
        """The model parameters through the tip's twists (:mod:`.tip_jacobian`), the nuisance
        by the kind (:meth:`Kind.nuisance_jacobian`) on the same tip poses; at the joints without
        deflections, a compliance's column zero (:meth:`columns` differences those)."""
        params, offsets = self.errors.parameters(self.names, x[:self.n])
        model = self.errors.model
        nuisance = x[self.n:]
        springs = self.errors.q_dependent(self.names)
        if springs:     # the tip without the deflections
            placements, _ = self.errors.placements(self.names, x[:self.n])
            T = fk_placements(placements, model.flange, self.data.q + offsets, model.prismatic)
        else:
            T = self.tip(x)
        geometric = [k for k in range(self.n) if k not in springs]
        twists = np.zeros((self.n, len(T), 6))
        if geometric:
            twists[geometric] = tip_twists(model, params, offsets,
                                           tuple(self.names[k] for k in geometric), self.data.q)
        return np.hstack([residual_jacobian(self.kind, T, nuisance, twists, FD_STEP),
                          self.kind.nuisance_jacobian(T, nuisance, FD_STEP)])

    def columns(self, x: Array) -> Array:
        """:meth:`jacobian`, the columns of terms that vary with the joint values
        (compliances) by central differences of the residuals. The other columns are taken
        at the joints without the deflections (~1 mrad): exact at the start (no deflection),
        a search direction off by ~1e-3 after; the residuals are exact."""
        key = np.asarray(x, dtype=float).tobytes()
        if key == self._columns_key:     # the solver's last, asked again for the std
            return self._columns.copy()
        J = self.jacobian(x)
        for k in self.errors.q_dependent(self.names):
            step = np.zeros(len(x))
            step[k] = FD_STEP
            J[:, k] = (self.residuals(x + step) - self.residuals(x - step)) / (2.0 * FD_STEP)
        self._columns_key, self._columns = key, J.copy()
        return J

    def bounds(self, bounds: DeviationBounds) -> tuple[Array, Array]:
        """(lower, upper) of x: the model parameters within ``bounds`` of nominal, the
        nuisance free."""
        width = bounds.half_widths(self.errors.model, self.names)
        lower = np.full(len(self.x0), -np.inf)
        upper = np.full(len(self.x0), np.inf)
        lower[:self.n], upper[:self.n] = self.x0[:self.n] - width, self.x0[:self.n] + width
        return lower, upper

    def solve(self, max_nfev: int | None = MAX_EVALUATIONS, loss: str = 'linear',
              bounds: DeviationBounds = DeviationBounds(), solver: str = 'lm',
              callback: Callback | None = None, options: dict | None = None,
              first_iteration: int = 0) -> Solution:
        """The bounded solve from x0 (module docstring); ``callback`` as :func:`calibrate`'s.

        'lm' with a robust loss starts from the least-squares solution: from the nominal
        start the residuals lie far out in the loss's tail, where trf's rescaled steps crawl
        (soft-L1 took 22 iterations on the bench's 3 x 625 poses where the linear loss takes
        3); from the least-squares solution it takes a few more, to the same minimum of the
        robust cost. ``max_nfev`` caps the residual evaluations of both stages.
        'nelder-mead' (the sphere paper's choice) minimises the same cost without
        derivatives on x = x0 + NM_STEP z inside the same bounds; ``options``: scipy's
        maxiter / maxfev as max_iterations / max_evaluations, xatol, fatol, adaptive
        (default NM_CONVERGED)."""
        if solver not in SOLVERS:
            raise ValueError(f'solver must be one of {SOLVERS}, got {solver!r}')
        if loss not in LOSSES:
            raise ValueError(f'loss must be one of {tuple(LOSSES)}, got {loss!r}')
        r0 = self.residuals(self.x0)
        if not np.all(np.isfinite(r0)):
            raise ValueError('the start model gives non-finite residuals: check the joint '
                             'columns and the units in the sidecar')
        f_scale = 1.0
        if loss != 'linear':      # inliers: within ~ the start's median residual
            f_scale = max(float(np.median(np.abs(r0))), 1e-9)
        monitor = _Monitor(self.objective, loss, f_scale, callback, first_iteration)
        lower, upper = self.bounds(bounds)
        start = time.perf_counter()
        monitor.step(self.start)
        if solver == 'nelder-mead':
            x, converged, message = _nelder_mead(monitor, self.start, lower, upper,
                                                 options or NM_CONVERGED)
        else:
            x, converged, message = self._trust_region(monitor, loss, f_scale, max_nfev,
                                                       (lower, upper))
        r = self.objective(x)
        return Solution(x, converged, message if converged else f'did not converge: {message}',
                        monitor.iterations, time.perf_counter() - start, monitor.cost(r),
                        float(np.sqrt(np.mean(r * r))), loss, f_scale)

    def _trust_region(self, monitor: '_Monitor', loss: str, f_scale: float,
                      max_nfev: int | None, bounds: tuple[Array, Array]
                      ) -> tuple[Array, bool, str]:
        """trf without the bounds first: where its minimum lies inside them it is the bounded
        problem's too, reached in half the steps (trf's reflective steps and scaling near
        bounds took 9 evaluations where the free solve takes 4: 3 x 625 sphere poses); else
        (a collapsing fit) the bounded solve from the start."""
        def jacobian(x: Array) -> Array:
            monitor.step(x)          # trf takes the Jacobian once per accepted step
            return self.objective_columns(x)

        def run(x0: Array, stage_loss: str, budget: int | None, box):
            from scipy.optimize import least_squares    # here: importing it takes 0.3 s
            return least_squares(monitor.residuals, x0, jac=jacobian, bounds=box,
                                 method='trf', x_scale='jac', xtol=TOLERANCE, ftol=TOLERANCE,
                                 gtol=TOLERANCE, max_nfev=budget, loss=stage_loss,
                                 f_scale=f_scale)

        def stages(box) -> tuple[Array, bool, str]:
            x0, budget = self.start, max_nfev
            if loss != 'linear':
                first = run(x0, 'linear', budget, box)
                if first.status <= 0:
                    return first.x, False, str(first.message)
                x0 = first.x
                budget = None if budget is None else max(budget - first.nfev, 1)
            r = run(x0, loss, budget, box)
            return r.x, bool(r.status > 0), str(r.message)

        lower, upper = bounds
        x, converged, message = stages((-np.inf, np.inf))
        if np.all((x > lower) & (x < upper)):
            return x, converged, message
        return stages(bounds)

    def standard_deviations(self, x: Array, loss: str = 'linear', f_scale: float = 1.0,
                            prior: bool = True) -> Array:
        """sqrt(diag(s^2 (J^T W J)^-1)) of every unknown at x, s^2 = sum(w r^2) / (N - U) (N
        residuals, U unknowns, W the robust ``loss``'s weights rho'((r / f_scale)^2) there)
        [m or rad]; inf for one the data do not determine. With a prior its rows join J (the
        posterior's spread: never above the prior's sigma) unless ``prior`` is False (what the
        data alone say), s^2 from the data's rows."""
        with_prior = prior and self.prior.any()
        J = self.objective_columns(x) if with_prior else self.columns(x)
        r = self.objective(x) if with_prior else self.residuals(x)
        root = np.sqrt(WEIGHTS[loss]((r / f_scale) ** 2))
        J, r = J * root[:, None], (r * root)[:len(r) - (self.n if with_prior else 0)]
        N, U = len(r), J.shape[1]
        scale = np.linalg.norm(J, axis=0)
        scale[scale == 0.0] = 1.0   # an all-zero column shows up as a zero singular value
        _, sv, Vt = np.linalg.svd(J / scale, full_matrices=False)
        null = sv <= sv[0] * max(len(J), U) * np.finfo(float).eps
        s2 = float(r @ r) / (N - U) if N > U else np.inf
        var = ((Vt[~null] / sv[~null, None]) ** 2).sum(axis=0) * s2 / scale ** 2
        undetermined = (np.abs(Vt[null]) > 1e-8).any(axis=0)
        return np.where(undetermined, np.inf, np.sqrt(var))


@dataclass(frozen=True)
class Solution:
    """How a solve ended: x, whether it met its stopping tolerances (``message`` then the
    solver's; else 'did not converge: ...'), solver iterations as the callback saw them,
    seconds, the cost 0.5 f^2 sum(rho((r / f)^2)) [m^2] and the RMS of the residuals [m]."""

    x: Array
    converged: bool
    message: str
    iterations: int
    seconds: float
    cost: float
    rms_m: float
    loss: str = 'linear'
    f_scale: float = 1.0          # [m]: the robust loss's inlier scale


class _Monitor:
    """Counts iterations and asks the callback whether to go on (:func:`calibrate`)."""

    def __init__(self, residuals: Callable[[Array], Array], loss: str, f_scale: float,
                 callback: Callback | None, first_iteration: int = 0) -> None:
        self.rho, self.f_scale, self.callback = LOSSES[loss], f_scale, callback
        self._residuals = residuals
        self.iterations = first_iteration - 1   # a later pass counts on (judged_fit)
        self._last_x, self._last_r, self._stepped = b'', np.empty(0), b''

    def cost(self, r: Array) -> float:
        f2 = self.f_scale ** 2
        return float(0.5 * f2 * np.sum(self.rho(r * r / f2)))

    def residuals(self, x: Array) -> Array:
        r = self._residuals(x)
        self._last_x, self._last_r = np.asarray(x, dtype=float).tobytes(), r
        return r

    def step(self, x: Array) -> None:
        """One iteration ended at x (the start: iteration 0); Cancelled when the callback
        returns False."""
        key = np.asarray(x, dtype=float).tobytes()
        if key == self._stepped:     # a robust stage starting where the linear one ended
            return
        self._stepped = key
        self.iterations += 1
        if self.callback is None:
            return
        r = self._last_r if key == self._last_x else self.residuals(x)
        keep_going = self.callback(self.iterations, self.cost(r),
                                   float(np.sqrt(np.mean(r * r))))
        if keep_going is not None and not keep_going:
            raise Cancelled(f'cancelled by the callback at iteration {self.iterations}')


def _nelder_mead(monitor: _Monitor, x0: Array, lower: Array, upper: Array,
                 options: dict) -> tuple[Array, bool, str]:
    U = len(x0)

    def cost(z: Array) -> float:
        return monitor.cost(monitor.residuals(x0 + NM_STEP * z))

    simplex = np.vstack([np.zeros(U), np.eye(U)])
    from scipy.optimize import minimize     # here: importing it takes 0.3 s
    res = minimize(cost, np.zeros(U), method='Nelder-Mead',
                   bounds=list(zip((lower - x0) / NM_STEP, (upper - x0) / NM_STEP)),
                   callback=lambda z: monitor.step(x0 + NM_STEP * z),
                   options={'maxiter': options.get('max_iterations'),
                            'maxfev': options.get('max_evaluations'),
                            'xatol': options.get('xatol', 1e-4),
                            'fatol': options.get('fatol', 1e-4),
                            'adaptive': options.get('adaptive', True),
                            'initial_simplex': simplex})
    return x0 + NM_STEP * res.x, bool(res.success), str(res.message)


@dataclass(frozen=True)
class Dropped:
    name: str
    reason: str


@dataclass(frozen=True)
class Identifiability:
    """Kept and dropped model parameters, the condition number of the kept unknowns' scaled
    Jacobian (nuisance included), pairs correlated above 0.9, the textbook minimum."""

    kept: tuple[str, ...]
    dropped: tuple[Dropped, ...]
    condition_number: float
    correlated: tuple[tuple[str, str, float], ...]
    frame_dofs: int                 # the base/tool nuisance counted by the textbook minimum
    minimum: int

    @property
    def parameters_kept(self) -> int:
        return len(self.kept) + self.frame_dofs


def _unit_columns(J: Array) -> Array:
    norms = np.linalg.norm(J, axis=0)
    return J / np.where(norms > 0.0, norms, 1.0)


def identifiable(errors: ErrorModel, data: Measurements, rank_tol: float = RANK_TOL,
                 nuisance: Array | None = None) -> Identifiability:
    """The identifiable candidates of ``errors`` on ``data`` (module docstring), at the
    nominal model with ``nuisance`` (default: fitted to the data with the nominal model, so
    that a start value on a symmetry, e.g. a ball on the last axis, does not hide a
    parameter)."""
    candidates = errors.candidates
    if nuisance is None:
        nuisance = fit(errors, data, ()).nuisance
    problem = _Problem(errors, data, candidates, nuisance)
    x0 = problem.x0
    gauge = problem.kind.gauge(problem.tip(x0), x0[problem.n:])
    J = _unit_columns(np.hstack([problem.columns(x0), gauge]))
    labels = candidates + problem.kind.names + tuple(
        f'base_rotation_{c}' for c in 'xyz'[:gauge.shape[1]])
    nuisance = len(candidates) + len(problem.kind.names)
    # zero offsets before the other parameters: at nominal a length can stand in for an
    # offset to first order (parallel axes), not for the degrees an encoder is zeroed off by
    zero = [c for c, n in enumerate(candidates) if gates.is_zero_offset(errors.model, n)]
    order = list(range(nuisance, len(labels))) + list(range(len(candidates), nuisance)) \
        + zero + [c for c in range(len(candidates)) if c not in zero]
    kept_cols: list[int] = []
    basis = np.empty((len(J), 0))
    dropped = []
    for c in order:
        v = J[:, c]
        new = v - basis @ (basis.T @ v)
        new -= basis @ (basis.T @ new)          # twice: Gram-Schmidt, re-orthogonalised
        size = float(np.linalg.norm(new))
        if size >= rank_tol and np.linalg.norm(v) > 0.0:
            basis = np.hstack([basis, (new / size)[:, None]])
            kept_cols.append(c)
        elif c < len(candidates):
            dropped.append(Dropped(labels[c], _reason(J, c, kept_cols, labels, size)))
    kept_model = tuple(labels[c] for c in kept_cols if c < len(candidates))
    kept_cols = [c for c in kept_cols if c < nuisance]     # the gauge is no unknown
    Jk = J[:, kept_cols]
    condition = float(np.linalg.cond(Jk)) if Jk.size else math.inf
    markers = len(np.unique(data.target)) if data.kind == 'points' else 1
    return Identifiability(kept_model, tuple(dropped), condition,
                           _correlated(Jk, [labels[c] for c in kept_cols]),
                           problem.kind.frame_dofs,
                           textbook_minimum(errors.model.prismatic, data.kind, markers))


def _reason(J: Array, c: int, kept: list[int], labels: tuple[str, ...], size: float) -> str:
    if np.linalg.norm(J[:, c]) == 0.0:
        return 'no effect on these measurements'
    coef = np.linalg.lstsq(J[:, kept], J[:, c], rcond=None)[0]
    top = np.argsort(-np.abs(coef))[:3]
    parts = ', '.join(f'{labels[kept[i]]} ({coef[i]:+.2f})' for i in top if abs(coef[i]) > 1e-3)
    return f'a combination of {parts} (new part {size:.1e} < tolerance)'


def _correlated(J: Array, names: list[str]) -> tuple[tuple[str, str, float], ...]:
    if J.shape[1] == 0:
        return ()
    cov = np.linalg.pinv(J.T @ J)
    s = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    corr = cov / np.outer(s, s)
    out = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if abs(corr[i, j]) > CORRELATED:
                out.append((names[i], names[j], float(corr[i, j])))
    return tuple(out)


@dataclass(frozen=True)
class Fit:
    """Identified values of ``names`` (model parameters) and the nuisance, and how the solve
    ended (``solution``)."""

    names: tuple[str, ...]
    values: Array
    nuisance: Array
    problem: _Problem
    solution: Solution
    prior_sigma_m: float = 0.0      # the data's sigma the prior was weighed with (0: none)

    @property
    def converged(self) -> bool:
        return self.solution.converged

    def data_rms(self) -> float:
        """RMS of the data's residuals at the solution [m] (the prior's rows left out)."""
        r = self.problem.residuals(self.solution.x)
        return float(np.sqrt(np.mean(r * r)))

    def standard_deviations(self, prior: bool = True) -> Array:
        """Of the named parameters, then the nuisance [m or rad] (:meth:`_Problem.
        standard_deviations`; ``prior`` False: what the data alone say)."""
        return self.problem.standard_deviations(self.solution.x, self.solution.loss,
                                                self.solution.f_scale, prior)

    @property
    def deltas(self) -> Array:
        """The identified values less nominal [m or rad]."""
        return self.values - self.problem.errors.start(self.names)

    def row_errors(self, data: Measurements) -> tuple[Array, Array]:
        """Position [m] and rotation [rad] errors of ``data``'s rows with this fit."""
        T = self.problem.errors.tip_poses(self.names, self.values, data.q)
        kind, x = self.problem.kind.held_out_nuisance(T, self.nuisance, data)
        return kind.errors(T, x, data)


def fit(errors: ErrorModel, data: Measurements, names: tuple[str, ...],
        nuisance: Array | None = None, loss: str = 'linear',
        bounds: DeviationBounds = DeviationBounds(), solver: str = 'lm',
        callback: Callback | None = None, options: dict | None = None,
        prior_sigma_m: float = 0.0, first_iteration: int = 0,
        start: Array | None = None) -> Fit:
    """Least squares over the named model parameters (none: the nuisance alone) and the
    nuisance on ``data``, from the nominal model and ``nuisance`` (default: the kind's
    start), the parameters kept within ``bounds`` of nominal (:meth:`_Problem.solve`).
    ``prior_sigma_m`` > 0: maximum a posteriori with a Gaussian prior around nominal, each
    parameter's sigma its typical deviation (:func:`gates.typical_deviation`), the data's
    residuals' sigma ``prior_sigma_m`` [m]."""
    prior = np.array([0.0 if n.startswith(compliance.PREFIX) else
                      prior_sigma_m / gates.typical_deviation(errors.model, n) for n in names])
    problem = _Problem(errors, data, names, nuisance, prior)
    if start is not None:       # a pass of judged_fit goes on from the last
        problem.start = np.asarray(start, dtype=float)
    minimum = len(problem.x0)
    count = len(problem.residuals(problem.x0))
    if count < minimum:
        raise ValueError(f'{len(data)} rows give {count} equations for {minimum} unknowns '
                         f'({len(names)} parameters + {minimum - len(names)} frames/targets): '
                         f'measure more rows or use a smaller --model')
    solution = problem.solve(loss=loss, bounds=bounds, solver=solver, callback=callback,
                             options=options, first_iteration=first_iteration)
    x = solution.x
    return Fit(tuple(names), x[:problem.n], x[problem.n:], problem, solution, prior_sigma_m)


@dataclass(frozen=True)
class Held:
    """A parameter the data do not determine, held at nominal: its std [m or rad] from the
    fit that held it (inf: none) and why (:func:`gates.undetermined_reason`)."""

    name: str
    std: float
    reason: str


def judged_fit(errors: ErrorModel, data: Measurements, names: tuple[str, ...],
               nuisance: Array | None = None, loss: str = 'linear',
               bounds: DeviationBounds = DeviationBounds(), solver: str = 'lm',
               callback: Callback | None = None,
               options: dict | None = None) -> tuple[Fit, tuple[Held, ...]]:
    """The fit of ``names`` as a real arm is judged (:mod:`.gates`): maximum a posteriori with
    a Gaussian prior around nominal (each parameter's sigma its kind's typical deviation; the
    data's sigma the RMS residual of the nominal model, then of each pass, each pass going on
    from the last's solution, until it falls by less than ``PRIOR_SETTLED``; those passes are
    'lm''s, and Nelder-Mead, when asked for, then solves once from nominal on the settled
    prior), so a parameter the data barely see stays near nominal without a hard bound; then
    each parameter's standard deviation from that fit (at the robust loss's weights, the
    prior's rows included): one the data do not determine (:func:`gates.determined`) is held
    at nominal with its reason and the rest refitted from nominal with the same prior. The
    bounds stay as the ceiling of what a real arm can be. Data that pull a parameter the
    prior's passes hold near nominal (noise-free data along a direction they barely see) keep
    the prior's bias: the data's scatter is estimated from the same residuals."""
    names = tuple(names)
    if not names:
        return fit(errors, data, (), nuisance, loss, bounds, solver, callback, options), ()
    result, iterations, start = fit(errors, data, (), nuisance, loss), 0, None
    sigma = result.data_rms()
    for _ in range(PRIOR_PASSES):      # 'lm' settles the prior (Nelder-Mead takes a minute)
        result = fit(errors, data, names, nuisance, loss, bounds, 'lm', callback, None,
                     sigma, iterations, start)
        iterations, start = result.solution.iterations + 1, result.solution.x
        last, sigma = sigma, result.data_rms()
        if sigma > PRIOR_SETTLED * last:
            break
    sigma = last
    if solver != 'lm':                 # the solver asked for, from nominal, on that prior
        result = fit(errors, data, names, nuisance, loss, bounds, solver, callback, options,
                     sigma, iterations)
        iterations = result.solution.iterations + 1
    std = result.standard_deviations()[:len(names)]
    held = tuple(Held(n, float(v), gates.undetermined_reason(errors.model, n, float(v)))
                 for n, v in zip(names, std) if not gates.determined(errors.model, n, float(v)))
    if held:
        names = tuple(n for n in names if n not in {h.name for h in held})
        result = fit(errors, data, names, nuisance, loss, bounds, solver, callback, options,
                     sigma, iterations)
    return result, held


def balanced(errors: ErrorModel, data: Measurements, loss: str = 'linear') -> Measurements:
    """``data`` with a rotation_weight of None (a sidecar's ``auto``) set to the ratio of the
    nominal model's RMS position and rotation errors on these rows (its frames fitted at
    1 m/rad), so that each counts by its own scatter; other data unchanged."""
    if data.kind != 'pose' or data.rotation_weight is not None:
        return data
    start = replace(data, rotation_weight=DEFAULT_ROTATION_WEIGHT)
    position, rotation = fit(errors, start, (), loss=loss).row_errors(start)
    return replace(data, rotation_weight=float(np.sqrt(np.mean(position ** 2)
                                                       / np.mean(rotation ** 2))))


def stats(position: Array, rotation: Array) -> dict:
    """{rmse_mm, mean_mm, max_mm, rot_rms_mrad (None without rotation), count}."""
    p = np.asarray(position) * 1e3
    r = np.asarray(rotation)
    rot = None if np.all(np.isnan(r)) else float(np.sqrt(np.mean(r ** 2)) * 1e3)
    return {'rmse_mm': float(np.sqrt(np.mean(p ** 2))), 'mean_mm': float(np.mean(p)),
            'max_mm': float(np.max(p)), 'rot_rms_mrad': rot, 'count': int(len(p))}


def kfold(m: int, k: int) -> list[Array]:
    """Held-out row indices of each fold: row i in fold i % k."""
    if not 2 <= k <= m:
        raise ValueError(f'--folds {k}: need 2 <= K <= rows ({m})')
    return [np.arange(f, m, k) for f in range(k)]


def by_group(groups: ArrayLike) -> tuple[tuple[str, ...], list[Array]]:
    """(group names in first-seen order, held-out row indices of each)."""
    g = np.asarray(groups).astype(str)
    names = tuple(dict.fromkeys(g.tolist()))
    if len(names) < 2:
        raise ValueError(f'leave-one-group-out needs at least 2 groups, got {list(names)}')
    return names, [np.flatnonzero(g == n) for n in names]


@dataclass(frozen=True)
class CrossValidation:
    """Pooled held-out errors (every row once), nominal and calibrated, and per fold."""

    nominal: dict
    calibrated: dict
    folds: tuple[dict, ...]
    errors_nominal: tuple[Array, Array]
    errors_calibrated: tuple[Array, Array]


def cross_validate(errors: ErrorModel, data: Measurements, held_out: list[Array],
                   labels: tuple[str, ...] | None = None,
                   rank_tol: float = RANK_TOL, loss: str = 'linear',
                   bounds: DeviationBounds = DeviationBounds()) -> CrossValidation:
    """For each fold: identifiability and fits on the other rows, errors on the held-out."""
    m = len(data)
    pos = {'nominal': np.full(m, np.nan), 'calibrated': np.full(m, np.nan)}
    rot = {'nominal': np.full(m, np.nan), 'calibrated': np.full(m, np.nan)}
    folds = []
    for f, rows in enumerate(held_out):
        train = balanced(errors, data.take(np.setdiff1d(np.arange(m), rows)), loss)
        test = data.take(rows)
        nominal = fit(errors, train, (), loss=loss)
        ident = identifiable(errors, train, rank_tol, nominal.nuisance)
        calibrated, held = judged_fit(errors, train, ident.kept, nominal.nuisance, loss,
                                      bounds)
        entry = {'held_out': labels[f] if labels else f, 'rows': int(len(rows)),
                 'parameters': len(calibrated.names), 'held': len(held)}
        for name, result in (('nominal', nominal), ('calibrated', calibrated)):
            e_pos, e_rot = result.row_errors(test)
            pos[name][rows], rot[name][rows] = e_pos, e_rot
            entry[name] = stats(e_pos, e_rot)
        folds.append(entry)
    return CrossValidation(stats(pos['nominal'], rot['nominal']),
                           stats(pos['calibrated'], rot['calibrated']), tuple(folds),
                           (pos['nominal'], rot['nominal']),
                           (pos['calibrated'], rot['calibrated']))


def outliers(position: Array, mads: float = OUTLIER_MADS) -> list[int]:
    """Rows whose error exceeds median + ``mads`` x 1.4826 MAD of all rows' errors."""
    e = np.asarray(position, dtype=float)
    median = float(np.median(e))
    spread = 1.4826 * float(np.median(np.abs(e - median)))
    return [int(i) for i in np.flatnonzero(e > median + mads * max(spread, 1e-12))]


def held_out_rows(sample: Array, folds: list[Array]) -> list[Array]:
    """Measurement rows of each fold given as samples (CSV data rows): a sample's markers
    are held out together."""
    return [np.flatnonzero(np.isin(sample, f)) for f in folds]


def data_problems(errors: ErrorModel, data: Measurements) -> list[str]:
    """Gate 1 (:mod:`.gates`): the joint values and the measured lengths against the arm."""
    problems = gates.joint_problems(errors.model, data.q) or gates.offset_problems(
        errors.model, data.ball, 'ball' if data.kind in ('spheres', 'plane') else 'marker')
    if problems:
        return problems
    T = errors.tip_poses((), np.empty(0), data.q)
    at_ball = np.einsum('mij,j->mi', T[:, :3, :3], data.ball) + T[:, :3, 3]
    if data.kind == 'points':
        return gates.scale_problems(data.values, at_ball, 'measured marker positions')
    if data.kind == 'pose':
        return gates.scale_problems(data.values[:, :3, 3], T[:, :3, 3],
                                    'measured target positions')
    if data.kind == 'spheres' and data.distances:
        ids = np.unique(data.target)
        centres = np.zeros((int(ids.max()) + 1, 3))
        for i in ids:
            centres[i] = at_ball[data.target == i].mean(axis=0)
        return gates.distance_problems(data.distances, centres)
    return []


@dataclass(frozen=True)
class Calibration:
    """One identification on all rows (:func:`calibrate`): the data as fitted (pose data
    balanced), the nuisance fitted with the nominal model, the identifiable parameters there,
    their fit (those the data do not determine held at nominal: ``held``), and the gates'
    problems with that fit itself (a determined parameter on its bound, a solve that did not
    converge)."""

    data: Measurements
    nominal: Fit
    identifiability: Identifiability
    fit: Fit
    problems: tuple[str, ...]
    held: tuple[Held, ...] = ()

    def large(self) -> list[str]:
        """One note per determined parameter far from nominal (:func:`gates.large_note`)."""
        model, std = self.fit.problem.errors.model, self.fit.standard_deviations()
        notes = (gates.large_note(model, n, float(d), float(s))
                 for n, d, s in zip(self.fit.names, self.fit.deltas, std))
        return [n for n in notes if n]


def calibrate(errors: ErrorModel, data: Measurements, *, loss: str = 'linear',
              bounds: DeviationBounds = DeviationBounds(), rank_tol: float = RANK_TOL,
              solver: str = 'lm', options: dict | None = None,
              callback: Callback | None = None) -> Calibration:
    """The identification every path ends in (a measurement file, a MUKCa folder, a
    collection, a bag, the live suite): the gates' data checks (a Refusal before any fit), the
    nuisance fitted with the nominal model, identifiability there (:func:`identifiable`),
    enough equations (a Refusal, TOO_FEW_POINTS), the bounded fit of the identifiable
    parameters (``solver`` 'lm' or 'nelder-mead', ``options`` for the latter:
    :meth:`_Problem.solve`), and the gates' problems with that fit.

    ``callback(iteration, cost [m^2], rms [m])`` at the start of the final solve (iteration
    0) and after each of its iterations; returning False stops it: :class:`Cancelled`."""
    gates.refuse(data_problems(errors, data))
    data = balanced(errors, data, loss)
    nominal = fit(errors, data, ())      # the start of the nuisance: least squares will do
    ident = identifiable(errors, data, rank_tol, nominal.nuisance)
    equations = len(nominal.problem.residuals(nominal.problem.x0))
    gates.refuse(gates.equation_problems(equations, len(ident.kept) + len(nominal.nuisance),
                                         len(data)), ErrorCode.TOO_FEW_POINTS)
    final, held = judged_fit(errors, data, ident.kept, nominal.nuisance, loss, bounds, solver,
                             callback, options)
    problems = gates.at_bounds(errors.model, final.names, final.deltas, bounds)
    if not final.converged:
        problems.append(f'the solver did not converge ({final.solution.message}): the model '
                        'may be far from the optimum')
    return Calibration(data, nominal, ident, final, tuple(problems), held)


def identify_measurements(errors: ErrorModel, data: Measurements, held_out: list[Array], *,
                          labels: tuple[str, ...] | None = None, sample: Array | None = None,
                          rank_tol: float = RANK_TOL, loss: str = 'linear',
                          bounds: DeviationBounds = DeviationBounds(),
                          noise_m: float = 0.0) -> dict:
    """The gates' data checks (a Refusal before any fit), cross-validation, then
    identifiability, the fit and the outlier rule on all rows, and the gates' verdict on the
    result: the report of ``cobot-calib identify --measurement`` (JSON-ready). ``sample`` maps
    rows to samples (CSV data rows) for the outliers (default: the rows themselves);
    ``noise_m``: the measurement's own RMS error [m] as the row errors count it (0: unknown)."""
    sample = np.arange(len(data)) if sample is None else np.asarray(sample)
    calibration = calibrate(errors, data, loss=loss, bounds=bounds, rank_tol=rank_tol)
    final, ident = calibration.fit, calibration.identifiability
    cv = cross_validate(errors, data, held_out, labels, rank_tol, loss, bounds)
    data = calibration.data
    e_pos, e_rot = final.row_errors(data)
    verdict = Verdict(calibration.problems + tuple(gates.result_problems(
        True, cv.nominal['rmse_mm'] * 1e-3, cv.calibrated['rmse_mm'] * 1e-3, noise_m)))
    nominal = dict(zip(errors.candidates, errors.start(errors.candidates)))
    std = final.standard_deviations()
    return {
        'measurement': data.kind, 'model': errors.name, 'robot': errors.model.name,
        'loss': loss, 'rotation_weight': data.rotation_weight if data.has_rotation else None,
        'rows': len(data), 'samples': int(len(np.unique(sample))),
        'verdict': verdict.to_dict(),
        'bounds': {'length_mm': bounds.length_m * 1e3, 'angle_mrad': bounds.angle_rad * 1e3},
        'offset_bound_mrad': bounds.offset_rad * 1e3,
        'prior': {'length_mm': gates.TYPICAL_LENGTH_M * 1e3,
                  'angle_mrad': gates.TYPICAL_ANGLE_RAD * 1e3,
                  'data_sigma_mm': final.prior_sigma_m * 1e3,
                  'compliance_yardstick_mrad_per_nm': gates.TYPICAL_COMPLIANCE * 1e3,
                  'determined_below': gates.DETERMINED, 'large_beyond': gates.LARGE},
        'noise_mm': noise_m * 1e3,
        'held_out': {'nominal': cv.nominal, 'calibrated': cv.calibrated},
        'folds': list(cv.folds),
        'training': stats(e_pos, e_rot),
        'parameters_kept': ident.parameters_kept,
        'parameters_minimum': ident.minimum,
        'parameters_model': len(ident.kept),
        'frame_dofs': ident.frame_dofs,
        'condition_number': ident.condition_number,
        'converged': final.converged,
        'identified': [{'name': n, 'value': float(v), 'nominal': float(nominal[n]),
                        'delta': float(v - nominal[n]), 'std': float(s)}
                       for n, v, s in zip(final.names, final.values, std)],
        'large': calibration.large(),
        'held': [{'name': h.name, 'std': h.std if math.isfinite(h.std) else None,
                  'reason': h.reason} for h in calibration.held],
        'dropped': [{'name': d.name, 'reason': d.reason} for d in ident.dropped],
        'correlated': [{'a': a, 'b': b, 'correlation': c} for a, b, c in ident.correlated],
        'outliers': [{'sample': int(sample[i]), 'error_mm': float(e_pos[i] * 1e3)}
                     for i in outliers(e_pos)],
    }
