"""Durable results on disk: atomic whole-file writes and append-only measurement logs.

Layout under a root directory given by the caller (nothing global)::

    <root>/calibrations/<id>.json            one calibration record, written atomically
    <root>/trials/<trial_id>/trial.yaml      trial metadata, rewritten atomically
    <root>/trials/<trial_id>/distances.csv   one line per probe reading [m], appended + fsynced

Durability: whole files go through a temporary file in the same directory that is fsynced and
then renamed over the target (``os.replace``), after which the directory is fsynced, so a
reader sees the old or the new content, never a mix. A crash may leave a hidden
``.<name>.*.tmp`` file behind; readers ignore it. Measurement lines are appended with one
``write`` each and fsynced, so a crash loses at most the line in flight; a truncated last line
is ignored on load. One writer per trial is assumed.

Failures: unreadable or inconsistent files are skipped and described in the store's
``warnings`` list (never raised); invalid arguments raise ValueError.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
import contextlib
import csv
from dataclasses import dataclass
import io
import json
import math
import os
from pathlib import Path
import re
import tempfile
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray
import yaml

from cobot_calib_ros.core.repeatability import correct_distance, Direction, DIRECTIONS

Array = NDArray[np.float64]
Cell = tuple[int, int]  # (cycle, point_index), both 0-based
FILE_MODE = 0o644
TEMP_SUFFIX = '.tmp'
RECORD_KEYS = ('id', 'stamp_ns', 'method', 'inputs', 'result')
TRIAL_KEYS = ('id', 'method', 'axis', 'layout', 'point_names', 'cycles_total', 'status',
              'created_ns', 'updated_ns')
TRIAL_STATUSES = ('running', 'done', 'aborted')
AXES = ('x', 'y', 'z')
CSV_COLUMNS = ('cycle', 'point_index', 'point_name', 'raw_distance_m', 'ff_m', 'direction',
               'corrected_distance_m', 'stamp_ns')
CSV_HEADER = ','.join(CSV_COLUMNS)
_ID_PATTERN = re.compile(r'[A-Za-z0-9][A-Za-z0-9_.-]{0,127}')


def fsync_dir(directory: Path) -> None:
    """Flush a directory entry (a rename or a new file in it) to disk (POSIX)."""
    fd = os.open(directory, os.O_RDONLY | getattr(os, 'O_DIRECTORY', 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Replace ``path`` by ``data`` atomically and durably (temp file, fsync, rename)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix=TEMP_SUFFIX)
    try:
        with os.fdopen(fd, 'wb') as f:
            os.fchmod(f.fileno(), FILE_MODE)
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    fsync_dir(path.parent)


def atomic_write_text(path: Path, text: str) -> None:
    """:func:`atomic_write_bytes` for UTF-8 text."""
    atomic_write_bytes(path, text.encode('utf-8'))


def check_id(value: object) -> str:
    """Return ``value`` if it is a safe file name stem (letters, digits, ``_.-``)."""
    if not isinstance(value, str) or not _ID_PATTERN.fullmatch(value):
        raise ValueError(f'id must match {_ID_PATTERN.pattern}, got {value!r}')
    return value


def to_plain(value: Any) -> Any:
    """Recursively turn numpy arrays/scalars, tuples and paths into YAML-safe builtins."""
    if isinstance(value, Mapping):
        return {to_plain(k): to_plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    return value


class _WarningLog:
    """Collects one message per distinct problem found while reading files."""

    def __init__(self) -> None:
        self.warnings: list[str] = []

    def _warn(self, message: str) -> None:
        if message not in self.warnings:
            self.warnings.append(message)

    def _read_mapping(self, path: Path) -> dict[str, Any] | None:
        """A YAML or (by suffix) JSON file's top-level mapping, or None with a warning."""
        try:
            text = path.read_text(encoding='utf-8')
            data = json.loads(text) if path.suffix == '.json' else yaml.safe_load(text)
        except (OSError, UnicodeDecodeError, ValueError, yaml.YAMLError) as exc:
            reason = ' '.join(str(exc).split())
            self._warn(f'{path}: skipped, unreadable ({reason})')
            return None
        if not isinstance(data, dict):
            self._warn(f'{path}: skipped, not a mapping')
            return None
        return data


def _ensure_dir(directory: Path) -> None:
    """mkdir -p, fsyncing the parent of every directory it creates."""
    missing = []
    current = directory
    while not current.exists():
        missing.append(current)
        current = current.parent
    directory.mkdir(parents=True, exist_ok=True)
    for created in reversed(missing):
        fsync_dir(created.parent)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _record_problem(record: Mapping[str, Any]) -> str:
    """'' if ``record`` is a valid calibration record, else what is wrong with it."""
    missing = [k for k in RECORD_KEYS if k not in record]
    if missing:
        return f'missing keys {missing}'
    if not isinstance(record['id'], str) or not _ID_PATTERN.fullmatch(record['id']):
        return f'bad id {record["id"]!r}'
    if not _is_int(record['stamp_ns']):
        return f'stamp_ns must be an int [ns], got {record["stamp_ns"]!r}'
    if not isinstance(record['method'], str):
        return f'method must be a string, got {record["method"]!r}'
    return ''


