"""rosbag2 replay and recording (cobot_calib_ros.bags) at the cell's real rates.

Replay: a bag of BENCH_BAG_REPLAY_SECONDS (default 20) of 1 kHz JointState (7 joints) is
played by `cobot-calib replay` (its own process) to a raw, reliable, keep-last 1000 subscriber
in this bench process that takes them in batches (ros.batch_reader, as joint_state_monitor),
at ``--rate`` 4, 8, 16 and max: plain (``bag_replay_rate4_*``: as ``ros2 bag play``, no
back-pressure) and with flow control (``bag_replay_window_rate4_*``: ``--window`` WINDOW, the
subscriber publishing how many it has taken on /bag_player/consumed after every batch and
every spin). Figures per rate: the
real-time factor the player reports (recorded time played / wall time from its first to its
last publish), the fraction of messages the subscriber received (each counted once, by
stamp), and the player's CPU (% of one core over its whole run, start-up included). Goal:
>= 4x real time with nothing lost (with flow control nothing can be: the subscriber's history
holds the window; the speed is what the load leaves).

Publish cost: one JointState published from its recorded bytes (rclpy publish_raw, what the
player does) against deserialize_message + publish of the message object, no subscriber.

Recording, per node executor (benchlib.executors(); `cobot-calib record` picks it up from
$COBOT_CALIB_EXECUTOR): bench/bag_source.py publishes BENCH_BAG_RECORD_SECONDS (default 60) of
1 kHz JointState and 10 Hz 752x480 mono8 Image (reliable) once the recorder has matched both,
waits for its acknowledgements, and says how many it published; then the recorder gets Ctrl-C.
Figures: messages lost (published - recorded, per topic; goal 0) and when the first was lost,
the recorder's CPU (% of one core between the source's first and last message), the bag's
write rate.

Loss comes from a recorder starved of CPU (seen at load 5-7 with the bench niced): its DDS
receive thread stops releasing the source's shared-memory buffers (one 361 KB image fills
most of a 512 KB segment), the source's next samples are not delivered, and a keep-last 100
writer has overwritten them before the next heartbeat (3 s) could have them repaired; the
lost messages come in runs as long as the stall. 0 lost on a quiet machine.
"""
from __future__ import annotations

import os
from pathlib import Path
import re
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time

from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import UInt64

import benchlib
from benchlib import BenchFailed, Figures, Ros
from cobot_calib_ros.bags.metadata import qos
from cobot_calib_ros.bags.reader import open_bag
from cobot_calib_ros.bags.writer import BagWriter

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bag_source import BASE_S  # noqa: E402 - the source's numbering

T0 = 1_795_000_000_000_000_000
STAMP = struct.Struct('<iI')
PUBLISHED = re.compile(r'published (\d+) messages in ([\d.]+) s \(([\d.]+|inf)x real time\)')
LOST = re.compile(r'^lost: (\d+) of \d+', re.M)
PUBLISH_CALLS = 20_000
RATES = ('4', '8', '16', 'max')
DEPTH = 1000             # the subscriber's history [messages]
WINDOW = 500             # messages out at most with flow control (the subscriber holds DEPTH)
BATCH_PERIOD = 0.002     # [s] the subscriber lets messages gather after the first of a batch


def cobot_calib(*args: str) -> list[str]:
    return [sys.executable, '-m', 'cobot_calib_ros.cli.main', *args]


def joint_states_bag(path: Path, seconds: float) -> int:
    """A bag of 1 kHz JointState; its message count."""
    from bag_source import templates
    data, _ = templates()
    count = int(seconds * 1000)
    with BagWriter(path) as bag:
        bag.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [qos()])
        for i in range(count):
            STAMP.pack_into(data, 4, *divmod(i, 1000))
            bag.write('/joint_states', bytes(data), T0 + i * 1_000_000)
    return count


def stamp_key(data: bytes) -> int:
    sec, nanosec = STAMP.unpack_from(data, 4)
    return sec * 1000 + nanosec


def replay_label(rate: str, window: int) -> str:
    """'rate4', 'max', 'window_rate4', ... in the figures' names."""
    return ('window_' if window else '') + ('max' if rate == 'max' else f'rate{rate}')


