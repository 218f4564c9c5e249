"""MUKCa sphere-socket data: its tables and MUKCa's consistency metric (identified held out
by the measurement path: loaders.measurements.load_socket_measurements, measurement_fit).

The core identification modules are imported directly (not through the package
``__init__``), so that the package may re-export this module.

MUKCa (platonics-delft/kinematics_calibration) records the joint angles of an arm whose flange
ball sits in one of two spherical sockets 50 mm apart, while the arm moves through its null
space and wrist. A data folder holds one sub-folder per tool location with ``hole_0.csv`` and
``hole_1.csv`` (no header, one row per configuration, one column per joint, radians).

Each (location, socket) is one fixed but unknown sphere centre; the two sockets of a location
are a known 0.050 m apart. Lengths are metres except in names ending ``_mm``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cobot_calib_ros.core.kinematics.identification.observations import SphereObservations
from cobot_calib_ros.core.kinematics.identification.parameters import tool_kinematics
from cobot_calib_ros.core.kinematics.model import KinematicModel

Array = NDArray[np.float64]

SOCKET_DISTANCE = 0.050  # [m] between the two socket centres of the MUKCa tool
SOCKET_FILES = ('hole_0.csv', 'hole_1.csv')   # per location folder, socket 0 and 1


@dataclass(frozen=True, eq=False)
class SocketData:
    """All configurations of a MUKCa data folder, in location then socket then file order."""

    locations: tuple[str, ...]  # location names (sub-folder names, sorted)
    q: Array                    # (m, n) joint angles [rad]
    location: NDArray[np.int_]  # (m,) index into locations
    socket: NDArray[np.int_]    # (m,) 0 or 1
    distance: float = SOCKET_DISTANCE  # [m] between the two sockets of a location

    def location_indices(self, locations: Sequence[str | int] | None = None) -> list[int]:
        """Indices of ``locations`` (names or indices; default all); ValueError if unknown."""
        if locations is None:
            return list(range(len(self.locations)))
        out = []
        for loc in locations:
            if isinstance(loc, str):
                if loc not in self.locations:
                    raise ValueError(f'unknown location {loc!r}; known: {list(self.locations)}')
                out.append(self.locations.index(loc))
            elif 0 <= int(loc) < len(self.locations):
                out.append(int(loc))
            else:
                raise ValueError(f'location index {loc} out of range 0..{len(self.locations) - 1}')
        if len(set(out)) != len(out):
            raise ValueError(f'locations repeated: {list(locations)}')
        return out

    def sphere_ids(self, locations: Sequence[str | int] | None = None
                   ) -> tuple[NDArray[np.bool_], NDArray[np.int_]]:
        """(mask (m,), sphere id per selected row): the k-th selected location's socket s is
        sphere 2 k + s."""
        idx = self.location_indices(locations)
        rank = np.full(len(self.locations), -1)
        rank[idx] = np.arange(len(idx))
        mask = rank[self.location] >= 0
        return mask, 2 * rank[self.location[mask]] + self.socket[mask]

    def observations(self, locations: Sequence[str | int] | None = None
                     ) -> SphereObservations:
        """SphereObservations of ``locations`` (default all): sphere 2 k + socket for the k-th
        location, and the known distance between spheres 2 k and 2 k + 1."""
        mask, sphere = self.sphere_ids(locations)
        k = len(self.location_indices(locations))
        known = tuple((2 * i, 2 * i + 1, self.distance) for i in range(k))
        return SphereObservations(self.q[mask], sphere, known)


def socket_data(tables: dict[str, Sequence[tuple[str, ArrayLike]]],
                distance: float = SOCKET_DISTANCE) -> SocketData:
    """SocketData of ``{location: [(source, hole_0 table), (source, hole_1 table)]}`` (the
    tables as read from ``<location>/hole_{0,1}.csv``, ``source`` naming the file for messages;
    loaders.load_socket_data reads them). ValueError for no location, or a table that is
    empty, not finite, or has another number of columns than the first."""
    if not tables:
        raise ValueError('no socket data: no <location>/hole_0.csv + hole_1.csv')
    q, location, socket = [], [], []
    for i, name in enumerate(tables):
        for s, (source, values) in enumerate(tables[name]):
            table = np.asarray(values, dtype=float)
            if table.ndim != 2 or len(table) == 0 or not np.all(np.isfinite(table)):
                raise ValueError(f'{source}: empty or not finite')
            if q and table.shape[1] != q[0].shape[1]:
                raise ValueError(f'{source}: {table.shape[1]} columns, expected '
                                 f'{q[0].shape[1]} (one per joint, radians)')
            q.append(table)
            location.append(np.full(len(table), i))
            socket.append(np.full(len(table), s))
    return SocketData(tuple(tables), np.vstack(q), np.concatenate(location),
                      np.concatenate(socket), float(distance))


def mukca_metrics(positions: ArrayLike, socket_ids: ArrayLike,
                  known_distances: Sequence[tuple[int, int, float]] | None = None) -> dict:
    """MUKCa's consistency metric of ball-centre positions (m, 3) [m] in any common frame.

    Per socket id: deviations ||p_i - mean p|| over its rows. ``mae_mm``: the per-socket means
    averaged with the sample counts as weights (= mean of all deviations); ``max_mm``: the
    largest deviation. ``known_distances`` (i, j, metres) pairs of socket ids, default
    ((0, 1, 0.050),) when the ids are exactly {0, 1}: ``centroid_distances_mm`` (one per pair)
    and ``distance_error_mm`` = the largest | ||c_i - c_j|| - d | (nan without pairs).
    No outlier removal (MUKCa removes outliers before it evaluates).
    """
    p = np.asarray(positions, dtype=float)
    ids = np.asarray(socket_ids)
    if p.ndim != 2 or p.shape[1] != 3 or ids.shape != (len(p),) or len(p) == 0:
        raise ValueError(f'expected positions (m, 3) and socket_ids (m,), got {p.shape} and '
                         f'{ids.shape}')
    unique = np.unique(ids)
    centres = {int(s): p[ids == s].mean(axis=0) for s in unique}
    deviation = np.empty(len(p))
    for s, c in centres.items():
        deviation[ids == s] = np.linalg.norm(p[ids == s] - c, axis=1)
    if known_distances is None:
        known_distances = ((0, 1, SOCKET_DISTANCE),) if set(centres) == {0, 1} else ()
    distances = tuple(float(np.linalg.norm(centres[i] - centres[j])) for i, j, _ in
                      known_distances)
    errors = [abs(d - k[2]) for d, k in zip(distances, known_distances)]
    return {'mae_mm': 1e3 * float(deviation.mean()),
            'max_mm': 1e3 * float(deviation.max()),
            'distance_error_mm': 1e3 * max(errors) if errors else float('nan'),
            'centroid_distances_mm': tuple(1e3 * d for d in distances)}


def location_metrics(model: KinematicModel, params: ArrayLike | None, p_flange_tool: ArrayLike,
                     data: SocketData, locations: Sequence[str | int] | None = None) -> dict:
    """:func:`mukca_metrics` of the ball centres (tool at ``p_flange_tool`` [m] in the flange) on
    ``locations`` together (default all; one pair of sockets per location)."""
    obs = data.observations(locations)
    p, _, _ = tool_kinematics(model, params, p_flange_tool, obs.q)
    return mukca_metrics(p, obs.sphere, obs.known_distances)
