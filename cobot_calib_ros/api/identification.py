"""Kinematic identification through the suite: collect on the robot, identify, validate.

Used by ``cobot-calib identify`` and ``cobot-calib demo --kinematics``. On the suite
(:func:`identify_on_suite`): one rclpy node with action clients for ``collect_sphere_data`` and
``identify_kinematics``. Offline, :func:`identify_source` is the one call for a measurement
file, a MUKCa folder, a recorded session (bag) or a collection folder (loaders.sources
recognises which): the CLI, bench and tests call it. Both give the same report shape.
"""
from __future__ import annotations

import os
from pathlib import Path
import time
from typing import Callable

import numpy as np

from cobot_calib_ros.api.identification_store import (cell_urdf, measurement_scope,
                                                      saved_keys, store_measurements, store_open,
                                                      ur_path, validation_figures)
from cobot_calib_ros.core.errors import Refusal
from cobot_calib_ros.core.kinematics.identification.gates import (MAX_DEVIATION_M,
                                                                   MAX_DEVIATION_RAD)

PAPER_RATIO_PERCENT = 41.6     # the paper's max error, calibrated / nominal (0.990 / 2.381 mm)
DEFAULT_FOLDS = 5


class IdentificationFailed(RuntimeError):
    """A collection or identification that did not succeed; the message says why.
    ``collection_id``: the sphere collection to resume, when it failed while collecting."""

    def __init__(self, message: str, collection_id: str = '') -> None:
        super().__init__(message)
        self.collection_id = collection_id


class IdentifyClient:
    """Action calls of an identification on one rclpy node: ``node`` if given, else one of its
    own (a ros.session, ended by close())."""

    def __init__(self, node=None) -> None:
        from cobot_calib_ros.ros.action_client import ActionClient
        from cobot_calib_msgs.action import CollectSphereData, IdentifyKinematics
        from cobot_calib_ros.ros.session import session
        self._session = session('cobot_calib_identify') if node is None else None
        if self._session is not None:
            node, _ = self._session.__enter__()
        self.node = node
        self.Collect, self.Identify = CollectSphereData, IdentifyKinematics
        self.collect = ActionClient(node, CollectSphereData, 'collect_sphere_data')
        self.identify = ActionClient(node, IdentifyKinematics, 'identify_kinematics')

    def close(self) -> None:
        self.collect.destroy()
        self.identify.destroy()
        if self._session is not None:
            self._session.__exit__(None, None, None)


# [s] for kinematic_identifier's actions to be discovered (a running suite's: < 2 s)
SUITE_WAIT = 5.0


def _refuse_without_identifier(client: IdentifyClient) -> None:
    """CallError when kinematic_identifier's actions are not on the graph: within SUITE_WAIT
    on an empty domain (no suite: the flows' own wait would take a minute to say less), within
    DISCOVERY_WAIT when other nodes are there (spin.absent_after)."""
    from cobot_calib_ros.ros.calls import CallError
    from cobot_calib_ros.ros.spin import absent_after, DISCOVERY_WAIT, others_on_graph
    absent = absent_after({'collect_sphere_data': client.collect.server_is_ready,
                           'identify_kinematics': client.identify.server_is_ready}, SUITE_WAIT,
                          client.node)
    if not absent:
        return
    domain = os.environ.get('ROS_DOMAIN_ID', '0')
    if 'kinematic_identifier' in client.node.get_node_names():
        raise CallError(f'{" and ".join(absent)} not on the graph after {DISCOVERY_WAIT:.0f} s, '
                        'though kinematic_identifier is: is it still starting? See its log')
    waited = DISCOVERY_WAIT if others_on_graph(client.node) else SUITE_WAIT
    raise CallError(f'{" and ".join(absent)} not on the graph after {waited:.0f} s: no '
                    f'kinematic_identifier on ROS_DOMAIN_ID={domain}; start the suite with '
                    f'cobot-calib up (same ROS_DOMAIN_ID)')