def measure_replay(ros: Ros, env: dict, bag: Path, count: int, rate: str,
                   window: int = 0) -> Figures:
    """Play the bag at ``rate`` (flow control with ``window`` > 0) to a subscriber here; speed,
    received fraction, player CPU. The subscriber takes the messages in batches on a thread of
    its own (ros.batch_reader, as joint_state_monitor does: an executor's wake per message
    tops out near 10 k messages/s) and counts each batch on /bag_player/consumed."""
    from cobot_calib_ros.ros.batch_reader import BatchReader
    received: set[int] = set()
    lock = threading.Lock()
    progress = ros.node.create_publisher(UInt64, 'bag_player/consumed', QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE))      # without a window: counts lost

    def report() -> None:
        with lock:
            progress.publish(UInt64(data=len(received)))

    def on_batch(batch: list[bytes]) -> None:
        received.update(stamp_key(data) for data in batch)
        report()
    reader = BatchReader(ros.node, 'joint_states', JointState, 'joint_states',
                         QoSProfile(depth=DEPTH, reliability=ReliabilityPolicy.RELIABLE),
                         on_batch, period=BATCH_PERIOD, raw=True)
    player = subprocess.Popen(cobot_calib('replay', str(bag), '--rate', rate,
                                          '--wait-subscribers', '60', '--window', str(window)),
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              env=env)
    started = time.monotonic()
    cpu = 0.0
    try:
        while player.poll() is None and time.monotonic() - started < 600:
            ros.spin_for(0.05)
            report()
            value = benchlib.process_cpu_seconds(player.pid)
            cpu = value if value == value else cpu              # NaN once it has exited
        wall = time.monotonic() - started
        ros.spin_until(lambda: len(received) >= count, 2.0)
        out, _ = player.communicate(timeout=30)
    finally:
        if player.poll() is None:
            player.kill()
        reader.destroy()
        ros.node.destroy_publisher(progress)
    match = PUBLISHED.search(out)
    if player.returncode != 0 or match is None:
        raise BenchFailed(f'replay --rate {rate} --window {window} failed '
                          f'({player.returncode}): {out.strip()}')
    label = replay_label(rate, window)
    got = len(received)
    said = LOST.search(out)
    if not window and (said is None or int(said.group(1)) != count - got):
        raise BenchFailed(f'replay --rate {rate}: the player did not count the {count - got} '
                          f'lost: {out.strip()}')
    return {
        f'bag_replay_{label}_speed_x': (float(match.group(3)), 'x real time'),
        f'bag_replay_{label}_received_percent': (100.0 * got / count, '%'),
        f'bag_replay_{label}_lost': (count - got, 'count'),
        f'bag_replay_{label}_player_cpu_percent': (100.0 * cpu / wall, '% of one core'),
    }


def measure_publish_cost(ros: Ros) -> Figures:
    """µs per publish: recorded bytes as they are, or deserialized first (no subscriber)."""
    from bag_source import templates
    data = bytes(templates()[0])
    pub = ros.node.create_publisher(JointState, 'bench_bag_publish_cost', 10)
    try:
        for _ in range(1000):
            pub.publish(data)
        start = time.perf_counter()
        for _ in range(PUBLISH_CALLS):
            pub.publish(data)
        raw = time.perf_counter() - start
        start = time.perf_counter()
        for _ in range(PUBLISH_CALLS):
            pub.publish(deserialize_message(data, JointState))
        typed = time.perf_counter() - start
    finally:
        ros.node.destroy_publisher(pub)
    return {'bag_publish_raw_us': (raw / PUBLISH_CALLS * 1e6, 'us'),
            'bag_publish_deserialize_us': (typed / PUBLISH_CALLS * 1e6, 'us')}


def run_replay(seconds: float) -> Figures:
    figures: Figures = {}
    with tempfile.TemporaryDirectory(prefix='bench_bag_') as scratch, \
            benchlib.private_domain() as (domain, env), \
            benchlib.ros_node('bench_bag_replay', domain) as ros:
        bag = Path(scratch) / 'joint_states_1khz'
        count = joint_states_bag(bag, seconds)
        figures.update(measure_publish_cost(ros))
        for window in (0, WINDOW):
            for rate in RATES:
                load = benchlib.load_average_1min()
                figures.update(measure_replay(ros, env, bag, count, rate, window))
                figures[f'bag_replay_{replay_label(rate, window)}_load_average'] = (
                    0.5 * (load + benchlib.load_average_1min()), 'load')
    return figures


