"""launcher: a node it started does not outlive it (killed launcher, or one gone before the
node's start)."""
import contextlib
import os
import signal
import sqlite3
import subprocess
import sys
import time

import domain_coordinator
import pytest

from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros import spin
from cobot_calib_ros.store.database import HEAD_REVISION, SQLITE_FILE

LAUNCHER_SCRIPT = '''
import sys, time
from pathlib import Path
from cobot_calib_ros.api import launcher
suite = launcher.Suite(Path(sys.argv[1]))
suite.start([launcher.NodeSpec('user_frame_solver', params={'data_dir': sys.argv[2]})])
print(suite.processes['user_frame_solver'].pid, flush=True)
time.sleep(600)
'''
GONE_WITHIN = 30.0      # [s] SIGTERM to a node still importing on a loaded machine


def _alive(pid: int) -> bool:
    try:
        with open(f'/proc/{pid}/stat') as stat:
            return stat.read().split(')')[-1].split()[0] != 'Z'
    except FileNotFoundError:
        return False


@pytest.fixture
def domain():
    with domain_coordinator.domain_id() as domain_id:
        yield domain_id


@pytest.mark.parametrize('after', [0.0, 6.0])      # killed at once, or after the node's start
def test_a_node_ends_when_its_launcher_is_killed(tmp_path, domain, after):
    env = {**os.environ, 'ROS_DOMAIN_ID': str(domain)}
    parent = subprocess.Popen([sys.executable, '-c', LAUNCHER_SCRIPT, str(tmp_path / 'logs'),
                               str(tmp_path / 'data')], stdout=subprocess.PIPE, text=True,
                              env=env)
    node = int(parent.stdout.readline())
    try:
        time.sleep(after)
        parent.kill()
        parent.wait()
        deadline = time.monotonic() + GONE_WITHIN
        while _alive(node) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(node), f'node {node} outlived its launcher by {GONE_WITHIN} s'
    finally:
        if _alive(node):
            os.kill(node, signal.SIGKILL)


def test_a_node_whose_launcher_is_gone_before_its_start_exits():
    env = {**os.environ, spin.LAUNCHER_PID_ENV: str(os.getppid())}   # not the node's parent
    done = subprocess.run([sys.executable, '-c', 'from cobot_calib_ros.ros import spin; '
                           'spin.die_with_launcher(); print("ran on")'],
                          capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 1 and 'ran on' not in done.stdout
    assert f'the launcher (pid {os.getppid()}) that started this node is gone' in done.stderr


def test_a_suite_s_databases_are_at_the_newest_migration_before_its_nodes_start(tmp_path):
    """prepare_stores (Suite.start, before any node): the data_dir parameter's database and
    the environment's data dir's; a data dir it cannot write is left to the nodes."""
    own, shared = tmp_path / 'own', tmp_path / 'shared'
    launcher.prepare_stores([launcher.NodeSpec('user_frame_solver', {'data_dir': str(own)}),
                             launcher.NodeSpec('mock_robot')],
                            {'COBOT_CALIB_DATA': str(shared)})
    for root in (own, shared):      # read without the store, which would migrate it itself
        with contextlib.closing(sqlite3.connect(root / SQLITE_FILE)) as db:
            assert db.execute('SELECT version_num FROM alembic_version').fetchall() == [
                (HEAD_REVISION,)]
    blocked = tmp_path / 'file'
    blocked.write_text('not a directory')
    launcher.prepare_stores([launcher.NodeSpec('user_frame_solver', {'data_dir': str(blocked)})])

