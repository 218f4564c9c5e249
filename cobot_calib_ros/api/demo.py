"""The demo (`cobot-calib demo`): its client (touch and capture on the mock, calibrate, move,
read the truth) and its procedure: the captures, every method's user frame, the moves through
each and their errors scored against the mock's ground truth (simulation only)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from cobot_calib_ros import store
from cobot_calib_ros.core import cell as cellmod
from cobot_calib_ros.core import frames, kinematics, user_frame
from cobot_calib_ros.core.errors import Refusal
from cobot_calib_ros.core.rig import ActiveSet, Rig
from cobot_calib_ros.core.user_frame.procedure import points_of_joints
from cobot_calib_ros.paths import data_dir
from cobot_calib_ros.ros import convert
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.kinematics import NOMINAL
from cobot_calib_ros.store.rigs import kinematics_of

POINTS = ('P1', 'P2', 'P3', 'P4', 'P5')


class DemoClient:
    """Service and action calls of the demo (one rclpy node, ros.session; close() ends it)."""

    def __init__(self) -> None:
        from cobot_calib_ros.ros.action_client import ActionClient
        from cobot_calib_msgs.action import MoveTo
        from cobot_calib_msgs.srv import (CalibrateUserFrame, CaptureJoints, GetGroundTruth,
                                          HandGuide)
        from cobot_calib_ros.ros.session import session
        self._session = session('cobot_calib_demo')
        self.node, self.executor = self._session.__enter__()
        self.MoveTo, self.Calibrate = MoveTo, CalibrateUserFrame
        self._truth = self.node.create_client(GetGroundTruth, 'get_ground_truth')
        self._capture = self.node.create_client(CaptureJoints, 'capture_joints')
        self._calibrate = self.node.create_client(CalibrateUserFrame, 'calibrate_user_frame')
        self._move = ActionClient(self.node, MoveTo, 'move_to')
        self._hand_guide = self.node.create_client(HandGuide, 'mock_robot/hand_guide')

    def close(self) -> None:
        self._session.__exit__(None, None, None)

    def ground_truth(self):
        from cobot_calib_ros.ros.calls import call_service
        return call_service(self.node, self._truth, self._truth.srv_type.Request(), 30.0,
                            idempotent=True)

    def calibrate(self, method: str, names=(), p_user=None, p_base=None, captures=(),
                  kinematics: str = ''):
        from cobot_calib_ros.ros.calls import call_service
        req = self.Calibrate.Request(method=method, point_names=list(names),
                                     joint_captures=list(captures), kinematics=kinematics)
        if p_user is not None:
            req.points_user = convert.array_to_points(p_user)
            req.points_base = convert.array_to_points(p_base)
        return call_service(self.node, self._calibrate, req, 120.0)

    def touch_and_capture(self, name: str, hold: float = 0.5):
        """The mock's simulated operator guides the tool onto ``name``; the joints held there
        (JointState)."""
        from sensor_msgs.msg import JointState
        from cobot_calib_ros.ros.calls import call_service
        result = call_service(self.node, self._hand_guide,
                              self._hand_guide.srv_type.Request(point_name=name), 60.0)
        if result.error_code != result.SUCCESS:
            raise RuntimeError(f'touching {name}: {result.message}')
        res = call_service(self.node, self._capture,
                           self._capture.srv_type.Request(duration=hold), 30.0)
        if res.error_code != 0:
            raise RuntimeError(f'capture at {name}: {res.message}')
        return JointState(name=list(res.name), position=list(res.position))

    def move_to_joints(self, q: np.ndarray):
        from cobot_calib_ros.ros.calls import run_action
        goal = self.MoveTo.Goal(target_type=self.MoveTo.Goal.TARGET_JOINTS,
                                positions=[float(v) for v in q])
        return run_action(self.node, self._move, goal, 60.0)[1]


def attached(cell: str | None, node) -> tuple[str, Path]:
    """(cell, data dir) of the suite running on the exported domain: --cell, else the cell
    file its user_frame_solver was started with, and that node's data dir."""
    from cobot_calib_ros.ros.remote_params import read_parameter
    cell = cell or read_parameter(node, 'user_frame_solver', 'cell_file', 15.0)
    return cell, data_dir(read_parameter(node, 'user_frame_solver', 'data_dir', 15.0))


