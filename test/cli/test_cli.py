"""The command line without a node suite: verbs, refusals in one line, discovery rules."""
import os
import subprocess
import sys
from types import SimpleNamespace

import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from cobot_calib_ros.ros import graph as ros_graph
from cobot_calib_ros.cli import main

CAPTURE = 'cobot_calib_msgs/srv/CaptureJoints'


def _cli(*args, timeout=30.0) -> subprocess.CompletedProcess:
    return _cli_all([args], timeout)[0]


def _cli_all(commands: list, timeout=30.0) -> list[subprocess.CompletedProcess]:
    """Run `cobot-calib ARGS` for each ARGS at once; the completed processes."""
    running = [subprocess.Popen([sys.executable, '-m', 'cobot_calib_ros.cli.main', *args],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=dict(os.environ)) for args in commands]
    done = []
    for args, p in zip(commands, running):
        out, err = p.communicate(timeout=timeout)
        done.append(subprocess.CompletedProcess(args, p.returncode, out, err))
    return done


def _one_line_refusal(out: subprocess.CompletedProcess, code: int) -> str:
    assert out.returncode == code, out.stderr
    assert 'Traceback' not in out.stderr and len(out.stderr.strip().splitlines()) == 1
    return out.stderr


def test_every_verb_is_a_module_with_add_parser_and_run():
    parser = main.build_parser()
    verbs = parser._subparsers._group_actions[0].choices
    assert len(verbs) == len(main.VERBS)
    assert {'up', 'echo', 'call', 'list', 'demo', 'trial', 'experiment', 'report'} <= set(verbs)
    for verb, module in [('call', 'call'), ('list', 'list_cmd'), ('demo', 'demo_cmd')]:
        run = verbs[verb].get_default('run')
        assert run.__module__ == f'cobot_calib_ros.cli.{module}' and run.__name__ == 'run'
    # a command line builds the parser of its own verb only, found by main.command_of
    for verb, sub in verbs.items():
        module = sub.get_default('run').__module__.rsplit('.', 1)[1]
        assert main.command_of(module) == verb
        alone = main.build_parser([verb, '--help'])._subparsers._group_actions[0].choices
        assert list(alone) == [verb]


def test_negative_numbers_in_exponent_notation_are_values_not_options():
    args = main.build_parser().parse_args(['move', '--xyz', '0.5', '-1e-3', '-.25', '--rpy',
                                           '-3.14151951', '-5.37e-05', '7.63E-05'])
    assert args.xyz == [0.5, -1e-3, -0.25]
    assert args.rpy == [-3.14151951, -5.37e-05, 7.63e-05]
    with pytest.raises(SystemExit):     # an option is still an option
        main.build_parser().parse_args(['move', '--xyz', '1', '2', '3', '--rpy', '0', '0', '-e'])


@pytest.mark.parametrize('values, problem', [
    ('{duration: 0.5', "expected ',' or '}'"), ('{a: [1, 2}', "expected ',' or ']'"),
    ('{duration: @x}', 'cannot start any token')])
def test_malformed_yaml_is_one_line_exit_2(domain_id, values, problem):
    err = _one_line_refusal(_cli('call', 'capture_joints', values), 2)
    assert err.startswith('bad request: VALUES is not valid YAML') and problem in err


@pytest.mark.parametrize('args, message', [
    (['--type', 'nope_msgs/srv/Nope'], "unknown type 'nope_msgs/srv/Nope': no interface "
                                       "package 'nope_msgs'"),
    (['cobot_calib_msgs/srv/Nope', '{}'], "cobot_calib_msgs/srv has no 'Nope'"),
    (['--type', 'cobot_calib_msgs/msg/ProbeVoltage'], 'not a service type name'),
    ([CAPTURE, '--type', 'cobot_calib_msgs/srv/AverageProximity'], 'two different types'),
])
def test_unknown_or_conflicting_types_are_one_line_exit_2(domain_id, args, message):
    err = _one_line_refusal(_cli('call', 'capture_joints', *args), 2)
    assert message in err


