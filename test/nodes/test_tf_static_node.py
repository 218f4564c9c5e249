"""user_frame_solver on /tf_static and /diagnostics, and its active calibration.

The active calibration's base_frame -> user_frame transform is latched on /tf_static as tf2_ros's
static broadcaster does it (RViz, Foxglove, MoveIt read it there): after a calibration, after a
restart, after set_active_calibration. /tf_static is absolute (no namespace), so the restart tests
run their own solver, with its own data_dir, on a ROS domain of its own: the session suite's
solver latches its user frame on the session domain and cannot answer for it.
"""
from __future__ import annotations

import ast
import os
from pathlib import Path
import sys
import xml.etree.ElementTree as ET

from cobot_calib_msgs.msg import UserFrameCalibration
from cobot_calib_msgs.srv import (CalibrateUserFrame, ConvertPoints, ListCalibrations,
                                  SetActiveCalibration)
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import domain_coordinator
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros.calls import spin_until
from cobot_calib_ros.core import frames
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.ros import convert, qos
from rosutil import call, listen_late, STARTUP_TIMEOUT, STOP_TIMEOUT

Res = CalibrateUserFrame.Response
Choice = SetActiveCalibration
TIMEOUT = 15.0           # [s] discovery plus a latched message
QUIET = 3.0              # [s] listened to when nothing may arrive
# tf2_ros StaticListenerQoS: what tf2 listeners, rviz2 and MoveIt subscribe /tf_static with.
TF_LISTENER = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
P_USER = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.2, 0.15, 0.0], [0.0, 0.15, 0.0],
                   [0.1, 0.075, 0.0]])
NOISE = 1e-6 * np.array([[12.0, -8.0, 5.0], [-10.0, 15.0, -7.0], [6.0, -4.0, -12.0],
                         [-9.0, -11.0, 8.0], [3.0, 9.0, 6.0]])


def _base_points(x: float, yaw: float) -> np.ndarray:
    """P_USER seen from a base frame: the user frame turned by yaw [rad], at x [m]."""
    T = frames.make_transform(frames.rot_z(yaw), [x, -0.12, 0.08])
    return frames.apply(T, P_USER) + NOISE


def _calibrate(node, base, ns='', **fields):
    return call(node, CalibrateUserFrame, f'{ns}/calibrate_user_frame', 20.0,
                points_user=convert.array_to_points(P_USER),
                points_base=convert.array_to_points(base), **fields)


def _good(node, x=0.55, yaw=0.5, ns='', **fields) -> UserFrameCalibration:
    res = _calibrate(node, _base_points(x, yaw), ns, **fields)
    assert res.error_code == Res.SUCCESS, res.message
    return res.calibration


def _choose(node, calibration_id, action=Choice.Request.ACTIVATE):
    return call(node, SetActiveCalibration, 'set_active_calibration',
                calibration_id=calibration_id, action=action)


def _tf(msg: TFMessage, child: str):
    return next((t for t in msg.transforms if t.child_frame_id == child), None)


def _latched_tf(node, child: str, expected=None):
    """The transform of ``child`` a late /tf_static subscriber gets (the last one, once it is
    ``expected``, if given); None if none arrives."""
    def done(msgs):
        found = [_tf(m, child) for m in msgs if _tf(m, child) is not None]
        return bool(found) and (expected is None or found[-1] == expected)
    got = listen_late(node, TFMessage, '/tf_static', TF_LISTENER, done, TIMEOUT)
    found = [_tf(m, child) for m in got if _tf(m, child) is not None]
    return found[-1] if found else None


def _latched_calibration(node, topic='user_frame', expected_id=None):
    got = listen_late(node, UserFrameCalibration, topic, qos.LATCHED,
                      lambda m: bool(m) and expected_id in (None, m[-1].id), TIMEOUT)
    return got[-1] if got else None


