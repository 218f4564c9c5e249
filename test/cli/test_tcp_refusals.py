"""`cobot-calib tcp` refuses a goal that cannot work before it contacts the suite (no ROS)."""
import pytest

from cobot_calib_ros.cli.main import main


@pytest.mark.parametrize('args, message', [
    (['--orientations', '3'], 'tcp: --orientations 3: need at least 4 (default 6)'),
    (['--tilt-deg', '-5'], '--tilt-deg, --elongation-mm and --hold must not be negative'),
])
def test_tcp_refuses_bad_goals_in_one_line(args, message, capsys):
    assert main(['tcp', *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err
