"""`cobot-calib report`: parser of the trial report; the work is in cli/experiment.py."""
from __future__ import annotations

from cobot_calib_ros.cli.db import add_db_options


def add_parser(subparsers):
    p = subparsers.add_parser('report', help='PNG box plot and table of stored trials')
    p.add_argument('trials', nargs='+', help='trial ids')
    add_db_options(p)
    p.add_argument('--out', help='report folder (default <data dir>/reports)')
    return p


def run(args) -> int:
    from cobot_calib_ros.cli import experiment
    return experiment.run_report(args)