def run_demo(client: DemoClient, cell, root: Path, kinematics_choice: str = NOMINAL, *,
             identify_configs: int | None = None, say=lambda text: None) -> dict:
    """The demo on the suite of ``cell`` whose data dir is ``root``: the captures, every
    method's frame scored against the mock's truth (through the nominal kinematics and, unless
    ``kinematics_choice`` is nominal, through that calibration), JSON-ready (mm)."""
    from cobot_calib_ros.api.client import wait_for_suite
    wait_for_suite(client.node)
    truth = client.ground_truth()
    T_true = convert.transform_to_matrix(truth.user_frame)
    true_by_name = dict(zip(truth.point_names, convert.points_to_array(truth.points_base)))
    p_true = np.array([true_by_name[n] for n in POINTS])
    true_chain = _truth_model(truth, cell)
    records = [None] + ([] if kinematics_choice == NOMINAL else
                        [_kinematics(kinematics_choice, client, cell, root, identify_configs,
                                     say)])
    say(f'touching {", ".join(POINTS)} and capturing joints ...')
    captures = [client.touch_and_capture(n) for n in POINTS]
    p_user = cell.nominal_points_user()[[cell.point_names.index(n) for n in POINTS]]
    sigma = math.hypot(truth.touch_sigma, truth.repeatability_sigma)
    limit_t, limit_r = user_frame.estimation_limit(p_user, sigma)
    runs = []
    for record in records:
        model = _model_entry(record, cell, truth, true_chain, p_true, p_user)
        rows = []
        for method in user_frame.METHODS:
            say(f'{method} ({model["label"]} kinematics): fitting and visiting the five '
                      'points through the frame ...')
            rows.append(_method_row(client, method, captures, model, T_true, p_true,
                                    true_chain))
        p_base = points_of_joints(model['chain'], [np.array(c.position) for c in captures])
        captured = [{'name': n, 'captured_mm': (pb * 1e3).tolist(),
                     'true_mm': (pt * 1e3).tolist(),
                     'error_mm': float(np.linalg.norm(pb - pt) * 1e3)}
                    for n, pb, pt in zip(POINTS, p_base, p_true)]
        runs.append({'kinematics': model['label'], 'captured': captured, 'methods': rows})
    result = {'cell': cell.name, 'robot': cell.robot, 'layout': cell.layout,
              **runs[-1],
              'estimation_limit_mm': limit_t * 1e3, 'estimation_limit_mrad': limit_r * 1e3,
              'noise_sigma_mm': sigma * 1e3}
    if len(runs) > 1:
        result['nominal'] = runs[0]
        result['systematic_reduction'] = _reduction(runs[0]['methods'], runs[-1]['methods'])
    return result


def _kinematics(choice: str, client: DemoClient, cell, root: Path, identify_configs,
                say) -> dict:
    """The kinematic calibration record ``choice`` (--kinematics) names for ``cell``'s robot in
    data dir ``root``; 'latest' with none of that robot stored identifies one on the mock
    first."""
    from cobot_calib_ros.api import identification
    robot = kinematics.model_for(cell).name
    kinematic_store = store.open(root, cell=ResultsCell.of(cell)).kinematics
    try:
        record = kinematic_store.resolve(choice, robot)
    except (KeyError, ValueError, Refusal) as e:
        raise RuntimeError(f'--kinematics {choice}: {e}') from None
    if record is None:
        say(f'no kinematic calibration of the {robot} in {kinematic_store.directory}: '
            'identifying one on the mock first (as cobot-calib identify) ...')
        identifier = identification.IdentifyClient(client.node)
        try:
            report = identification.identify_on_suite(
                identifier, say=say, max_configs=identify_configs,
                validation_configs=0)
        except identification.IdentificationFailed as e:
            raise RuntimeError(str(e)) from None
        finally:
            identifier.close()
        record = store.open(root, cell=ResultsCell.of(cell)).kinematics.get(
            report['calibration_id'])
    return record


def _model_entry(record, cell, truth, true_chain, p_true, p_user) -> dict:
    """A kinematic model the demo maps captures through: label, chain, apparent points."""
    rig = Rig(cell, ActiveSet(kinematics_of(record)))   # the kinematics alone: the demo's
    chain = rig.chain('tcp')
    true_arm = rig.model.chain(np.array(truth.true_parameters), tool=rig.tool('tcp'))
    p_apparent, p_arm = _apparent_points(truth, cell, true_chain, p_true, chain, true_arm)
    return {'label': NOMINAL if record is None else record['id'], 'chain': chain,
            'home': cell.home, 'p_user': p_user, 'p_apparent': p_apparent, 'p_arm': p_arm}


def _reduction(before: list[dict], after: list[dict]) -> dict:
    """Per method: the systematic frame error before / after [mm], its kinematic part before /
    after [mm] and that part's factor; the table part is the same in both."""
    out = {}
    for b, a in zip(before, after):
        if 'error' in b or 'error' in a:
            continue
        out[b['name']] = {'before_mm': b['frame_error_systematic_mm'],
                          'after_mm': a['frame_error_systematic_mm'],
                          'kinematic_before_mm': b['systematic_kinematic_mm'],
                          'kinematic_after_mm': a['systematic_kinematic_mm'],
                          'tool_mm': b['systematic_tool_mm'],
                          'table_mm': b['systematic_table_mm'],
                          'kinematic_factor': b['systematic_kinematic_mm']
                          / max(a['systematic_kinematic_mm'], 1e-12)}
    return out


