"""Program filtering (issue 29 item 2, must-show 2): corrected targets that a controller's nominal
inverse kinematics turns into the calibrated model's joints; unreachable targets named."""
from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose
import pytest

from cobot_calib_ros.core.frames import from_pose, to_pose
from cobot_calib_ros.core.kinematics import fk, model_for
from cobot_calib_ros.core.kinematics.ik import solve_ik
from cobot_calib_ros.core.kinematics.program_filter import (columns, COLUMNS,
                                                            filter_targets, filtered_csv,
                                                            parse_targets, Target)
from cobot_calib_ros.core.vendor_frames import to_values
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.paths import cell_file

# UR10e (6 joints: one solution per branch, so the joints are the controller's too), a walk
# around home that stays off the elbow, wrist and shoulder singularities [rad]
SPAN = np.array([1.0, 0.5, 0.6, 1.0, 0.8, 1.5])


def ur10e():
    cell = load_cell(cell_file('ur10e_close'))
    model = model_for(cell)
    rng = np.random.default_rng(29)
    sign = rng.choice([-1.0, 1.0], model.nominal.size)
    lengths = np.array([n.split('_')[0] in 'xyz' for n in model.parameter_names])
    deviation = np.where(lengths, rng.uniform(1e-4, 5e-4, lengths.size),
                         rng.uniform(5e-4, 2e-3, lengths.size))
    calibrated = model.chain(model.nominal + sign * deviation, tool=cell.T_flange_tool)
    return cell, model.chain(tool=cell.T_flange_tool), calibrated


def program(home, rng, m) -> np.ndarray:
    """m joint vectors of a random walk (steps ~0.05 rad) reflected inside home +- SPAN."""
    q, out = home.copy(), []
    for _ in range(m):
        q = q + rng.normal(0, 0.05, q.size)
        q = np.where(q > home + SPAN, 2 * (home + SPAN) - q, q)
        q = np.where(q < home - SPAN, 2 * (home - SPAN) - q, q)
        out.append(q)
    return np.array(out)


def test_the_nominal_ik_of_the_corrected_targets_gives_the_calibrated_joints():
    cell, nominal, calibrated = ur10e()
    rng = np.random.default_rng(2)
    q_true = program(cell.home, rng, 1000)
    targets = [Target(f'p{k}', T) for k, T in enumerate(fk(calibrated, q_true))]
    far = [Target('far_away', from_pose([3.0, 0.0, 0.5], [0, 0, 0, 1])),
           Target('under_the_floor', from_pose([0.2, 0.1, -2.0], [1, 0, 0, 0]))]
    targets = targets[:500] + far[:1] + targets[500:] + far[1:]

    result = filter_targets(targets, calibrated, nominal, cell.home)
    assert [u.name for u in result.unreachable] == ['far_away', 'under_the_floor']
    assert result.unreachable[0].line() == (
        'target far_away: cannot be reached by the calibrated model (3.017 m from the first '
        'joint, 1.47 m beyond the arm\'s reach of 1.547 m with this tool)')
    assert [f.name for f in result.filtered] == [f'p{k}' for k in range(1000)]
    q_cal = np.array([f.q for f in result.filtered])
    assert_allclose(q_cal, q_true, rtol=0, atol=1e-6)     # the walk's own branch
    # the corrections are the calibration's: tenths of a millimetre to millimetres
    corrections = np.array([f.correction_m for f in result.filtered])
    assert 1e-4 < np.median(corrections) and corrections.max() < 2e-2

    worst = 0.0
    for f in result.filtered:
        seed = f.q + rng.normal(0, 0.02, f.q.size)
        solved = solve_ik(nominal, f.pose, seed)
        assert solved, f.name
        worst = max(worst, float(np.abs(solved.q - f.q).max()))
    assert worst <= 1e-6
    # and the calibrated arm at those joints puts the tool on the given target
    assert_allclose(fk(calibrated, q_cal), fk(calibrated, q_true), rtol=0, atol=1e-9)


def test_targets_in_a_user_frame_come_back_in_that_frame():
    cell, nominal, calibrated = ur10e()
    T_base_user = from_pose([0.4, -0.2, 0.05], [0.0, 0.0, np.sin(0.3), np.cos(0.3)])
    q = program(cell.home, np.random.default_rng(5), 20)
    in_user = np.linalg.inv(T_base_user) @ fk(calibrated, q)
    result = filter_targets([Target(f't{k}', T) for k, T in enumerate(in_user)], calibrated,
                            nominal, cell.home, T_base_user)
    assert not result.unreachable
    assert_allclose(np.array([f.q for f in result.filtered]), q, rtol=0, atol=1e-6)
    assert_allclose(T_base_user @ np.array([f.pose for f in result.filtered]), fk(nominal, q),
                    rtol=0, atol=1e-9)


