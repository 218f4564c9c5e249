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
import os
from pathlib import Path
import sys
import tempfile

from cobot_calib_ros.api import launcher
from cobot_calib_ros.api.demo import attached, copy_kinematics, DemoClient, run_demo
from cobot_calib_ros.cli.common import say
from cobot_calib_ros.core import user_frame
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file, data_dir, DEFAULT_CELL
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.database import DB_ENV
from cobot_calib_ros.store.kinematics import NOMINAL


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
        with _without_env(DB_ENV):
            if args.kinematics != NOMINAL:
                copy_kinematics(_results_cell(args.cell), data_dir(''), tmp)
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
    name = args.cell
    if root is None:
        name, root = attached(args.cell, client.node)
    return run_demo(client, load_cell(cell_file(name)), root, args.kinematics,
                    identify_configs=args.identify_configs, say=lambda text: say(args, text))


def run(args) -> int:
    from cobot_calib_ros.cli.common import cell_problem, EXIT_USAGE, fail
    from cobot_calib_ros.ros.calls import CallError
    if not args.attach and args.cell is None:
        args.cell = DEFAULT_CELL
    problem = cell_problem(args.cell) if args.cell else None
    if problem is not None:
        return fail(f'demo: {problem.message}', EXIT_USAGE)
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
