"""Failure as a value: the error codes shared by core results and the node interfaces."""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum


class ErrorCode(IntEnum):
    """Matches the constants of cobot_calib_msgs/srv/CalibrateUserFrame."""

    SUCCESS = 0
    TOO_FEW_POINTS = 1
    DEGENERATE_POINTS = 2
    INVALID_INPUT = 3
    UNKNOWN_METHOD = 4
    UNKNOWN_POINT = 5
    CAPTURE_FAILED = 6
    STORAGE_FAILED = 7
    IMPLAUSIBLE_FIT = 8


class MotionCode(IntEnum):
    """Matches the error constants of cobot_calib_msgs/action/MoveTo."""

    SUCCESS = 0
    UNREACHABLE = 1
    INVALID_TARGET = 2
    CANCELED = 3


@dataclass(frozen=True)
class Failure:
    """Falsy: what went wrong (``code``, an IntEnum of the interface it answers) and what to do."""

    code: IntEnum
    message: str

    def __bool__(self) -> bool:
        return False