class CollectionStopped(KeyboardInterrupt):
    """Ctrl-C during a collection: its goal was cancelled. The sphere collection
    ``collection_id`` is stored up to its last pose and resumes with that id."""

    def __init__(self, collection_id: str, message: str) -> None:
        super().__init__(message)
        self.collection_id, self.message = collection_id, message


def identify_on_suite(client: IdentifyClient, *, say: Callable[[str], None],
                      source: str = 'mock', solver: str = 'lm', loss: str = 'soft_l1',
                      max_configs: int = 0, hold: float = 0.05,
                      validation_configs: int = 125, dry_run: bool = False,
                      resume: str = '', collected: bool = False, planned: bool = False,
                      max_poses: int = 0, target_mm: float = 0.0,
                      min_gain: float = 0.0) -> dict:
    """Collect (source 'mock') or take a collection folder, identify; the report (mm).

    ``planned``: the sphere poses are planned (collect_sphere_data's planned mode: up to
    ``max_poses``, stopping at the predicted max error ``target_mm`` or below ``min_gain``).

    ``resume``: the id of a sphere collection to carry on from its first pose without a row
    (``collected``: it is complete, go on with the validation sets). The sphere collection's
    id is chosen here, so a Ctrl-C (CollectionStopped) or a node that dies (IdentificationFailed)
    can always say which collection to resume."""
    from cobot_calib_ros.api.client import wait_for_suite
    from cobot_calib_ros.ros.calls import CallError, run_action
    from cobot_calib_ros.ros.types import to_dict
    from cobot_calib_ros.core.ids import record_id
    _refuse_without_identifier(client)
    wait_for_suite(client.node)
    collections, collect_seconds = {}, {}
    if source == 'mock':
        spheres = resume or record_id('spheres')
        jobs = [] if collected else [('spheres', 'spheres', '', max_configs, spheres)]
        if validation_configs:
            jobs += [(region, 'laser_tracker', region, validation_configs,
                      record_id(f'tracker-{region}')) for region in ('volume', 'workspace')]
        for key, kind, region, count, collection_id in jobs:
            say(f'{"resuming" if collection_id == resume else "collecting"} {key} ({kind}'
                f'{" " + region if region else ""}) {collection_id} ...')
            start = time.perf_counter()
            goal = client.Collect.Goal(collection_id=collection_id, source=kind, region=region,
                                       max_configs=count, hold=hold,
                                       seed=1 if region == 'workspace' else 0)
            if key == 'spheres' and planned:
                goal.planned, goal.max_poses = True, max_poses
                goal.target_error, goal.min_gain = target_mm * 1e-3, min_gain
            result = _collect(client, goal, say, spheres)
            collect_seconds[key] = time.perf_counter() - start
            collections[key] = {'id': result.collection_id, 'recorded': result.recorded,
                                'skipped': result.skipped, 'path': result.path,
                                'robot_s': result.robot_time,
                                'robot_s_at_paper_hold': result.robot_time_at_paper_hold}
            if result.stop_reason:
                collections[key].update(stop_reason=result.stop_reason,
                                        predicted_max_mm=result.predicted_max_error * 1e3)
            say(f'  {result.message} in {collect_seconds[key]:.1f} s')
        collections.setdefault('spheres', {'id': spheres})
    say(f'identifying ({solver}) ...')
    goal = client.Identify.Goal(
        collection_id=collections.get('spheres', {}).get('id', ''),
        file='' if source == 'mock' else str(Path(source).resolve()),
        solver=solver, loss=loss, max_configs=max_configs,
        validation_volume=collections.get('volume', {}).get('id', ''),
        validation_workspace=collections.get('workspace', {}).get('id', ''),
        dry_run=dry_run)
    try:
        _, result = run_action(client.node, client.identify, goal, 3600.0)
    except CallError as e:
        raise IdentificationFailed(f'identify_kinematics: {e}') from None
    if result.error_code != 0:
        raise IdentificationFailed(f'identify_kinematics failed: {result.message}')
    data = to_dict(result)
    tracker = {region: _stats_pair(data[f'{prefix}_nominal'], data[f'{prefix}_calibrated'])
               for region, prefix in (('volume', 'validation'), ('workspace', 'workspace'))}
    return validation_figures({
        'source': source, 'source_kind': 'suite', 'calibration_id': result.calibration_id,
        'stored': bool(result.calibration_id),
        'message': result.message, 'verdict': {'passed': True, 'problems': []},
        'converged': True,          # the node answers an error for anything its gates refuse
        'identified': [{'name': n, 'value': v, 'nominal': n0, 'delta': v - n0, 'std': s}
                       for n, v, n0, s in zip(result.parameter_names, result.values,
                                              result.nominal_values, result.std)],
        'dropped': [{'name': n, 'reason': r} for n, r in zip(result.dropped_parameters,
                                                             result.dropped_reasons)],
        'tracker': {region: table for region, table in tracker.items() if table},
        'rms_mm': result.rms * 1e3, 'iterations': result.iterations,
        'solve_seconds': result.solve_seconds, 'collections': collections,
        'collect_seconds': collect_seconds, 'yaml_path': result.yaml_path,
        'urdf_path': result.urdf_path, **ur_path(result.urdf_path),
        'paper_ratio_percent': PAPER_RATIO_PERCENT})




