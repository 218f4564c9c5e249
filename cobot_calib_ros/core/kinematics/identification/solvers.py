"""identify(): fit the free parameters to sphere-coupling or tracker data.

Two solvers on the same residuals (:mod:`.objectives`): ``'lm'``, scipy's trust-region
least squares (``least_squares(method='trf')``, a Levenberg-Marquardt-type method that also
takes robust losses) with the analytic Jacobian; ``'nelder-mead'``, the paper's choice
(section 3.2), minimising the same cost without derivatives from the start values.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import time
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares, minimize

from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics.identification.objectives import (
    AbsoluteObjective, CentresObjective, PairsObjective)
from cobot_calib_ros.core.kinematics.identification.observations import (
    PositionObservations, SphereObservations)
from cobot_calib_ros.core.kinematics.identification.parameters import ParameterSet

Array = NDArray[np.float64]

SOLVERS = ('lm', 'nelder-mead')
OBJECTIVES = ('relative', 'absolute')
# rho(z), z = (r / f_scale)^2, as scipy.optimize.least_squares defines its losses
LOSSES: dict[str, Callable[[Array], Array]] = {
    'linear': lambda z: z,
    'soft_l1': lambda z: 2.0 * (np.sqrt(1.0 + z) - 1.0),
    'huber': lambda z: np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0),
    'cauchy': np.log1p,
    'arctan': np.arctan,
}
NM_STEP = 1e-3  # Nelder-Mead initial simplex edge along each unknown: 1 mm or 1 mrad
# Nelder-Mead run to convergence (the product's setting and make bench's): the simplex within
# 0.1 um / 0.1 urad and the cost within 1e-16 m^2 (the RMS no longer moves in the 5th digit);
# a tighter xatol (1e-6) ran for over 12 CPU minutes on noisy data without changing the
# held-out error. scipy's own caps (200 iterations per unknown) stop it long before: 0.178 mm
# held-out max where LM reaches 0.083 mm (iiwa 7, 300 poses, issue 16.6)
NM_CONVERGED = {'max_iterations': 400_000, 'max_evaluations': 400_000, 'xatol': 1e-4,
                'fatol': 1e-16}

Callback = Callable[[int, float, float], 'bool | None']


@dataclass(frozen=True)
class IdentificationResult:
    """Identified parameters and how the fit went.

    ``std`` is sqrt(diag(s^2 (J^T J)^-1)) of the free parameters with s^2 = sum(r^2)/(N - U)
    (N residuals, U unknowns including nuisance) [m or rad]; inf for a parameter the data do
    not determine (``extra['unidentifiable']`` lists them). ``cost`` is the solver's cost
    0.5 f^2 sum(rho((r/f)^2)) [m^2], ``rms_m`` the RMS of the residual components [m].
    ``iterations`` counts solver iterations as the callback sees them (the start is 0).
    ``converged``: the solver met its stopping tolerances (False: it hit an iteration or
    evaluation cap, or was cancelled; ``message`` then starts with "did not converge").
    ``extra`` holds the nuisance estimates: 'sphere_centres_base' {sphere: (3,)} [m] (centres
    form), 'T_world_base' (4, 4) (absolute), pair counts (pairs form); 'objective'
    ('relative' or 'absolute') and 'form' ('centres', 'pairs' or 'absolute') always.
    """

    params: Array
    tool_xyz: Array
    free: tuple[str, ...]
    std: Array
    iterations: int
    cost: float
    rms_m: float
    solve_seconds: float
    code: ErrorCode        # SUCCESS, or CANCELED (params: the best evaluated)
    message: str
    extra: dict = field(default_factory=dict)
    converged: bool = True


@dataclass(frozen=True)
class Stop:
    """How a solver stopped: met its tolerances (``success``) or not, and its message."""

    success: bool
    message: str


class _Cancelled(Exception):
    """The callback asked to stop."""


class _Monitor:
    """Wraps the objective: keeps the best point evaluated, calls the user callback."""

    def __init__(self, objective, loss: str, f_scale: float, callback: Callback | None) -> None:
        self.objective, self.rho, self.f_scale = objective, LOSSES[loss], f_scale
        self.callback = callback
        self.best_x = np.array(objective.x0, dtype=float)
        self.best_cost, self.best_rms = np.inf, np.inf
        self.iterations = -1

    def cost(self, r: Array) -> float:
        f2 = self.f_scale ** 2
        return float(0.5 * f2 * np.sum(self.rho(r * r / f2)))

    def residuals(self, x: Array) -> Array:
        r = self.objective.residuals(x)
        cost = self.cost(r)
        if cost < self.best_cost:
            self.best_x, self.best_cost = np.array(x, dtype=float), cost
            self.best_rms = float(np.sqrt(np.mean(r * r)))
        return r

    def iteration(self) -> None:
        """One solver iteration done (the first call is iteration 0, the start)."""
        self.iterations += 1
        if self.callback is not None:
            keep_going = self.callback(self.iterations, self.best_cost, self.best_rms)
            if keep_going is not None and not keep_going:
                raise _Cancelled


def _objective(parameter_set: ParameterSet, observations, objective: str | None, pairs,
               params0: Array, tool_xyz0: Array, distance_weight: float | None):
    if objective is None:
        objective = 'relative' if isinstance(observations, SphereObservations) else 'absolute'
    if objective not in OBJECTIVES:
        raise ValueError(f'objective must be one of {OBJECTIVES}, got {objective!r}')
    wanted = SphereObservations if objective == 'relative' else PositionObservations
    if not isinstance(observations, wanted):
        raise ValueError(f'objective {objective!r} needs {wanted.__name__}, got '
                         f'{type(observations).__name__}')
    if objective == 'absolute':
        if pairs is not None:
            raise ValueError('pairs apply to the relative objective only')
        return AbsoluteObjective(parameter_set, observations, params0, tool_xyz0)
    if pairs is not None:
        return PairsObjective(parameter_set, observations, params0, tool_xyz0, pairs)
    return CentresObjective(parameter_set, observations, params0, tool_xyz0, distance_weight)


def _check_inputs(parameter_set: ParameterSet, observations, params0: Array,
                  tool_xyz0: Array) -> None:
    model = parameter_set.model
    n = len(model.joint_names)
    if observations.q.shape[1] != n:
        raise ValueError(f'q has {observations.q.shape[1]} joints, model {model.name!r} has {n}')
    if params0.shape != model.nominal.shape or not np.all(np.isfinite(params0)):
        raise ValueError(f'params0 must be {model.nominal.shape} finite values (or None for '
                         f'the nominal model)')
    if tool_xyz0.shape != (3,) or not np.all(np.isfinite(tool_xyz0)):
        raise ValueError(f'tool_xyz0 must be 3 finite values [m], got {tool_xyz0}')


def _standard_deviations(J: Array, r: Array, n_free: int) -> tuple[Array, NDArray[np.bool_]]:
    """std [m or rad] of the first n_free unknowns, and which are not determined (std inf)."""
    N, U = J.shape
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0.0] = 1.0  # an all-zero column shows up as a zero singular value
    _, s, Vt = np.linalg.svd(J / scale, full_matrices=False)
    null = s <= s[0] * max(N, U) * np.finfo(float).eps
    s2 = float(r @ r) / (N - U) if N > U else np.inf
    var = ((Vt[~null] / s[~null, None]) ** 2).sum(axis=0) * s2 / scale ** 2
    undetermined = (np.abs(Vt[null]) > 1e-8).any(axis=0)
    std = np.where(undetermined, np.inf, np.sqrt(var))
    return std[:n_free], undetermined[:n_free]


def identify(parameter_set: ParameterSet,
             observations: SphereObservations | PositionObservations, *,
             tool_xyz0: ArrayLike, params0: ArrayLike | None = None, solver: str = 'lm',
             objective: str | None = None, loss: str = 'soft_l1', pairs: ArrayLike | None = None,
             max_iterations: int | None = None, callback: Callback | None = None,
             f_scale: float = 1e-4, distance_weight: float | None = None,
             tolerance: float = 1e-12, max_evaluations: int | None = None,
             xatol: float = 1e-6, fatol: float = 1e-20,
             adaptive: bool = True) -> IdentificationResult:
    """Identify ``parameter_set.free`` from the observations, the rest held at ``params0``.

    tool_xyz0 (3,) [m] tool centre in the flange (start value, fixed unless tool_* are free);
    params0 (P,) start/fixed model parameters (default nominal). ``objective`` 'relative'
    (SphereObservations; ``pairs`` (k, 2) row indices selects the paper's pair form, else the
    sphere-centre form) or 'absolute' (PositionObservations, identifies T_world_base too);
    inferred from the observations when None. ``loss`` and ``f_scale`` [m] (the residual size
    where a robust loss starts to discount) as in scipy's least_squares, applied by both
    solvers. ``distance_weight``: see :class:`CentresObjective`.

    'lm': ``max_iterations`` caps residual evaluations (scipy max_nfev), ``tolerance`` is
    ftol = xtol = gtol. 'nelder-mead': works on x = x0 + NM_STEP z, simplex edge NM_STEP
    (1 mm / 1 mrad) from the start; ``max_iterations`` / ``max_evaluations`` are scipy's
    maxiter / maxfev, ``xatol`` [units of NM_STEP] and ``fatol`` [m^2] its stopping
    thresholds (both must hold), ``adaptive`` its dimension-adapted coefficients; scipy's
    defaults stop long before convergence on this problem.

    ``callback(iteration, cost, rms_m)``: at the start (iteration 0) and after every solver
    iteration, with the best cost so far; returning False cancels, and the result then holds
    the best parameters evaluated, code CANCELED.

    ValueError, saying what to do, on inconsistent input (shapes, NaN, too few data, unknown
    names, solver, loss or objective).
    """
    if solver not in SOLVERS:
        raise ValueError(f'solver must be one of {SOLVERS}, got {solver!r}')
    if loss not in LOSSES:
        raise ValueError(f'loss must be one of {tuple(LOSSES)}, got {loss!r}')
    if not f_scale > 0.0:
        raise ValueError(f'f_scale must be > 0 [m], got {f_scale}')
    model = parameter_set.model
    p0 = np.array(model.nominal if params0 is None else params0, dtype=float)
    t0 = np.array(tool_xyz0, dtype=float)
    _check_inputs(parameter_set, observations, p0, t0)
    problem = _objective(parameter_set, observations, objective, pairs, p0, t0,
                         distance_weight)
    x0 = problem.x0
    # more residuals than unknowns (parameters, tool, sphere centres), so the noise and the
    # standard deviations can be estimated: a pose on a sphere is 3 residuals, not 1
    if problem.residual_count <= len(x0):
        raise ValueError(f'{problem.residual_count} residuals for {len(x0)} unknowns: record '
                         f'more poses or free fewer parameters')
    monitor = _Monitor(problem, loss, f_scale, callback)
    if not np.all(np.isfinite(monitor.residuals(x0))):
        raise ValueError('residuals are not finite at the start values: check params0 and '
                         'tool_xyz0')
    start = time.perf_counter()
    try:
        if solver == 'lm':
            x, iterations, stop = _solve_lm(problem, monitor, loss, f_scale, tolerance,
                                            max_iterations)
        else:
            monitor.iteration()
            x, iterations, stop = _solve_nelder_mead(
                monitor, max_iterations, max_evaluations, xatol, fatol, adaptive)
        code = ErrorCode.SUCCESS
        message = stop.message if stop.success else f'did not converge: {stop.message}'
    except _Cancelled:
        x, iterations, code = monitor.best_x, monitor.iterations, ErrorCode.CANCELED
        message = f'cancelled by the callback at iteration {iterations}'
        stop = Stop(False, message)
    seconds = time.perf_counter() - start
    return _result(problem, monitor, x, parameter_set.free, iterations, seconds, code,
                   message, stop.success)


def _solve_lm(problem, monitor: _Monitor, loss: str, f_scale: float, tolerance: float,
              max_iterations: int | None) -> tuple[Array, int, Stop]:
    """trf with ``loss``; a robust loss starts from the least-squares solution.

    From the nominal start the residuals (~1 mm) lie far out in a robust loss's tail
    (f_scale 0.1 mm), where trf's rescaled steps crawl: soft-L1 took 22 iterations on the
    bench's 3 x 625 poses where the linear loss takes 3. From the least-squares solution it
    takes 2 more, to the same minimum of the robust cost (3e-11 m apart there, within the
    stopping tolerance). ``max_iterations`` caps the residual evaluations of both stages.
    """
    last_x = [b'']

    def jacobian(x: Array) -> Array:
        J = problem.jacobian(x)
        if x.tobytes() != last_x[0]:   # not the second stage's start, the first's end
            monitor.iteration()        # trf evaluates the Jacobian once per accepted step
        last_x[0] = x.tobytes()
        return J

    def solve(x0: Array, stage_loss: str, max_nfev: int | None):
        return least_squares(monitor.residuals, x0, jac=jacobian, method='trf',
                             loss=stage_loss, f_scale=f_scale, x_scale='jac', ftol=tolerance,
                             xtol=tolerance, gtol=tolerance, max_nfev=max_nfev)

    x0, budget = problem.x0, max_iterations
    if loss != 'linear':
        first = solve(x0, 'linear', budget)
        if first.status <= 0:
            return first.x, monitor.iterations, Stop(False, str(first.message))
        x0 = first.x
        budget = None if budget is None else max(budget - first.nfev, 1)
    res = solve(x0, loss, budget)
    return res.x, monitor.iterations, Stop(res.status > 0, str(res.message))


def _solve_nelder_mead(monitor: _Monitor, max_iterations: int | None,
                       max_evaluations: int | None, xatol: float, fatol: float,
                       adaptive: bool) -> tuple[Array, int, Stop]:
    x0 = monitor.objective.x0
    U = len(x0)

    def cost(z: Array) -> float:
        return monitor.cost(monitor.residuals(x0 + NM_STEP * z))

    simplex = np.vstack([np.zeros(U), np.eye(U)])
    res = minimize(cost, np.zeros(U), method='Nelder-Mead',
                   callback=lambda _z: monitor.iteration(),
                   options={'maxiter': max_iterations, 'maxfev': max_evaluations,
                            'xatol': xatol, 'fatol': fatol, 'adaptive': adaptive,
                            'initial_simplex': simplex})
    return x0 + NM_STEP * res.x, monitor.iterations, Stop(bool(res.success), str(res.message))


def _result(problem, monitor: _Monitor, x: Array, free: tuple[str, ...], iterations: int,
            seconds: float, code: ErrorCode, message: str,
            converged: bool) -> IdentificationResult:
    r = problem.residuals(x)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(r))):
        raise ValueError(f'the solver ended on non-finite values ({message}): check the data '
                         f'for coincident spheres and the start values')
    std, undetermined = _standard_deviations(problem.jacobian(x), r, len(free))
    params, tool_xyz, extra = problem.solution(x)
    extra.update(objective=problem.objective, form=problem.form)
    if undetermined.any():
        names = [n for n, u in zip(free, undetermined) if u]
        extra['unidentifiable'] = names
        message += f'; not determined by these data: {", ".join(names)}'
    return IdentificationResult(params, tool_xyz, free, std, iterations, monitor.cost(r),
                                float(np.sqrt(np.mean(r * r))), seconds, code, message,
                                extra, converged)
