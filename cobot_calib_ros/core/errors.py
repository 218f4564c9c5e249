"""Failure as a value: one list of causes (ErrorCode) and one falsy Failure(code, message).

Core results carry a Failure's code and message (or are one); each ROS interface maps a cause to
its own result constant in ros/results.py, the one place that knows the interfaces' numbers. A
node helper that cannot return a Failure raises it as a :class:`Refusal`.
The first nine causes keep the numbers of CalibrateUserFrame's constants.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum


class ErrorCode(IntEnum):
    """Why something failed: the causes every result and interface shares."""

    SUCCESS = 0
    TOO_FEW_POINTS = 1       # too few points / views / samples to fit
    DEGENERATE_POINTS = 2    # collinear, duplicate, or views that do not rotate
    INVALID_INPUT = 3        # malformed request or data (NaN, shapes, unknown names)
    UNKNOWN_METHOD = 4
    UNKNOWN_POINT = 5
    CAPTURE_FAILED = 6       # a measurement (joints, image) could not be taken
    STORAGE_FAILED = 7       # the store could not be written: disk full, no permission, no database
    IMPLAUSIBLE_FIT = 8      # a result beyond what its data allows (units? order?)
    NO_DATA = 9              # nothing to work on: no samples, no collection
    MOTION_FAILED = 10       # the robot did not reach a target (unreachable, no IK)
    PROBE_FAILED = 11        # the distance probe gave no usable reading
    SOLVER_FAILED = 12       # an estimator failed numerically or did not converge
    CANCELED = 13
    NO_CALIBRATION = 14      # no such (or no active) calibration
    MOVING = 15              # the arm moved while it should stand still
    OUT_OF_RANGE = 16        # readings outside the instrument's range
    NOT_AVAILABLE = 17       # the cell has no such instrument
    BUSY = 18                # another job is running
    FOREIGN_RESULT = 19      # a stored result of another cell or robot (store.cells)


@dataclass(frozen=True)
class Failure:
    """Falsy: what went wrong (``code``, an ErrorCode) and what to do."""

    code: ErrorCode
    message: str

    def __bool__(self) -> bool:
        return False


class Refusal(Exception):
    """A Failure raised, where a helper deep in a request cannot return it; the handler catches
    it and answers ``failure`` (ros/results.py). The one exception that carries a cause."""

    def __init__(self, failure: Failure) -> None:
        super().__init__(failure.message)
        self.failure = failure


def first_failure(*checks: Failure | None) -> Failure | None:
    """The first of ``checks`` that is a Failure, else None (a Failure is falsy: checks that
    return ``Failure | None`` cannot be chained with ``or``)."""
    return next((check for check in checks if check is not None), None)
