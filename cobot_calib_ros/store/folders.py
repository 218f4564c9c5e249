"""One folder per record: the half that trials and kinematic-data collections share.

``<directory>/<id>/<meta file>`` holds the record's metadata (YAML, or JSON by the file's suffix,
rewritten atomically) beside the append-only log the subclass keeps (store.files). A folder
without its metadata file is an aborted create (the metadata is written last) and is skipped.
A store whose metadata file changed name reads the old one where the new one is not (written
by an older version) and replaces it at the next write.
"""
from __future__ import annotations

from collections.abc import Mapping
import contextlib
from pathlib import Path
from typing import Any, ClassVar

from cobot_calib_ros.core.errors import Failure
from cobot_calib_ros.store.files import (atomic_write_text, check_id, ensure_dir, fsync_dir,
                                         read_mapping, to_plain, WarningLog, write_mapping)


class FolderStore(WarningLog):
    """Records as folders under ``directory``; subclasses name the files and check the meta."""

    META_FILE: ClassVar[str]    # e.g. 'trial.yaml'
    OLD_META_FILES: ClassVar[tuple[str, ...]] = ()     # read where META_FILE is not
    LOG_FILE: ClassVar[str]     # e.g. 'distances.csv'
    LOG_HEADER: ClassVar[str]   # the log's first line

    def __init__(self, directory: Path) -> None:
        super().__init__()
        self.directory = Path(directory)
        self._meta: dict[str, dict[str, Any]] = {}   # written or read by this store

    def _meta_problem(self, meta: Mapping[str, Any], record_id: str) -> Failure | None:
        """None if ``meta`` is valid metadata of ``record_id``, else an INVALID_INPUT Failure
        saying what is wrong."""
        raise NotImplementedError

    def _create_folder(self, meta: dict[str, Any]) -> None:
        """The folder of a new record with an empty log, then its metadata (last: a folder
        without it is an aborted create). FileExistsError if the id is taken."""
        ensure_dir(self.directory)
        folder = self.directory / check_id(meta['id'])
        folder.mkdir()
        fsync_dir(self.directory)
        atomic_write_text(folder / self.LOG_FILE, self.LOG_HEADER + '\n')
        self._write_meta(meta)

    def _write_meta(self, meta: dict[str, Any]) -> None:
        folder = self.directory / meta['id']
        write_mapping(folder / self.META_FILE, to_plain(meta))
        for old in self.OLD_META_FILES:
            with contextlib.suppress(FileNotFoundError):
                (folder / old).unlink()
        self._meta[meta['id']] = meta

    def meta_problem(self, record_id: str) -> str:
        """'' if the metadata of ``record_id`` reads and is valid, else why not (this call's
        answer: nothing is added to ``warnings``)."""
        return self._load_meta(check_id(record_id))[1]

    def _read_meta(self, record_id: str) -> dict[str, Any] | None:
        """The metadata from disk, or None with a warning."""
        meta, problem = self._load_meta(record_id)
        if problem:
            self._warn(problem)
            return None
        self._meta[record_id] = meta
        return meta

    @classmethod
    def meta_path(cls, folder: Path) -> Path:
        """The metadata file of the record in ``folder``: META_FILE, or an older name it was
        written under where there is no META_FILE (the name META_FILE when neither exists)."""
        for name in (cls.META_FILE, *cls.OLD_META_FILES):
            if (folder / name).exists():
                return folder / name
        return folder / cls.META_FILE

    def _load_meta(self, record_id: str) -> tuple[dict[str, Any] | None, str]:
        path = self.meta_path(self.directory / record_id)
        if not path.exists():
            return None, (f'{path.parent}: skipped, no {self.META_FILE} (missing or aborted '
                          'create)')
        meta, problem = read_mapping(path)
        if not problem and (invalid := self._meta_problem(meta, record_id)) is not None:
            problem = invalid.message
        return (None, f'{path}: skipped, {problem}') if problem else (meta, '')

    def _list_meta(self) -> list[dict[str, Any]]:
        """Metadata of every readable record, newest created first."""
        if not self.directory.is_dir():
            return []
        ids = sorted(p.name for p in self.directory.iterdir() if p.is_dir())
        metas = [m for m in map(self._read_meta, ids) if m is not None]
        return sorted(metas, key=lambda m: (m['created_ns'], m['id']), reverse=True)
