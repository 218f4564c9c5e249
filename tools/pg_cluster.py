"""A throwaway PostgreSQL cluster for the tests and benchmarks of the results database.

``initdb`` in a fresh temp dir, ``pg_ctl start`` on a free local port (TCP on 127.0.0.1 only,
its socket in the temp dir), as an unprivileged user (the caller; as root: the ``postgres``
system user, or ``nobody``, since PostgreSQL refuses to run as root), stopped and removed on
exit. The server binaries are found on PATH or under /usr/lib/postgresql/*/bin (Debian's
``postgresql-15``; ``make setup`` installs it where missing).
"""
from __future__ import annotations

import contextlib
import glob
import os
from pathlib import Path
import pwd
import shutil
import socket
import subprocess
import tempfile

START_TIMEOUT_S = 60


def server_bin() -> Path | None:
    """The folder of initdb and pg_ctl, or None if PostgreSQL's server is not installed."""
    found = shutil.which('pg_ctl')
    if found:
        return Path(found).resolve().parent      # Debian links only some tools onto PATH
    candidates = sorted(glob.glob('/usr/lib/postgresql/*/bin/pg_ctl'),
                        key=lambda p: int(Path(p).parts[-3]) if Path(p).parts[-3].isdigit()
                        else 0)
    return Path(candidates[-1]).parent if candidates else None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def _run_as(user: str | None):
    """subprocess kwargs that run a command as ``user`` (None: as the caller)."""
    if user is None:
        return {}
    entry = pwd.getpwnam(user)
    return {'user': entry.pw_uid, 'group': entry.pw_gid, 'extra_groups': [],
            'env': {**os.environ, 'HOME': tempfile.gettempdir()}}


@contextlib.contextmanager
def throwaway_cluster(database: str = 'cobot_calib'):
    """Yield the URL of a database on a fresh local cluster; stop and remove it after."""
    bin_dir = server_bin()
    if bin_dir is None:
        raise RuntimeError('PostgreSQL server binaries (initdb, pg_ctl) not found: run '
                           '`make setup` (it installs postgresql on Debian) or install them')
    user = None
    if os.geteuid() == 0:
        user = next(u for u in ('postgres', 'nobody') if _has_user(u))
    top = Path(tempfile.mkdtemp(prefix='cobot_calib_pg_'))
    kwargs = _run_as(user)
    if user:
        entry = pwd.getpwnam(user)
        os.chown(top, entry.pw_uid, entry.pw_gid)
    data, port = top / 'data', _free_port()
    superuser = user or pwd.getpwuid(os.geteuid()).pw_name
    try:
        subprocess.run([bin_dir / 'initdb', '-D', data, '-A', 'trust', '-U', superuser,
                        '--no-sync', '-E', 'UTF8'], check=True, capture_output=True, **kwargs)
        subprocess.run([bin_dir / 'pg_ctl', '-D', data, '-l', top / 'server.log', '-w',
                        '-t', str(START_TIMEOUT_S), '-o',
                        f'-p {port} -k {top} -c listen_addresses=127.0.0.1 -c fsync=on '
                        '-c max_connections=200', 'start'],
                       check=True, capture_output=True, **kwargs)
        try:
            subprocess.run([bin_dir / 'createdb', '-h', '127.0.0.1', '-p', str(port),
                            '-U', superuser, database], check=True, capture_output=True,
                           **kwargs)
            yield f'postgresql://{superuser}@127.0.0.1:{port}/{database}'
        finally:
            subprocess.run([bin_dir / 'pg_ctl', '-D', data, '-m', 'fast', '-w', 'stop'],
                           capture_output=True, **kwargs)
    except subprocess.CalledProcessError as exc:
        log = (top / 'server.log').read_text() if (top / 'server.log').exists() else ''
        raise RuntimeError(f'throwaway PostgreSQL failed: {exc.cmd}: '
                           f'{exc.stderr.decode(errors="replace")}{log}') from exc
    finally:
        shutil.rmtree(top, ignore_errors=True)


def _has_user(name: str) -> bool:
    try:
        pwd.getpwnam(name)
        return True
    except KeyError:
        return False
