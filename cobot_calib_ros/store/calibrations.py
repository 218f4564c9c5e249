"""Calibration records, one JSON file each under ``<root>/calibrations`` (see store.files),
and which one is active: ``<root>/calibrations/active.json`` (chosen ids, retired ids).

Activation is scoped: a store built with ``scope_key`` (kinematics: ``'robot'``) keeps one
active record per value of that key, so one robot's calibration never becomes another's.

Keyed by cell (store.cells): a store opened for a cell holds that cell's records only (and
the legacy ones it takes, see store.cells); many cells' records share the directory, each
cell's active choice is its entry in ``active.json``'s ``cells``."""
from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
import contextlib
from dataclasses import dataclass
import fcntl
from pathlib import Path
from typing import Any

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.store.cells import foreign_result, LEGACY_CELL, legacy_note, ResultsCell
from cobot_calib_ros.store.files import (check_id, ensure_dir, ID_PATTERN, is_int, read_mapping,
                                         to_plain, WarningLog, write_mapping)
from cobot_calib_ros.store.renamed import with_current_names

RECORD_KEYS = ('id', 'stamp_ns', 'method', 'inputs', 'result')
ACTIVE_FILE = 'active.json'
LOCK_FILE = '.active.lock'
RESERVED_IDS = (ACTIVE_FILE.removesuffix('.json'),)


def _record_problem(record: Mapping[str, Any]) -> Failure | None:
    """None if ``record`` is a valid calibration record, else an INVALID_INPUT Failure
    saying what is wrong with it."""
    missing = [k for k in RECORD_KEYS if k not in record]
    if missing:
        return Failure(ErrorCode.INVALID_INPUT, f'missing keys {missing}')
    if not isinstance(record['id'], str) or not ID_PATTERN.fullmatch(record['id']):
        return Failure(ErrorCode.INVALID_INPUT, f'bad id {record["id"]!r}')
    if record['id'] in RESERVED_IDS:
        return Failure(ErrorCode.INVALID_INPUT,
                       f'id {record["id"]!r} is reserved (the active choice is stored under it)')
    if not is_int(record['stamp_ns']):
        return Failure(ErrorCode.INVALID_INPUT,
                       f'stamp_ns must be an int [ns], got {record["stamp_ns"]!r}')
    if not isinstance(record['method'], str):
        return Failure(ErrorCode.INVALID_INPUT,
                       f'method must be a string, got {record["method"]!r}')
    return None


@dataclass(frozen=True)
class Activation:
    """What :meth:`CalibrationStore.activate` did: ``active`` (truthy) if ``record_id`` is now
    the active record of its scope, else ``reason`` says why not (its gate problem)."""

    record_id: str
    active: bool
    reason: str = ''

    def __bool__(self) -> bool:
        return self.active


def stored_gate_problem(record: Mapping[str, Any]) -> str:
    """The default gate: the record's own ``gate_problem`` ('' or absent: it passes)."""
    return str(record.get('gate_problem') or '')


def _read_selection(path: Path) -> tuple[dict[str, Any], str]:
    """active.json's mapping and '', or {} and what is wrong with the file."""
    data, problem = read_mapping(path)
    if problem:
        return {}, problem
    cells = data.get('cells', {})
    if not isinstance(cells, dict) or not all(isinstance(c, dict) for c in cells.values()):
        return {}, f'cells must map cell names to their choices, got {cells!r}'
    for choices in (data, *cells.values()):
        problem = _choices_problem(choices)
        if problem is not None:
            return {}, problem.message
    return data, ''


def _choices_problem(data: Mapping[str, Any]) -> Failure | None:
    """None if ``data`` holds valid choices (active_id, active_ids, retired), else an
    INVALID_INPUT Failure saying why not."""
    chosen, retired = data.get('active_id'), data.get('retired', [])
    if chosen is not None and not (isinstance(chosen, str) and ID_PATTERN.fullmatch(chosen)):
        return Failure(ErrorCode.INVALID_INPUT,
                       f'active_id must be null or a calibration id, got {chosen!r}')
    scoped = data.get('active_ids', {})
    if not isinstance(scoped, dict) or not all(
            isinstance(k, str) and isinstance(v, str) and ID_PATTERN.fullmatch(v)
            for k, v in scoped.items()):
        return Failure(ErrorCode.INVALID_INPUT,
                       f'active_ids must map scopes to calibration ids, got {scoped!r}')
    if not isinstance(retired, list) or not all(
            isinstance(r, str) and ID_PATTERN.fullmatch(r) for r in retired):
        return Failure(ErrorCode.INVALID_INPUT,
                       f'retired must be a list of calibration ids, got {retired!r}')
    return None


