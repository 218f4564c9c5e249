"""Calibration records, one JSON file each under ``<root>/calibrations`` (see store.files)."""
from __future__ import annotations

from collections.abc import Mapping
import json
from pathlib import Path
from typing import Any

from cobot_calib_ros.store.files import (atomic_write_text, check_id, ensure_dir, ID_PATTERN,
                                         is_int, to_plain, WarningLog)

RECORD_KEYS = ('id', 'stamp_ns', 'method', 'inputs', 'result')


def _record_problem(record: Mapping[str, Any]) -> str:
    """'' if ``record`` is a valid calibration record, else what is wrong with it."""
    missing = [k for k in RECORD_KEYS if k not in record]
    if missing:
        return f'missing keys {missing}'
    if not isinstance(record['id'], str) or not ID_PATTERN.fullmatch(record['id']):
        return f'bad id {record["id"]!r}'
    if not is_int(record['stamp_ns']):
        return f'stamp_ns must be an int [ns], got {record["stamp_ns"]!r}'
    if not isinstance(record['method'], str):
        return f'method must be a string, got {record["method"]!r}'
    return ''


class CalibrationStore(WarningLog):
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
        ensure_dir(self.directory)
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