def test_call_takes_ros2_argument_order_and_options_anywhere(domain_id):
    """Nothing answers on this domain: each form gets as far as the service lookup."""
    forms = [[CAPTURE, '{duration: 0.5}'], ['--type', CAPTURE, '{duration: 0.5}'],
             ['{duration: 0.5}', '--type', CAPTURE], [CAPTURE],
             ['cobot_calib_msgs/CaptureJoints']]
    # a name no node offers: a suite another test started on this domain may still be in the
    # DDS graph (seen in fresh-clone runs), and /capture_joints would then be found
    outs = _cli_all([['call', '/no_such_capture_joints', *f, '--timeout', '0.3'] for f in forms])
    for form, out in zip(forms, outs):
        err = _one_line_refusal(out, 1)
        assert err.startswith('service /no_such_capture_joints not found within 0.3 s'), form
        assert f'ROS_DOMAIN_ID={domain_id}' in err


def test_echo_of_a_missing_topic_is_one_line(domain_id):
    err = _one_line_refusal(_cli('echo', 'no/such/topic', '--once', '--timeout', '0.3'), 1)
    assert err.startswith('topic /no/such/topic not found within 0.3 s')


def test_up_refuses_a_cell_that_does_not_exist(domain_id):
    err = _one_line_refusal(_cli('up', '--cell', 'no_such_cell'), 2)
    assert 'no_such_cell.yaml not found' in err and 'sawyer_close' in err


@pytest.mark.parametrize('verb', ['demo', 'experiment'])
def test_demo_and_experiment_help_say_which_domain_they_use(verb, capsys):
    with pytest.raises(SystemExit):
        main.main([verb, '--help'])
    text = ' '.join(capsys.readouterr().out.split())
    assert 'private ROS_DOMAIN_ID (printed)' in text
    assert 'ignores the exported ROS_DOMAIN_ID' in text
    assert 'running on the exported ROS_DOMAIN_ID' in text
    if verb == 'demo':
        assert '--attach uses the suite already running on the exported ROS_DOMAIN_ID' in text


# -------------------------------------------------------------------------- discovery rules


class _Timeline:
    """A fake clock and graph: graph_now(node) returns the graph of the current time."""

    def __init__(self, monkeypatch, changes: dict[float, str],
                 services: dict[float, str] | None = None):
        """``services``: when each node's parameter services are found (default: never)."""
        self.now, self.changes, self.services = 0.0, changes, services or {}
        monkeypatch.setattr(ros_graph.time, 'monotonic', lambda: self.now)
        monkeypatch.setattr(ros_graph, 'spin_until', self._spin)
        monkeypatch.setattr(ros_graph, 'graph_now', self._graph)
        self.get_fully_qualified_name = lambda: '/cobot_calib_list'
        self.get_service_names_and_types = lambda: [
            (f'{n}/get_parameters', ['rcl_interfaces/srv/GetParameters'])
            for t, n in self.services.items() if t <= self.now]

    def _spin(self, node, done, timeout, executor=None):
        self.now += timeout
        return False

    def _graph(self, node):
        seen = [g for t, g in sorted(self.changes.items()) if t <= self.now]
        return {'nodes': {n: [] for n in seen}}


def test_graph_waits_past_a_quiet_gap_before_a_late_node(monkeypatch):
    """As measured: most nodes at once, the last one 2.4 s later."""
    clock = _Timeline(monkeypatch, {0.0: '/a', 0.1: '/b', 2.5: '/late'})
    assert list(ros_graph.graph(clock, max_wait=10.0)['nodes']) == ['/a', '/b', '/late']
    assert ros_graph.DISCOVERY_MIN_WAIT <= clock.now < ros_graph.DISCOVERY_MIN_WAIT + 0.2


def test_graph_lists_a_node_whose_first_two_announcements_were_missed(monkeypatch):
    """Fast DDS announces a participant every 3 s: one missed at the start and at 3 s shows
    at ~6.5 s, just past the minimum wait (fresh-clone run U: `list` without /mock_robot). A
    graph that changed within the last announcement period is not taken as complete."""
    clock = _Timeline(monkeypatch, {0.0: '/a', 3.4: '/b', 6.5: '/late'})
    assert list(ros_graph.graph(clock, max_wait=10.0)['nodes']) == ['/a', '/b', '/late']


