"""Removes the Fast DDS shared-memory segments of processes that are gone.

Each DDS participant maps segments /dev/shm/fastrtps_<16 hex digits> (16 MB with
config/fastdds_large_images.xml) and holds a flock on the empty file beside each,
fastrtps_<id>_el, created just before the segment. A participant destroyed in an orderly way
removes both; a process killed (SIGKILL, the OOM killer, a crash) leaves both behind, and
nothing else ever removes them: /dev/shm is memory, and a day of test runs whose suites were
killed filled its 24 GB (about 1,300 segments; the machine then ran out of memory and the
test workers were killed). Fast DDS's own `fastdds shm clean` does the same, but its CLI is not
in the PyPI wheels.

A segment is stale when its lock file can be locked by us (no process holds it) and it is
older than MIN_AGE s (a participant being created right now has its lock file before it has
locked it). Port files (fastrtps_port<N>) are shared between processes, are small, and Fast
DDS checks them itself when it opens them: they are left alone.
"""
from __future__ import annotations

from dataclasses import dataclass
import fcntl
import os
from pathlib import Path
import re
import time

SHM_DIR = Path('/dev/shm')
SEGMENT = re.compile(r'fastrtps_[0-9a-f]{16}')
LOCK_SUFFIX = '_el'
MIN_AGE = 60.0      # [s]


@dataclass(frozen=True)
class Cleaned:
    segments: int
    bytes_freed: int


def remove_stale_segments(directory: Path = SHM_DIR, min_age: float = MIN_AGE) -> Cleaned:
    """Remove every stale Fast DDS segment in ``directory`` (module doc) with its lock file;
    what was removed. A file that vanishes or cannot be opened meanwhile is skipped."""
    segments = freed = 0
    now = time.time()
    try:
        names = os.listdir(directory)
    except OSError:
        return Cleaned(0, 0)
    for name in names:
        if not SEGMENT.fullmatch(name):
            continue
        segment = directory / name
        lock = directory / f'{name}{LOCK_SUFFIX}'
        try:
            stat = segment.stat()
        except OSError:
            continue
        if now - stat.st_mtime < min_age or not _unlocked(lock):
            continue
        try:
            segment.unlink()
            lock.unlink(missing_ok=True)
        except OSError:
            continue
        segments += 1
        freed += stat.st_blocks * 512
    return Cleaned(segments, freed)


def _unlocked(lock: Path) -> bool:
    """Whether no process holds ``lock``'s flock (a missing lock file: its process is gone).
    Our own lock is let go at once, and the file is removed with its segment."""
    try:
        fd = os.open(lock, os.O_RDONLY)
    except FileNotFoundError:
        return True
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    else:
        fcntl.flock(fd, fcntl.LOCK_UN)
        return True
    finally:
        os.close(fd)
