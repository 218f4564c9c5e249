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

import contextlib
import json
import os
from pathlib import Path
import re
import tempfile
from collections.abc import Mapping
from typing import Any

import numpy as np
import yaml

from cobot_calib_ros.core.yaml_c import DUMPER, LOADER

FILE_MODE = 0o644
TEMP_SUFFIX = '.tmp'
ID_PATTERN = re.compile(r'[A-Za-z0-9][A-Za-z0-9_.-]{0,127}')


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
    if not isinstance(value, str) or not ID_PATTERN.fullmatch(value):
        raise ValueError(f'id must match {ID_PATTERN.pattern}, got {value!r}')
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


class WarningLog:
    """Collects one message per distinct problem found while reading files."""

    def __init__(self) -> None:
        self.warnings: list[str] = []

    def _warn(self, message: str) -> None:
        if message not in self.warnings:
            self.warnings.append(message)

    def _read_mapping(self, path: Path) -> dict[str, Any] | None:
        """A YAML or (by suffix) JSON file's top-level mapping, or None with a warning."""
        data, problem = read_mapping(path)
        if problem:
            self._warn(f'{path}: skipped, {problem}')
        return data


def dump_yaml(data: Any, **options: Any) -> str:
    """yaml.safe_dump(data, **options), by libyaml where there is one."""
    return yaml.dump(data, Dumper=DUMPER, **options)


def write_mapping(path: Path, data: Mapping[str, Any]) -> None:
    """``data`` (plain values) atomically as YAML or (by suffix) JSON, read_mapping's formats.
    JSON is written compact: ``indent=`` takes json's pure-Python encoder (0.24 s against 0.10 s
    for a 5.8 MB collection)."""
    atomic_write_text(path, json.dumps(data) + '\n' if path.suffix == '.json' else
                      dump_yaml(data, sort_keys=False, allow_unicode=True))


def read_mapping(path: Path) -> tuple[dict[str, Any] | None, str]:
    """A YAML or (by suffix) JSON file's top-level mapping and '', or None and why not."""
    try:
        text = path.read_text(encoding='utf-8')
        data = json.loads(text) if path.suffix == '.json' else yaml.load(text, LOADER)
    except (OSError, UnicodeDecodeError, ValueError, yaml.YAMLError) as exc:
        return None, f'unreadable ({" ".join(str(exc).split())})'
    if not isinstance(data, dict):
        return None, 'not a mapping'
    return data, ''


def ensure_dir(directory: Path) -> None:
    """mkdir -p, fsyncing the parent of every directory it creates."""
    missing = []
    current = directory
    while not current.exists():
        missing.append(current)
        current = current.parent
    directory.mkdir(parents=True, exist_ok=True)
    for created in reversed(missing):
        fsync_dir(created.parent)


def append_line(path: Path, line: str, header: str) -> None:
    """Append one line with a single write, then fsync (at most this line is lost); a new
    file starts with ``header``; a line truncated by a crash is ended first (readers skip it)."""
    data = line.encode('utf-8')
    with open(path, 'a+b') as f:  # writes always go to the end, reads do not
        size = f.seek(0, os.SEEK_END)
        if size == 0:
            data = (header + '\n').encode('utf-8') + data
        else:
            f.seek(size - 1)
            if f.read(1) != b'\n':
                data = b'\n' + data
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def read_lines(path: Path, header: str, log: 'WarningLog') -> list[tuple[int, str]]:
    """(line number, text) of the complete data lines after ``header``; a truncated last line
    is reported in ``log`` and left out."""
    try:
        text = path.read_bytes().decode('utf-8', errors='replace')
    except OSError as exc:
        log._warn(f'{path}: no rows read ({exc})')
        return []
    lines = text.split('\n')
    tail = lines.pop()  # '' when the file ends with a newline
    if tail:
        log._warn(f'{path}: ignored truncated last line {tail!r} (crash mid-write?)')
    return [(n, line) for n, line in enumerate(lines, start=1)
            if line and not (n == 1 and line == header)]


def is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


