"""Real data from three labs, identified held out (issue 17), against the anchors of an
independent implementation on the same rows: FIGAROH's UR10e camera poses (5-fold), MUKCa's
iiwa 14 sphere sockets (leave one location out), industrial_calibration's two-axis positioner
(5-fold, DH). The same calls as `make bench` (bench/bench_real_data.py) and `cobot-calib
identify --measurement`, with the CLI's defaults (soft-L1 loss).

No figure of an earlier run is pinned (issue 39 item 5). Each held-out figure is bounded by
what does not depend on this code:
- the nominal arm's error (its frames fitted on the training rows) is the other tool's on the
  same rows within FOLDS (the tools split the folds differently, and the anchors' loss is
  linear: the UR10e's nominal is 4.49 mm linear, 4.528 mm soft-L1);
- the calibrated error is no worse than the other tool's calibrated one (within FOLDS) and
  below the nominal;
- it is not below the fit's own residual on its training rows: a model does not predict rows
  it never saw better than the rows it was fitted to (the noise floor the data show).
"""
from __future__ import annotations

from pathlib import Path

import pytest

from cobot_calib_ros.api.identification import identify_source

DATA = Path(__file__).resolve().parent / 'data'
UR10E = DATA / 'figaroh-ur10e'
MUKCA = DATA / 'mukca-kuka-iiwa14'
POSITIONER = DATA / 'industrial-calibration-positioner'
FOLDS = 0.02             # the relative allowance between two tools' fold partitions
# the independent implementations' held-out figures on the same rows: (nominal, calibrated)
UR10E_ANCHOR_MM, UR10E_ANCHOR_MRAD = (4.49, 4.33), (10.0, 7.7)         # FIGAROH
MUKCA_ANCHOR_MM = (0.704, 0.233)   # MUKCa's README: ball offset alone 0.704 (all rows); MAE
POSITIONER_ANCHOR_MM, POSITIONER_ANCHOR_MRAD = (0.465, 0.413), (0.932, 0.922)


def held_out(report: dict, which: str, key: str) -> float:
    return report['held_out'][which][key]


def within_anchors(report: dict, key: str, anchor: tuple[float, float]) -> None:
    """The nominal and calibrated held-out ``key`` against the other tool's (module doc)."""
    nominal, calibrated = held_out(report, 'nominal', key), held_out(report, 'calibrated', key)
    assert nominal == pytest.approx(anchor[0], rel=FOLDS), (key, nominal, anchor)
    assert calibrated <= anchor[1] * (1 + FOLDS), (key, calibrated, anchor)
    assert report['training'][key] <= calibrated < nominal, (key, report['training'][key])


@pytest.fixture(scope='module')
def mukca_geometric() -> dict:
    return identify_source(MUKCA / 'kuka_14', measurement='spheres',
                           urdf=str(MUKCA / 'iiwa14.urdf'), base_link='base_link',
                           tip_link='tool0', leave_out='location')


def test_ur10e_camera_poses_five_fold():
    """Anchor 4.49 -> 4.33 mm, 10.0 -> 7.7 mrad; goal <= 4.3 mm and <= 7.7 mrad."""
    r = identify_source(UR10E / 'calibration.csv', measurement='pose',
                        urdf=str(UR10E / 'robot.urdf'), folds=5)
    assert r['parameters_kept'] == r['parameters_minimum'] == 30
    within_anchors(r, 'rmse_mm', UR10E_ANCHOR_MM)
    within_anchors(r, 'rot_rms_mrad', UR10E_ANCHOR_MRAD)
    assert held_out(r, 'calibrated', 'rmse_mm') <= 4.3
    assert held_out(r, 'calibrated', 'rot_rms_mrad') <= 7.7


def test_mukca_iiwa14_leave_one_location_out(mukca_geometric):
    """Anchor 0.778 -> 0.233 mm MAE (0.704 with the ball offset fitted alone); goal <= 0.20
    mm: missed (MUKCa removes outliers before it evaluates; this does not)."""
    r = mukca_geometric
    assert [f['held_out'] for f in r['folds']] == ['front', 'left_back', 'raised_left']
    within_anchors(r, 'mean_mm', MUKCA_ANCHOR_MM)
    assert all(f['calibrated']['mean_mm'] < f['nominal']['mean_mm'] for f in r['folds'])


def test_mukca_iiwa14_with_joint_compliance_leave_one_location_out(mukca_geometric):
    """Issue 28 item 7: a joint compliance per revolute joint (full+compliance: a deflection
    in proportion to the joint's gravity torque) explains what the geometric model leaves:
    held out it beats the geometric model at every location, most at the raised one (where
    the arm's pose, hence its gravity torques, differ most from the other two), and meets the
    goal <= 0.20 mm. The first and last axes carry no gravity torque here (a1 vertical, the
    ball on a7's axis): their compliances are dropped.
    a5's the data do not determine (+- 3.4 mrad/(N m) against the 1 mrad/(N m) yardstick):
    held at nominal (0) with its reason (issue 37)."""
    r = identify_source(MUKCA / 'kuka_14', measurement='spheres',
                        urdf=str(MUKCA / 'iiwa14.urdf'), base_link='base_link',
                        tip_link='tool0', leave_out='location',
                        model='full+compliance')
    assert r['verdict']['passed'] and r['converged']
    assert held_out(r, 'nominal', 'mean_mm') == held_out(mukca_geometric, 'nominal', 'mean_mm')
    assert r['training']['mean_mm'] <= held_out(r, 'calibrated', 'mean_mm') <= 0.20
    gains = {f['held_out']: g['calibrated']['mean_mm'] - f['calibrated']['mean_mm']
             for f, g in zip(r['folds'], mukca_geometric['folds'])}
    assert min(gains.values()) > 0, gains
    assert max(gains, key=gains.get) == 'raised_left', gains
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
    within_anchors(r, 'rmse_mm', POSITIONER_ANCHOR_MM)
    within_anchors(r, 'rot_rms_mrad', POSITIONER_ANCHOR_MRAD)
    assert held_out(r, 'calibrated', 'rmse_mm') <= 0.41
    assert r['rotation_weight'] == pytest.approx(0.497, abs=5e-3)
