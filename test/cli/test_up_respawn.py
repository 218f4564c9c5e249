"""`up`'s respawn (cli/up._Respawn) on processes of its own: a restarted node that never answers
is named with its log (session 24: a node `up` restarted did not answer for 120 s, and `up`
said nothing)."""
import sys

from cobot_calib_ros.api import launcher
from cobot_calib_ros.cli import up
from cobot_calib_ros.cli.common import ros_node
from cobot_calib_ros.ros.calls import spin_until


class _Mute(launcher.NodeSpec):
    """A 'node' whose process runs and never answers (no ROS node at all)."""

    def command(self) -> list[str]:
        return [sys.executable, '-c', 'import time; time.sleep(120)']


class _News:
    def started(self, name: str, pid: int) -> None:
        pass

    def exited(self, name: str, code: int, left_down: bool = False) -> None:
        pass


def test_a_restarted_node_that_does_not_answer_is_named_once_with_its_log(
        tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(up, 'READY_TIMEOUT', 1.0)
    suite = launcher.Suite(tmp_path)
    suite.start([_Mute('mute')])
    try:
        with ros_node('test_up_respawn') as node:
            respawn = up._Respawn(suite, node, _News())
            suite.processes['mute'].kill()
            suite.processes['mute'].wait()
            assert respawn.check() == ['mute']
            capsys.readouterr()
            said = []

            def named() -> bool:
                respawn.check()
                said.append(capsys.readouterr().err)
                return 'does not answer' in said[-1]

            def checked_on() -> bool:       # `up`'s loop going on: said only once
                respawn.check()
                return False

            assert spin_until(node, named, 15.0)
            spin_until(node, checked_on, 1.5)
            err = ''.join(said) + capsys.readouterr().err
            respawn.forget_all()
    finally:
        suite.stop(timeout=2.0)
    assert err.count('does not answer') == 1, err
    assert (f'mute: restarted 1 s ago and does not answer yet (its process runs; log: '
            f'{suite.log_path("mute")})') in err
    assert 'answering again' not in err