class CalibrationStore(_WarningLog):
    """Calibration records, one JSON file each under ``<root>/calibrations``.

    A record is a mapping with at least ``id`` (file name stem), ``stamp_ns`` (int, ns),
    ``method``, ``inputs`` and ``result``; numpy values are stored as plain lists/numbers.
    Saving an existing id replaces that record. Order is by (stamp_ns, id). The directory is
    read once, on first use; later reads come from memory (one writer per root is assumed).
    JSON rather than YAML: PyYAML's representer alone took 1.7 ms per record.
    """

    def __init__(self, root: Path) -> None:
        super().__init__()
        self.root = Path(root)
        self.directory = self.root / 'calibrations'
        self._records: dict[str, dict[str, Any]] | None = None

    def save(self, record: Mapping[str, Any]) -> Path:
        """Write ``record`` atomically and durably; returns its path."""
        plain = to_plain(record)
        problem = _record_problem(plain)
        if problem:
            raise ValueError(f'invalid calibration record: {problem}')
        _ensure_dir(self.directory)
        path = self._path(plain['id'])
        atomic_write_text(path, json.dumps(plain) + '\n')  # indent= is the slow encoder
        self._index()[plain['id']] = plain
        return path

    def get(self, record_id: str) -> dict[str, Any] | None:
        """The record with this id, or None if absent or unreadable (see ``warnings``)."""
        return self._index().get(check_id(record_id))

    def history(self, max_count: int = 0) -> list[dict[str, Any]]:
        """Readable records, newest first; at most ``max_count`` of them (0: all)."""
        if max_count < 0:
            raise ValueError(f'max_count must be >= 0, got {max_count}')
        records = sorted(self._index().values(), key=lambda r: (r['stamp_ns'], r['id']),
                         reverse=True)
        return records[:max_count] if max_count else records

    def latest(self) -> dict[str, Any] | None:
        """The newest readable record, or None."""
        newest = self.history(max_count=1)
        return newest[0] if newest else None

    def _index(self) -> dict[str, dict[str, Any]]:
        if self._records is None:
            paths = sorted(self.directory.glob('*.json')) if self.directory.is_dir() else []
            loaded = (self._load(p) for p in paths)
            self._records = {r['id']: r for r in loaded if r is not None}
        return self._records

    def _path(self, record_id: str) -> Path:
        return self.directory / f'{record_id}.json'

    def _load(self, path: Path) -> dict[str, Any] | None:
        record = self._read_mapping(path)
        if record is None:
            return None
        problem = _record_problem(record)
        if not problem and record['id'] != path.stem:
            problem = f'id {record["id"]!r} does not match the file name'
        if problem:
            self._warn(f'{path}: skipped, {problem}')
            return None
        return record


@dataclass(frozen=True, eq=False)
class TrialData:
    """A trial rebuilt from disk; distance arrays are (m_points, cycles_total) [m]."""

    meta: dict[str, Any]
    distances: Array       # corrected distances d_i,n of eq (15) [m], NaN = not measured
    raw_distances: Array   # probe readings before correction [m], NaN = not measured
    resume: Cell | None        # next (cycle, point_index) to measure; None: all done
    missing: tuple[Cell, ...]  # (cycle, point_index) not measured before ``resume``


@dataclass(frozen=True)
class _Row:
    cycle: int
    point_index: int
    raw: float
    corrected: float
    stamp_ns: int


def _trial_problem(meta: Mapping[str, Any], trial_id: str) -> str:
    """'' if ``meta`` is valid trial metadata for ``trial_id``, else what is wrong."""
    missing = [k for k in TRIAL_KEYS if k not in meta]
    if missing:
        return f'missing keys {missing}'
    if meta['id'] != trial_id:
        return f'id {meta["id"]!r} does not match the directory name'
    names = meta['point_names']
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        return f'point_names must be a non-empty list of strings, got {names!r}'
    if not _is_int(meta['cycles_total']) or meta['cycles_total'] < 1:
        return f'cycles_total must be an int >= 1, got {meta["cycles_total"]!r}'
    if meta['status'] not in TRIAL_STATUSES:
        return f'status must be one of {TRIAL_STATUSES}, got {meta["status"]!r}'
    return ''


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


def _resume_point(measured: NDArray[np.bool_]) -> tuple[Cell | None, tuple[Cell, ...]]:
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


