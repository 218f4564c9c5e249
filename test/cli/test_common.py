"""The robot options every suite-less verb shares (cli.common.add_robot_options)."""
import argparse
from pathlib import Path

import numpy as np

from cobot_calib_ros.cli.common import add_robot_options, robot_cell
from cobot_calib_ros.core.frames import from_xyz_rpy

URDF = Path(__file__).resolve().parents[1] / 'data' / 'plant-ur5e' / 'ur5e.urdf'


def _cell(option: str):
    parser = argparse.ArgumentParser()
    add_robot_options(parser, 'cell')
    args = parser.parse_args(['--urdf', str(URDF), '--tip-link', 'tool0', option,
                              '0.01', '0', '0.12', '0', '0', '0.5'])
    return robot_cell(args)


def test_the_tool_is_given_by_t_flange_tool_or_its_old_name():
    expected = from_xyz_rpy([0.01, 0.0, 0.12], [0.0, 0.0, 0.5])
    np.testing.assert_array_equal(_cell('--t-flange-tool').T_flange_tool, expected)
    np.testing.assert_array_equal(_cell('--tool-offset').T_flange_tool, expected)  # legacy name
