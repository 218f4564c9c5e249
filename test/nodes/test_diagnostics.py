"""/diagnostics from mock_robot, joint_state_monitor and proximity_sensor (ros.diagnostics)."""
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import pytest

from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros.calls import spin_until
from rosutil import STOP_TIMEOUT

TIMEOUT = 10.0  # [s] for every node's status to arrive (they publish at 1 Hz)
EXPECTED_KEYS = {
    'mock_robot: health': {
        'published', 'publish_rate_hz', 'publish_gap_max_ms', 'stamp_gaps_missing',
        'mark_stamp_s', 'published_before_mark', 'probe_published', 'moving', 'cell', 'robot',
        'layout'},
    'joint_state_monitor: health': {
        'received', 'dropped_non_finite', 'dropped_length_mismatch', 'dropped_unknown_joints',
        'missing_by_stamp', 'receive_rate_hz', 'no_message_for_ms', 'mark_stamp_s',
        'received_before_mark'},
    'proximity_sensor: health': {
        'readings', 'below_range', 'above_range', 'invalid', 'last_distance_m',
        'last_voltage_v', 'reading_rate_hz', 'last_reading_age_s'},
}
ISO_PROBE = 'quiet/proximity_sensor: health'   # a probe node of this module's, never fed


@pytest.fixture(scope='module')
def quiet_probe(suite, tmp_path_factory):
    """A proximity_sensor no test publishes voltages to (the suite's /iso one gets some)."""
    node = launcher.Suite(tmp_path_factory.mktemp('quiet_probe_logs'))
    node.start([launcher.NodeSpec('proximity_sensor', namespace='quiet')])
    yield node
    assert all(c == 0 for c in node.stop(STOP_TIMEOUT).values())


@pytest.fixture(scope='module')
def statuses(ros, quiet_probe):
    """The latest status per name, with its message stamp [ns], once every node has reported
    receiving data (or TIMEOUT)."""
    latest: dict[str, tuple[int, DiagnosticStatus]] = {}

    def on_diagnostics(msg: DiagnosticArray) -> None:
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        for status in msg.status:
            latest[status.name] = (stamp_ns, status)

    def all_flowing() -> bool:
        names = set(EXPECTED_KEYS) | {ISO_PROBE}
        return names <= set(latest) and latest[ISO_PROBE][1].message != 'starting' and all(
            _values(latest[n][1]).get(key, '0') not in ('0', 'never') for n, key in (
                ('mock_robot: health', 'published'),
                ('joint_state_monitor: health', 'received'),
                ('proximity_sensor: health', 'readings')))

    sub = ros.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 50)
    try:
        spin_until(ros, all_flowing, TIMEOUT, ros.executor_for_tests)
    finally:
        ros.destroy_subscription(sub)
    return latest


def _values(status: DiagnosticStatus) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


@pytest.mark.parametrize('name', sorted(EXPECTED_KEYS))
def test_each_node_reports_its_figures_with_a_real_stamp(statuses, name):
    assert name in statuses, f'no /diagnostics status {name!r}; got {sorted(statuses)}'
    stamp_ns, status = statuses[name]
    assert stamp_ns > 0
    assert EXPECTED_KEYS[name] <= set(_values(status)), _values(status)


def test_the_flowing_streams_are_healthy_and_counted(statuses):
    for name, count_key in (('mock_robot: health', 'published'),
                            ('joint_state_monitor: health', 'received'),
                            ('proximity_sensor: health', 'readings')):
        _, status = statuses[name]
        assert int(_values(status)[count_key]) > 0, (name, _values(status))
        if name == 'mock_robot: health':    # WARNs when a loaded machine slows it down
            assert status.level != DiagnosticStatus.ERROR, status.message
        else:
            assert status.level == DiagnosticStatus.OK, (name, status.message)
    monitor = {k: int(v) for k, v in _values(statuses['joint_state_monitor: health'][1]).items()}
    assert monitor['received_before_mark'] <= monitor['received']
    assert monitor['receive_rate_hz'] > 0


def test_a_probe_node_without_voltage_warns(statuses):
    assert ISO_PROBE in statuses, sorted(statuses)
    _, status = statuses[ISO_PROBE]
    assert status.level == DiagnosticStatus.WARN
    assert 'probe/voltage' in status.message
    assert _values(status)['readings'] == '0'
