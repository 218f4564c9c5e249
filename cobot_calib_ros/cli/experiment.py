"""`cobot-calib trial` and `cobot-calib experiment user-frame`: repeatability trials over ROS.

The experiment reproduces the first paper's comparison (Tables 1-5, Figures 2-4, 7) on the
mock robot: a reference trial and one trial per calibration method (the landmark methods after
a hand-eye calibration), each n cycles over P1..P5 of the chosen set-up, then one table (with
the paper's figures and each method's calibration time beside) and one box plot.
"""
from __future__ import annotations

import functools
import json
import math
from pathlib import Path
import sys
import time

from cobot_calib_ros import paths, store
from cobot_calib_ros.api import launcher, report
from cobot_calib_ros.api.trial import TrialClient
from cobot_calib_ros.cli import common
from cobot_calib_ros.core.repeatability.trial import METHODS
from cobot_calib_ros.core.user_frame.landmarks import LANDMARK_METHODS

# the paper's comparison: every trial method but robust (this project's, not the paper's)
EXPERIMENT_METHODS = tuple(m for m in METHODS if m != 'robust')


def run_trial(args) -> int:
    """`cobot-calib trial`: one trial on a running suite. Exit codes: 0 done, 1 failed,
    2 invalid request, 130 stopped with Ctrl-C (the goal is canceled; it can be resumed).

    --method, --axis, --cycles left out (None / '') send '' / 0: a new trial takes the
    defaults, a resumed one its stored values (a given value must match the stored one)."""
    from cobot_calib_ros.ros.calls import CallError
    from cobot_calib_ros.core.errors import ErrorCode, Failure, first_failure
    from cobot_calib_ros.core.repeatability.trial import cycles_problem
    method, axis, trial_id = args.method or '', args.axis or '', args.trial_id or ''
    cycles = args.cycles if args.cycles is not None else 0
    stall = getattr(args, 'stall_timeout', None)
    stall = TrialClient.STALL_TIMEOUT if stall is None else stall
    problem = first_failure(
        cycles_problem(args.cycles) if args.cycles is not None else None,
        TrialClient.request_problem(method, axis, cycles, trial_id),
        None if math.isfinite(stall) and stall > 0.0 else Failure(
            ErrorCode.INVALID_INPUT, f'--stall-timeout {stall:g}: give a time > 0 [s] '
            f'(default {TrialClient.STALL_TIMEOUT:g})'))
    if problem is not None:
        print(f'trial rejected: {problem.message}', file=sys.stderr)
        return 2
    client = TrialClient(functools.partial(common.say, args), stall)
    try:
        unknown = client.unknown_trial(trial_id) if trial_id else None
        if unknown is not None:
            print(f'trial rejected: {unknown.message}', file=sys.stderr)
            return 2
        result = client.run(method, axis, cycles, trial_id)
    except TrialClient.Stopped as e:
        print(e.line, file=sys.stderr)
        return 130
    except CallError as e:
        print(f'trial failed: {e}', file=sys.stderr)
        return 1
    finally:
        client.close()
    if result.error_code != 0:
        print(f'trial {result.trial_id} failed: {result.message}', file=sys.stderr)
        return 1
    s = result.statistics
    out = {'trial_id': result.trial_id, 'method': s.method, 'axis': s.axis,
           'cycles': s.cycles_total, 'message': result.message, 'rp_mm': list(s.rp_mm),
           'rp_all_mm': s.rp_all_mm, 'csv': result.csv_path,
           'capture_retries': result.capture_retries, 'probe_retries': result.probe_retries}
    print(json.dumps(out) if args.json else
          f'trial {result.trial_id}: {result.message}\n  data: {result.csv_path}'
          + _retries_line(result))
    return 0


def _retries_line(result) -> str:
    """Retries after NO_DATA (a starved joint_states or probe stream), when there were any."""
    if not (result.capture_retries or result.probe_retries):
        return ''
    return (f'\n  retried after NO_DATA: {result.capture_retries} joint captures, '
            f'{result.probe_retries} probe readings (a stalling stream: see /diagnostics)')


