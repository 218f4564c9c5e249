"""Redundant parameters: the paper's Algorithm 1 on the stacked tool-position Jacobian.

Rank and condition number are numpy.linalg.matrix_rank and numpy.linalg.cond (2-norm, SVD),
as in the paper. While the rank is below the number of columns, every column whose removal
keeps the rank is tried, and the one leaving the smallest condition number goes.

Caveat, inherent to the algorithm: while the matrix is still rank deficient, the condition
numbers compared are ~1e16, set by rounding, so the choice among parameters that are
redundant *with each other* is arbitrary (it can change with the configurations or the BLAS);
the rank, the number kept and the space they span do not. ``Dropped.condition_after`` shows
it: values above ~1e12 mean "another member of the same redundant group would have done".
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.kinematics.identification.parameters import ParameterSet
from cobot_calib_ros.core.kinematics.model import KinematicModel

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Dropped:
    """A parameter left out, why, and the Jacobian's condition number before/after."""

    name: str
    reason: str
    condition_before: float
    condition_after: float


@dataclass(frozen=True)
class Identifiability:
    """Algorithm 1's outcome: parameters to identify, those dropped (in order), the rank of
    the candidates' Jacobian and the condition number with only ``kept``."""

    kept: tuple[str, ...]
    dropped: tuple[Dropped, ...]
    rank: int
    condition_number: float


REDUNDANT = 'redundant (Algorithm 1: removing it keeps the rank, lowest condition number)'


def uniform_configurations(model: KinematicModel, count: int, seed: int) -> Array:
    """(count, n) joint angles [rad] drawn uniformly within the joint limits (paper: 29)."""
    if not (np.all(np.isfinite(model.lower)) and np.all(np.isfinite(model.upper))):
        raise ValueError(f'model {model.name!r} has unbounded joints: give configurations')
    rng = np.random.default_rng(seed)
    return rng.uniform(model.lower, model.upper, (count, len(model.lower)))


def base_motion_columns(p: ArrayLike) -> Array:
    """(3 m, 6) d p / d (small rigid motion of the base: translation [m], rotation [rad]) for
    positions p (m, 3) [m]: the 6 dof a world frame (or relative data) leaves unobservable."""
    p = np.asarray(p, dtype=float)
    translation = np.broadcast_to(np.eye(3), (len(p), 3, 3))
    rotation = -np.cross(p[:, :, None], np.eye(3)[None, :, :], axis=1)  # w x p = -[p]x w
    return np.concatenate([translation, rotation], axis=2).reshape(-1, 6)


