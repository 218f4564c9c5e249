"""The live view's markers (visualization_msgs/MarkerArray, latched on ``cobot_calib/markers``):
what a calibration measured, for RViz, Foxglove or Lichtblick (``cobot-calib view``).

One ``ns`` per layer, each array starting with a DELETEALL of each of its own layers (RViz 2
clears only that ``ns``), so a new result replaces the last one of the same producer and leaves
the other producers' layers; every marker is in the base frame [m]:
- ``user_frame/points``: the touched (measured) points, SPHERE_LIST, red where an outlier;
- ``user_frame/residuals``: an ARROW per point, measured -> fitted, drawn RESIDUAL_GAIN times
  longer (0.1 mm shows as 1 cm), green to red as |r| goes from 0 to the fit's gate;
- ``user_frame/frame``: the user frame's axes, three ARROWs (x red, y green, z blue);
- ``user_frame/labels``: the point names;
- ``kinematics/spheres`` and ``kinematics/poses``: the sphere centres (nominal) and the
  coupling positions collected on them so far (nominal model; kinematic_identifier).
A landmark calibration's landmarks show as its points (user_frame/points).
"""
from __future__ import annotations

from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point
import numpy as np
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from cobot_calib_ros.ros import qos

TOPIC = 'cobot_calib/markers'
QOS = qos.LATCHED
RESIDUAL_GAIN = 100.0      # [1] residual arrows are drawn this many times their length
AXIS_LENGTH = 0.1          # [m] of a frame's axes
POINT_DIAMETER = 0.01      # [m]
RED, GREEN, BLUE, WHITE = (1.0, 0.2, 0.2), (0.2, 0.8, 0.2), (0.2, 0.4, 1.0), (1.0, 1.0, 1.0)


def _colour(rgb, alpha: float = 1.0) -> ColorRGBA:
    return ColorRGBA(r=float(rgb[0]), g=float(rgb[1]), b=float(rgb[2]), a=alpha)


def _point(p) -> Point:
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def gate_colour(norm: float, gate: float) -> tuple[float, float, float]:
    """Green at 0, red at ``gate`` and beyond [m]."""
    f = min(max(norm / gate, 0.0), 1.0) if gate > 0 else 1.0
    return (GREEN[0] + f * (RED[0] - GREEN[0]), GREEN[1] + f * (RED[1] - GREEN[1]),
            GREEN[2] + f * (RED[2] - GREEN[2]))


USER_FRAME_LAYERS = ('user_frame/points', 'user_frame/residuals', 'user_frame/frame',
                     'user_frame/labels')
SPHERE_LAYERS = ('kinematics/spheres', 'kinematics/poses')


def cleared(layers: tuple[str, ...]) -> MarkerArray:
    """Only the DELETEALLs of these layers: what a producer latches when it has nothing."""
    return MarkerArray(markers=[Marker(ns=ns, action=Marker.DELETEALL) for ns in layers])


class Layers:
    """A MarkerArray under construction, for one frame, clearing ``layers`` first; ids count
    per ns."""

    def __init__(self, frame_id: str, stamp, layers: tuple[str, ...]) -> None:
        self.frame_id, self.stamp = frame_id, stamp
        self.array = cleared(layers)
        self._ids: dict[str, int] = {}

    def add(self, ns: str, kind: int, scale, colour=WHITE, **fields) -> Marker:
        marker = Marker(ns=ns, id=self._ids.get(ns, 0), type=kind, action=Marker.ADD,
                        lifetime=Duration(), frame_locked=False, **fields)
        self._ids[ns] = marker.id + 1
        marker.header.frame_id, marker.header.stamp = self.frame_id, self.stamp
        marker.pose.orientation.w = 1.0
        marker.scale.x, marker.scale.y, marker.scale.z = map(float, scale)
        marker.color = _colour(colour)
        self.array.markers.append(marker)
        return marker

    def points(self, ns: str, positions, colours=None, diameter: float = POINT_DIAMETER):
        """A SPHERE_LIST; ``colours``: one (r, g, b) per point, or one for all."""
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        marker = self.add(ns, Marker.SPHERE_LIST, (diameter,) * 3,
                          points=[_point(p) for p in positions])
        if colours is not None:
            marker.colors = [_colour(c) for c in colours]
        return marker

    def arrow(self, ns: str, start, end, colour, shaft: float = 0.002) -> Marker:
        return self.add(ns, Marker.ARROW, (shaft, 2 * shaft, 0.0), colour,
                        points=[_point(start), _point(end)])

    def axes(self, ns: str, T: np.ndarray, length: float = AXIS_LENGTH) -> None:
        """A frame (4, 4) in base: its x, y, z axes as arrows."""
        for axis, colour in zip(range(3), (RED, GREEN, BLUE)):
            self.arrow(ns, T[:3, 3], T[:3, 3] + length * T[:3, axis], colour, shaft=0.004)

    def text(self, ns: str, position, text: str, height: float = 0.015) -> Marker:
        marker = self.add(ns, Marker.TEXT_VIEW_FACING, (0.0, 0.0, height), WHITE, text=text)
        marker.pose.position = _point(position)
        return marker


def user_frame_markers(calibration, gate: float) -> MarkerArray:
    """The layers of one cobot_calib_msgs/UserFrameCalibration; ``gate`` [m]: the residual
    that shows fully red (the solver's RMS limit)."""
    layers = Layers(calibration.transform.header.frame_id, calibration.stamp, USER_FRAME_LAYERS)
    residuals = calibration.residuals
    measured = np.array([[r.point_base.x, r.point_base.y, r.point_base.z] for r in residuals])
    if len(residuals):
        layers.points('user_frame/points', measured,
                      [RED if r.outlier else WHITE for r in residuals])
    for r, p in zip(residuals, measured):
        d = np.array([r.residual.x, r.residual.y, r.residual.z])
        layers.arrow('user_frame/residuals', p, p + RESIDUAL_GAIN * d,
                     gate_colour(r.residual_norm, gate))
        layers.text('user_frame/labels', p + [0.0, 0.0, 0.02],
                    f'{r.name} {r.residual_norm * 1e3:.3f} mm')
    layers.axes('user_frame/frame', np.array(calibration.matrix).reshape(4, 4))
    return layers.array


def sphere_markers(frame_id: str, stamp, centres, collected) -> MarkerArray:
    """The sphere plate's centres and the coupling positions collected on them [m] (base)."""
    layers = Layers(frame_id, stamp, SPHERE_LAYERS)
    if len(centres):
        layers.points('kinematics/spheres', centres, diameter=0.025)
    if len(collected):
        layers.points('kinematics/poses', collected, [BLUE] * len(collected), diameter=0.006)
    return layers.array
