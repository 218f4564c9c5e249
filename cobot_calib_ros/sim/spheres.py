"""The sphere plate as it really stands, the compliant coupling, and a laser tracker.

Truth for the kinematic calibration of the second paper: the mock robot couples to the true
sphere centres (the coupling self-centres under impedance control) and the laser tracker
measures the true coupling centre. Metres, radians.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core import frames

Array = NDArray[np.float64]


@dataclass(frozen=True)
class LaserTracker:
    """Absolute position measurement of the coupling centre (an SMR in its place)."""

    T_base_tracker: Array   # (4, 4) tracker frame in the base frame
    sigma: float            # measurement noise per axis [m]

    def measure(self, p_base: Array, rng: np.random.Generator) -> Array:
        """(3,) the point ``p_base`` [m] as the tracker reports it, in the tracker frame."""
        p = frames.apply(frames.invert(self.T_base_tracker), p_base)
        return p + rng.normal(0.0, self.sigma, 3)


@dataclass(frozen=True)
class SphereTruth:
    centres_base: Array        # (k, 3) true sphere centres in the base frame [m]
    T_flange_coupling: Array   # (4, 4) true flange -> coupling centre
    capture_radius: float      # the coupling self-centres from up to this far [m]
    compliance_sigma: float    # residual centring error per axis [m]
    tracker: LaserTracker

    def nearest(self, p_base: Array) -> tuple[int, float]:
        """Index of the sphere nearest ``p_base`` and its centre's distance [m]."""
        d = np.linalg.norm(self.centres_base - p_base, axis=1)
        i = int(np.argmin(d))
        return i, float(d[i])