def _assert_tf_is(node, cal: UserFrameCalibration):
    """/tf_static has exactly the transform of ``cal`` for its user frame."""
    t = _latched_tf(node, cal.transform.child_frame_id, cal.transform)
    assert t is not None, f'no {cal.transform.child_frame_id} on /tf_static'
    assert t == cal.transform, (t, cal.transform)     # frame ids, stamp, values: all equal
    assert (t.header.frame_id, t.child_frame_id) == (cal.transform.header.frame_id,
                                                     cal.transform.child_frame_id)


# -------------------------------------------------------------- the session suite's solver


def test_suite_latches_the_calibrated_user_frame_on_tf_static(ros):
    """A distinct user frame id, so that what an earlier test latched cannot pass for it."""
    cal = _good(ros, x=0.61, yaw=0.2, user_frame='tf_static_check')
    assert (cal.transform.header.frame_id, cal.transform.child_frame_id) == \
        ('base_link', 'tf_static_check')
    _assert_tf_is(ros, cal)
    np.testing.assert_allclose(convert.transform_to_matrix(_latched_tf(ros, 'tf_static_check')),
                               np.array(cal.matrix).reshape(4, 4), atol=1e-12)
    info = ros.get_publishers_info_by_topic('/tf_static')
    assert info and all(i.topic_type == 'tf2_msgs/msg/TFMessage' for i in info)
    assert all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in info)


# -------------------------------------------------------------- a solver of our own


class PrivateSolver:
    """One user_frame_solver process on a domain of its own, restartable on the same data_dir,
    and a client node (``node``) in this process on that domain."""

    def __init__(self, domain: int, data_dir: Path, log_dir: Path) -> None:
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
        self.spec = launcher.NodeSpec('user_frame_solver', params={
            'cell_file': str(cell_file('sawyer_close')), 'data_dir': str(data_dir)})
        self.log_dir, self.runs, self.suite = log_dir, 0, None
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('tf_static_node_test', context=self.context)
        self.node.executor_for_tests = SingleThreadedExecutor(context=self.context)
        self.node.executor_for_tests.add_node(self.node)

    def start(self) -> None:
        self.runs += 1
        self.suite = launcher.Suite(self.log_dir / f'run{self.runs}')
        self.suite.start([self.spec], env=self.env)
        client = self.node.create_client(SetActiveCalibration, 'set_active_calibration')
        try:
            up = spin_until(self.node, client.service_is_ready, STARTUP_TIMEOUT,
                            self.node.executor_for_tests)
        finally:
            self.node.destroy_client(client)
        if not up:
            self.stop()
            pytest.fail(f'user_frame_solver did not come up in {STARTUP_TIMEOUT:.0f} s:\n'
                        f'{self.suite.log_tail("user_frame_solver")}')

    def stop(self) -> int:
        return self.suite.stop(STOP_TIMEOUT)['user_frame_solver']

    def restart(self) -> None:
        code = self.stop()
        assert code == 0, f'exit code {code}:\n{self.suite.log_tail("user_frame_solver")}'
        self.start()

    def close(self) -> None:
        self.node.executor_for_tests.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture(scope='module')
def own(tmp_path_factory):
    with domain_coordinator.domain_id() as domain:
        solver = PrivateSolver(domain, tmp_path_factory.mktemp('own_results'),
                               tmp_path_factory.mktemp('own_logs'))
        try:
            solver.start()
            yield solver
            assert solver.stop() == 0, solver.suite.log_tail('user_frame_solver')
        finally:
            solver.close()


def test_calibration_is_on_tf_static_and_again_after_a_restart(own):
    node = own.node
    first = _good(node, x=0.50)
    _assert_tf_is(node, first)
    second = _good(node, x=0.52, yaw=0.6)
    _assert_tf_is(node, second)
    own.restart()
    _assert_tf_is(node, second)                       # from the store, before any new call
    assert _latched_calibration(node).id == second.id
    assert call(node, ListCalibrations, 'list_calibrations').active_id == second.id