def run_experiment(args) -> int:
    """`cobot-calib experiment user-frame`: reference + each method, one table, one figure."""
    from cobot_calib_ros.ros.calls import CallError
    from cobot_calib_ros.api.client import wait_for_suite
    say = functools.partial(common.say, args)
    data_dir = paths.data_dir(args.data_dir)
    stamp = time.strftime('%Y%m%dT%H%M%S')
    methods = args.methods or EXPERIMENT_METHODS
    overrides = {n: {'layout': args.setup, 'data_dir': str(data_dir)}
                 for n in ('repeatability_trial', 'user_frame_solver', 'hand_eye_calibrator')}
    overrides['mock_robot'] = {'layout': args.setup}
    rows, trial_ids, hand_eye = [], [], None
    try:
        with launcher.private_suite(args.cell, overrides, say):
            client = TrialClient(say, each_reading=False)      # six trials: a line per cycle
            try:
                wait_for_suite(client.node)
                for method in methods:
                    if method in LANDMARK_METHODS and hand_eye is None:
                        hand_eye = (_calibrate_hand_eye(client.node, args.cell, say)
                                    if args.hand_eye == 'calibrate' else {'hand_eye': 'nominal'})
                    trial_id = f'{stamp}-{args.setup}-{args.axis}-{method}'
                    say(f'{method}: {args.cycles} cycles on the {args.setup} set-up ...')
                    result = client.run(method, args.axis, args.cycles, trial_id, args.setup)
                    if result.error_code != 0:
                        raise RuntimeError(f'{method} trial failed: {result.message}')
                    trial_ids.append(trial_id)
                    rows.append({'method': method, 'trial_id': trial_id,
                                 'rp_mm': list(result.statistics.rp_mm),
                                 'rp_all_mm': result.statistics.rp_all_mm,
                                 'calibration_s': result.calibration_seconds})
            finally:
                client.close()
    except (CallError, RuntimeError) as e:
        print(f'experiment failed: {e}', file=sys.stderr)
        return 1
    png, table_file, table = report.write_report(store.open(data_dir).trials, trial_ids,
                                                 _report_dir(args, data_dir))
    if args.json:
        print(json.dumps({'setup': args.setup, 'axis': args.axis, 'cycles': args.cycles,
                          'rows': rows, 'hand_eye': hand_eye, 'figure': str(png),
                          'table': str(table_file)}))
    else:
        print(f'\n{table}\nfigure: {png}\ntable:  {table_file}')
    return 0


def _calibrate_hand_eye(node, cell: str, say) -> dict:
    """What the landmark rows need first, as an integrator does it: a user frame from the five
    touched points (so the hand-eye views find the board), then calibrate_hand_eye; the result
    and its error against the mock's truth. CallError / RuntimeError when a step fails."""
    from cobot_calib_msgs.srv import CalibrateUserFrame
    from geometry_msgs.msg import TransformStamped
    from cobot_calib_ros.ros.calls import call_service
    from cobot_calib_ros.api.hand_eye import calibrate_hand_eye, error_against_truth
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.ros import convert
    nominal_cell = load_cell(paths.cell_file(cell))
    say('landmark rows: a five-point user frame (to find the board), then the hand-eye ...')
    client = node.create_client(CalibrateUserFrame, 'calibrate_user_frame')
    try:
        frame = call_service(node, client, CalibrateUserFrame.Request(
            method='rigid', point_names=list(nominal_cell.point_names)), 300.0)
    finally:
        node.destroy_client(client)
    if frame.error_code != 0:
        raise RuntimeError(f'user frame for the hand-eye failed: {frame.message}')
    result = calibrate_hand_eye(node)
    if result.error_code != 0:
        raise RuntimeError(f'hand-eye calibration failed: {result.message}')
    X = convert.transform_to_matrix(TransformStamped(transform=result.t_flange_optical))
    error = error_against_truth(node, X, nominal_cell.camera.T_flange_optical)
    say(f'hand-eye {result.calibration_id}: {result.views_used} views, residual '
        f'{result.residual_mm:.3f} mm / {result.residual_mrad:.3f} mrad; error against the '
        f'truth {error.position_m * 1e3:.3f} mm / {error.rotation_rad * 1e3:.3f} mrad '
        f'(nominal: {error.nominal_position_m * 1e3:.3f} mm / '
        f'{error.nominal_rotation_rad * 1e3:.3f} mrad)')
    return {'hand_eye': result.calibration_id, 'views_used': result.views_used,
            'error_mm': error.position_m * 1e3, 'error_mrad': error.rotation_rad * 1e3,
            'nominal_error_mm': error.nominal_position_m * 1e3,
            'nominal_error_mrad': error.nominal_rotation_rad * 1e3}


def run_report(args) -> int:
    """`cobot-calib report TRIAL...`: PNG box plot and the paper's table for stored trials."""
    data_dir = paths.data_dir(args.data_dir)
    try:
        png, table_file, table = report.write_report(store.open(data_dir, args.db,
                                                                args.cell).trials, args.trials,
                                                     _report_dir(args, data_dir))
    except ValueError as e:
        print(f'report failed: {e}', file=sys.stderr)
        return 1
    print(f'{table}\nfigure: {png}\ntable:  {table_file}')
    return 0


def _report_dir(args, data_dir: Path) -> Path:
    """--out, else <data dir>/reports."""
    return Path(args.out) if args.out else data_dir / 'reports'
