"""Each interface's result constant for a failure's cause (core.errors.ErrorCode): one table each.

A node answers a Failure with ``code(interface, failure.code)``, :func:`fill` or :func:`answer`,
never with an interface's constant or the cause's own number: the interfaces number their
constants differently (test/nodes/test_answers.py scans the nodes for any other way). Every
table is total: a cause an interface has no constant of maps to the nearest one it has (listed
explicitly), so a new cause can never reach a client as a number the interface does not define
(test/ros/test_results.py checks it, and that every constant is some cause's answer).
"""
from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

from cobot_calib_msgs.action import (CalibrateHandEye, CalibrateIntrinsics, CalibrateTcp,
                                     CollectSphereData, IdentifyKinematics, MoveTo, RunTrial)
from cobot_calib_msgs.srv import (AverageProximity, CalibrateUserFrame, CaptureJoints,
                                  ConvertPoints, HandGuide, MeasurePosition,
                                  SetActiveCalibration)

from cobot_calib_ros.core.errors import ErrorCode as E, Failure


@dataclass(frozen=True)
class Table:
    """One interface: the class holding its constants and the constant's name of each cause."""

    constants: type
    names: Mapping[E, str]

    def code(self, cause: E) -> int:
        return int(getattr(self.constants, self.names[E(cause)]))


def _table(constants: type, *groups: tuple[str, tuple[E, ...]]) -> Table:
    names = {cause: name for name, causes in groups for cause in causes}
    return Table(constants, MappingProxyType(names))


_FIT = (E.TOO_FEW_POINTS, E.DEGENERATE_POINTS, E.IMPLAUSIBLE_FIT, E.SOLVER_FAILED)
_ROBOT = (E.CAPTURE_FAILED, E.MOTION_FAILED, E.PROBE_FAILED, E.NO_DATA, E.MOVING,
          E.OUT_OF_RANGE, E.NOT_AVAILABLE)
_REQUEST = (E.INVALID_INPUT, E.UNKNOWN_METHOD, E.UNKNOWN_POINT, E.NO_CALIBRATION, E.BUSY,
            E.FOREIGN_RESULT)

