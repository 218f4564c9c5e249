"""Repeatability trials: metadata plus an append-only log of probe readings (see store.files)."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
import csv
from dataclasses import dataclass
import io
import math
from pathlib import Path
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.core.repeatability import AXES, correct_distance, Direction, DIRECTIONS
from cobot_calib_ros.store.files import append_line, check_id, is_int, read_lines, to_plain
from cobot_calib_ros.store.folders import FolderStore

Array = NDArray[np.float64]
Slot = tuple[int, int]  # (cycle, point_index), both 0-based
TRIAL_KEYS = ('id', 'method', 'axis', 'layout', 'point_names', 'cycles_total', 'status',
              'created_ns', 'updated_ns')
TRIAL_STATUSES = ('running', 'done', 'aborted')
CSV_COLUMNS = ('cycle', 'point_index', 'point_name', 'raw_distance_m', 'ff_m', 'direction',
               'corrected_distance_m', 'stamp_ns')
CSV_HEADER = ','.join(CSV_COLUMNS)


@dataclass(frozen=True, eq=False)
class TrialData:
    """A trial rebuilt from disk; distance arrays are (m_points, cycles_total) [m]."""

    meta: dict[str, Any]
    distances: Array       # corrected distances d_i,n of eq (15) [m], NaN = not measured
    raw_distances: Array   # probe readings before correction [m], NaN = not measured
    resume: Slot | None        # next (cycle, point_index) to measure; None: all done
    missing: tuple[Slot, ...]  # (cycle, point_index) not measured before ``resume``


@dataclass(frozen=True)
class _Row:
    cycle: int
    point_index: int
    raw: float
    corrected: float
    stamp_ns: int


def _trial_problem(meta: Mapping[str, Any], trial_id: str) -> Failure | None:
    """None if ``meta`` is valid trial metadata for ``trial_id``, else an INVALID_INPUT
    Failure saying what is wrong."""
    missing = [k for k in TRIAL_KEYS if k not in meta]
    if missing:
        return Failure(ErrorCode.INVALID_INPUT, f'missing keys {missing}')
    if meta['id'] != trial_id:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'id {meta["id"]!r} does not match the directory name')
    names = meta['point_names']
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        return Failure(ErrorCode.INVALID_INPUT,
                       f'point_names must be a non-empty list of strings, got {names!r}')
    if not is_int(meta['cycles_total']) or meta['cycles_total'] < 1:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'cycles_total must be an int >= 1, got {meta["cycles_total"]!r}')
    if meta['status'] not in TRIAL_STATUSES:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'status must be one of {TRIAL_STATUSES}, got {meta["status"]!r}')
    return None


def _check_point_names(point_names: Sequence[str]) -> list[str]:
    names = list(point_names)
    if not names or len(set(names)) != len(names):
        raise ValueError(f'point_names must be non-empty and unique, got {names}')
    for name in names:
        if not isinstance(name, str) or not name or '\n' in name or '\r' in name:
            raise ValueError(f'bad point name {name!r}')
    return names


def _csv_line(values: Sequence[object]) -> str:
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator='\n').writerow(values)
    return buffer.getvalue()


def _parse_row(line: str, meta: Mapping[str, Any]) -> _Row | str:
    """One distances.csv line -> _Row, or a description of what is wrong with it."""
    try:
        fields = next(csv.reader([line]))
        if len(fields) != len(CSV_COLUMNS):
            return f'expected {len(CSV_COLUMNS)} fields, got {len(fields)}'
        cycle, index, stamp = int(fields[0]), int(fields[1]), int(fields[7])
        raw, ff, corrected = float(fields[3]), float(fields[4]), float(fields[6])
        direction = fields[5] or None
        if direction not in (None, *DIRECTIONS):
            return f'bad direction {direction!r}'
        expected = correct_distance(raw, ff, direction)
    except (csv.Error, ValueError) as exc:
        return f'unparsable ({exc})'
    if not (0 <= cycle < meta['cycles_total'] and 0 <= index < len(meta['point_names'])):
        return f'(cycle, point) = ({cycle}, {index}) out of range'
    if fields[2] != meta['point_names'][index]:
        return f'point name {fields[2]!r} != {meta["point_names"][index]!r}'
    if not (math.isfinite(raw) and math.isclose(corrected, expected, abs_tol=1e-12)):
        return f'raw {raw} m, corrected {corrected} m inconsistent (expected {expected} m)'
    return _Row(cycle, index, raw, corrected, stamp)


def _resume_point(measured: NDArray[np.bool_]) -> tuple[Slot | None, tuple[Slot, ...]]:
    """Next (cycle, point) after the last measured one, and the holes before it.

    Measurement order is cycle-major: every point of cycle 0, then cycle 1, ...
    """
    m = measured.shape[0]
    order = measured.T.ravel()
    done = np.flatnonzero(order)
    after = int(done[-1]) + 1 if done.size else 0
    holes = tuple(divmod(int(i), m) for i in np.flatnonzero(~order[:after]))
    resume = divmod(after, m) if after < order.size else None
    return resume, holes


class TrialStore(FolderStore):
    """Repeatability trials: metadata plus an append-only log of probe readings.

    Cycles and point indices are 0-based. A later line for the same (cycle, point)
    supersedes an earlier one, so a partial cycle may be redone from its first point.
    """

    META_FILE, LOG_FILE, LOG_HEADER = 'trial.yaml', 'distances.csv', CSV_HEADER

    def __init__(self, root: Path) -> None:
        super().__init__(Path(root) / 'trials')
        self.root = Path(root)

    def _meta_problem(self, meta: Mapping[str, Any], record_id: str) -> Failure | None:
        return _trial_problem(meta, record_id)

    def create(self, trial_id: str, *, method: str, axis: str, layout: str,
               point_names: Sequence[str], cycles_total: int,
               stamp_ns: int | None = None,
               extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Start a new 'running' trial; raises FileExistsError if the id is taken.

        ``extra`` is stored in the metadata beside the required keys (set-up a resume needs).
        """
        if axis not in AXES or not is_int(cycles_total) or cycles_total < 1:
            raise ValueError(f'need axis in {AXES} and int cycles_total >= 1, got '
                             f'{axis!r}, {cycles_total!r}')
        now = time.time_ns() if stamp_ns is None else stamp_ns
        meta = {**to_plain(dict(extra or {})),
                'id': check_id(trial_id), 'method': method, 'axis': axis, 'layout': layout,
                'point_names': _check_point_names(point_names),
                'cycles_total': cycles_total, 'status': 'running',
                'created_ns': now, 'updated_ns': now}
        self._create_folder(meta)
        return meta

    def append(self, trial_id: str, cycle: int, point_index: int, raw_distance_m: float,
               ff_m: float = 0.0, direction: Direction | None = None,
               stamp_ns: int | None = None) -> float:
        """Log one reading [m] durably; returns the eq (15) corrected distance [m]."""
        meta = self._require_running(trial_id)
        names = meta['point_names']
        if not (0 <= cycle < meta['cycles_total'] and 0 <= point_index < len(names)):
            raise ValueError(f'(cycle, point) = ({cycle}, {point_index}) out of range')
        if not math.isfinite(raw_distance_m):
            raise ValueError(f'raw distance must be finite, got {raw_distance_m}')
        corrected = correct_distance(raw_distance_m, ff_m, direction)
        stamp = time.time_ns() if stamp_ns is None else stamp_ns
        line = _csv_line([cycle, point_index, names[point_index], float(raw_distance_m),
                          float(ff_m), direction or '', float(corrected), stamp])
        append_line(self.directory / trial_id / 'distances.csv', line, CSV_HEADER)
        return corrected

    def record_calibration_time(self, trial_id: str, cycle: int, seconds: float) -> None:
        """Keep the robot time [s] of a cycle's calibration pass (``calibration_s`` in the
        metadata: a list by cycle, None where not measured; a redone cycle overwrites)."""
        meta = self._require_running(trial_id)
        times = list(meta.get('calibration_s') or [None] * meta['cycles_total'])
        times[cycle] = float(seconds)
        self._write_meta({**meta, 'calibration_s': times})

    def record_retries(self, trial_id: str, retries: dict[str, int]) -> dict[str, Any]:
        """Add one goal's retries (``{'capture_joints': n, 'probe_average': n}``: holds and
        probe windows tried again after NO_DATA) to the trial's ``retries`` in the metadata;
        the updated metadata."""
        meta = self._read_meta(check_id(trial_id))
        if meta is None:
            raise ValueError(f'trial {trial_id!r} is missing or unreadable')
        total = dict(meta.get('retries') or {})
        for key, count in retries.items():
            total[key] = int(total.get(key, 0)) + int(count)
        meta = {**meta, 'retries': total}
        self._write_meta(meta)
        return meta

    def load(self, trial_id: str) -> TrialData | None:
        """Rebuild a trial from disk, or None if its metadata is unreadable (see warnings)."""
        meta = self._read_meta(check_id(trial_id))
        if meta is None:
            return None
        shape = (len(meta['point_names']), meta['cycles_total'])
        corrected, raw = np.full(shape, math.nan), np.full(shape, math.nan)
        for row in self._read_rows(self.directory / trial_id / 'distances.csv', meta):
            corrected[row.point_index, row.cycle] = row.corrected
            raw[row.point_index, row.cycle] = row.raw
        resume, holes = _resume_point(np.isfinite(corrected))
        return TrialData(meta, corrected, raw, resume, holes)

    def set_status(self, trial_id: str, status: str,
                   stamp_ns: int | None = None) -> dict[str, Any]:
        """Set 'running', 'done' or 'aborted' and return the updated metadata."""
        if status not in TRIAL_STATUSES:
            raise ValueError(f'status must be one of {TRIAL_STATUSES}, got {status!r}')
        meta = self._read_meta(check_id(trial_id))
        if meta is None:
            raise ValueError(f'trial {trial_id!r} is missing or unreadable')
        meta = {**meta, 'status': status,
                'updated_ns': time.time_ns() if stamp_ns is None else stamp_ns}
        self._write_meta(meta)
        return meta

    def list_trials(self) -> list[dict[str, Any]]:
        """Metadata of every readable trial, newest created first."""
        return self._list_meta()

    def _require_running(self, trial_id: str) -> dict[str, Any]:
        meta = self._meta.get(trial_id) or self._read_meta(check_id(trial_id))
        if meta is None:
            raise ValueError(f'trial {trial_id!r} is missing or unreadable')
        if meta['status'] != 'running':
            raise ValueError(f'trial {trial_id!r} is {meta["status"]}, not running')
        return meta

    def _read_rows(self, path: Path, meta: Mapping[str, Any]) -> list[_Row]:
        rows = []
        for number, line in read_lines(path, CSV_HEADER, self):
            row = _parse_row(line, meta)
            if isinstance(row, str):
                self._warn(f'{path}:{number}: ignored line, {row}')
            else:
                rows.append(row)
        return rows
