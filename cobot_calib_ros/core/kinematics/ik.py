"""Inverse kinematics with pinocchio: the only module of the package that imports it.

Pinocchio is imported where it is used: every node and most commands import this module
through the kinematic models, and most never solve a pose (its import is ~130 ms of CPU per
process).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.kinematics.model import _as_batch, Chain

if TYPE_CHECKING:
    import pinocchio as pin

Array = NDArray[np.float64]

def to_pinocchio(chain: Chain) -> pin.Model:
    """Pinocchio model of the chain: RZ joints (PZ where prismatic), frames 'flange' and
    'tool' on the last joint."""
    import pinocchio as pin
    model = pin.Model()
    model.name = 'chain'
    parent = 0
    for i, name in enumerate(chain.joint_names):
        joint = pin.JointModelPZ() if chain.prismatic[i] else pin.JointModelRZ()
        parent = model.addJoint(parent, joint, pin.SE3(chain.placements[i]), name)
        model.addJointFrame(parent)
    model.lowerPositionLimit = np.array(chain.lower)
    model.upperPositionLimit = np.array(chain.upper)
    last_frame = model.nframes - 1
    flange = pin.Frame('flange', parent, last_frame, pin.SE3(chain.flange),
                       pin.FrameType.OP_FRAME)
    model.addFrame(flange, False)
    tool = pin.Frame('tool', parent, last_frame, pin.SE3(chain.flange @ chain.tool),
                     pin.FrameType.OP_FRAME)
    model.addFrame(tool, False)
    return model


@lru_cache(maxsize=32)
def _cached_pinocchio(chain: Chain) -> pin.Model:
    """to_pinocchio, cached per Chain object (Chain compares and hashes by identity)."""
    return to_pinocchio(chain)


@dataclass(frozen=True)
class IkResult:
    """Inverse kinematics result; falsy on failure (``code`` MOTION_FAILED: not reached)."""

    q: Array                   # (n,) [rad], the last iterate (within limits) even on failure
    code: ErrorCode
    position_error: float      # [m]
    orientation_error: float   # [rad]; nan when position_only
    iterations: int
    message: str = ''

    def __bool__(self) -> bool:
        return self.code == ErrorCode.SUCCESS


_STALL_ITERATIONS = 20  # give up after this many iterations without progress
_MAX_STEP = 0.5         # [rad] the largest joint step of an iteration


def solve_ik(chain: Chain, T_base_tool_target: ArrayLike, q_seed: ArrayLike, *,
             position_only: bool = False, tol: float = 1e-10,
             max_iter: int = 200) -> IkResult:
    """Joint angles [rad] putting the tool at T_base_tool_target (4, 4), from q_seed (n,).

    Damped least squares on the SE(3) log error; each iterate is clipped to the joint limits,
    so a returned solution respects them. Redundancy resolves towards the seed. Converged when
    position error < tol [m] and, unless position_only, rotation error < tol [rad].
    Unreachable or limit-blocked targets return success False with a message.

    One loop without helper calls or objects per iteration: the candidate pools' IK runs
    ~10^6 iterations (~20 us each, 22 s for the iiwa 7's), most of them in solves that fail.
    Hence the norms as sqrt(v @ v) (np.linalg.norm's arithmetic without its per-call cost)
    and the step's solve by LAPACK's Cholesky (dposv) called directly (J J^T + damping I is
    positive definite; np.linalg.solve where rounding makes the factorisation fail).
    """
    import pinocchio as pin
    from scipy.linalg.lapack import dposv
    model = _cached_pinocchio(chain)
    data = model.createData()
    frame = model.getFrameId('tool')
    target = pin.SE3(np.asarray(T_base_tool_target, dtype=float))
    target_position = target.translation
    lower, upper = chain.lower, chain.upper
    q = np.clip(_as_batch(chain, q_seed)[0], lower, upper)
    orientation = math.nan
    best, stalled = math.inf, 0
    for iteration in range(max_iter + 1):
        pin.computeJointJacobians(model, data, q)  # also runs forward kinematics
        current = pin.updateFramePlacement(model, data, frame)
        offset = current.translation - target_position
        position = math.sqrt(offset @ offset)
        if position_only:
            error = offset
        else:
            delta = target.actInv(current)  # T_target_tool, identity at the solution
            error = pin.log6(delta).vector  # its angular part is log3(delta.rotation)
            angular = error[3:]
            orientation = math.sqrt(angular @ angular)
        if position < tol and (position_only or orientation < tol):
            return IkResult(q, ErrorCode.SUCCESS, position, orientation, iteration,
                            'converged')
        squared = float(error @ error)
        size = math.sqrt(squared)
        best, stalled = (size, 0) if size < best * (1.0 - 1e-6) else (best, stalled + 1)
        if iteration == max_iter or stalled >= _STALL_ITERATIONS:
            break
        # the task Jacobian d error / dq from the LOCAL frame Jacobian (rotated for position)
        J = pin.getFrameJacobian(model, data, frame, pin.LOCAL)
        J = current.rotation @ J[:3] if position_only else pin.Jlog6(delta) @ J
        # damped least-squares step dq = -J^T (J J^T + damping I)^-1 e, damping ~ |e|^2,
        # its largest component at most _MAX_STEP
        A = J @ J.T
        A.flat[::len(error) + 1] += squared + 1e-12
        _, x, info = dposv(A, error)
        dq = J.T @ (x if info == 0 else np.linalg.solve(A, error))
        largest = max(dq.max(), -dq.min())
        if largest > _MAX_STEP:
            dq *= _MAX_STEP / largest
        q = np.minimum(np.maximum(q - dq, lower), upper)
    return IkResult(q, ErrorCode.MOTION_FAILED, position, orientation, iteration,
                    _failure_message(chain, q, position, orientation, iteration))


def _failure_message(chain: Chain, q: Array, position: float, orientation: float,
                     iterations: int) -> str:
    at_limit = [n for n, v, lo, hi in zip(chain.joint_names, q, chain.lower, chain.upper)
                if v <= lo or v >= hi]
    limits = f'; joints at limits: {", ".join(at_limit)}' if at_limit else ''
    return (f'no convergence after {iterations} iterations: position error {position:.3g} m, '
            f'orientation error {orientation:.3g} rad{limits}')


def solve_ik_with_restarts(chain: Chain, T_base_tool_target: ArrayLike, q_seed: ArrayLike,
                           home: ArrayLike, margin: float = 0.0) -> IkResult:
    """:func:`solve_ik` from ``q_seed``, then from ``home`` and from home with the last joint
    turned by -pi/2 and +pi/2: the local solver can stall at a joint limit, typically the
    wrist's when the tool orientation changes a lot. The first success at least ``margin``
    [rad] inside every joint limit, else the first failure (a solution only closer than
    ``margin`` to a limit fails, its message naming the joints and the limits)."""
    home = np.asarray(home, dtype=float)
    turn = np.zeros_like(home)
    turn[-1] = math.pi / 2
    first = None
    for seed in (q_seed, home, home - turn, home + turn):
        result = solve_ik(chain, T_base_tool_target, seed)
        if result and margin > 0.0:
            result = _inside(chain, result, margin)
        if result:
            return result
        if first is None:
            first = result
    return first


def _inside(chain: Chain, result: IkResult, margin: float) -> IkResult:
    """``result`` itself when its joints are ``margin`` [rad] inside their limits, else a
    failure naming the joints that are closer and their limits."""
    q = result.q
    near = [f'{name} {math.degrees(v):.1f} deg (limits {math.degrees(lo):.1f} .. '
            f'{math.degrees(hi):.1f})'
            for name, v, lo, hi in zip(chain.joint_names, q, chain.lower, chain.upper)
            if v < lo + margin or v > hi - margin]
    if not near:
        return result
    return IkResult(q, ErrorCode.MOTION_FAILED, result.position_error,
                    result.orientation_error, result.iterations,
                    f'within {math.degrees(margin):.1f} deg of a joint limit: '
                    + ', '.join(near))