def resumable(given: str, cell: str) -> tuple[str, bool]:
    """(collection id, complete?) for --resume [ID]: the given id, else the newest unfinished
    sphere collection of the cell (its robot, and its name where stored) in the data dir
    ($COBOT_CALIB_DATA, the suite's default). An id not in this data dir is sent as it is
    (an attached suite may store elsewhere). ValueError when there is nothing to resume."""
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.store.cells import ResultsCell
    from cobot_calib_ros.store.files import check_id
    collections = store.open(paths.data_dir('')).collections
    if given:
        stored = collections.load(check_id(given))
        return given, stored is not None and stored.meta['status'] == 'done'
    results_cell = ResultsCell.of(load_cell(paths.cell_file(cell)))
    robot = results_cell.robot
    for meta in collections.list_collections():     # the suite's cell's own, as it resumes
        if meta['source'] == 'spheres' and meta['status'] != 'done' and \
                results_cell.problem(meta.get('cell', ''), meta.get('robot', '')) is None:
            return meta['id'], False
    raise ValueError(f'no unfinished {robot} sphere collection in {collections.directory}; give '
                     'its id (--resume ID)')


def _collect(client: IdentifyClient, goal, say, spheres: str):
    """One collect_sphere_data goal to its end; its result. Ctrl-C cancels it
    (CollectionStopped), a failure or a node that is gone raises IdentificationFailed."""
    from cobot_calib_ros.ros.calls import CallError, Interrupted, run_action
    what = f'collect_sphere_data ({goal.source} {goal.collection_id})'
    from action_msgs.msg import GoalStatus
    try:
        status, result = run_action(client.node, client.collect, goal, 3600.0,
                                    feedback=_progress(say))
    except Interrupted as e:
        raise CollectionStopped(spheres, e.message) from None
    except CallError as e:
        raise IdentificationFailed(f'{what}: {e}', spheres) from None
    if result.error_code != 0 or status != GoalStatus.STATUS_SUCCEEDED:
        why = result.message or 'the node ended the goal without a result (see its log)'
        refused = result.error_code == client.Collect.Result.INVALID_GOAL   # nothing stored
        raise IdentificationFailed(f'{what} failed: {why}', '' if refused else spheres)
    return result


def _stats_pair(nominal: dict, calibrated: dict) -> dict:
    """Table 5 rows in mm from ErrorStats messages [m]; empty when not validated."""
    if not nominal['count']:
        return {}
    return _ratio({key: {f'{k}_mm': stats[k] * 1e3 for k in ('mean', 'std', 'min', 'max')}
                   | {'count': stats['count']} for key, stats in (('nominal', nominal),
                                                                   ('calibrated', calibrated))})


