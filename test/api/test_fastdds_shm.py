"""Fast DDS shared-memory segments: a node that stops leaves none behind (ros.spin.destroy), and
the segments of a killed process are removed by api.fastdds_shm (a day of killed test suites
once filled /dev/shm's 24 GB)."""
import fcntl
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

from cobot_calib_ros.api.dds_profile import large_data_env
from cobot_calib_ros.api.fastdds_shm import LOCK_SUFFIX, remove_stale_segments, SHM_DIR
from cobot_calib_ros.api.launcher import NodeSpec

SEGMENT_BYTES = 16 * 2 ** 20
# a participant with an action server (what kept rclpy's destroy_node from ending the
# participant), destroyed by ros.spin.destroy and ended with os._exit as a stopped node is
PARTICIPANT = '''
import os, sys, rclpy
from rclpy.action import ActionServer
from cobot_calib_msgs.action import MoveTo
from cobot_calib_ros.ros import spin
rclpy.init()
node = rclpy.create_node('segment_probe')
server = ActionServer(node, MoveTo, "move", lambda goal: MoveTo.Result())
print('up', flush=True)
sys.stdin.readline()
spin.destroy(node)
rclpy.try_shutdown()
os._exit(0)
'''


def own_segments(pid: int) -> set[str]:
    """The names of the Fast DDS segments (not ports) process ``pid`` made: those whose lock
    file it holds (/proc/locks: pid, device:inode). It maps its peers' segments too."""
    inodes = set()
    for line in Path('/proc/locks').read_text().splitlines():
        fields = line.split()
        if fields[1] == 'FLOCK' and fields[4] == str(pid):
            inodes.add(int(fields[5].rsplit(':', 1)[1]))
    return {p.name.removesuffix(LOCK_SUFFIX) for p in SHM_DIR.glob(f'fastrtps_*{LOCK_SUFFIX}')
            if re.fullmatch(r'fastrtps_[0-9a-f]{16}_el', p.name) and _inode(p) in inodes}


def _inode(path: Path) -> int | None:
    try:
        return path.stat().st_ino
    except FileNotFoundError:
        return None


def start_participant() -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, '-c', PARTICIPANT], env=large_data_env(),
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == 'up'
    return proc


def left(names: set[str]) -> set[str]:
    return {n for n in names if (SHM_DIR / n).exists() or (SHM_DIR / f'{n}{LOCK_SUFFIX}').exists()}


def test_a_participant_with_an_action_server_leaves_no_segment_when_destroyed():
    proc = start_participant()
    segments = own_segments(proc.pid)
    assert segments and left(segments) == segments
    proc.communicate('\n', timeout=30)
    assert proc.returncode == 0
    assert left(segments) == set()


def test_a_stopped_node_process_leaves_no_segment():
    """user_frame_solver (an action server on a companion) stopped by SIGINT, as the launcher
    stops it: it left two segments of 16 MB and 512 KB before ros.spin.destroy."""
    proc = subprocess.Popen(NodeSpec('user_frame_solver').command(), env=large_data_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while len(segments := own_segments(proc.pid)) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    time.sleep(2.0)        # its action servers made
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=30) == 0
    assert segments and left(segments) == set()


def test_the_segments_of_a_killed_process_are_removed_and_a_live_ones_kept():
    killed, live = start_participant(), start_participant()
    try:
        gone = own_segments(killed.pid)
        kept = own_segments(live.pid)
        killed.kill()
        killed.wait(timeout=10)
        assert left(gone) == gone                  # Fast DDS removes nothing of a killed process
        cleaned = remove_stale_segments(min_age=0.0)
        assert left(gone) == set()
        assert left(kept) == kept
        assert cleaned.segments >= len(gone)
        assert cleaned.bytes_freed >= SEGMENT_BYTES
    finally:
        live.communicate('\n', timeout=30)
    assert left(kept) == set()


def test_a_young_segment_or_a_held_lock_is_kept(tmp_path):
    names = {k: f'fastrtps_{i:016x}' for i, k in enumerate(('stale', 'young', 'held', 'no_lock'))}
    for name in names.values():
        (tmp_path / name).write_bytes(b'x' * 4096)
        (tmp_path / f'{name}{LOCK_SUFFIX}').touch()
    (tmp_path / f'{names["no_lock"]}{LOCK_SUFFIX}').unlink()
    (tmp_path / 'fastrtps_port7000').write_bytes(b'p')        # ports: Fast DDS's own business
    (tmp_path / 'fastrtps_port7000_el').touch()
    old = time.time() - 120
    for key in ('stale', 'held', 'no_lock'):
        os.utime(tmp_path / names[key], (old, old))
    holder = os.open(tmp_path / f'{names["held"]}{LOCK_SUFFIX}', os.O_RDONLY)
    fcntl.flock(holder, fcntl.LOCK_EX)
    try:
        cleaned = remove_stale_segments(tmp_path, min_age=60.0)
    finally:
        os.close(holder)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([
        names['young'], f'{names["young"]}{LOCK_SUFFIX}',
        names['held'], f'{names["held"]}{LOCK_SUFFIX}',
        'fastrtps_port7000', 'fastrtps_port7000_el'])
    assert cleaned.segments == 2 and cleaned.bytes_freed >= 2 * 4096
