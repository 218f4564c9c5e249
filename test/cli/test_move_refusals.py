"""`cobot-calib move`: input that does not fit is refused in one line before any ROS node."""
import pytest

from cobot_calib_ros.cli.main import main


@pytest.mark.parametrize('extra, words', [
    (['--xyz', 'nan', '0', '0'], '--xyz and --rpy take finite numbers'),
    (['--xyz', '0.5', '0', '0.3', '--user-frame', 'uf-1'], '--user-frame goes with --frame user'),
    (['--xyz', '0.5', '0', '0.3', '--speed-scale', '2'], '--speed-scale 2.0: give 0..1'),
])
def test_move_refusals_say_what_to_do(capsys, extra, words):
    assert main(['move', '--rpy', '0', '0', '0', *extra]) == 2
    assert words in capsys.readouterr().err
