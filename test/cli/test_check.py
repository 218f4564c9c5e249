"""`cobot-calib check` without a suite to check (issue 31 item 4): refused before the robot
could be asked for anything, saying why and what to start, instead of trying every pose."""
import os
import subprocess
import sys

import domain_coordinator


def test_check_kinematics_without_a_suite_says_so_and_checks_nothing(tmp_path):
    with domain_coordinator.domain_id() as domain:      # a domain nothing runs on
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), COBOT_CALIB_DATA=str(tmp_path),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        out = subprocess.run([sys.executable, '-m', 'cobot_calib_ros.cli.main', 'check',
                              'kinematics'], capture_output=True, text=True, env=env,
                             timeout=60)     # the old check moved through every pose: 95 s
    assert out.returncode == 1, out.stderr
    assert out.stderr.strip() == (f'check kinematics: no suite running on ROS_DOMAIN_ID='
                                  f'{domain}; start one with cobot-calib up; nothing checked')
    assert out.stdout == ''
    assert not any(tmp_path.rglob('*.json'))            # no check stored
