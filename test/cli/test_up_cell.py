"""`cobot-calib up` checks the whole cell file before it starts any node."""
import os
import subprocess
import sys

import pytest

from cobot_calib_ros.paths import cell_file


@pytest.mark.parametrize('old, new, words', [
    ('  robot: sawyer ', '  robt: sawyer ', ["cell.robt: unknown key 'robt'; did you mean 'robot'"]),
    ('  seed: 7', '  seed: seven', ['simulation.seed: expected a finite number']),
    ('  layout: close', '  layout: narrow', ['cell.layout', 'close, wide'])])
def test_up_refuses_a_broken_cell_file_before_starting_anything(tmp_path, old, new, words):
    text = cell_file('sawyer_close').read_text()
    assert old in text
    broken = tmp_path / 'broken.yaml'
    broken.write_text(text.replace(old, new, 1))
    out = subprocess.run([sys.executable, '-m', 'cobot_calib_ros.cli.main', 'up', '--cell',
                          str(broken)], capture_output=True, text=True, timeout=60,
                         env=dict(os.environ, ROS_DOMAIN_ID='101'))
    assert out.returncode == 2
    assert 'node suite up' not in out.stdout and 'Traceback' not in out.stderr
    assert f'{broken}:' in out.stderr and 'nothing started' in out.stderr
    for word in words:
        assert word in out.stderr
