"""Real data from three labs, identified held out (issue 17 must-show 1), beside the anchors.

`cobot-calib identify --measurement` on the data in test/data (each folder's README: origin,
licence), with the CLI's defaults (soft-L1 loss; error model full for a URDF, mdh for a DH
table):

- FIGAROH's UR10e, 23 camera-on-board poses, 5-fold (anchor, an independent implementation:
  position 4.49 -> 4.33 mm, rotation 10.0 -> 7.7 mrad; goal <= 4.3 mm and <= 7.7 mrad);
- MUKCa's iiwa 14 sphere sockets, leave one location out (anchor 0.778 -> 0.233 mm MAE; this
  project's sphere path 0.240; goal <= 0.20 mm), with the model full+compliance (a joint
  deflection in proportion to its gravity torque; ``mukca_geometric_*``: full alone);
- industrial_calibration's two-axis positioner, 205 poses, DH, 5-fold (anchor 0.465 -> 0.413
  mm, 0.932 -> 0.922 mrad; goal <= 0.41 mm), its sidecar's rotation_weight auto (position and
  rotation each by its own scatter on the training rows).

``_nominal``: the same held-out rows predicted by the nominal model with the measurement's own
frames fitted on the training rows.
"""
from __future__ import annotations

import benchlib
from benchlib import Figures
from cobot_calib_ros.api.identification import identify_source

DATA = benchlib.REPO_ROOT / 'test' / 'data'
UR10E = DATA / 'figaroh-ur10e'
MUKCA = DATA / 'mukca-kuka-iiwa14'
POSITIONER = DATA / 'industrial-calibration-positioner'


def ur10e() -> dict:
    return identify_source(UR10E / 'calibration.csv', measurement='pose',
                           urdf=str(UR10E / 'robot.urdf'), folds=5)


def mukca(model: str = 'full+compliance') -> dict:
    return identify_source(MUKCA / 'kuka_14', measurement='spheres',
                           urdf=str(MUKCA / 'iiwa14.urdf'), base_link='base_link',
                           tip_link='tool0', leave_out='location',
                           model=model)


def positioner() -> dict:
    return identify_source(POSITIONER / 'measurements.csv', measurement='pose',
                           dh=str(POSITIONER / 'positioner_dh.yaml'), folds=5)


def _pair(figures: Figures, name: str, report: dict, key: str, unit: str) -> None:
    for which, suffix in (('calibrated', ''), ('nominal', '_nominal')):
        figures[f'{name}{suffix}'] = (report['held_out'][which][key], unit)


def run() -> Figures:
    figures: Figures = {}
    report = ur10e()
    _pair(figures, 'ur10e_held_out_position_rmse_mm', report, 'rmse_mm', 'mm')
    _pair(figures, 'ur10e_held_out_rotation_rms_mrad', report, 'rot_rms_mrad', 'mrad')
    _pair(figures, 'mukca_held_out_mae_mm', mukca(), 'mean_mm', 'mm')
    figures['mukca_geometric_held_out_mae_mm'] = (
        mukca('full')['held_out']['calibrated']['mean_mm'], 'mm')
    report = positioner()
    _pair(figures, 'positioner_held_out_position_rmse_mm', report, 'rmse_mm', 'mm')
    _pair(figures, 'positioner_held_out_rotation_rms_mrad', report, 'rot_rms_mrad', 'mrad')
    return figures


if __name__ == '__main__':
    for key, (value, unit) in run().items():
        print(benchlib.format_figure(key, value, unit))
