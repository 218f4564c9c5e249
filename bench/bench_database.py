"""Results database under load (issue 19 must-show 1): CELLS cell processes write RESULTS user
frames each at once, to one throwaway PostgreSQL (tools/pg_cluster.py) and to one shared SQLite
file (the worst case for SQLite: every cell in one file, WAL, BEGIN IMMEDIATE).

Each process opens its repository first (connects, checks the schema: a node does this once
at its start), then all write at once; each stores its records through the repository (``store.open(..., db, cell)
.user_frames.save_and_activate``, a realistic 5-point user frame), times every write, and
prints the latencies; then the rows are counted per cell and compared, id by id and body by
body, with what was written. Figures:

- ``db_load_lost`` [count]: records written (acknowledged) but not in the database, both back-ends;
- ``db_load_duplicated`` [count]: rows beyond one per (cell, id), both back-ends;
- ``db_write_p99_ms`` / ``_p50_ms`` [ms]: one save_and_activate on PostgreSQL, over every write;
- ``db_write_sqlite_p99_ms`` / ``_p50_ms`` [ms]: the same on the shared SQLite file.
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import benchlib
from benchlib import BenchFailed, Figures

sys.path.insert(0, str(benchlib.REPO_ROOT / 'tools'))
from pg_cluster import throwaway_cluster  # noqa: E402 (shared with test/store)

CELLS = 20
RESULTS = 30

WRITER = r'''
import json, sys, time
import numpy as np
from cobot_calib_ros import store
from cobot_calib_ros.core import user_frame
url, root, cell, count = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
rng = np.random.default_rng(abs(hash(cell)) % 2**32)
p_user = np.array([[0, 0, 0], [.2, 0, 0], [.2, .15, 0], [0, .15, 0], [.1, .075, 0]])
from cobot_calib_ros.store.records import UserFrameRecord
history = store.open(root, url, cell).user_frames
history.active()                            # connected, schema checked: as a node after start
print('ready', flush=True)
sys.stdin.readline()                        # every process starts writing at once
seconds = []
for k in range(count):
    p_base = p_user + [0.5, -0.1, 0.0] + rng.normal(0, 3e-5, (5, 3))
    fit = user_frame.calibrate('rigid', p_user, p_base)
    record = UserFrameRecord.from_fit(fit, None, [f'P{i}' for i in range(1, 6)], p_user,
                                      p_base, ('base', 'user'), k)
    record.id = f'{cell}-{k:04d}'
    start = time.perf_counter()
    history.save_and_activate(record)
    seconds.append(time.perf_counter() - start)
print(json.dumps({'seconds': seconds}), flush=True)
'''


def load(url: str, root: Path) -> tuple[list[float], int, int]:
    """(write latencies [s], lost, duplicated) of CELLS processes writing RESULTS each."""
    procs = [subprocess.Popen([sys.executable, '-c', WRITER, url, str(root / f'cell_{c:02d}'),
                               f'cell_{c:02d}', str(RESULTS)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True) for c in range(CELLS)]
    for p in procs:
        if p.stdout.readline().strip() != 'ready':
            raise BenchFailed(f'a writer did not start (exit {p.wait()})')
    for p in procs:
        p.stdin.write('go\n')
        p.stdin.flush()
    seconds = []
    for p in procs:
        out, _ = p.communicate(timeout=600)
        if p.returncode != 0:
            raise BenchFailed(f'a writer failed (exit {p.returncode})')
        seconds += json.loads(out.strip().splitlines()[-1])['seconds']
    from cobot_calib_ros.store.database import Database
    database = Database(url)
    lost = duplicated = 0
    for c in range(CELLS):
        rows = database.rows(f'cell_{c:02d}', 'user_frame')
        ids = [r['id'] for r in rows]
        expected = {f'cell_{c:02d}-{k:04d}' for k in range(RESULTS)}
        lost += len(expected - set(ids))
        duplicated += len(ids) - len(set(ids))
        lost += sum(1 for r in rows if json.loads(r['body'])['id'] != r['id'])
    return seconds, lost, duplicated


def run() -> Figures:
    figures: Figures = {}
    with tempfile.TemporaryDirectory(prefix='bench_db_') as tmp, throwaway_cluster() as pg:
        pg_seconds, pg_lost, pg_dup = load(pg, Path(tmp) / 'pg')
        sq_seconds, sq_lost, sq_dup = load(f'sqlite:///{tmp}/plant.sqlite', Path(tmp) / 'sq')
    figures['db_load_lost'] = (pg_lost + sq_lost, 'count')
    figures['db_load_duplicated'] = (pg_dup + sq_dup, 'count')
    figures['db_load_writes'] = (len(pg_seconds) + len(sq_seconds), 'count')
    for name, seconds in (('db_write', pg_seconds), ('db_write_sqlite', sq_seconds)):
        p50, p99 = np.percentile(np.asarray(seconds) * 1e3, [50, 99])
        figures[f'{name}_p50_ms'] = (float(p50), 'ms')
        figures[f'{name}_p99_ms'] = (float(p99), 'ms')
    figures['db_load_1min_load_average'] = (benchlib.load_average_1min(), '')
    return figures


if __name__ == '__main__':
    sys.exit(benchlib.main(run))