def test_tf_static_follows_the_active_choice_across_a_restart(own):
    node = own.node
    older, newer = _good(node, x=0.40), _good(node, x=0.42)
    chose = _choose(node, older.id)
    assert chose.error_code == Choice.Response.SUCCESS, chose.message
    assert chose.active.id == older.id and older.id in chose.message
    _assert_tf_is(node, older)
    assert _latched_calibration(node, expected_id=older.id).id == older.id
    own.restart()
    _assert_tf_is(node, older)
    listed = call(node, ListCalibrations, 'list_calibrations')
    assert listed.active_id == older.id and listed.calibrations[0].id == newer.id
    # conversions without a calibration_id use the active one
    to_base = call(node, ConvertPoints, 'user_to_robot', points=convert.array_to_points(P_USER))
    assert to_base.error_code == ConvertPoints.Response.SUCCESS, to_base.message
    assert older.id in to_base.message
    np.testing.assert_allclose(convert.points_to_array(to_base.points),
                               frames.apply(np.array(older.matrix).reshape(4, 4), P_USER),
                               atol=1e-12)
    # a new calibration becomes the active one
    newest = _good(node, x=0.44)
    _assert_tf_is(node, newest)
    assert call(node, ListCalibrations, 'list_calibrations').active_id == newest.id


def test_retired_calibrations_are_listed_but_never_latched(own):
    node = own.node
    kept, retired = _good(node, x=0.30), _good(node, x=0.32)
    done = _choose(node, retired.id, Choice.Request.RETIRE)
    assert done.error_code == Choice.Response.SUCCESS, done.message
    assert done.active.id == kept.id
    _assert_tf_is(node, kept)
    own.restart()
    _assert_tf_is(node, kept)
    listed = call(node, ListCalibrations, 'list_calibrations')
    assert listed.active_id == kept.id and listed.calibrations[0].id == retired.id
    assert listed.retired_ids == [retired.id]
    # retire every calibration: nothing stays latched, conversions say what to do
    for cal in listed.calibrations:
        assert _choose(node, cal.id, Choice.Request.RETIRE).error_code == 0
    assert listen_late(node, TFMessage, '/tf_static', TF_LISTENER, bool, QUIET) == []
    assert listen_late(node, UserFrameCalibration, 'user_frame', qos.LATCHED, bool, QUIET) == []
    none = call(node, ConvertPoints, 'user_to_robot', points=convert.array_to_points(P_USER))
    assert none.error_code == ConvertPoints.Response.NO_CALIBRATION, none.message
    assert 'calibrate_user_frame' in none.message
    back = _choose(node, retired.id)                  # activating un-retires
    assert back.error_code == Choice.Response.SUCCESS and back.active.id == retired.id
    _assert_tf_is(node, retired)


def test_a_new_user_frame_id_replaces_the_old_one_on_tf_static(own):
    node = own.node
    old = _good(node, x=0.35)
    _assert_tf_is(node, old)
    table = _good(node, x=0.36, user_frame='table_b')
    _assert_tf_is(node, table)
    got = listen_late(node, TFMessage, '/tf_static', TF_LISTENER,
                      lambda m: any(_tf(x, 'table_b') for x in m), TIMEOUT)
    assert got and [t.child_frame_id for t in got[-1].transforms] == ['table_b']


