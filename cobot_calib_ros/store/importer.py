"""`cobot-calib db import DIR`: a folder store (store.calibrations, .kinematics, .trials,
.collections files) brought into a database repository, nothing lost.

Every readable calibration record goes in as it is on disk (its JSON mapping), with the
active choices and retired ids; kinematics' YAML and URDF files and the trial and collection
folders are copied into the repository's data dir (when it is another folder), and each trial
and collection is also stored as a result (its metadata and its log's text, byte for byte).
Files the folder store cannot read are listed (``skipped``), never dropped silently.
Importing again replaces the same ids: nothing is duplicated.

Cells (store.cells): into a repository opened for a cell, everything goes under that cell;
else each record under the cell it names (with its choices), and records that name none
under cell ``default``, for the cell of their robot to take.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import shutil

from cobot_calib_ros.store.cells import LEGACY_CELL
from cobot_calib_ros.store.repository import DatabaseRepository, FolderRepository

# repository attribute -> database kind
HISTORIES = {'user_frames': 'user_frame', 'hand_eye': 'hand_eye', 'kinematics': 'kinematics',
             'tcp': 'tcp', 'intrinsics': 'intrinsics'}


@dataclass
class ImportReport:
    counts: dict[str, int] = field(default_factory=dict)     # kind -> records imported
    skipped: list[str] = field(default_factory=list)         # unreadable files, with why

    def summary(self) -> str:
        kinds = ', '.join(f'{n} {kind}' for kind, n in self.counts.items())
        return f'imported {kinds or "nothing"}' + (
            f'; {len(self.skipped)} unreadable file(s) skipped' if self.skipped else '')


def import_folder(source: Path, target: DatabaseRepository) -> ImportReport:
    """Bring the folder store at ``source`` into ``target`` (see the module docstring)."""
    source = Path(source)
    folder, report = FolderRepository(source), ImportReport()
    database, cell = target.database, target.cell_name
    for attribute, kind in HISTORIES.items():
        history = getattr(folder, attribute)
        records = history.history()
        for record in reversed(records):
            database.put(cell if target.cell else str(record.get('cell') or LEGACY_CELL),
                         kind, record, history.scope_of(record))
        database.set_selection(cell, kind, history._choices(), history.retired())
        if target.cell is None:
            stored = history._read_selection_file()[0] or {}
            for name, choices in stored.get('cells', {}).items():
                database.set_selection(name, kind, choices.get('active_ids', {}),
                                       frozenset(choices.get('retired', [])))
        report.counts[kind] = len(records)
        report.skipped += history.warnings
    _copy_files(source / 'kinematics', target.root / 'kinematics', ('*.yaml', '*.urdf'))
    for kind, store in (('trial', folder.trials), ('collection', folder.collections)):
        metas = store._list_meta()
        for meta in metas:
            log = (store.directory / meta['id'] / store.LOG_FILE).read_text(encoding='utf-8')
            database.put(cell, kind, {'id': meta['id'], 'stamp_ns': int(meta['created_ns']),
                                      'method': str(meta.get('method', meta.get('source', ''))),
                                      'meta': meta, 'log': log})
            _copy_tree(store.directory / meta['id'],
                       target.root / store.directory.name / meta['id'])
        report.counts[kind] = len(metas)
        report.skipped += store.warnings
    return report


def _copy_files(source: Path, target: Path, patterns: tuple[str, ...]) -> None:
    if not source.is_dir() or source.resolve() == target.resolve():
        return
    target.mkdir(parents=True, exist_ok=True)
    for pattern in patterns:
        for path in source.glob(pattern):
            shutil.copy2(path, target / path.name)


def _copy_tree(source: Path, target: Path) -> None:
    if source.resolve() != target.resolve() and not target.exists():
        shutil.copytree(source, target)
