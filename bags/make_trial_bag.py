"""Make bags/trial_close (see README.md): ``python bags/make_trial_bag.py [--force]``.

A short ISO 9283 repeatability trial on the mock Sawyer (cell sawyer_close), method
five_point_lsq, z axis, CYCLES cycles. ``cobot-calib up`` runs the suite on a private
ROS_DOMAIN_ID (domain_coordinator, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) with a temporary
data_dir; ``cobot-calib record --compress zstd`` records:

- ``/probe/voltage`` (cobot_calib_msgs/ProbeVoltage): the raw probe output (mock, 200 Hz);
- ``/cobot_calib/probe_averages`` (cobot_calib_msgs/ProbeAverageMark, ros.marks):
  proximity_sensor's mark of every probe/average it served (window start, duration, the
  response, the readings' stamps; the bag kept here was made before that message and has
  sensor_msgs/JointState marks, read through bags.mark_converter);
- ``/repeatability`` (cobot_calib_msgs/Repeatability, latched): the live statistics after each
  cycle;

while ``cobot-calib trial --method five_point_lsq --cycles CYCLES`` runs (a new trial: its id is
the one the node stored).
Then, from the recording and the trial the node stored (``trials/<id>/distances.csv``):

1. every stored reading (cycle, point) is tied to the probe/average it came from: the first
   SUCCESS mark after the previous reading's whose distance equals the stored raw distance to
   the bit (the service response and the CSV carry the same float64);
2. every mark is averaged again from the recorded voltages it lists (converted with
   proximity_sensor's read_distance and the calibration table of config/proximity_sensor.yaml,
   averaged with core.sensors.probe.average, as the node): the result must equal the mark's
   to the bit, and a listed
   voltage missing from the recording (the recorder lost it) stops the script (run it again);
3. ``/probe/voltage`` is kept only within MARGIN s of a mark's window (what lies between is
   the robot moving; the trial never read it), every mark and ``/repeatability`` whole; the
   messages keep their recorded bytes, receive stamps, QoS and type hashes;
4. ``expected.yaml``: the trial (id, method, axis, cycles, points, probe window), the probe's
   calibration table, the final live statistics (RP_i, RP_all, d_i, D_i, sigma_i [m]) and the
   readings: for each (cycle, point) the mark index, FF [m] and its direction (eq 15).

``--force`` replaces an existing bag; ``--keep`` keeps the raw recording (prints its path).
Run from anywhere; uses this interpreter (.venv's python).
"""
from __future__ import annotations

import argparse
import csv
import json
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import tempfile
import time

