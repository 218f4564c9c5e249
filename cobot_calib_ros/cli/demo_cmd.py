"""`cobot-calib demo`: parser of the demo; the work is in cli/demo.py."""
from __future__ import annotations

from cobot_calib_ros.paths import DEFAULT_CELL


def add_parser(subparsers):
    p = subparsers.add_parser(
        'demo', help='the main job on the mock robot (own suite on a private domain)',
        description='Five-point user-frame calibration on the mock robot, scored on its '
                    'ground truth. It starts its own node suite on a free private '
                    'ROS_DOMAIN_ID (printed) and ignores the exported ROS_DOMAIN_ID, with a '
                    'temporary data dir (no other suite\'s results change); --attach '
                    'uses the suite already running on the exported ROS_DOMAIN_ID '
                    '(cobot-calib up) instead, with its cell and data dir.')
    p.add_argument('--cell', default=None, help=f'cell YAML path or name (default '
                   f'{DEFAULT_CELL}; with --attach: the running suite\'s)')
    p.add_argument('--kinematics', default='nominal',
                   help='kinematic model for the captured joints: nominal (default), latest '
                        '(the active kinematic calibration; identified on the mock first if '
                        'there is none) or a kinematic calibration id; not nominal: the '
                        'figures before and after')
    p.add_argument('--identify-configs', type=int, default=0,
                   help='sphere poses when --kinematics latest has to identify first '
                        '(default all)')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    p.add_argument('--attach', action='store_true',
                   help='use the suite already running on the exported ROS_DOMAIN_ID '
                        'instead of starting one on a private domain')
    return p


def run(args) -> int:
    from cobot_calib_ros.cli import demo
    return demo.run(args)
