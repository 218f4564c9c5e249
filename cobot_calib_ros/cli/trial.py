"""`cobot-calib trial`: parser of one repeatability trial; the work is in cli/experiment.py."""
from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        'trial', help='run (or resume) one ISO 9283 repeatability trial on a running suite, '
                      'printing RP after each cycle',
        description='Run (or resume) one ISO 9283 repeatability trial on the suite running on '
                    'the exported ROS_DOMAIN_ID (cobot-calib up).')
    p.add_argument('--method', default='reference',
                   help='reference | three_point | five_point_lsq | rigid | robust')
    p.add_argument('--axis', default='z', choices=('x', 'y', 'z'))
    p.add_argument('--cycles', type=int, default=30)
    p.add_argument('--trial-id', default='', help='an unfinished trial id resumes it')
    p.add_argument('--json', action='store_true')
    return p


def run(args) -> int:
    from cobot_calib_ros.cli import experiment
    return experiment.run_trial(args)