def test_the_filtered_csv_reads_back_as_targets_with_the_joints_beside():
    cell, nominal, calibrated = ur10e()
    q = program(cell.home, np.random.default_rng(6), 5)
    text = ','.join(COLUMNS) + '\n' + ''.join(
        f'{n},' + ','.join(repr(float(v)) for v in (*to_pose(T)[0], *to_pose(T)[1])) + '\n'
        for n, T in zip('abcde', fk(calibrated, q)))
    targets = parse_targets(text)
    assert [t.name for t in targets] == list('abcde')
    result = filter_targets(targets, calibrated, nominal, cell.home)
    out = filtered_csv(result.filtered, nominal.joint_names)
    header, *lines = out.splitlines()
    assert header == ','.join(COLUMNS + nominal.joint_names)
    again = parse_targets('\n'.join([','.join(COLUMNS)] + [
        ','.join(line.split(',')[:8]) for line in lines]))
    assert_allclose(np.array([t.pose for t in again]),
                    np.array([f.pose for f in result.filtered]), rtol=0, atol=1e-12)
    assert_allclose(np.array([[float(v) for v in line.split(',')[8:]] for line in lines]), q,
                    rtol=0, atol=1e-6)
    assert all(float(line.split(',')[7]) >= 0 for line in lines)     # qw >= 0


@pytest.mark.parametrize('fmt', ['kuka', 'abb', 'fanuc', 'ur', 'yaskawa'])
def test_a_program_in_a_controllers_values_comes_back_in_them(fmt):
    cell, nominal, calibrated = ur10e()
    q = program(cell.home, np.random.default_rng(7), 4)
    poses = fk(calibrated, q)
    text = ','.join(columns(fmt)) + '\n' + ''.join(
        f'w{k},' + ','.join(repr(v) for v in to_values(T, fmt)) + '\n'
        for k, T in enumerate(poses))
    targets = parse_targets(text, 'p.csv', fmt)
    assert_allclose(np.array([t.pose for t in targets]), poses, rtol=0, atol=1e-12)
    result = filter_targets(targets, calibrated, nominal, cell.home)
    header, *lines = filtered_csv(result.filtered, nominal.joint_names, fmt).splitlines()
    assert header.split(',') == list(columns(fmt) + nominal.joint_names)
    n = len(columns(fmt))
    assert_allclose([[float(v) for v in line.split(',')[1:n]] for line in lines],
                    [to_values(T, fmt) for T in fk(nominal, q)], rtol=0, atol=1e-6)


@pytest.mark.parametrize('text, words', [
    ('x,y,z\n', 'line 1: expected the header name,x,y,z,qx,qy,qz,qw'),
    ('name,x,y,z,qx,qy,qz,qw\n', 'no targets after the header'),
    ('name,x,y,z,qx,qy,qz,qw\na,0,0,0,0,0,0\n', 'line 2: expected 8 columns, got 7'),
    ('name,x,y,z,qx,qy,qz,qw\na,0,0,0.5,0,0,0,1\na,0,0,0.4,0,0,0,1\n',
     "line 3: name 'a' is empty or repeated"),
    ('name,x,y,z,qx,qy,qz,qw\na,0,zero,0,0,0,0,1\n', "line 2: y: expected a finite number, "
                                                       "got 'zero'"),
    ('name,x,y,z,qx,qy,qz,qw\na,0,0,0,0,0,0,2\n', 'line 2: the quaternion (qx qy qz qw) has '
                                                  'norm 2'),
    ('name,x,y,z,qx,qy,qz,qw\n', 'line 1: expected the header name,X,Y,Z,A,B,C (X [mm], Y [mm], '
                                 'Z [mm], A [deg], B [deg], C [deg])'),
    ('name,x,y,z,q1,q2,q3,q4\na,0,0,0,0.5,0,0,0\n', 'line 2: abb: the quaternion'),
])
def test_a_broken_targets_file_names_line_and_column(text, words):
    fmt = 'kuka' if 'A [deg]' in words else 'abb' if 'abb' in words else 'csv'
    with pytest.raises(ValueError) as caught:
        parse_targets(text, 'prog.csv', fmt)
    assert str(caught.value).startswith('prog.csv: ') and words in str(caught.value)