def find_redundant(model: KinematicModel, q: ArrayLike, tool_xyz: ArrayLike,
                   candidates: tuple[str, ...],
                   excluded: dict[str, str] | None = None,
                   rank_rtol: float | None = None,
                   base_frame: bool = False,
                   keep: tuple[str, ...] = ()) -> Identifiability:
    """Run Algorithm 1 on the position Jacobian of ``candidates`` at the nominal model.

    q (m, n) [rad], tool centre ``tool_xyz`` (3,) [m] in the flange. ``excluded`` maps names
    left out a priori to the reason (e.g. the first joint's row: 'tied to the world frame').
    They come first in ``dropped``, whether or not they are among the candidates: their
    columns are appended to the candidates' and removed one by one, the condition numbers
    being those of the Jacobian with and without each.

    ``rank_rtol``: singular values below rank_rtol times the largest count as zero; None is
    numpy's default (the paper's), max(3 m, columns) * eps. Models whose nominal angles are
    rounded (the Sawyer URDF's 1.57079632679 for pi/2) have near-redundancies ~1e-12 above that
    default: pass e.g. 1e-10 there, or Algorithm 1 keeps a ~1e12-conditioned set.

    ``base_frame`` (not in the paper): also append the 6 columns of a rigid base motion
    (:func:`base_motion_columns`), never removed, so that parameters equivalent to moving the
    base go too. Both objectives of :func:`identify` leave that motion free (relative data do
    not see it, the absolute objective fits T_world_base). For MDH the first row, excluded a
    priori, covers it; for origin (URDF) models the second joint's z, a translation along
    joint 1's axis, does not get caught otherwise. ``rank`` and ``condition_number`` then
    count the base columns (rank minus 6, so that len(kept) == rank).

    ``keep`` (not in the paper): candidates never removed; a parameter redundant with one of
    them goes instead. Used for the tool: the flange-side part of an arm/tool redundancy (the
    last joint's d against tool_z) is then attributed to the tool, which is remounted for every
    tool, and the arm keeps its nominal value there.
    """
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or not np.all(np.isfinite(q)):
        raise ValueError(f'q must be (m, n) finite joint angles [rad], got shape {q.shape}')
    excluded = dict(excluded or {})
    keep = tuple(keep)
    unknown = [n for n in keep if n not in candidates]
    if unknown:
        raise ValueError(f'keep names {unknown} that are not candidates')
    names = [n for n in candidates if n not in keep] + [n for n in excluded
                                                        if n not in candidates]
    p, J = ParameterSet(model, tuple(names) + keep).positions_and_jacobian(None, tool_xyz, q)
    J = J.reshape(-1, len(names) + len(keep))
    J, J_keep = J[:, :len(names)], J[:, len(names):]
    fixed = np.hstack([base_motion_columns(p) if base_frame else np.empty((len(J), 0)),
                       J_keep])

    base_columns = fixed.shape[1] - len(keep)
    rows = len(J)

    def rank_and_condition(columns: Array, fixed: Array = fixed) -> tuple[int, float]:
        """numpy's matrix_rank and cond of [columns fixed] as if it had ``rows`` rows, from
        one SVD."""
        full = np.hstack([columns, fixed])
        s = np.linalg.svd(full, compute_uv=False)
        rtol = rank_rtol if rank_rtol is not None else max(rows, full.shape[1]) * np.finfo(
            float).eps
        return int(np.count_nonzero(s > s[0] * rtol)) - base_columns, float(s[0] / s[-1])

    dropped = []
    for name, reason in excluded.items():
        k = names.index(name)
        before = dropped[-1].condition_after if dropped else rank_and_condition(J)[1]
        J, _ = np.delete(J, k, axis=1), names.pop(k)
        dropped.append(Dropped(name, reason, before, rank_and_condition(J)[1]))
    # Every trial below is a subset of the columns of [J fixed] = Q R, whose singular values
    # are those of the same columns of R (Q has orthonormal columns): the ranks of the trials
    # come from R, (c, c) instead of (3 m, c). The condition numbers that choose among the
    # removals keeping the rank come from the full matrix as before: while it is rank
    # deficient they are rounding noise (module doc), and R's noise picked other members of
    # the Sawyer's redundant groups, whose model carried the coupling's fit worse to the probe
    # (test_demo_with_kinematics: 3.5x -> 1.7x). The bench's 1875 poses: 0.55 s -> 0.05 s.
    R = np.linalg.qr(np.hstack([J, fixed]), mode='r')
    J_r, fixed_r = R[:, :J.shape[1]], R[:, J.shape[1]:]
    if keep and rank_and_condition(J_r[:, :0], fixed_r)[0] < len(keep):
        raise ValueError(f'the kept parameters {keep} are themselves redundant on these data')
    rank, condition = rank_and_condition(J)
    while rank - len(keep) < J.shape[1]:
        best, best_condition = -1, np.inf
        for k in range(J.shape[1]):
            if rank_and_condition(np.delete(J_r, k, axis=1), fixed_r)[0] != rank:
                continue
            c = rank_and_condition(np.delete(J, k, axis=1))[1]
            if best < 0 or c < best_condition:
                best, best_condition = k, c
        J, J_r = np.delete(J, best, axis=1), np.delete(J_r, best, axis=1)
        dropped.append(Dropped(names.pop(best), REDUNDANT, condition, best_condition))
        condition = best_condition
    return Identifiability(tuple(names) + keep, tuple(dropped), rank, condition)