class TrialStore(_WarningLog):
    """Repeatability trials: metadata plus an append-only log of probe readings.

    Cycles and point indices are 0-based. A later line for the same (cycle, point)
    supersedes an earlier one, so a partial cycle may be redone from its first point.
    """

    def __init__(self, root: Path) -> None:
        super().__init__()
        self.root = Path(root)
        self.directory = self.root / 'trials'
        self._meta: dict[str, dict[str, Any]] = {}

    def create(self, trial_id: str, *, method: str, axis: str, layout: str,
               point_names: Sequence[str], cycles_total: int,
               stamp_ns: int | None = None,
               extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Start a new 'running' trial; raises FileExistsError if the id is taken.

        ``extra`` is stored in the metadata beside the required keys (set-up a resume needs).
        """
        if axis not in AXES or not _is_int(cycles_total) or cycles_total < 1:
            raise ValueError(f'need axis in {AXES} and int cycles_total >= 1, got '
                             f'{axis!r}, {cycles_total!r}')
        now = time.time_ns() if stamp_ns is None else stamp_ns
        meta = {**to_plain(dict(extra or {})),
                'id': check_id(trial_id), 'method': method, 'axis': axis, 'layout': layout,
                'point_names': _check_point_names(point_names),
                'cycles_total': cycles_total, 'status': 'running',
                'created_ns': now, 'updated_ns': now}
        _ensure_dir(self.directory)
        trial_dir = self.directory / trial_id
        trial_dir.mkdir()
        fsync_dir(self.directory)
        atomic_write_text(trial_dir / 'distances.csv', CSV_HEADER + '\n')
        self._write_meta(meta)  # last: a directory without trial.yaml is an aborted create
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
        self._append_line(self.directory / trial_id / 'distances.csv', line)
        return corrected

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
        if not self.directory.is_dir():
            return []
        trial_ids = sorted(p.name for p in self.directory.iterdir() if p.is_dir())
        metas = [m for m in map(self._read_meta, trial_ids) if m is not None]
        return sorted(metas, key=lambda m: (m['created_ns'], m['id']), reverse=True)

    def _write_meta(self, meta: dict[str, Any]) -> None:
        path = self.directory / meta['id'] / 'trial.yaml'
        atomic_write_text(path, yaml.safe_dump(to_plain(meta), sort_keys=False,
                                               allow_unicode=True))
        self._meta[meta['id']] = meta

    def _read_meta(self, trial_id: str) -> dict[str, Any] | None:
        path = self.directory / trial_id / 'trial.yaml'
        if not path.exists():
            self._warn(f'{path.parent}: skipped, no trial.yaml (missing or aborted create)')
            return None
        meta = self._read_mapping(path)
        if meta is None:
            return None
        problem = _trial_problem(meta, trial_id)
        if problem:
            self._warn(f'{path}: skipped, {problem}')
            return None
        self._meta[trial_id] = meta
        return meta

    def _require_running(self, trial_id: str) -> dict[str, Any]:
        meta = self._meta.get(trial_id) or self._read_meta(check_id(trial_id))
        if meta is None:
            raise ValueError(f'trial {trial_id!r} is missing or unreadable')
        if meta['status'] != 'running':
            raise ValueError(f'trial {trial_id!r} is {meta["status"]}, not running')
        return meta

    @staticmethod
    def _append_line(path: Path, line: str) -> None:
        """Append one line with a single write, then fsync (at most this line is lost)."""
        data = line.encode('utf-8')
        with open(path, 'a+b') as f:  # writes always go to the end, reads do not
            size = f.seek(0, os.SEEK_END)
            if size == 0:
                data = (CSV_HEADER + '\n').encode('utf-8') + data
            else:
                f.seek(size - 1)
                if f.read(1) != b'\n':
                    data = b'\n' + data  # end a line truncated by a crash; load skips it
            f.write(data)
            f.flush()
            os.fsync(f.fileno())

    def _read_rows(self, path: Path, meta: Mapping[str, Any]) -> list[_Row]:
        try:
            text = path.read_bytes().decode('utf-8', errors='replace')
        except OSError as exc:
            self._warn(f'{path}: no measurements read ({exc})')
            return []
        lines = text.split('\n')
        tail = lines.pop()  # '' when the file ends with a newline
        if tail:
            self._warn(f'{path}: ignored truncated last line {tail!r} (crash mid-write?)')
        if lines and lines[0] == CSV_HEADER:
            lines[0] = ''
        rows = []
        for number, line in enumerate(lines, start=1):
            row = _parse_row(line, meta) if line else None
            if isinstance(row, str):
                self._warn(f'{path}:{number}: ignored line, {row}')
            elif row is not None:
                rows.append(row)
        return rows