def read_line(proc: subprocess.Popen, timeout: float) -> str:
    """The source's next stdout line (blocking read with a deadline via select)."""
    import select
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 1.0)
        if ready:
            line = proc.stdout.readline()
            if line:
                return line.strip()
            break
        if proc.poll() is not None:
            break
    raise BenchFailed(f'bag_source said nothing within {timeout:.0f} s '
                      f'(exit code {proc.poll()})')


def run_record(kind: str, seconds: float) -> Figures:
    """Record the source for ``seconds`` with the recorder on executor ``kind``."""
    with tempfile.TemporaryDirectory(prefix='bench_bag_') as scratch, \
            benchlib.private_domain() as (_, env):
        env = benchlib.executor_env(env, kind)
        bag = Path(scratch) / f'record_{kind}'
        recorder = subprocess.Popen(cobot_calib('record', '-o', str(bag), '/joint_states',
                                                '/camera/image_raw'),
                                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                    text=True, env=env)
        source = subprocess.Popen([sys.executable, str(benchlib.BENCH_DIR / 'bag_source.py'),
                                   '--seconds', str(seconds)],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                  env=env)
        try:
            if read_line(source, 120.0) != 'start':
                raise BenchFailed('bag_source did not start')
            cpu0, t0 = benchlib.process_cpu_seconds(recorder.pid), time.monotonic()
            load0 = benchlib.load_average_1min()
            end = read_line(source, seconds + 120.0).split()
            cpu1, t1 = benchlib.process_cpu_seconds(recorder.pid), time.monotonic()
            if end[0] != 'end' or read_line(source, 60.0) != 'done':
                raise BenchFailed(f'bag_source: {end}')
            published = {'/joint_states': int(end[1]), '/camera/image_raw': int(end[2])}
            source.wait(timeout=30)
            recorder.send_signal(signal.SIGINT)
            out, _ = recorder.communicate(timeout=120)
        finally:
            for proc in (source, recorder):
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        if recorder.returncode != 0:
            raise BenchFailed(f'record exited with {recorder.returncode}: {out.strip()}')
        with open_bag(bag, strict=True) as reader:
            counts = {t: info.count for t, info in reader.topics.items()}
            size = reader.size_bytes
            seqs = {(sec - BASE_S) * 1000 + nanosec // 1_000_000
                    for sec, nanosec in (STAMP.unpack_from(m.rawdata, 4)
                                         for m in reader.messages(['/joint_states']))}
        missing = sorted(set(range(published['/joint_states'])) - seqs)
        lost_js = published['/joint_states'] - counts.get('/joint_states', 0)
        lost_img = published['/camera/image_raw'] - counts.get('/camera/image_raw', 0)
        return {
            'bag_record_joint_states_lost': (lost_js, 'count'),
            'bag_record_images_lost': (lost_img, 'count'),
            'bag_record_joint_states_recorded': (counts.get('/joint_states', 0), 'count'),
            # where the first lost one was (s after the source's first message; -1: none)
            'bag_record_joint_states_first_lost_s': (missing[0] / 1000 if missing else -1, 's'),
            'bag_record_images_recorded': (counts.get('/camera/image_raw', 0), 'count'),
            'bag_record_cpu_percent': (100.0 * (cpu1 - cpu0) / (t1 - t0), '% of one core'),
            'bag_record_write_mb_per_s': (size / (t1 - t0) / 1e6, 'MB/s'),
            'bag_record_seconds': (t1 - t0, 's'),
            'bag_record_load_average': (0.5 * (load0 + benchlib.load_average_1min()), 'load'),
        }


def run() -> Figures:
    replay_s = float(os.environ.get('BENCH_BAG_REPLAY_SECONDS', '20'))
    record_s = float(os.environ.get('BENCH_BAG_RECORD_SECONDS', '60'))
    figures: Figures = {}
    try:
        figures.update(run_replay(replay_s))
        for kind in benchlib.executors():
            figures.update(benchlib.suffixed(run_record(kind, record_s), kind))
    except BenchFailed as exc:
        raise BenchFailed(str(exc), figures) from exc
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
