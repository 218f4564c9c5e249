"""Make bags/iiwa_spheres (see README.md): ``python bags/make_sphere_bag.py [--force]``.

A sphere-coupling session on the mock iiwa 7 (cell iiwa7_close): ``cobot-calib up`` runs the
suite on a private ROS_DOMAIN_ID with a temporary data_dir, ``cobot-calib record`` records
``/cobot_calib/captures`` (every pose kinematic_identifier records: cobot_calib_msgs/CaptureMark,
target = sphere name, the joints averaged over the hold and their standard deviation; the bag
kept here was made before that message and has sensor_msgs/JointState marks, read through
bags.mark_converter), and ``cobot-calib identify --attach`` collects POSES of the 3 x 625 grid and
identifies. Its JSON report, with the ``cell``, is stored as ``expected.json``: ``cobot-calib
replay bags/iiwa_spheres --check`` (and ``identify --source bags/iiwa_spheres``) must give the
same parameters from the bag.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import tempfile
import time

from cobot_calib_ros.ros.marks import CAPTURES_TOPIC
from printed import start_logged, wait_printed

HERE = Path(__file__).resolve().parent
NAME = 'iiwa_spheres'
CELL = 'iiwa7_close'
POSES = 150
HOLD = 0.05
CLI = [sys.executable, '-m', 'cobot_calib_ros.cli.main']
UP_TIMEOUT = 120.0          # [s] for the suite to answer, and for the recorder to subscribe


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--force', action='store_true', help='replace an existing bag')
    args = ap.parse_args(argv)
    out = HERE / NAME
    if out.exists():
        if not args.force:
            print(f'{out} exists; --force replaces it', file=sys.stderr)
            return 2
        shutil.rmtree(out)
    import domain_coordinator
    with domain_coordinator.domain_id() as domain, \
            tempfile.TemporaryDirectory(prefix='cobot_calib_sample_') as tmp:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), COBOT_CALIB_DATA=tmp,
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        logs = Path(tmp)
        up = start_logged(CLI + ['up', '--cell', CELL], env, logs / 'up.log')
        try:
            wait_printed(up, logs / 'up.log', ['ready: '], UP_TIMEOUT)   # every node answers
            record = start_logged(CLI + ['record', '-o', str(out), CAPTURES_TOPIC,
                                         '--compress', 'zstd'], env, logs / 'record.log')
            wait_printed(record, logs / 'record.log', [f'recording {CAPTURES_TOPIC} ('],
                         UP_TIMEOUT)
            report = subprocess.run(
                CLI + ['identify', '--attach', '--json', '--max-configs', str(POSES),
                       '--hold', str(HOLD), '--validation-configs', '0', '--dry-run'],
                env=env, capture_output=True, text=True, check=True)
            time.sleep(1.0)         # the last messages on their way to the recorder
            record.send_signal(signal.SIGINT)
            record.wait(30)
        finally:
            up.send_signal(signal.SIGINT)
            up.wait(60)
    expected = {'cell': CELL, **json.loads(report.stdout)}
    (out / 'expected.json').write_text(json.dumps(expected, indent=2) + '\n')
    print(f'{out}: {sum(p.stat().st_size for p in out.iterdir())} bytes')
    return 0


if __name__ == '__main__':
    sys.exit(main())