@pytest.mark.parametrize('calibration_id, action, code, words', [
    pytest.param('no-such-calibration', Choice.Request.ACTIVATE,
                 Choice.Response.NO_CALIBRATION, ['no-such-calibration', 'list_calibrations'],
                 id='unknown'),
    pytest.param('bad id!', Choice.Request.RETIRE, Choice.Response.INVALID_INPUT,
                 ['bad id!', 'must match'], id='malformed'),
    pytest.param('', Choice.Request.RETIRE, Choice.Response.INVALID_INPUT,
                 ['RETIRE needs a calibration_id'], id='retire_nothing'),
    pytest.param('', 7, Choice.Response.INVALID_INPUT, ['unknown action 7', 'ACTIVATE'],
                 id='unknown_action'),
])
def test_bad_choice_is_refused_and_changes_nothing(own, calibration_id, action, code, words):
    node = own.node
    active = _good(node, x=0.38)
    res = _choose(node, calibration_id, action)
    assert res.error_code == code, res.message
    for word in words:
        assert word in res.message
    assert res.active.id == active.id
    assert call(node, ListCalibrations, 'list_calibrations').active_id == active.id


def _health(node, done) -> DiagnosticStatus | None:
    """The solver's latest status on /diagnostics once done(values) holds (or the last one)."""
    def statuses(msgs):
        return [s for m in msgs for s in m.status if s.name == 'user_frame_solver: health']

    def values_ok(msgs):
        found = statuses(msgs)
        return bool(found) and done({kv.key: kv.value for kv in found[-1].values})
    got = listen_late(node, DiagnosticArray, '/diagnostics', 10, values_ok, TIMEOUT)
    found = statuses(got)
    return found[-1] if found else None


def test_diagnostics_name_the_active_calibration_and_the_last_refusal(own):
    node = own.node
    cal = _good(node, x=0.37)
    refused = _calibrate(node, _base_points(0.37, 0.5) * 1e3)        # millimetres
    assert refused.error_code == Res.IMPLAUSIBLE_FIT, refused.message
    stored = len(call(node, ListCalibrations, 'list_calibrations').calibrations)
    status = _health(node, lambda v: v.get('active_id') == cal.id
                     and 'IMPLAUSIBLE_FIT' in v.get('last_refusal', ''))
    assert status is not None, 'no user_frame_solver status on /diagnostics'
    values = {kv.key: kv.value for kv in status.values}
    assert values['active_id'] == cal.id and 'millimetres' in values['last_refusal']
    assert float(values['active_rms_mm']) == pytest.approx(cal.rms_residual * 1e3, abs=1e-4)
    assert int(values['calibrations_stored']) == stored
    assert status.level == DiagnosticStatus.OK and cal.id in status.message


# -------------------------------------------------------------- package.xml


def _imports(root: Path) -> set[str]:
    """Top-level modules imported anywhere in the package (also inside functions)."""
    found = set()
    for path in root.rglob('*.py'):
        for n in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            if isinstance(n, ast.Import):
                found |= {a.name.split('.')[0] for a in n.names}
            elif isinstance(n, ast.ImportFrom) and n.level == 0 and n.module:
                found.add(n.module.split('.')[0])
    return found


def test_package_xml_declares_every_runtime_import():
    """rosdep installs what package.xml lists: tf2_msgs and diagnostic_msgs for this node, ..."""
    repo = Path(__file__).resolve().parents[2]
    xml = ET.parse(repo / 'package.xml').getroot()
    declared = {e.text for e in xml if e.tag in ('depend', 'exec_depend')}
    rosdep_key = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'yaml': 'python3-yaml',
                  'matplotlib': 'python3-matplotlib', 'cv2': 'python3-opencv',
                  'mcap': 'python3-mcap', 'rosbags': 'python3-rosbags',
                  'sqlalchemy': 'python3-sqlalchemy', 'alembic': 'python3-alembic',
                  'foxglove': 'python3-foxglove-sdk-pip'}
    third_party = _imports(repo / 'cobot_calib_ros') - set(sys.stdlib_module_names) - {
        'cobot_calib_ros'}
    missing = sorted(rosdep_key.get(m, m) for m in third_party
                     if rosdep_key.get(m, m) not in declared)
    assert missing == [], f'package.xml does not declare {missing}'
    assert {'tf2_msgs', 'diagnostic_msgs', 'rosgraph_msgs'} <= declared
