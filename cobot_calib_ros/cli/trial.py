"""`cobot-calib trial`: parser of one repeatability trial; the work is in cli/experiment.py."""
from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        'trial', help='run (or resume) one ISO 9283 repeatability trial on a running suite, '
                      'printing RP after each cycle',
        description='Run (or resume) one ISO 9283 repeatability trial on the suite running on '
                    'the exported ROS_DOMAIN_ID (cobot-calib up).')
    p.add_argument('--method', default=None,
                   help='reference | three_point | five_point_lsq | rigid | robust | '
                        'landmark_single | landmark_multi (wrist camera; calibrate the hand-eye '
                        'first: cobot-calib hand-eye) (default reference; a resumed trial keeps '
                        'its own)')
    from cobot_calib_ros.core.repeatability.iso9283 import AXES
    p.add_argument('--axis', default=None, choices=AXES,
                   help='probed axis (default z; a resumed trial keeps its own)')
    p.add_argument('--cycles', type=int, default=None,
                   help='2..10000 (default 30; a resumed trial keeps its own)')
    p.add_argument('--trial-id', default='', help='an unfinished trial id resumes it')
    p.add_argument('--stall-timeout', type=float, default=None,
                   help='[s] without feedback from repeatability_trial before giving up '
                        '(default 30)')
    p.add_argument('--json', action='store_true')
    return p


def run(args) -> int:
    from cobot_calib_ros.cli import experiment
    return experiment.run_trial(args)
