"""`cobot-calib experiment`: parser of the paper's comparison; the work is in
cli/experiment.py."""
from __future__ import annotations


def add_parser(subparsers):
    p = subparsers.add_parser(
        'experiment', help="reproduce the first paper's comparison on the mock robot "
                           '(own suite on a private domain)',
        description="Reproduce the first paper's comparison on the mock robot: a reference "
                    'trial and one per calibration method, one table, one box plot. It always '
                    'starts its own node suite on a free private ROS_DOMAIN_ID (printed) and '
                    'ignores the exported ROS_DOMAIN_ID. It has no --attach: with the suite '
                    'running on the exported ROS_DOMAIN_ID, run `cobot-calib trial` per '
                    'method, then `cobot-calib report`.')
    p.add_argument('which', choices=('user-frame',))
    p.add_argument('--setup', default='close', choices=('close', 'wide'))
    p.add_argument('--axis', default='z', choices=('x', 'y', 'z'))
    p.add_argument('--cycles', type=int, default=30)
    p.add_argument('--cell', default='sawyer_close', help='cell YAML path or name')
    p.add_argument('--data-dir', help='where trials are stored (default ~/.ros/cobot_calib)')
    p.add_argument('--out', help='report folder (default <data dir>/reports)')
    p.add_argument('--json', action='store_true')
    return p


def run(args) -> int:
    from cobot_calib_ros.cli import experiment
    return experiment.run_experiment(args)