def _progress(say):
    last = [0.0]

    def on_feedback(message) -> None:
        fb = message.feedback
        now = time.monotonic()
        if now - last[0] > 5.0 or fb.index + 1 == fb.total or fb.predicted_max_error:
            last[0] = now
            predicted = (f', predicted max error {fb.predicted_max_error * 1e3:.4f} mm (RMS '
                         f'{fb.predicted_rms_error * 1e3:.4f} mm)'
                         if fb.predicted_max_error else '')
            say(f'  pose {fb.index + 1}/{fb.total} ({fb.target}): {fb.recorded} '
                f'recorded, {fb.skipped} skipped, robot time {fb.robot_time:.1f} s{predicted}')
    return on_feedback


def identify_source(path: str | Path, *, cell: str | None = None,
                    measurement: str | None = None, urdf: str | None = None,
                    base_link: str | None = None, tip_link: str | None = None,
                    dh: str | None = None, model: str | None = None,
                    folds: int | None = None, leave_out: str | None = None,
                    ball=(0.0, 0.0, 0.04), solver: str = 'lm', loss: str = 'soft_l1',
                    max_configs: int = 0,
                    max_deviation: tuple[float, float] = (MAX_DEVIATION_M, MAX_DEVIATION_RAD),
                    store: bool = False, data_dir: str | None = None,
                    db: str | None = None) -> dict:
    """Identify a source offline (loaders.sources: a measurement file, a MUKCa folder, a bag or
    a collection folder) through the one engine; the report (JSON-ready, mm), the same shape
    for every source: ``source``, ``source_kind``, ``robot``, ``measurement``, ``rows``,
    ``verdict`` {passed, problems}, ``converged``, ``identified`` [{name, value, nominal,
    delta[, std]}] [m, rad], ``dropped`` [{name, reason}], ``bounds``, and the figures the
    source has: ``held_out`` (a measurement file, a MUKCa folder: every row predicted by a
    model identified without it, ``validation`` says how: k-fold or one group out), ``tracker``
    (a collection with laser-tracker sets beside it: region -> nominal / calibrated).

    A measurement file or MUKCa folder: its arm from ``urdf`` / ``dh`` (else the ``cell``'s
    URDF chain) (``measurement``, when
    given, must be the file's kind), error ``model``, held out by ``folds`` or ``leave_out``
    (default: a MUKCa folder one location at a time, else 5-fold); ``unseen`` names the
    parameters its measurement kind cannot see (core writeback). A bag or a collection: the
    ``cell``'s (a name or path) robot, identified by the node's own call
    (api.kinematics.identify: ``solver``, ``max_configs``).

    ``store``: a result that passes its gate is stored and made active in ``data_dir`` /
    ``db`` (paths.data_dir, store.open), whatever the source, as the node does: the record,
    the given URDF rewritten (a measurement file's ``urdf``, else the cell's) and a UR arm's
    kinematics YAML; ``calibration_id``, ``record_path``, ``yaml_path``, ``urdf_path`` (and
    ``ur_kinematics_path``) in the report, ``stored`` True; else ``stored`` False and
    ``not_stored`` says why. Scoped by ``cell`` when given (its robot must be the file's arm),
    else by the arm's model name (the URDF's file name). Every report has
    ``validation_max_mm`` (:func:`validation_figures`).

    ValueError (one line) for a path that is none of the sources, bad data or arguments;
    IdentificationFailed when a bag or collection holds nothing to identify; core.errors.
    Refusal (one line, REFUSED: ...) for data the gates refuse before the fit; BagError for an
    unreadable bag. A result the gates refuse after the fit comes back with its verdict."""
    from cobot_calib_ros.core.kinematics.identification.gates import DeviationBounds
    from cobot_calib_ros.loaders import sources
    path = Path(path).expanduser()
    kind = sources.recognise(path)
    bounds = DeviationBounds(*max_deviation)
    if kind in (sources.MEASUREMENT_FILE, sources.MUKCA):
        _only_for('a bag or a collection folder', kind,
                  ('--solver nelder-mead', solver != 'lm'), ('--max-configs', max_configs))
        if cell and not (urdf or dh):
            urdf, base_link, tip_link = cell_urdf(cell, base_link, tip_link)
        source = sources.load_source(path, urdf=urdf, base_link=base_link, tip_link=tip_link,
                                     dh=dh, ball=ball)
        scope = measurement_scope(cell, source.model) if store else None
        report = _identify_measurements(source, measurement, model, folds, leave_out, loss,
                                        bounds)
        if store:
            report.update(store_measurements(source, report, scope, data_dir, db))
        else:
            report.update(stored=False, not_stored='--no-store: a dry run')
        return validation_figures(report)
    _only_for('a measurement file or a MUKCa folder', kind, ('--measurement', measurement),
              ('--urdf', urdf), ('--dh', dh), ('--base-link', base_link),
              ('--tip-link', tip_link), ('--model', model), ('--folds', folds),
              ('--leave-out', leave_out))
    from cobot_calib_ros.api import kinematics
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.paths import cell_file
    if not cell:
        raise ValueError(f'{path}: a {kind} is identified on its cell: give --cell or --robot')
    from cobot_calib_ros.store.cells import ResultsCell
    from cobot_calib_ros.store.collections import CollectionStore
    try:
        source = sources.load_source(path, cell=load_cell(cell_file(cell)))
        # the tracker sets beside a collection, of its cell, as the node validates with
        validation = kinematics.validation_sets(
            CollectionStore.of_folder(path.parent.resolve()), source.cell,
            ResultsCell.of(source.cell), {'volume': '', 'workspace': ''}) \
            if kind == sources.COLLECTION else {}
    except (KeyError, ValueError, Refusal) as e:
        raise IdentificationFailed(_on_path(path, e)) from None
    repository = store_open(source.cell, data_dir, db) if store else None
    got = kinematics.identify(kinematics.JobSource(source, validation), kinematics.Settings(
        solver, loss, max_configs=max_configs, bounds=bounds),
        None if repository is None else repository.kinematics)
    outcome = got.outcome if isinstance(got, (kinematics.Identified, kinematics.GateRefused)) \
        else None
    if outcome is None:
        _raise(got, path)
    report = _job_report(source, outcome, bounds)
    if not store:
        report.update(stored=False, not_stored='--no-store: a dry run')
    elif not got:
        report.update(stored=False, not_stored='refused by its gate: nothing stored')
    else:
        report.update(saved_keys(got.saved))
    return validation_figures(report)