TABLES: Mapping[str, Table] = MappingProxyType({
    'CalibrateUserFrame': _table(
        CalibrateUserFrame.Response, *((c.name, (c,)) for c in (
            E.SUCCESS, E.TOO_FEW_POINTS, E.DEGENERATE_POINTS, E.INVALID_INPUT, E.UNKNOWN_METHOD,
            E.UNKNOWN_POINT, E.CAPTURE_FAILED, E.STORAGE_FAILED, E.IMPLAUSIBLE_FIT)),
        ('CAPTURE_FAILED', (E.MOTION_FAILED, E.PROBE_FAILED, E.NO_DATA, E.MOVING,
                            E.OUT_OF_RANGE, E.NOT_AVAILABLE, E.CANCELED)),
        ('IMPLAUSIBLE_FIT', (E.SOLVER_FAILED,)),
        ('INVALID_INPUT', (E.NO_CALIBRATION, E.BUSY, E.FOREIGN_RESULT))),
    'CalibrateHandEye': _table(
        CalibrateHandEye.Result, ('SUCCESS', (E.SUCCESS,)), ('INVALID_GOAL', _REQUEST),
        ('TOO_FEW_VIEWS', (E.TOO_FEW_POINTS,)),
        ('SOLVER_FAILED', (E.DEGENERATE_POINTS, E.IMPLAUSIBLE_FIT, E.SOLVER_FAILED)),
        ('MOTION_FAILED', (E.MOTION_FAILED,)),
        ('CAPTURE_FAILED', (E.CAPTURE_FAILED, E.PROBE_FAILED, E.NO_DATA, E.MOVING,
                            E.OUT_OF_RANGE, E.NOT_AVAILABLE)),
        ('STORAGE_FAILED', (E.STORAGE_FAILED,)), ('CANCELED', (E.CANCELED,))),
    'CalibrateIntrinsics': _table(
        CalibrateIntrinsics.Result, ('SUCCESS', (E.SUCCESS,)), ('INVALID_GOAL', _REQUEST),
        ('TOO_FEW_VIEWS', (E.TOO_FEW_POINTS,)),
        ('SOLVER_FAILED', (E.DEGENERATE_POINTS, E.SOLVER_FAILED)),
        ('REJECTED', (E.IMPLAUSIBLE_FIT,)),
        ('CAPTURE_FAILED', _ROBOT),
        ('STORAGE_FAILED', (E.STORAGE_FAILED,)), ('CANCELED', (E.CANCELED,))),
    'CalibrateTcp': _table(
        CalibrateTcp.Result, ('SUCCESS', (E.SUCCESS,)), ('INVALID_GOAL', _REQUEST),
        ('TOO_ALIKE', (E.DEGENERATE_POINTS,)),
        ('SOLVER_FAILED', (E.TOO_FEW_POINTS, E.SOLVER_FAILED)),
        ('REJECTED', (E.IMPLAUSIBLE_FIT,)),
        ('MOTION_FAILED', (E.MOTION_FAILED,)),
        ('CAPTURE_FAILED', (E.CAPTURE_FAILED, E.PROBE_FAILED, E.NO_DATA, E.MOVING,
                            E.OUT_OF_RANGE, E.NOT_AVAILABLE)),
        ('STORAGE_FAILED', (E.STORAGE_FAILED,)), ('CANCELED', (E.CANCELED,))),
    'CollectSphereData': _table(
        CollectSphereData.Result, ('SUCCESS', (E.SUCCESS,)), ('INVALID_GOAL', _REQUEST + _FIT),
        ('MOTION_FAILED', (E.MOTION_FAILED,)),
        ('CAPTURE_FAILED', (E.CAPTURE_FAILED, E.PROBE_FAILED, E.NO_DATA, E.MOVING,
                            E.OUT_OF_RANGE, E.NOT_AVAILABLE)),
        ('STORAGE_FAILED', (E.STORAGE_FAILED,)), ('CANCELED', (E.CANCELED,))),
    'IdentifyKinematics': _table(
        IdentifyKinematics.Result, ('SUCCESS', (E.SUCCESS,)), ('INVALID_GOAL', _REQUEST),
        ('NO_DATA', _ROBOT), ('SOLVER_FAILED', _FIT),
        ('STORAGE_FAILED', (E.STORAGE_FAILED,)), ('CANCELED', (E.CANCELED,))),
    'RunTrial': _table(
        RunTrial.Result, ('SUCCESS', (E.SUCCESS,)), ('INVALID_GOAL', _REQUEST + _FIT),
        ('MOTION_FAILED', (E.MOTION_FAILED, E.CAPTURE_FAILED, E.MOVING)),
        ('PROBE_FAILED', (E.PROBE_FAILED, E.NO_DATA, E.OUT_OF_RANGE, E.NOT_AVAILABLE)),
        ('STORAGE_FAILED', (E.STORAGE_FAILED,)), ('CANCELED', (E.CANCELED,))),
    'MoveTo': _table(
        MoveTo.Result, ('SUCCESS', (E.SUCCESS,)),
        ('UNREACHABLE', (E.MOTION_FAILED, E.CAPTURE_FAILED, E.PROBE_FAILED, E.NO_DATA,
                         E.MOVING, E.OUT_OF_RANGE, E.NOT_AVAILABLE, E.STORAGE_FAILED) + _FIT),
        ('INVALID_TARGET', _REQUEST), ('CANCELED', (E.CANCELED,))),
    'HandGuide': _table(
        HandGuide.Response, ('SUCCESS', (E.SUCCESS,)), ('BUSY', (E.BUSY,)),
        ('UNREACHABLE', (E.MOTION_FAILED, E.CAPTURE_FAILED, E.PROBE_FAILED, E.NO_DATA,
                         E.MOVING, E.OUT_OF_RANGE, E.NOT_AVAILABLE, E.STORAGE_FAILED,
                         E.CANCELED) + _FIT),
        ('INVALID_TARGET', tuple(c for c in _REQUEST if c != E.BUSY))),
    'CaptureJoints': _table(
        CaptureJoints.Response, ('SUCCESS', (E.SUCCESS,)), ('MOVING', (E.MOVING,)),
        ('NO_DATA', (E.NO_DATA, E.CAPTURE_FAILED, E.MOTION_FAILED, E.PROBE_FAILED,
                     E.OUT_OF_RANGE, E.NOT_AVAILABLE, E.STORAGE_FAILED, E.CANCELED) + _FIT),
        ('BAD_REQUEST', _REQUEST)),
    'AverageProximity': _table(
        AverageProximity.Response, ('SUCCESS', (E.SUCCESS,)), ('OUT_OF_RANGE', (E.OUT_OF_RANGE,)),
        ('NO_DATA', (E.NO_DATA, E.CAPTURE_FAILED, E.MOTION_FAILED, E.PROBE_FAILED, E.MOVING,
                     E.NOT_AVAILABLE, E.STORAGE_FAILED, E.CANCELED) + _FIT),
        ('BAD_REQUEST', _REQUEST)),
    'MeasurePosition': _table(
        MeasurePosition.Response, ('SUCCESS', (E.SUCCESS,)),
        ('NOT_AVAILABLE', tuple(c for c in E if c != E.SUCCESS))),
    'ConvertPoints': _table(
        ConvertPoints.Response, ('SUCCESS', (E.SUCCESS,)), ('NO_CALIBRATION', (E.NO_CALIBRATION,)),
        ('INVALID_INPUT', tuple(c for c in E if c not in (E.SUCCESS, E.NO_CALIBRATION)))),
    'SetActiveCalibration': _table(
        SetActiveCalibration.Response, ('SUCCESS', (E.SUCCESS,)),
        ('NO_CALIBRATION', (E.NO_CALIBRATION,)), ('STORAGE_FAILED', (E.STORAGE_FAILED,)),
        ('INVALID_INPUT', tuple(c for c in E
                                if c not in (E.SUCCESS, E.NO_CALIBRATION, E.STORAGE_FAILED)))),
})


def code(interface: str, cause: E) -> int:
    """The result constant of ``interface`` (a name of TABLES) for ``cause``."""
    return TABLES[interface].code(cause)


def interface_of(message) -> str:
    """The name in TABLES of the interface a result or response message (or its class) is of."""
    constants = message if isinstance(message, type) else type(message)
    for name, table in TABLES.items():
        if table.constants is constants:
            return name
    raise KeyError(f'{constants.__name__} has no table in ros/results.py; add one')


def answer(message, cause: E, text: str):
    """Set ``message.error_code`` to its own interface's constant for ``cause`` (an ErrorCode,
    never an interface's number) and ``message.message`` to ``text``; the message."""
    if not isinstance(cause, E):
        raise TypeError(f'a cause is a core.errors.ErrorCode, not {cause!r}: the interfaces '
                        'number their constants differently (ros/results.py)')
    message.error_code, message.message = code(interface_of(message), cause), text
    return message


def fill(message, interface: str, failure: Failure):
    """Set ``message.error_code`` and ``message.message`` from ``failure``; the message."""
    message.error_code, message.message = code(interface, failure.code), failure.message
    return message
