"""`cobot-calib demo`: five-point user-frame calibration on the mock robot, scored on truth.

Touches P1..P5 live and captures the joints (capture_joints), then has calibrate_user_frame
fit the user frame with every method from the same captures and sends the robot to each
marker through each frame. The mock's ground truth scores every figure. With --kinematics the
same captures are mapped through the nominal and through a kinematic calibration (identified
first on the mock when 'latest' finds none), before and after.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
from pathlib import Path
import sys
import tempfile

import numpy as np

from cobot_calib_ros.api import launcher
from cobot_calib_ros.api.demo import DemoClient
from cobot_calib_ros.cli.common import say
from cobot_calib_ros.ros import convert
from cobot_calib_ros.core import cell as cellmod
from cobot_calib_ros.core import frames, kinematics, user_frame
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file, data_dir, DEFAULT_CELL
from cobot_calib_ros import store
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.database import DB_ENV
from cobot_calib_ros.core.rig import ActiveSet, Rig
from cobot_calib_ros.store.rigs import kinematics_of
from cobot_calib_ros.store.kinematics import NOMINAL

POINTS = ('P1', 'P2', 'P3', 'P4', 'P5')


STORING_NODES = ('user_frame_solver', 'repeatability_trial', 'hand_eye_calibrator',
                 'kinematic_identifier', 'tcp_calibrator', 'camera_calibrator',
                 'landmark_detector')      # the nodes with a data_dir


@contextlib.contextmanager
def _suite(args):
    """The data dir of the demo's suite (None with --attach: the running suite's). Without
    --attach: a suite on a private domain storing in a temporary data dir (its own SQLite,
    $COBOT_CALIB_DB left out while it runs), removed at the end, so that no other suite's
    results change (the active user frame above all); the user's kinematic calibrations of
    the cell are copied in for --kinematics latest|ID."""
    if args.attach:
        yield None
        return
    with tempfile.TemporaryDirectory(prefix='cobot_calib_demo_') as tmp:
        cell = _results_cell(args.cell)
        source = store.open(data_dir(''), cell=cell) if args.kinematics != NOMINAL else None
        with _without_env(DB_ENV):
            if source is not None:
                _copy_kinematics(source, store.open(tmp, cell=cell))
            overrides = {n: {'data_dir': tmp} for n in STORING_NODES}
            with launcher.private_suite(args.cell, overrides,
                                        say=lambda text: say(args, text)):
                yield Path(tmp)


@contextlib.contextmanager
def _without_env(*names: str):
    """os.environ without ``names`` (the suite's nodes inherit it), restored afterwards."""
    saved = {n: os.environ.pop(n) for n in names if n in os.environ}
    try:
        yield
    finally:
        os.environ.update(saved)


def _results_cell(name: str) -> ResultsCell:
    """The cell the results of a suite of cell file ``name`` (no namespace) are stored as."""
    return ResultsCell.of(load_cell(cell_file(name)))


def _copy_kinematics(source, target) -> None:
    """Every kinematic calibration of repository ``source`` into ``target``, with the same
    active one per robot (``source`` is only read)."""
    records = source.kinematics.history()
    for record in reversed(records):                  # oldest first, as they were stored
        target.kinematics.save(record)
    for robot in {source.kinematics.scope_of(r) for r in records}:
        active = source.kinematics.active(robot)
        if active is not None:
            target.kinematics.activate(active['id'], robot)


def _attached(args, node) -> tuple[str, Path]:
    """(cell, data dir) of the suite running on the exported domain: --cell, else the cell
    file its user_frame_solver was started with, and that node's data dir."""
    from cobot_calib_ros.ros.remote_params import read_parameter
    cell = args.cell or read_parameter(node, 'user_frame_solver', 'cell_file', 15.0)
    return cell, data_dir(read_parameter(node, 'user_frame_solver', 'data_dir', 15.0))


def _truth_model(truth, cell):
    """The true robot (simulation only): nominal model with the mock's true parameters and
    its real tool."""
    tool = convert.transform_to_matrix(truth.tool_offset_true)
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


def _report(args, result: dict) -> None:
    if args.json:
        print(json.dumps(result, indent=2))
        return
    if 'nominal' in result:
        _report_run(result['nominal'], 'nominal kinematics (before)')
    _report_run(result, f'kinematics: {result["kinematics"]}'
                + (' (after)' if 'nominal' in result else ''))
    print(f"\nestimation limit from point noise alone (rigid, 5 points, sigma "
          f"{result['noise_sigma_mm']:.4f} mm): {result['estimation_limit_mm']:.4f} mm, "
          f"{result['estimation_limit_mrad']:.4f} mrad (RMS); a noise part above "
          f"{user_frame.LIMIT_FACTOR:g}x that is suspect")
    reduction = result.get('systematic_reduction', {})
    if reduction:
        print('\nsystematic frame error before -> after kinematic identification [mm]: total, '
              'its kinematic part (fit through the model vs through the true arm with the '
              'model\'s tool), the tool part (the model\'s tool vs the real one: a TCP '
              'calibration removes it) and the table part (uneven table, marker heights: no '
              'model removes it)')
    for name, r in reduction.items():
        print(f"{name:<16}{r['before_mm']:.4f} -> {r['after_mm']:.4f}   kinematic "
              f"{r['kinematic_before_mm']:.4f} -> {r['kinematic_after_mm']:.4f} "
              f"({r['kinematic_factor']:.1f}x smaller)   tool {r['tool_mm']:.4f}   table "
              f"{r['table_mm']:.4f}")


def _report_run(run: dict, title: str) -> None:
    print(f'\n== {title}')
    print('captured tool points beside the truth, base frame [mm]:')
    for c in run['captured']:
        cap, tru = c['captured_mm'], c['true_mm']
        print(f"  {c['name']}: captured ({cap[0]:9.3f} {cap[1]:9.3f} {cap[2]:8.3f})  true "
              f"({tru[0]:9.3f} {tru[1]:9.3f} {tru[2]:8.3f})  |diff| {c['error_mm']:.3f}")
    print('\nframe error against the true user frame, split into the systematic part (kinematic '
          'errors, the tool\'s, the\ntable: the frame perfect touches would give) and the part '
          'due to noise; point err: robot sent to each marker')
    print(f"{'method':<16}{'frame err':>18}{'systematic':>18}{'noise part':>18}"
          f"{'resid RMS':>11}{'point err max':>15}")
    print(f"{'':<16}{'mm / mrad':>18}{'mm / mrad':>18}{'mm / mrad':>18}{'mm':>11}{'mm':>15}")
    for m in run['methods']:
        if 'error' in m:
            print(f"{m['name']:<16} failed: {m['error']}")
            continue
        print(f"{m['name']:<16}"
              f"{m['frame_error_mm']:9.4f} /{m['frame_error_mrad']:7.4f}"
              f"{m['frame_error_systematic_mm']:9.4f} /{m['frame_error_systematic_mrad']:7.4f}"
              f"{m['frame_error_noise_mm']:9.4f} /{m['frame_error_noise_mrad']:7.4f}"
              f"{m['residual_rms_mm']:11.4f}{m['point_error_max_mm']:15.4f}")


def _run(args, client: DemoClient, root: Path | None) -> dict:
    """The demo on the suite whose data dir is ``root`` (None: the attached suite's)."""
    from cobot_calib_ros.api.client import wait_for_suite
    name = args.cell
    if root is None:
        name, root = _attached(args, client.node)
    cell = load_cell(cell_file(name))
    wait_for_suite(client.node)
    truth = client.ground_truth()
    T_true = convert.transform_to_matrix(truth.user_frame)
    true_by_name = dict(zip(truth.point_names, convert.points_to_array(truth.points_base)))
    p_true = np.array([true_by_name[n] for n in POINTS])
    true_chain = _truth_model(truth, cell)
    records = [None] + ([] if args.kinematics == NOMINAL else
                        [_kinematics(args, client, cell, root)])
    say(args, f'touching {", ".join(POINTS)} and capturing joints ...')
    captures = [client.touch_and_capture(n) for n in POINTS]
    p_user = cell.nominal_points_user()[[cell.point_names.index(n) for n in POINTS]]
    sigma = math.hypot(truth.touch_sigma, truth.repeatability_sigma)
    limit_t, limit_r = user_frame.estimation_limit(p_user, sigma)
    runs = []
    for record in records:
        model = _model_entry(record, cell, truth, true_chain, p_true, p_user)
        rows = []
        for method in user_frame.METHODS:
            say(args, f'{method} ({model["label"]} kinematics): fitting and visiting the five '
                      'points through the frame ...')
            rows.append(_method_row(client, method, captures, model, T_true, p_true,
                                    true_chain))
        p_base = np.array([kinematics.fk(model['chain'], np.array(c.position))[:3, 3]
                           for c in captures])
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


def _kinematics(args, client: DemoClient, cell, root: Path) -> dict:
    """The kinematic calibration record --kinematics names for ``cell``'s robot in data dir
    ``root``; 'latest' with none of that robot stored identifies one on the mock first."""
    from cobot_calib_ros.api import identification
    robot = kinematics.model_for(cell).name
    kinematic_store = store.open(root, cell=ResultsCell.of(cell)).kinematics
    try:
        record = kinematic_store.resolve(args.kinematics, robot)
    except (KeyError, ValueError) as e:
        raise RuntimeError(f'--kinematics {args.kinematics}: {e}') from None
    if record is None:
        say(args, f'no kinematic calibration of the {robot} in {kinematic_store.directory}: '
                  'identifying one on the mock first (as cobot-calib identify) ...')
        identifier = identification.IdentifyClient(client.node)
        try:
            report = identification.identify_on_suite(
                identifier, say=lambda t: say(args, t), max_configs=args.identify_configs,
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


def run(args) -> int:
    from cobot_calib_ros.cli.common import cell_problem, EXIT_USAGE, fail
    from cobot_calib_ros.ros.calls import CallError
    if not args.attach and args.cell is None:
        args.cell = DEFAULT_CELL
    problem = cell_problem(args.cell) if args.cell else ''
    if problem:
        return fail(f'demo: {problem}', EXIT_USAGE)
    try:
        with _suite(args) as root:
            client = DemoClient()
            try:
                result = _run(args, client, root)
            finally:
                client.close()
    except (CallError, RuntimeError) as e:
        print(f'demo failed: {e}', file=sys.stderr)
        return 1
    _report(args, result)
    return 0