def _truth_model(truth, cell):
    """The true robot (simulation only): nominal model with the mock's true parameters and
    its real tool."""
    tool = convert.transform_to_matrix(truth.t_flange_tool_true)
    model = kinematics.model_for(cell)
    return model.chain(np.array(truth.true_parameters), tool=tool)


def _point_errors(client, M, p_user, p_true, true_chain, chain, home) -> np.ndarray:
    """Send the tool to every marker through the frame M, with joints from ``chain`` (the
    kinematic model in use); true error of each arrival [m]."""
    orientation = cellmod.tool_down_orientation(user_frame.nearest_rigid(M))
    errors = []
    for pu, pt in zip(p_user, p_true):
        target = frames.make_transform(orientation, frames.apply(M, pu))
        ik = kinematics.solve_ik_with_restarts(chain, target, home, home)
        if not ik:
            errors.append(math.nan)
            continue
        result = client.move_to_joints(ik.q)
        if result.error_code != client.MoveTo.Result.SUCCESS:
            errors.append(math.nan)
            continue
        reached = kinematics.fk(true_chain, np.array(result.positions))[:3, 3]
        errors.append(float(np.linalg.norm(reached - pt)))
    return np.array(errors)


def _apparent_points(truth, cell, true_chain, p_true, *chains) -> list[np.ndarray]:
    """Where each of ``chains`` (the kinematic model in use; the true arm with the model's
    tool) sees perfectly touched markers [m]: the captures without noise.

    The robot's kinematic errors (what the model does not know of them), its tool's and the
    table's unevenness shift every captured point, and no user-frame fit can remove that;
    fitting these noise-free points tells that systematic part apart from what the noise does.
    """
    R = cellmod.tool_down_orientation(convert.transform_to_matrix(truth.user_frame))
    q = []
    for name, p in zip(POINTS, p_true):
        ik = kinematics.solve_ik_with_restarts(true_chain, frames.make_transform(R, p),
                                               cell.home, cell.home)
        if not ik:
            raise RuntimeError(f'the true robot cannot reach marker {name}: {ik.message}')
        q.append(ik.q)
    return [kinematics.fk(chain, np.array(q))[:, :3, 3] for chain in chains]


def _method_row(client, method, captures, model, T_true, p_true, true_chain) -> dict:
    res = client.calibrate(method, POINTS, captures=captures, kinematics=model['label'])
    if res.error_code != 0:
        return {'name': method, 'error': res.message}
    cal = res.calibration
    p_user, p_apparent = model['p_user'], model['p_apparent']
    T = convert.transform_to_matrix(cal.transform)
    M = np.array(cal.matrix).reshape(4, 4)            # the map the method converts with
    dt, dr = frames.transform_error(T, T_true)
    T_apparent = user_frame.calibrate(method, p_user, p_apparent).T_base_user
    nt, nr = frames.transform_error(T, T_apparent)
    st, sr = frames.transform_error(T_apparent, T_true)
    # the same fit of perfect touches measured by the true robot: what the table alone does;
    # by the true arm with the model's tool: the arm's part apart from the tool's
    T_table = user_frame.calibrate(method, p_user, p_true).T_base_user
    T_arm = user_frame.calibrate(method, p_user, model['p_arm']).T_base_user
    kt, kr = frames.transform_error(T_apparent, T_arm)
    ot, orr = frames.transform_error(T_arm, T_table)
    tt, tr = frames.transform_error(T_table, T_true)
    errors = _point_errors(client, M, p_user, p_true, true_chain, model['chain'],
                           model['home'])
    return {'name': method, 'frame_error_mm': dt * 1e3, 'frame_error_mrad': dr * 1e3,
            'frame_error_noise_mm': nt * 1e3, 'frame_error_noise_mrad': nr * 1e3,
            'frame_error_systematic_mm': st * 1e3, 'frame_error_systematic_mrad': sr * 1e3,
            'systematic_kinematic_mm': kt * 1e3, 'systematic_kinematic_mrad': kr * 1e3,
            'systematic_tool_mm': ot * 1e3, 'systematic_tool_mrad': orr * 1e3,
            'systematic_table_mm': tt * 1e3, 'systematic_table_mrad': tr * 1e3,
            'residual_rms_mm': cal.rms_residual * 1e3,
            'point_error_max_mm': float(np.nanmax(errors)) * 1e3,
            'point_error_mm': (errors * 1e3).tolist(),
            'id': cal.id}


def copy_kinematics(cell: ResultsCell, source_root, target_root) -> None:
    """Every kinematic calibration of ``cell`` in the data dir ``source_root`` into
    ``target_root``'s, with the same active one per robot (the source is only read)."""
    source, target = (store.open(root, cell=cell).kinematics
                      for root in (source_root, target_root))
    records = source.history()
    for record in reversed(records):                  # oldest first, as they were stored
        target.save(record)
    for robot in {source.scope_of(r) for r in records}:
        active = source.active(robot)
        if active is not None:
            target.activate(active['id'], robot)
