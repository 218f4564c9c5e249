"""Kinematic calibration data: one folder per collection, the plan and an append-only log.

Layout under a root directory::

    <root>/kinematic_data/<id>/collection.json   metadata and the plan, rewritten atomically
    <root>/kinematic_data/<id>/rows.csv          one line per planned pose, appended + fsynced

The metadata is JSON: a planned collection keeps its whole candidate pool for a resume (the
iiwa 7's: 22,614 steps, 5.8 MB), which libyaml read in 4.5 s and wrote in 2.8 s on a quiet
machine (three writes and two reads per collection; a Ctrl-C'd collection must end its goal
within spin.STOP_GRACE), JSON in 0.07 and 0.14 s. Collections of older versions
(collection.yaml) are read, and written back as JSON.

A row is a pose the robot was sent to: ``ok`` with the averaged joints [rad] (and, for a laser
tracker collection, the measured position [m] in the tracker frame), or ``skipped`` with why
(unreachable, not coupled). A crash loses at most the row in flight; the collection resumes at
the first planned index without a row. One writer per collection is assumed.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math
from pathlib import Path
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.store.files import append_line, check_id, read_lines, to_plain
from cobot_calib_ros.store.folders import FolderStore

Array = NDArray[np.float64]
SOURCES = ('spheres', 'laser_tracker')
STATUSES = ('running', 'done', 'aborted')
CSV_HEADER = 'index,target,status,sample_count,std_max_rad,q_rad...,p_m...,note'
META_KEYS = ('id', 'source', 'robot', 'joint_names', 'targets', 'plan', 'status', 'created_ns')


@dataclass(frozen=True)
class Collection:
    """A stored collection, rebuilt from disk."""

    meta: dict[str, Any]
    index: NDArray[np.int64]    # (m,) plan index of each ok row
    target: NDArray[np.int64]   # (m,) index into meta['targets'] (sphere), -1 for the tracker
    q: Array                    # (m, n) averaged joints [rad]
    p: Array                    # (m, 3) tracker measurement [m]; NaN for sphere rows
    skipped: dict[int, str]     # plan index -> why

    @property
    def next_index(self) -> int:
        """First plan index with no row (ok or skipped): where a resume starts."""
        done = set(self.index.tolist()) | set(self.skipped)
        return next((i for i in range(len(self.meta['plan'])) if i not in done),
                    len(self.meta['plan']))


def _problem(meta: Mapping[str, Any], collection_id: str) -> Failure | None:
    missing = [k for k in META_KEYS if k not in meta]
    if missing:
        return Failure(ErrorCode.INVALID_INPUT, f'missing keys {missing}')
    if meta['id'] != collection_id:
        return Failure(ErrorCode.INVALID_INPUT, f'id {meta["id"]!r} does not match the folder name')
    if meta['source'] not in SOURCES or meta['status'] not in STATUSES:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'bad source {meta["source"]!r} or status {meta["status"]!r}')
    n = len(meta['joint_names'])
    if not all(isinstance(step, Mapping) and len(step.get('q', ())) == n
               for step in meta['plan']):
        return Failure(ErrorCode.INVALID_INPUT, f'every plan step needs q with {n} joint positions')
    return None


class CollectionStore(FolderStore):
    META_FILE, LOG_FILE, LOG_HEADER = 'collection.json', 'rows.csv', CSV_HEADER
    OLD_META_FILES = ('collection.yaml',)

    def __init__(self, root: Path) -> None:
        super().__init__(Path(root) / 'kinematic_data')

    @classmethod
    def of_folder(cls, directory: Path) -> CollectionStore:
        """The collections in ``directory`` itself (a folder given by path, e.g. a copy of
        ``<root>/kinematic_data``), not under a data dir."""
        folder_store = cls(Path(directory).parent)
        folder_store.directory = Path(directory)
        return folder_store

    def _meta_problem(self, meta: Mapping[str, Any], record_id: str) -> Failure | None:
        return _problem(meta, record_id)

    def create(self, collection_id: str, *, source: str, robot: str,
               joint_names: Sequence[str], targets: Sequence[str],
               plan: Sequence[Mapping[str, Any]],
               extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Start a 'running' collection; plan steps are mappings with 'q' [rad] and 'target'
        (an index into ``targets``, -1 for none). FileExistsError if the id is taken."""
        if source not in SOURCES:
            raise ValueError(f'source must be one of {SOURCES}, got {source!r}')
        now = time.time_ns()
        meta = {**to_plain(dict(extra or {})), 'id': check_id(collection_id),
                'source': source, 'robot': robot, 'joint_names': list(joint_names),
                'targets': list(targets), 'plan': to_plain(list(plan)), 'status': 'running',
                'created_ns': now, 'updated_ns': now}
        problem = _problem(meta, collection_id)
        if problem is not None:
            raise ValueError(f'invalid collection: {problem.message}')
        self._create_folder(meta)
        return meta

    def append(self, collection_id: str, index: int, target: int, q: Array | None, *,
               sample_count: int = 0, std_max: float = math.nan,
               p: Array | None = None, note: str = '') -> None:
        """Log one pose durably: joints ``q`` [rad] (None: skipped, ``note`` says why)."""
        n = len(self.meta(collection_id)['joint_names'])
        status = 'skipped' if q is None else 'ok'
        q_values = [math.nan] * n if q is None else [float(v) for v in q]
        if len(q_values) != n or (q is not None and not all(map(math.isfinite, q_values))):
            raise ValueError(f'need {n} finite joint positions [rad], got {q_values}')
        p_values = [math.nan] * 3 if p is None else [float(v) for v in p]
        fields = [index, target, status, sample_count, float(std_max), *q_values, *p_values,
                  note.replace(',', ';').replace('\n', ' ')]
        append_line(self.directory / collection_id / 'rows.csv',
                    ','.join(repr(f) if isinstance(f, float) else str(f) for f in fields)
                    + '\n', CSV_HEADER)

    def meta(self, collection_id: str) -> dict[str, Any]:
        meta = self._meta.get(collection_id)
        if meta is None:
            meta, problem = self._load_meta(check_id(collection_id))
            if problem:
                raise ValueError(f'collection {collection_id!r} is missing or unreadable: '
                                 f'{problem}')
            self._meta[collection_id] = meta
        return meta

    def set_status(self, collection_id: str, status: str) -> dict[str, Any]:
        if status not in STATUSES:
            raise ValueError(f'status must be one of {STATUSES}, got {status!r}')
        meta = {**self.meta(collection_id), 'status': status, 'updated_ns': time.time_ns()}
        self._write_meta(meta)
        return meta

    def update(self, collection_id: str, **fields: Any) -> dict[str, Any]:
        """Set top-level metadata ``fields`` (not the keys every collection has), durably."""
        fixed = [k for k in fields if k in META_KEYS]
        if fixed:
            raise ValueError(f'update cannot change {fixed}; use set_status for the status')
        meta = {**self.meta(collection_id), **to_plain(fields), 'updated_ns': time.time_ns()}
        self._write_meta(meta)
        return meta

    def load(self, collection_id: str) -> Collection | None:
        """The collection with its rows, or None if unreadable (see ``warnings``)."""
        meta = self._read_meta(check_id(collection_id))
        if meta is None:
            return None
        n = len(meta['joint_names'])
        ok: dict[int, tuple[int, list[float], list[float]]] = {}
        skipped: dict[int, str] = {}
        path = self.directory / collection_id / 'rows.csv'
        for number, line in read_lines(path, CSV_HEADER, self):
            parts = line.split(',')
            try:
                index, target, status = int(parts[0]), int(parts[1]), parts[2]
                values = [float(v) for v in parts[5:5 + n + 3]]
                if len(values) != n + 3 or len(parts) != 5 + n + 3 + 1:
                    raise ValueError('wrong number of fields')
            except (ValueError, IndexError) as exc:
                self._warn(f'{path}:{number}: ignored line ({exc})')
                continue
            if status == 'ok':
                ok[index] = (target, values[:n], values[n:])
                skipped.pop(index, None)
            else:
                skipped[index] = parts[-1]
                ok.pop(index, None)
        order = sorted(ok)
        return Collection(
            meta, np.array(order, dtype=np.int64),
            np.array([ok[i][0] for i in order], dtype=np.int64),
            np.array([ok[i][1] for i in order], dtype=float).reshape(-1, n),
            np.array([ok[i][2] for i in order], dtype=float).reshape(-1, 3), skipped)

    def list_collections(self) -> list[dict[str, Any]]:
        """Metadata of every readable collection, newest first."""
        return self._list_meta()
