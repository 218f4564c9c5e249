"""Real data from three labs, identified held out (issue 17), against the anchors of an
independent implementation: FIGAROH's UR10e camera poses (5-fold), MUKCa's iiwa 14 sphere
sockets (leave one location out), industrial_calibration's two-axis positioner (5-fold, DH).
The same calls as `make bench` (bench/bench_real_data.py) and `cobot-calib identify
--measurement`, with the CLI's defaults (soft-L1 loss)."""
from __future__ import annotations

from pathlib import Path

import pytest

from cobot_calib_ros.api.identification import identify_source

DATA = Path(__file__).resolve().parent / 'data'
UR10E = DATA / 'figaroh-ur10e'
MUKCA = DATA / 'mukca-kuka-iiwa14'
POSITIONER = DATA / 'industrial-calibration-positioner'
# measured held-out figures (make bench prints them)
UR10E_NOMINAL_MM, UR10E_MM = 4.528, 3.956          # 4.156 before issue 37's prior
UR10E_NOMINAL_MRAD, UR10E_MRAD = 9.933, 7.541      # 7.608 before
MUKCA_NOMINAL_MM, MUKCA_MM = 0.705, 0.232
MUKCA_COMPLIANCE_MM = 0.136            # per location 0.090, 0.080, 0.249
POSITIONER_NOMINAL_MM, POSITIONER_MM, POSITIONER_MRAD = 0.460, 0.410, 0.927


def held_out(report: dict, which: str, key: str) -> float:
    return report['held_out'][which][key]


def test_ur10e_camera_poses_five_fold():
    """Anchor 4.49 -> 4.33 mm, 10.0 -> 7.7 mrad; goal <= 4.3 mm and <= 7.7 mrad."""
    r = identify_source(UR10E / 'calibration.csv', measurement='pose',
                        urdf=str(UR10E / 'robot.urdf'), folds=5)
    assert r['parameters_kept'] == r['parameters_minimum'] == 30
    assert held_out(r, 'nominal', 'rmse_mm') == pytest.approx(UR10E_NOMINAL_MM, abs=5e-3)
    assert held_out(r, 'nominal', 'rot_rms_mrad') == pytest.approx(UR10E_NOMINAL_MRAD, abs=5e-3)
    assert held_out(r, 'calibrated', 'rmse_mm') == pytest.approx(UR10E_MM, abs=5e-3)
    assert held_out(r, 'calibrated', 'rot_rms_mrad') == pytest.approx(UR10E_MRAD, abs=5e-3)
    assert held_out(r, 'calibrated', 'rmse_mm') <= 4.3
    assert held_out(r, 'calibrated', 'rot_rms_mrad') <= 7.7


def test_mukca_iiwa14_leave_one_location_out():
    """Anchor 0.778 -> 0.233 mm MAE (this project's sphere path 0.240); goal <= 0.20 mm:
    missed (MUKCa removes outliers before it evaluates; this does not)."""
    r = identify_source(MUKCA / 'kuka_14', measurement='spheres',
                        urdf=str(MUKCA / 'iiwa14.urdf'), base_link='base_link',
                        tip_link='tool0', leave_out='location')
    assert [f['held_out'] for f in r['folds']] == ['front', 'left_back', 'raised_left']
    assert held_out(r, 'nominal', 'mean_mm') == pytest.approx(MUKCA_NOMINAL_MM, abs=2e-3)
    assert held_out(r, 'calibrated', 'mean_mm') == pytest.approx(MUKCA_MM, abs=2e-3)


def test_mukca_iiwa14_with_joint_compliance_leave_one_location_out():
    """Issue 28 item 7: the geometric model leaves 0.407 mm at the raised location; a joint
    compliance per revolute joint (full+compliance: a deflection in proportion to the joint's
    gravity torque) brings the held-out MAE to 0.136 mm (goal <= 0.20 mm: met), the raised
    location to 0.249 mm. The first and last axes carry no gravity torque here (a1 vertical,
    the ball on a7's axis): their compliances are dropped; a5's the data do not determine
    (+- 3.4 mrad/(N m) against the 1 mrad/(N m) yardstick): held at nominal (0) with its
    reason (issue 37; 0.1360 mm with it, 0.1358 without)."""
    r = identify_source(MUKCA / 'kuka_14', measurement='spheres',
                        urdf=str(MUKCA / 'iiwa14.urdf'), base_link='base_link',
                        tip_link='tool0', leave_out='location',
                        model='full+compliance')
    assert r['verdict']['passed'] and r['converged']
    assert held_out(r, 'nominal', 'mean_mm') == pytest.approx(MUKCA_NOMINAL_MM, abs=2e-3)
    assert held_out(r, 'calibrated', 'mean_mm') == pytest.approx(MUKCA_COMPLIANCE_MM, abs=2e-3)
    assert held_out(r, 'calibrated', 'mean_mm') <= 0.20
    assert [round(f['calibrated']['mean_mm'], 3) for f in r['folds']] == \
        pytest.approx([0.090, 0.080, 0.249], abs=2e-3)
    springs = {p['name'] for p in r['identified'] if p['name'].startswith('compliance_')}
    assert springs == {f'compliance_joint_a{i}' for i in (2, 3, 4, 6)}
    assert [h['name'] for h in r['held']] == ['compliance_joint_a5']


def test_two_axis_positioner_dh_five_fold():
    """Anchor 0.465 -> 0.413 mm, 0.932 -> 0.922 mrad; goal <= 0.41 mm with the DH model
    calibrated. The sidecar's rotation_weight is auto (issue 28 item 7): rotation counts
    against position by the ratio of their scatter under the nominal model on each fold's
    training rows (~0.5 m/rad; at 1 m/rad: 0.465 -> 0.414 mm, 0.924 mrad). 0.40999 mm: at the
    goal, with no margin to speak of."""
    r = identify_source(POSITIONER / 'measurements.csv', measurement='pose',
                        dh=str(POSITIONER / 'positioner_dh.yaml'), folds=5)
    assert r['model'] == 'mdh' and {p['name'] for p in r['identified']} == {'alpha_2', 'a_2'}
    assert r['parameters_kept'] == r['parameters_minimum'] == 14
    assert held_out(r, 'nominal', 'rmse_mm') == pytest.approx(POSITIONER_NOMINAL_MM, abs=2e-3)
    assert held_out(r, 'calibrated', 'rmse_mm') == pytest.approx(POSITIONER_MM, abs=2e-3)
    assert held_out(r, 'calibrated', 'rot_rms_mrad') == pytest.approx(POSITIONER_MRAD, abs=2e-3)
    assert held_out(r, 'calibrated', 'rmse_mm') <= 0.41
    assert r['rotation_weight'] == pytest.approx(0.497, abs=5e-3)