from cobot_calib_ros.paths import DEFAULT_CELL
from cobot_calib_ros.ros.marks import PROBE_AVERAGES_TOPIC
from printed import start_logged, wait_printed

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
NAME = 'trial_close'
CELL = DEFAULT_CELL
METHOD = 'five_point_lsq'
AXIS = 'z'
CYCLES = 4
MARGIN = 0.05               # [s] of /probe/voltage kept on each side of a probe window
CLI = [sys.executable, '-m', 'cobot_calib_ros.cli.main']
VOLTAGE_TOPIC = '/probe/voltage'
MARKS_TOPIC = PROBE_AVERAGES_TOPIC
STATS_TOPIC = '/repeatability'
UP_TIMEOUT = 120.0          # [s] for the suite to answer, and for the recorder to subscribe


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--force', action='store_true', help='replace an existing bag')
    ap.add_argument('--out', default=str(HERE), help='folder for the bag (default: here)')
    ap.add_argument('--keep', action='store_true', help='keep the raw recording')
    args = ap.parse_args(argv)
    out = Path(args.out) / NAME
    if out.exists():
        if not args.force:
            print(f'{out} exists; --force replaces it', file=sys.stderr)
            return 2
        shutil.rmtree(out)
    import domain_coordinator
    tmp = Path(tempfile.mkdtemp(prefix='cobot_calib_trial_bag_'))
    try:
        with domain_coordinator.domain_id() as domain:
            env = dict(os.environ, ROS_DOMAIN_ID=str(domain), COBOT_CALIB_DATA=str(tmp / 'data'),
                       ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
            record(tmp / 'raw', env)
        build(out, tmp / 'raw', tmp / 'data')
    finally:
        if args.keep:
            print(f'raw recording and data: {tmp}')
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


def record(raw: Path, env: dict) -> None:
    """The live part: the suite, the recorder and the trial."""
    logs = raw.parent
    up = start_logged(CLI + ['up', '--cell', CELL], env, logs / 'up.log')
    try:
        wait_printed(up, logs / 'up.log', ['ready: '], UP_TIMEOUT)    # every node answers
        recorder = start_logged(CLI + ['record', '-o', str(raw), VOLTAGE_TOPIC, MARKS_TOPIC,
                                       STATS_TOPIC, '--compress', 'zstd'], env,
                                logs / 'record.log')
        try:
            wait_printed(recorder, logs / 'record.log',
                         [f'recording {t} (' for t in (VOLTAGE_TOPIC, MARKS_TOPIC, STATS_TOPIC)],
                         UP_TIMEOUT)
            started = time.monotonic()
            result = subprocess.run(
                CLI + ['trial', '--method', METHOD, '--axis', AXIS, '--cycles', str(CYCLES),
                       '--json'],
                env=env, capture_output=True, text=True)
            if result.returncode != 0:
                raise SystemExit(f'trial failed ({result.returncode}): {result.stderr}')
            print(f'trial: {time.monotonic() - started:.1f} s, {result.stdout.strip()}',
                  flush=True)
            time.sleep(1.0)         # the last messages on their way to the recorder
        finally:
            recorder.send_signal(signal.SIGINT)
            recorder.wait(30)
    finally:
        up.send_signal(signal.SIGINT)
        up.wait(60)


def build(out: Path, raw: Path, data: Path) -> None:
    """The sample bag and expected.yaml from the raw recording and the stored trial."""
    import yaml

    from cobot_calib_ros.api import replay_trial_check as check
    from cobot_calib_ros.bags.reader import open_bag
    from cobot_calib_ros.ros.time import header_ns, s_to_ns
    from cobot_calib_ros.bags.writer import BagWriter
    from cobot_calib_ros.core.repeatability import point_statistics

    params = yaml.safe_load((REPO / 'config' / 'proximity_sensor.yaml').read_text())
    params = next(iter(params.values()))['ros__parameters']
    table = {'calibration_distance': [float(v) for v in params['calibration_distance']],
             'calibration_voltage': [float(v) for v in params['calibration_voltage']],
             'saturation_margin': float(params['saturation_margin'])}
    trial_dir, = (data / 'trials').iterdir()          # the one trial the node stored
    meta = yaml.safe_load((trial_dir / 'trial.yaml').read_text())
    rows = {}
    with open(trial_dir / 'distances.csv', newline='') as f:
        for row in csv.DictReader(f):                 # a later line supersedes (store.trials)
            rows[int(row['cycle']), int(row['point_index'])] = row
    with open_bag(raw) as bag:
        for topic in (VOLTAGE_TOPIC, MARKS_TOPIC, STATS_TOPIC):
            if not bag.topics.get(topic) or not bag.topics[topic].count:
                raise SystemExit(f'{raw}: nothing recorded on {topic}')
        marks = check.read_marks(bag)
        samples = check.bag_samples(bag, table)
        if len({x[0] for x in samples}) != len(samples):
            raise SystemExit(f'{raw}: two probe voltages with the same stamp; run this again')
        stats_msgs = [bag.deserialize(m.rawdata, m.msgtype) for m in bag.messages([STATS_TOPIC])]
        final = stats_msgs[-1]
        # 1. each stored reading -> the mark it came from
        readings, previous = [], -1
        m = len(meta['point_names'])
        for cycle in range(meta['cycles_total']):
            for i in range(m):
                row = rows[cycle, i]
                raw_d = float(row['raw_distance_m'])
                index = next((k for k in range(previous + 1, len(marks))
                              if marks[k].ok and marks[k].distance == raw_d), None)
                if index is None:
                    raise SystemExit(f'no probe/average mark after #{previous} with the stored '
                                     f'distance {raw_d!r} of cycle {cycle}, point {i}')
                readings.append({'cycle': cycle, 'point': i, 'mark': index,
                                 'ff_m': float(row['ff_m']), 'direction': row['direction'] or None})
                previous = index
        # 2. the recording holds every voltage each mark averaged
        try:
            rebuilt = check.rebuild_marks(marks, samples)
        except check.LostReading as exc:
            raise SystemExit(f'{exc} from the recording: run this again')
        for k, (mark, again) in enumerate(zip(marks, rebuilt)):
            problem = check.mark_difference(mark, again)
            if problem:
                raise SystemExit(f'probe/average #{k}: {problem}')
        stats = point_statistics(check.distances(readings, rebuilt, m, meta['cycles_total']))
        worst = max(abs(a - b) for a, b in zip(stats.rp, final.rp))
        print(f'{len(marks)} probe averages, {len(readings)} trial readings; statistics from '
              f'the recorded voltages vs the live ones: RP differs by at most {worst:.3e} m',
              flush=True)
        # 3. the sample bag
        windows = [(mk.t0_ns - s_to_ns(MARGIN), mk.t0_ns + s_to_ns(mk.duration + MARGIN))
                   for mk in marks]
        writer = BagWriter(out, compression='zstd')
        kept = 0
        try:
            for topic in (VOLTAGE_TOPIC, MARKS_TOPIC, STATS_TOPIC):
                info = bag.topics[topic]
                writer.add_topic(topic, info.type, info.offered_qos, type_hash=info.type_hash)
            for msg in bag.messages([VOLTAGE_TOPIC, MARKS_TOPIC, STATS_TOPIC]):
                if msg.topic == VOLTAGE_TOPIC:
                    stamp = header_ns(bag.deserialize(msg.rawdata, msg.msgtype))
                    if not any(lo <= stamp <= hi for lo, hi in windows):
                        continue
                    kept += 1
                writer.write(msg.topic, msg.rawdata, msg.timestamp_ns)
        finally:
            writer.close()
        total = bag.topics[VOLTAGE_TOPIC].count
    print(f'kept {kept} of {total} probe voltages (within {MARGIN} s of a window)', flush=True)
    # 4. expected.yaml
    check.write_expected(out / check.EXPECTED_FILE, {
        'trial_id': meta['id'], 'method': meta['method'], 'axis': meta['axis'],
        'cycles': int(meta['cycles_total']), 'point_names': list(meta['point_names']),
        'cell': CELL, 'layout': meta['layout'],
        'proximity_sensor': table,
        'rp': [float(v) for v in final.rp], 'rp_all': float(final.rp_all),
        'mean_distance': [float(v) for v in final.mean_distance],
        'mean_deviation': [float(v) for v in final.mean_deviation],
        'sigma': [float(v) for v in final.sigma],
        'cycles_done': int(final.cycles_done),
        'readings': readings,
    })
    size = sum(p.stat().st_size for p in out.iterdir())
    print(f'{out}: RP_all {final.rp_all * 1e3:.4f} mm, {size} bytes; '
          + json.dumps({'marks': len(marks), 'voltages': kept}))


if __name__ == '__main__':
    sys.exit(main())
