"""The robot and the wrist camera as calibration procedures see them: two ports (Protocols).

A procedure in core (the trial, the landmark views, the hand-eye views, the sphere collection)
drives the cell only through these, so it runs the same over ROS (``ros.robot_calls.RobotCalls``
and ``ros.landmark_watch.LandmarkWatch``) and in-process on the simulation
(``sim.robot.DirectRobot`` and ``sim.camera.DirectCamera``), where a test can assert the ground
truth. SI units: joints [rad], poses (4, 4) in the base frame [m], durations [s], stamps [ns]
in the camera's clock.

Failures. A call that did not happen raises a :class:`PortError`: :class:`MoveFailed` for a
move or a touch (unreachable, refused, timed out; :class:`RobotStopped` when the arm was
stopped), :class:`CaptureFailed` for a joint capture, a probe reading, a tracker measurement or
a camera that sends no images, :class:`Stopped` for a cancel. The message says what to check;
the procedure decides whether that skips a pose or ends the run. These stay exceptions: they
are not a refusal of data (that is a core.errors.Failure, or a Refusal raised deep inside) but
a port call that did not happen, which a procedure cannot return past; at its edge
:func:`port_failure` turns them into the Failure it returns (MOTION_FAILED, CAPTURE_FAILED,
CANCELED).

Cancelling. A procedure takes ``cancelled: Cancelled`` (default :func:`never`) and calls it
between poses (never inside a port call): when it returns True the procedure stops at that pose
boundary and reports what it has, or raises :class:`Stopped` via :func:`check_cancel`.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import math
import re
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.sensors.probe import Reading

Array = NDArray[np.float64]
Cancelled = Callable[[], bool]     # True once the caller wants the procedure to stop


def never() -> bool:
    """The default ``cancelled``: never."""
    return False


class PortError(RuntimeError):
    """A robot or camera call that did not happen; the message says what to check."""


class MoveFailed(PortError):
    """A move or a touch did not end where it was sent (unreachable, refused, timed out)."""


class RobotStopped(MoveFailed):
    """The robot ended the move itself without reaching the target because it stopped (its
    driver shutting down): not a pose it cannot reach, so a collection ends there and a
    resume visits the pose again."""


class CaptureFailed(PortError):
    """A joint capture, probe reading, tracker measurement or camera image did not come."""


class Stopped(PortError):
    """The caller cancelled the procedure (raised between poses by :func:`check_cancel`)."""


def port_failure(error: PortError, suffix: str = '') -> Failure:
    """The Failure a procedure returns for a port call that did not happen (issue 39.2):
    Stopped CANCELED, MoveFailed MOTION_FAILED, any other CAPTURE_FAILED; ``suffix`` is
    appended to the message (e.g. '; nothing stored')."""
    code = (ErrorCode.CANCELED if isinstance(error, Stopped) else ErrorCode.MOTION_FAILED
            if isinstance(error, MoveFailed) else ErrorCode.CAPTURE_FAILED)
    return Failure(code, f'{error}{suffix}')


def check_cancel(cancelled: Cancelled, where: str) -> None:
    """Raise Stopped ('cancelled at <where>') when ``cancelled()`` is True."""
    if cancelled():
        raise Stopped(f'cancelled at {where}')


@dataclass(frozen=True)
class Capture:
    """Joints averaged over a hold."""

    q: Array                 # (n,) mean joint positions [rad], the model's joint order
    std: Array               # (n,) their standard deviation over the hold [rad]
    sample_count: int        # joint readings averaged


@dataclass(frozen=True)
class Approach:
    """How the tool comes onto a touched point (the TCP calibration's approaches).

    ``orientation``: the tool's (3, 3) orientation in the base frame. ``axis`` 'z' or 'x':
    not the point itself but the elongator point ``distance`` [m] from it along that axis of
    the tool, the tool turned as in ``orientation`` (ABB's 5- and 6-point methods)."""

    orientation: Array
    axis: str = ''
    distance: float = 0.0

    def describe(self, name: str) -> str:
        """What the operator is asked to do, in words."""
        if not self.axis:
            return f'the top-face centre of {name}, the tool tilted as planned'
        return (f'the elongator point {self.distance * 1e3:.0f} mm from {name} along the '
                f"tool's {self.axis}, without turning the tool from the first approach")


def elongator_problem(axis: str, distance: float) -> Failure | None:
    """None if (``axis``, ``distance`` [m]) names an elongator point ('' and 0: the point
    itself), else an INVALID_INPUT Failure saying what is wrong with it."""
    if not axis:
        return None if distance == 0.0 else Failure(
            ErrorCode.INVALID_INPUT, f'elongation {distance} m without an elongator axis')
    if axis not in ('z', 'x'):
        return Failure(ErrorCode.INVALID_INPUT, f"elongator axis {axis!r}: use 'z' or 'x'")
    if not math.isfinite(distance) or not 0.0 < abs(distance) < 1.0:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'elongation {distance} m: must be non-zero and within 1 m, e.g. -0.05')
    return None


class RobotPort(Protocol):
    """The arm, its encoders, the proximity probe and the laser tracker."""

    robot_seconds: float
    """Robot time spent so far [s]: moves (as the robot reports them), holds, probe windows."""

    def move_joints(self, q: Array, *, compliant: bool = False) -> Array:
        """Move to joints ``q`` [rad] (``compliant``: under impedance control, so a coupling
        near a sphere self-centres on it); the joints reached [rad]. MoveFailed."""

    def move_to_pose(self, T_base_tool: Array) -> Array:
        """Move the tool to a (4, 4) pose in the base frame, IK by the robot's own (nominal)
        model; the joints reached [rad]. MoveFailed."""

    def touch(self, name: str, approach: Approach | None = None) -> None:
        """Have the tool tip put onto the top of cell point ``name`` and return once it rests
        there: a real cell waits for the operator's confirmation after hand-guiding, the
        simulation hand-guides itself. ``approach``: with the tool in that orientation, or onto
        an elongator point (None: the cell's touch orientation). Capture the joints
        afterwards. MoveFailed."""

    def capture(self, duration: float) -> Capture:
        """The joints averaged over a hold of ``duration`` [s]. CaptureFailed."""

    def probe(self) -> Reading:
        """One averaged proximity reading (core.sensors.probe.average); out of range: status
        BELOW_RANGE / ABOVE_RANGE and a NaN distance. CaptureFailed when none came."""

    def measure_position(self) -> Array:
        """(3,) the tool position the laser tracker measures, in its frame [m]. CaptureFailed."""


@dataclass(frozen=True)
class Sighting:
    """One fiducial posed in one image."""

    kind: str                # 'marker' or 'board'
    id: int                  # marker id; a board: its first marker id
    T_optical_target: Array  # (4, 4) [m]
    covariance: Array        # (6, 6) of the pose (x y z rx ry rz), optical axes


@dataclass(frozen=True)
class LandmarkImage:
    """What the landmark detector found in one image, stamped with the camera's clock."""

    stamp_ns: int
    sightings: tuple[Sighting, ...]

    def find(self, kind: str, target_id: int | None = None) -> Sighting | None:
        """The first sighting of that kind (and id), else None."""
        return next((s for s in self.sightings if s.kind == kind
                     and (target_id is None or s.id == target_id)), None)


class CameraPort(Protocol):
    """The wrist camera with its landmark detector."""

    def now_ns(self) -> int:
        """The camera clock now [ns]: an image stamped after it shows the arm from now on."""

    def landmarks_after(self, t_ns: int, wanted: Callable[[LandmarkImage], bool],
                        max_images: int, timeout: float) -> LandmarkImage:
        """The first image stamped after ``t_ns`` for which ``wanted`` is true; else the last
        of the images looked at, when ``max_images`` were or ``timeout`` [s] passed. Raises
        CaptureFailed when no image stamped after ``t_ns`` came within ``timeout``."""
