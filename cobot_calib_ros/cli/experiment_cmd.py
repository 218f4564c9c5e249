"""`cobot-calib experiment`: parser of the paper's comparison; the work is in
cli/experiment.py."""
from __future__ import annotations

from cobot_calib_ros.cli.db import DATA_DIR_HELP
from cobot_calib_ros.paths import DEFAULT_CELL


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
    from cobot_calib_ros.core.repeatability.iso9283 import AXES
    p.add_argument('--axis', default='z', choices=AXES)
    p.add_argument('--cycles', type=int, default=30)
    p.add_argument('--methods', type=_methods, default=None, metavar='M[,M...]',
                   help='trials to run, in this order (default: reference, three_point, '
                        'five_point_lsq, rigid, landmark_single, landmark_multi)')
    p.add_argument('--hand-eye', default='calibrate', choices=('calibrate', 'nominal'),
                   help='before the landmark rows: calibrate the wrist camera first (a '
                        'five-point user frame to find the board, then calibrate_hand_eye; '
                        'its error against the mock\'s truth is printed), or use the cell\'s '
                        'nominal hand-eye')
    p.add_argument('--cell', default=DEFAULT_CELL, help='cell YAML path or name')
    p.add_argument('--data-dir', help=DATA_DIR_HELP)
    p.add_argument('--out', help='report folder (default <data dir>/reports)')
    p.add_argument('--json', action='store_true')
    return p


def _methods(text: str) -> tuple[str, ...]:
    import argparse
    from cobot_calib_ros.core.repeatability.trial import METHODS
    methods = tuple(m.strip() for m in text.split(',') if m.strip())
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise argparse.ArgumentTypeError(f'unknown method(s) {unknown}; use any of '
                                         f'{", ".join(METHODS)}')
    return methods


def run(args) -> int:
    from cobot_calib_ros.cli import experiment
    return experiment.run_experiment(args)
