"""Calibration records, one JSON file each under ``<root>/calibrations`` (see store.files),
and which one is active: ``<root>/calibrations/active.json`` (chosen id, retired ids)."""
from __future__ import annotations

from collections.abc import Mapping
import json
from pathlib import Path
from typing import Any

from cobot_calib_ros.store.files import (atomic_write_text, check_id, ensure_dir, ID_PATTERN,
                                         is_int, to_plain, WarningLog)

RECORD_KEYS = ('id', 'stamp_ns', 'method', 'inputs', 'result')
ACTIVE_FILE = 'active.json'
RESERVED_IDS = (ACTIVE_FILE.removesuffix('.json'),)


def _record_problem(record: Mapping[str, Any]) -> str:
    """'' if ``record`` is a valid calibration record, else what is wrong with it."""
    missing = [k for k in RECORD_KEYS if k not in record]
    if missing:
        return f'missing keys {missing}'
    if not isinstance(record['id'], str) or not ID_PATTERN.fullmatch(record['id']):
        return f'bad id {record["id"]!r}'
    if record['id'] in RESERVED_IDS:
        return f'id {record["id"]!r} is reserved (the active choice is stored under it)'
    if not is_int(record['stamp_ns']):
        return f'stamp_ns must be an int [ns], got {record["stamp_ns"]!r}'
    if not isinstance(record['method'], str):
        return f'method must be a string, got {record["method"]!r}'
    return ''


def _read_selection(path: Path) -> tuple[dict[str, Any], str]:
    """active.json's mapping and '', or {} and what is wrong with the file."""
    try:
        data = json.loads(path.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        return {}, f'unreadable: {" ".join(str(exc).split())}'
    if not isinstance(data, dict):
        return {}, 'not a mapping'
    chosen, retired = data.get('active_id'), data.get('retired', [])
    if chosen is not None and not (isinstance(chosen, str) and ID_PATTERN.fullmatch(chosen)):
        return {}, f'active_id must be null or a calibration id, got {chosen!r}'
    if not isinstance(retired, list) or not all(
            isinstance(r, str) and ID_PATTERN.fullmatch(r) for r in retired):
        return {}, f'retired must be a list of calibration ids, got {retired!r}'
    return data, ''


class CalibrationStore(WarningLog):
    """Calibration records, one JSON file each under ``<root>/calibrations``.

    A record is a mapping with at least ``id`` (file name stem), ``stamp_ns`` (int, ns),
    ``method``, ``inputs`` and ``result``; numpy values are stored as plain lists/numbers.
    Saving an existing id replaces that record. Order is by (stamp_ns, id). The directory is
    read once, on first use; later reads come from memory (one writer per root is assumed).
    JSON rather than YAML: PyYAML's representer alone took 1.7 ms per record.

    The active calibration (the default for conversions, the one to publish) is the chosen one
    (:meth:`activate`) while it exists and is not retired, else the newest non-retired one.
    Retired records stay in the history. The choice and the retired ids are in ``active.json``
    in the same directory, rewritten atomically on every change; the choice is kept only where
    it differs from the default, so activating the newest record (after each calibration)
    writes nothing in the common case.
    """

    def __init__(self, root: Path, subdir: str = 'calibrations') -> None:
        super().__init__()
        self.root = Path(root)
        self.directory = self.root / subdir
        self.selection_path = self.directory / ACTIVE_FILE
        self._records: dict[str, dict[str, Any]] | None = None
        self._chosen: str | None = None
        self._retired: frozenset[str] | None = None

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

    def ids(self) -> frozenset[str]:
        """The ids of the readable records (no sorting: cheap on the calibration path)."""
        return frozenset(self._index())

    def active(self) -> dict[str, Any] | None:
        """The active record: the chosen one if it is stored and not retired, else the newest
        non-retired one; None if there is none."""
        retired = self.retired()
        chosen = self._index().get(self._chosen or '')
        if chosen is not None and chosen['id'] not in retired:
            return chosen
        return next((r for r in self.history() if r['id'] not in retired), None)

    def retired(self) -> frozenset[str]:
        """The ids of retired records (some may no longer be stored)."""
        if self._retired is None:
            self._load_selection()
        return self._retired

    def activate(self, record_id: str | None) -> None:
        """Make ``record_id`` (un-retired) the active record; None or '': no choice, the
        newest non-retired record is active. KeyError if no such record, ValueError if not an
        id, OSError if active.json cannot be written (then nothing changed)."""
        retired = self.retired()
        if record_id:
            self._require(record_id)
            retired = retired - {record_id}
        self._select(record_id or None, retired)

    def retire(self, record_id: str) -> None:
        """Mark ``record_id`` retired: kept in the history, never active; if it was chosen,
        the newest non-retired record becomes active. Errors as :meth:`activate`."""
        self._require(record_id)
        chosen = None if self._chosen == record_id else self._chosen
        self._select(chosen, self.retired() | {record_id})

    def _require(self, record_id: str) -> None:
        if self.get(record_id) is None:
            raise KeyError(f'no calibration {record_id!r}')

    def _select(self, chosen: str | None, retired: frozenset[str]) -> None:
        """Store the choice (only where it differs from the default) and the retired ids."""
        newest = next((r['id'] for r in self.history() if r['id'] not in retired), None)
        chosen = None if chosen == newest else chosen
        if (chosen, retired) == (self._chosen, self.retired()):
            return
        ensure_dir(self.directory)
        atomic_write_text(self.selection_path, json.dumps(
            {'active_id': chosen, 'retired': sorted(retired)}) + '\n')
        self._chosen, self._retired = chosen, retired

    def _load_selection(self) -> None:
        self._chosen, self._retired = None, frozenset()
        if not self.selection_path.exists():
            return
        data, problem = _read_selection(self.selection_path)
        if problem:
            self._warn(f'{self.selection_path}: ignored ({problem}); the newest calibration '
                       'is active and none is retired until set_active_calibration is called')
            return
        self._chosen, self._retired = data.get('active_id'), frozenset(data.get('retired', []))

    def _index(self) -> dict[str, dict[str, Any]]:
        if self._records is None:
            paths = (sorted(p for p in self.directory.glob('*.json')
                            if p.name != ACTIVE_FILE) if self.directory.is_dir() else [])
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