@contextlib.contextmanager
def _locked(directory: Path) -> Iterator[None]:
    """One writer of ``directory``'s active.json at a time (several cells share it)."""
    with open(directory / LOCK_FILE, 'a') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield


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

    ``gate``: record -> '' if it may become active, else why not (default: the record's own
    ``gate_problem``, which its builder sets with its kind's criterion). A record that fails
    its gate is stored and stays in the history, marked rejected (:meth:`rejected`), and is
    never active: :meth:`activate` refuses it with an :class:`Activation` saying why, and the
    default (newest) skips it.

    ``scope_key``: the record key whose value scopes activation ('' : one scope). Each scope
    (e.g. each robot) has its own active record, chosen or newest among that scope's records;
    :meth:`active` takes the scope. In ``active.json`` a chosen id of scope '' is
    ``active_id`` (the format before scopes; an ``active_id`` of a scoped record counts for
    that record's scope), the others are in ``active_ids`` {scope: id}.

    ``cell`` (store.cells.ResultsCell): the cell whose records this store holds; saved
    records get its name and robot (a record of another is refused: a core.errors.Refusal
    of cause FOREIGN_RESULT), :meth:`get` of another cell's id is refused naming both. Its
    choices are ``cells: {name: {active_ids, retired}}`` in ``active.json``; the top-level
    ones are those made before results were keyed by cell (and of a store opened with no
    cell: every record, as before).
    """

    def __init__(self, root: Path, subdir: str = 'calibrations', scope_key: str = '',
                 gate: Callable[[Mapping[str, Any]], str] = stored_gate_problem,
                 cell: ResultsCell | None = None) -> None:
        super().__init__()
        self.gate = gate
        self.root = Path(root)
        self.directory = self.root / subdir
        self.selection_path = self.directory / ACTIVE_FILE
        self.scope_key = scope_key
        self.cell = cell
        self._records: dict[str, dict[str, Any]] | None = None
        self._others: dict[str, str] = {}       # id -> why it is not this cell's
        self._legacy: frozenset[str] = frozenset()   # taken from before keying by cell
        self._chosen: dict[str, str] | None = None     # scope -> chosen id
        self._retired: frozenset[str] | None = None
        self._legacy_chosen: dict[str, str] = {}
        self._legacy_retired: frozenset[str] = frozenset()

    def scope_of(self, record: Mapping[str, Any]) -> str:
        """The activation scope ``record`` belongs to ('' in an unscoped store)."""
        return str(record.get(self.scope_key) or '') if self.scope_key else ''

    def save(self, record) -> Path:
        """Write ``record`` (a mapping or a store.records record) atomically and durably;
        returns its path."""
        return self._put(self._checked(record))

    def _checked(self, record) -> dict[str, Any]:
        """``record`` as stored: plain, with this store's cell and robot (ValueError if it is
        not a valid record, a FOREIGN_RESULT Refusal if it is another cell's). Nothing
        written."""
        plain = to_plain(record.to_dict() if hasattr(record, 'to_dict') else record)
        problem = _record_problem(plain)
        if problem is not None:
            raise ValueError(f'invalid calibration record: {problem.message}')
        return self._keyed(plain)

    def _put(self, plain: dict[str, Any]) -> Path:
        """Write a :meth:`_checked` record: from here on other readers see it."""
        ensure_dir(self.directory)
        path = self._path(plain['id'])
        write_mapping(path, plain)
        self._index()[plain['id']] = plain
        return path

    def _keyed(self, plain: dict[str, Any]) -> dict[str, Any]:
        """``plain`` with this store's cell name and robot; a FOREIGN_RESULT Refusal if it is
        another cell's or was made on another robot."""
        if self.cell is None:
            return plain
        why = self.cell.problem(str(plain.get('cell') or ''), str(plain.get('robot') or ''))
        if why is not None:
            raise foreign_result(f'calibration {plain["id"]} refused: {why.message}')
        return {**plain, 'cell': self.cell.name,
                **({'robot': self.cell.robot} if self.cell.robot else {})}

    def get(self, record_id: str) -> dict[str, Any] | None:
        """The record with this id, or None if absent or unreadable (see ``warnings``);
        a FOREIGN_RESULT Refusal naming both if it is another cell's or robot's."""
        record = self._index().get(check_id(record_id))
        if record is None:
            why = self._elsewhere(record_id)
            if why:
                raise foreign_result(f'calibration {record_id} is not this cell\'s: {why}')
        return record

    def _elsewhere(self, record_id: str) -> str:
        """Why ``record_id`` is not this cell's if it is stored for another, else ''."""
        return self._others.get(record_id, '')

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

    def active(self, scope: str = '') -> dict[str, Any] | None:
        """The active record of ``scope``: the chosen one if it is stored and not retired, else
        the newest non-retired one of that scope; None if there is none."""
        retired = self.retired()
        chosen = self._index().get(self._choices().get(scope, ''))
        if (chosen is not None and chosen['id'] not in retired
                and self.scope_of(chosen) == scope and not self.gate(chosen)):
            return chosen
        return self._newest(scope, retired)

    def retired(self) -> frozenset[str]:
        """The ids of retired records (some may no longer be stored)."""
        if self._retired is None:
            self._load_selection()
        return self._retired

    def rejected(self) -> dict[str, str]:
        """{id: why} of the stored records that fail their gate (never active)."""
        return {r['id']: problem for r in self._index().values() if (problem := self.gate(r))}

    def activate(self, record_id: str | None, scope: str = '') -> Activation:
        """Make ``record_id`` (un-retired) the active record of its scope, if it passes its
        gate (else nothing changes and the result says why); None or '': no choice in
        ``scope``, its newest non-retired record that passes is active. KeyError if no such
        record, ValueError if not an id, OSError if active.json cannot be written (then nothing
        changed)."""
        retired, chosen = self.retired(), dict(self._choices())
        if record_id:
            record = self._require(record_id)
            problem = self.gate(record)
            if problem:
                return Activation(record_id, False, (
                    f'{record_id} is rejected ({problem}): kept in the history, never active'))
            scope = self.scope_of(record)
            retired = retired - {record_id}
            chosen[scope] = record_id
        else:
            chosen.pop(scope, None)
        self._select(chosen, retired)
        active = self.active(scope)
        return Activation(active['id'] if active else '', active is not None,
                          '' if active else 'no calibration can be active: none is stored, or '
                          'all are retired or rejected')

    def save_and_activate(self, record) -> Activation:
        """:meth:`save` ``record``, then :meth:`activate` it: a record that fails its gate is
        kept (rejected) and the active one stays as it was."""
        plain = record.to_dict() if hasattr(record, 'to_dict') else record
        self.save(plain)
        return self.activate(plain['id'])

    def retire(self, record_id: str) -> None:
        """Mark ``record_id`` retired: kept in the history, never active; if it was chosen,
        the newest non-retired record of its scope becomes active. Errors as
        :meth:`activate`."""
        scope = self.scope_of(self._require(record_id))
        chosen = dict(self._choices())
        if chosen.get(scope) == record_id:
            del chosen[scope]
        self._select(chosen, self.retired() | {record_id})

    def _require(self, record_id: str) -> dict[str, Any]:
        record = self.get(record_id)
        if record is None:
            raise KeyError(f'no calibration {record_id!r}')
        return record

    def _newest(self, scope: str, retired: frozenset[str]) -> dict[str, Any] | None:
        return next((r for r in self.history() if r['id'] not in retired
                     and self.scope_of(r) == scope and not self.gate(r)), None)

    def _choices(self) -> dict[str, str]:
        if self._chosen is None:
            self._load_selection()
        return self._chosen

    def _select(self, chosen: dict[str, str], retired: frozenset[str]) -> None:
        """Store the choices (only where they differ from the default, or from a legacy
        choice, see store.cells) and the retired ids."""
        kept = {}
        for scope in chosen.keys() | self._legacy_chosen.keys():
            record_id, legacy = chosen.get(scope), self._legacy_chosen.get(scope)
            newest = self._newest(scope, retired)
            if record_id is None:       # back to the newest: said over a legacy choice
                if legacy is not None and newest is not None:
                    kept[scope] = newest['id']
            elif (newest is None or newest['id'] != record_id or legacy not in (None, record_id)
                  or record_id in self._legacy_retired):
                kept[scope] = record_id
        if (kept, retired) == (self._choices(), self.retired()):
            return
        self._write_selection(kept, retired)
        self._set_choices(kept, retired)

    def _set_choices(self, own_chosen: dict[str, str], own_retired: frozenset[str]) -> None:
        """The choices in force: this cell's own over the legacy ones it took (a legacy
        retired id stays retired unless this cell chose it)."""
        self._chosen = {**self._legacy_chosen, **own_chosen}
        self._retired = frozenset((own_retired | self._legacy_retired)
                                  - set(own_chosen.values()))

    def _write_selection(self, kept: dict[str, str], retired: frozenset[str]) -> None:
        """Store the choices {scope: id} and the retired ids atomically (active.json: the
        cell's entry, or the top level for a store opened with no cell)."""
        ensure_dir(self.directory)
        with _locked(self.directory):       # other cells' entries are kept as they are now
            data = self._read_selection_file()[0] or {}
            if self.cell is not None:
                cells = {**data.get('cells', {}), self.cell.name: {
                    'active_ids': dict(sorted(kept.items())), 'retired': sorted(retired)}}
                data = {**data, 'cells': dict(sorted(cells.items()))}
            else:
                scoped = {scope: record_id for scope, record_id in sorted(kept.items())
                          if scope}
                data = {'active_id': kept.get(''), **({'active_ids': scoped} if scoped else {}),
                        'retired': sorted(retired),
                        **({'cells': data['cells']} if data.get('cells') else {})}
            write_mapping(self.selection_path, data)

    def _read_selection_file(self) -> tuple[dict[str, Any] | None, str]:
        if not self.selection_path.exists():
            return None, ''
        return _read_selection(self.selection_path)

    def _stored_selections(self) -> tuple[tuple[dict[str, Any] | None, str],
                                          tuple[dict[str, Any] | None, str]]:
        """(this cell's stored choices, the legacy ones), each as active.json's mapping and
        '', None if none is stored, or {} and what is wrong with them."""
        data, problem = self._read_selection_file()
        if data is None or problem or self.cell is None:
            return (data, problem), (None, '')
        return (data.get('cells', {}).get(self.cell.name), ''), (data, '')

    def _load_selection(self) -> None:
        self._index()           # which records are legacy ones this cell took
        own, legacy = self._stored_selections()
        legacy_chosen, legacy_retired = self._choices_of(*legacy)
        self._legacy_chosen = {scope: record_id for scope, record_id in legacy_chosen.items()
                               if record_id in self._legacy}
        self._legacy_retired = legacy_retired & self._legacy
        self._set_choices(*self._choices_of(*own))

    def _choices_of(self, data: Mapping[str, Any] | None, problem: str
                    ) -> tuple[dict[str, str], frozenset[str]]:
        """{scope: chosen id} and the retired ids of stored choices."""
        if data is None:
            return {}, frozenset()
        if problem:
            self._warn(f'{self.selection_path}: ignored ({problem}); the newest calibration '
                       'is active and none is retired until set_active_calibration is called')
            return {}, frozenset()
        chosen = dict(data.get('active_ids', {}))
        legacy = self._index().get(data.get('active_id') or '')
        if legacy is not None:      # the id chosen in scope '', or before scopes existed
            chosen.setdefault(self.scope_of(legacy), legacy['id'])
        return chosen, frozenset(data.get('retired', []))

    def _index(self) -> dict[str, dict[str, Any]]:
        """This cell's records (its own and the legacy ones it takes, store.cells)."""
        if self._records is None:
            records, others, legacy = {}, {}, []
            for record, cell, robot in self._stored():
                why = self.cell.problem(cell, robot) if self.cell else None
                if why is not None:
                    others[record['id']] = why.message
                    continue
                records[record['id']] = record
                if self.cell and cell in ('', LEGACY_CELL):
                    legacy.append(record['id'])
            self._records, self._others, self._legacy = records, others, frozenset(legacy)
            if legacy:
                self._warn(legacy_note(self.cell, str(self), sorted(legacy)))
        return self._records

    def _stored(self) -> Iterator[tuple[dict[str, Any], str, str]]:
        """(record, its cell, its robot: '' where not recorded) of every readable record."""
        paths = (sorted(p for p in self.directory.glob('*.json')
                        if p.name != ACTIVE_FILE) if self.directory.is_dir() else [])
        for path in paths:
            record = self._load(path)
            if record is not None:
                yield record, str(record.get('cell') or ''), str(record.get('robot') or '')

    def __str__(self) -> str:
        return str(self.directory)

    def _path(self, record_id: str) -> Path:
        return self.directory / f'{record_id}.json'

    def _load(self, path: Path) -> dict[str, Any] | None:
        record = self._read_mapping(path)
        if record is None:
            return None
        problem = _record_problem(record)
        if problem is None and record['id'] != path.stem:
            problem = Failure(ErrorCode.INVALID_INPUT,
                              f'id {record["id"]!r} does not match the file name')
        if problem is not None:
            self._warn(f'{path}: skipped, {problem.message}')
            return None
        return with_current_names(record)