def _on_path(path: Path, error: Exception) -> str:
    message = str(error).strip("'")
    return message if str(path) in message else f'{path}: {message}'


def _raise(failure, path: Path):
    """A failure of api.kinematics.identify as the CLI's exceptions: the gates' refusal of
    the data as a Refusal, storage as OSError, anything else IdentificationFailed."""
    from cobot_calib_ros.core.errors import ErrorCode, Refusal
    if failure.code in (ErrorCode.INVALID_INPUT, ErrorCode.SOLVER_FAILED, ErrorCode.CANCELED):
        raise IdentificationFailed(_on_path(path, ValueError(failure.message)))
    if failure.code == ErrorCode.STORAGE_FAILED:
        raise OSError(failure.message)
    raise Refusal(failure)


def _only_for(where: str, kind: str, *given) -> None:
    """ValueError naming the options given that a ``kind`` source does not take."""
    named = [flag for flag, value in given if value]
    if named:
        raise ValueError(f'{", ".join(named)} apply to {where}, not a {kind}')


def _identify_measurements(source, measurement: str | None, model: str | None,
                           folds: int | None, leave_out: str | None, loss: str,
                           bounds) -> dict:
    """A measurement file or MUKCa folder identified held out (core measurement_fit.
    identify_measurements)."""
    from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
    from cobot_calib_ros.core.kinematics.identification.writeback import unseen
    file, robot = source.file, source.model
    if measurement and file.measurements.kind != measurement:
        raise ValueError(f'{file.source} holds {file.measurements.kind} measurements, not '
                         f'{measurement}: pass --measurement {file.measurements.kind}')
    errors = mf.ErrorModel(robot, model or ('mdh' if robot.kind == 'mdh' else 'full'))
    extra = [j for j in file.joints if j not in robot.joint_names]
    file = file.in_joint_order(robot.joint_names, robot.prismatic)
    if extra:
        raise ValueError(f'{file.source}: joint columns {extra} are not joints of the chain '
                         f'{robot.name} ({", ".join(robot.joint_names)}); give the --tip-link '
                         'whose chain has them, or leave them out of the sidecar\'s "joints"')
    leave_out = leave_out or (None if folds else _default_group(file))
    if leave_out:
        labels, held = mf.by_group(file.groups(leave_out))
        validation = {'leave_out': leave_out, 'groups': list(labels)}
    else:
        k = folds or DEFAULT_FOLDS
        held = mf.held_out_rows(file.sample, mf.kfold(file.samples, k))
        labels, validation = tuple(f'fold {i}' for i in range(k)), {'folds': k}
    report = mf.identify_measurements(errors, file.measurements, held, labels=labels,
                                      sample=file.sample, loss=loss, bounds=bounds,
                                      noise_m=file.noise_m)
    data = file.measurements
    on_tool = len(np.unique(data.target)) if data.kind == 'points' else \
        0 if data.kind == 'pose' else 1
    return {**source.provenance, 'validation': validation, **report,
            'unseen': unseen(robot, data.kind, on_tool, report['dropped'])}












