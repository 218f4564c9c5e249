"""Where an identification goes (api.identification): stored and made active in a repository,
written back as the given URDF and a UR arm's kinematics YAML (store.kinematics), whatever its
source; and the validation figures every report carries as numbers."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def ur_path(urdf_path: str) -> dict:
    """{'ur_kinematics_path': ...} when the suite wrote a UR kinematics YAML beside the
    calibrated URDF (store.kinematics.SUFFIXES), else {}."""
    if not urdf_path.endswith('.urdf'):
        return {}
    ur = Path(urdf_path[:-len('.urdf')] + '.ur_kinematics.yaml')
    return {'ur_kinematics_path': str(ur)} if ur.is_file() else {}


def cell_urdf(cell: str, base_link: str | None, tip_link: str | None
              ) -> tuple[str | None, str | None, str | None]:
    """(urdf, base_link, tip_link) of a cell whose robot is a URDF chain (the measurement
    file's arm when no --urdf is given); (None, ...) for a built-in robot."""
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.paths import cell_file
    path = cell_file(cell)
    robot = load_cell(path).urdf_robot
    if robot is None or robot.model:
        return None, base_link, tip_link
    urdf = Path(robot.urdf_file).expanduser()
    return (str(urdf if urdf.is_absolute() else path.parent / urdf),
            base_link or robot.base_link, tip_link or robot.tip_link)


def measurement_scope(cell: str | None, model):
    """The results cell a measurement file's result is stored under: ``cell``'s (a name or
    path; its robot must be the file's arm), else the arm's own (its model name)."""
    from cobot_calib_ros.store.cells import ResultsCell
    if not cell:
        return ResultsCell(model.name, model.name)
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.paths import cell_file
    loaded = load_cell(cell_file(cell))
    if loaded.robot != model.name:
        raise ValueError(f'--cell {cell}: its robot is {loaded.robot!r}, the measurement\'s '
                         f'arm is {model.name!r} (--urdf); give the cell of this arm, or no '
                         f'--cell (stored under the arm, {model.name!r})')
    return ResultsCell.of(loaded)


def store_measurements(source, report: dict, scope, data_dir, db) -> dict:
    """Store a measurement file's passing result and make it active (api.identification.
    identify_source); the report's storage keys."""
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.core.kinematics.identification import measurement_fit as mf
    from cobot_calib_ros.core.kinematics.identification.writeback import model_parameters
    from cobot_calib_ros.store.records import KinematicRecord
    if not report['verdict']['passed']:
        return {'stored': False, 'not_stored': 'refused by its gate: nothing stored'}
    if source.description is not None:
        from cobot_calib_ros.core.kinematics import model_for
        used = model_for(source.description)       # the model filter, move, the nodes build
        if not np.allclose(used.nominal, source.model.nominal, rtol=0.0, atol=1e-12):
            return {'stored': False, 'not_stored': (
                f'not stored: {source.description.urdf_file} has a joint frame pitched near '
                '90 deg, which identification turns (free pitch) and the cell\'s model does '
                'not: their parameters differ; use the result printed here')}
    errors = mf.ErrorModel(source.model, report['model'])
    try:
        params = model_parameters(errors, [p['name'] for p in report['identified']],
                                  [p['value'] for p in report['identified']])
    except ValueError as e:
        return {'stored': False, 'not_stored': f'not stored: {e}'}
    typed = KinematicRecord.from_report(report, source.model, params, unseen=report['unseen'])
    repo = store.open(paths.data_dir(data_dir), db, scope)
    saved = repo.kinematics.save_record(typed, source.model, description=source.description)
    return saved_keys(saved)


def saved_keys(saved) -> dict:
    """The report keys of a store.kinematics.SavedKinematics."""
    out = {'stored': True, 'calibration_id': saved.record.id,
           'record_path': str(saved.paths['json']), 'yaml_path': str(saved.paths['yaml']),
           'urdf_path': str(saved.paths['urdf']),
           'active': bool(saved.activation) if saved.activation is not None else False}
    if 'ur_kinematics' in saved.paths:
        out['ur_kinematics_path'] = str(saved.paths['ur_kinematics'])
    return out


def validation_figures(report: dict) -> dict:
    """``report`` with ``validation_max_mm``: region ('held_out', 'volume', 'workspace') ->
    {'nominal', 'calibrated'} max error [mm], the figures a gate compares, as numbers."""
    figures = {region: {k: rows[k]['max_mm'] for k in ('nominal', 'calibrated')}
               for region, rows in report.get('tracker', {}).items()}
    if report.get('held_out'):
        figures['held_out'] = {k: report['held_out'][k]['max_mm']
                               for k in ('nominal', 'calibrated')}
    report['validation_max_mm'] = figures
    return report


def store_open(cell, data_dir: str | None = None, db: str | None = None):
    """The repository a bag's or a collection's result of ``cell`` is stored in, as the node
    stores it (``data_dir``: paths.data_dir; ``db``: a database instead)."""
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.store.cells import ResultsCell
    return store.open(paths.data_dir(data_dir), db, ResultsCell.of(cell))