def test_graph_waits_for_a_change_to_settle_and_stops_at_the_max(monkeypatch):
    clock = _Timeline(monkeypatch, {0.0: '/a', 3.9: '/b'})
    assert list(ros_graph.graph(clock, max_wait=10.0, min_wait=1.0)['nodes']) == ['/a']
    assert clock.now == pytest.approx(ros_graph.GRAPH_SETTLE, abs=0.15)
    clock = _Timeline(monkeypatch, {0.0: '/a', 3.9: '/b'})
    assert list(ros_graph.graph(clock, max_wait=10.0, min_wait=4.0)['nodes']) == ['/a', '/b']
    assert clock.now == pytest.approx(3.9 + ros_graph.GRAPH_SETTLE, abs=0.15)
    clock = _Timeline(monkeypatch, {t / 10: f'/n{t}' for t in range(100)})
    ros_graph.graph(clock, max_wait=2.0)
    assert clock.now == pytest.approx(2.0, abs=0.15)


def test_graph_waits_for_a_node_whose_services_are_seen_before_its_name(monkeypatch):
    """/late's parameter services are found at 1 s, its name (ros_discovery_info) at 8 s:
    past the minimum wait and settled, the graph is not over while it misses /late; hidden
    nodes and the caller itself do not count."""
    clock = _Timeline(monkeypatch, {0.0: '/a', 8.0: '/late'},
                      {0.0: '/a', 0.5: '/_hidden', 0.6: '/cobot_calib_list', 1.0: '/late'})
    assert list(ros_graph.graph(clock, max_wait=10.0)['nodes']) == ['/a', '/late']
    assert clock.now == pytest.approx(min(10.0, 8.0 + ros_graph.GRAPH_SETTLE), abs=0.25)
    clock = _Timeline(monkeypatch, {0.0: '/a'}, {1.0: '/never'})
    assert list(ros_graph.graph(clock, max_wait=10.0)['nodes']) == ['/a']
    assert clock.now == pytest.approx(10.0, abs=0.15)


def test_graph_stops_early_when_done(monkeypatch):
    clock = _Timeline(monkeypatch, {0.0: '/a', 0.3: '/b'})
    ros_graph.graph(clock, max_wait=10.0, done=lambda g: '/b' in g['nodes'])
    assert clock.now == pytest.approx(0.3, abs=0.15)


def _publisher(reliability, durability):
    return SimpleNamespace(qos_profile=QoSProfile(depth=1, reliability=reliability,
                                                  durability=durability))


R, B = ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT
V, T = DurabilityPolicy.VOLATILE, DurabilityPolicy.TRANSIENT_LOCAL


@pytest.mark.parametrize('publishers, reliability, durability', [
    ([], R, V), ([(B, V)], B, V), ([(R, V), (B, V)], B, V), ([(R, T)], R, T),
    ([(R, T), (R, V)], R, V), ([(B, T), (B, T)], B, T)])
def test_echo_qos_matches_every_publisher_as_ros2_topic_echo(publishers, reliability,
                                                              durability):
    qos = ros_graph.subscription_qos([_publisher(*p) for p in publishers])
    assert (qos.reliability, qos.durability) == (reliability, durability)


def test_report_help_names_the_data_dir_it_reads(tmp_path, monkeypatch, capsys):
    """Issue 31.9: `report --help` said the default was ~/.ros/cobot_calib; it is
    $COBOT_CALIB_DATA when set (as every verb's)."""
    import shutil
    with pytest.raises(SystemExit):
        main.main(['report', '--help'])
    assert 'default $COBOT_CALIB_DATA, else ~/.ros/cobot_calib' in ' '.join(
        capsys.readouterr().out.split())
    data = tmp_path / 'data'
    shutil.copytree(os.path.join(os.path.dirname(__file__), '..', 'data', 'store-5252a67'), data)
    monkeypatch.setenv('COBOT_CALIB_DATA', str(data))
    monkeypatch.delenv('COBOT_CALIB_DB', raising=False)
    assert main.main(['report', 'trial-1']) == 0
    assert f'figure: {data / "reports"}' in capsys.readouterr().out