def _default_group(file) -> str | None:
    """A MUKCa folder is held out by location (its tool placements)."""
    return 'location' if 'socket' in file.columns and 'location' in file.columns else None


def _job_report(source, outcome, bounds) -> dict:
    """The report of a bag's or a collection's CalibrationJob outcome."""
    from cobot_calib_ros.store.kinematics import outcome_unseen
    r = outcome.result
    return {**source.provenance, 'robot': outcome.model.name,
            'measurement': 'spheres' if r.extra['objective'] == 'relative' else 'points',
            'rows': outcome.inputs.rows, 'model': 'mdh' if outcome.model.kind == 'mdh'
            else 'full', 'solver': outcome.inputs.solver, 'loss': outcome.inputs.loss,
            'message': outcome.summary(), 'verdict': outcome.verdict.to_dict(),
            'bounds': {'length_mm': bounds.length_m * 1e3, 'angle_mrad': bounds.angle_rad * 1e3},
            'converged': r.converged,
            'identified': [{'name': n, 'value': float(v), 'nominal': float(v0),
                            'delta': float(v - v0), 'std': float(sd)} for n, v, v0, sd in
                           zip(r.free, outcome.free_values, outcome.nominal_values, r.std)],
            'dropped': [{'name': d.name, 'reason': d.reason}
                        for d in outcome.identifiability.dropped],
            'unseen': outcome_unseen(outcome),
            'tracker': {region: _ratio(_in_mm(t)) for region, t in outcome.validation.items()},
            'rms_mm': r.rms_m * 1e3, 'iterations': r.iterations,
            'solve_seconds': r.solve_seconds, 'calibration_id': '', 'table6': outcome.table}


def _in_mm(table: dict) -> dict:
    """A region's Table 5 rows from core (error_stats [m]) as the report's [mm]."""
    return {key: {'count': table[key]['count'], **{
        f'{k}_mm': table[key][f'{k}_m'] * 1e3 for k in ('mean', 'std', 'min', 'max')}}
        for key in ('nominal', 'calibrated')}


def _ratio(table: dict) -> dict:
    """A region's tracker statistics (mm) with the max error calibrated / nominal [%]."""
    rows = {key: table[key] for key in ('nominal', 'calibrated')}
    return rows | {'ratio_max_percent': 100.0 * rows['calibrated']['max_mm']
                   / rows['nominal']['max_mm']}

