"""ros.suite_nodes: the launcher's news of node processes, through its message and back."""
from builtin_interfaces.msg import Time

from cobot_calib_ros.ros.suite_nodes import from_message, NodeProcess, to_message


def test_node_processes_go_through_the_message_unchanged():
    processes = [
        NodeProcess('/tcp_calibrator', 4242, 1, 1_795_000_000.125),
        NodeProcess('/cell_07/mock_robot', 77, 3, 1_795_000_010.5, True, -9, 1_795_000_009.25),
        NodeProcess('/joint_state_monitor', 99, 3, 1_795_000_001.0, False, 1, 1_795_000_002.0,
                    left_down=True)]
    msg = to_message(processes, Time(sec=1_795_000_011))
    assert [s.message for s in msg.status] == ['running', 'running',
                                                'exited with code 1, left down']
    assert from_message(msg) == {p.name: p for p in processes}


def test_how_a_process_ended_is_said_in_words():
    assert NodeProcess('/a', 1, 1, 0.0, False, -9, 1.0).how_it_ended() == 'killed by SIGKILL'
    assert NodeProcess('/a', 1, 1, 0.0, False, -15, 1.0).how_it_ended() == 'killed by SIGTERM'
    assert NodeProcess('/a', 1, 1, 0.0, False, 2, 1.0).how_it_ended() == 'exited with code 2'
