"""MUKCa KUKA iiwa 14 sphere-socket data (real robot): loading and MUKCa's metric (held out:
test/test_real_data.py and test/cli/test_identify.py, through the measurement path)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.testing import assert_allclose
import pytest

from cobot_calib_ros.core.kinematics import fk
from cobot_calib_ros.core.kinematics.identification import SphereObservations, TOOL_NAMES
from cobot_calib_ros.core.kinematics.kinematic_calibration import fit_spheres
from cobot_calib_ros.core.kinematics.identification.sockets import (
    location_metrics, mukca_metrics, SocketData)
from cobot_calib_ros.loaders import load_socket_data
from cobot_calib_ros.core.kinematics.urdf import model_from_urdf

MUKCA = Path(__file__).resolve().parents[3] / 'data' / 'mukca-kuka-iiwa14'
BALL = (0.0, 0.0, 0.04)  # iiwa14.urdf ball_joint: 0.04 m along tool0 z [m]

# test/data/mukca-kuka-iiwa14/README.md, nominal iiwa14.urdf, no outlier removal [mm]
REFERENCE = {'front': (0.723, 1.662, 49.897), 'left_back': (0.808, 1.457, 50.120),
             'raised_left': (0.804, 1.766, 50.185)}
REFERENCE_ALL_MAE = 0.778


@pytest.fixture(scope='module')
def data() -> SocketData:
    return load_socket_data(MUKCA / 'kuka_14')


@pytest.fixture(scope='module')
def model():
    return model_from_urdf((MUKCA / 'iiwa14.urdf').read_text(), 'base_link', 'tool0', 'iiwa14')


def ball_positions(model, q, params=None, ball=BALL):
    tool = np.eye(4)
    tool[:3, 3] = ball
    return fk(model.chain(params, tool), q)[:, :3, 3]


def test_load_socket_data(data):
    assert data.locations == ('front', 'left_back', 'raised_left')
    assert data.q.shape == (180, 7)
    counts = {(data.locations[i], s): int(np.sum((data.location == i) & (data.socket == s)))
              for i in range(3) for s in (0, 1)}
    assert counts == {('front', 0): 31, ('front', 1): 31, ('left_back', 0): 31,
                      ('left_back', 1): 31, ('raised_left', 0): 28, ('raised_left', 1): 28}
    first = np.loadtxt(MUKCA / 'kuka_14' / 'front' / 'hole_0.csv', delimiter=',')[0]
    assert np.array_equal(data.q[0], first)
    assert np.all(np.abs(data.q) < np.pi)  # radians


def test_observations_of_a_subset(data):
    obs = data.observations(['raised_left', 'front'])
    assert isinstance(obs, SphereObservations)
    assert len(obs.q) == 56 + 62
    assert obs.spheres == (0, 1, 2, 3)
    assert obs.known_distances == ((0, 1, 0.05), (2, 3, 0.05))
    raised = data.location == 2
    # raised_left is the first location asked for: its sockets are spheres 0 and 1
    mask = (obs.sphere == 0) | (obs.sphere == 1)
    assert np.array_equal(obs.q[mask], data.q[raised])
    assert np.array_equal(obs.sphere[mask], data.socket[raised])
    assert len(data.observations().q) == 180
    with pytest.raises(ValueError, match='unknown location'):
        data.observations(['kitchen'])
    with pytest.raises(ValueError, match='repeated'):
        data.observations(['front', 0])


def test_load_errors(tmp_path):
    with pytest.raises(ValueError, match='does not exist'):
        load_socket_data(tmp_path / 'missing')
    with pytest.raises(ValueError, match='no <location>'):
        load_socket_data(tmp_path)
    (tmp_path / 'a').mkdir()
    (tmp_path / 'a' / 'hole_0.csv').write_text('0,1,2\n3,4,5\n')
    (tmp_path / 'a' / 'hole_1.csv').write_text('0,1\n3,4\n')
    with pytest.raises(ValueError, match='2 columns, expected 3'):
        load_socket_data(tmp_path)
    (tmp_path / 'a' / 'hole_1.csv').write_text('0,1,x\n')
    with pytest.raises(ValueError, match='numeric'):
        load_socket_data(tmp_path)


def test_mukca_metrics_by_hand():
    p = np.array([[0, 0, 0], [0.002, 0, 0], [0.05, 0, 0], [0.05, 0.001, 0], [0.05, -0.001, 0]])
    m = mukca_metrics(p, [0, 0, 1, 1, 1])
    # socket 0: deviations 1, 1 mm (mean 1); socket 1: 0, 1, 1 mm (mean 2/3)
    assert_allclose(m['mae_mm'], (2 * 1 + 3 * 2 / 3) / 5)
    assert_allclose(m['max_mm'], 1.0)
    assert_allclose(m['centroid_distances_mm'], [49.0])
    assert_allclose(m['distance_error_mm'], 1.0)
    assert np.isnan(mukca_metrics(p, [3, 3, 4, 4, 4])['distance_error_mm'])
    with pytest.raises(ValueError, match='positions'):
        mukca_metrics(p[:, :2], [0, 0, 1, 1, 1])


def test_nominal_model_reproduces_the_readme_table(data, model):
    p = ball_positions(model, data.q)
    for i, name in enumerate(data.locations):
        rows = data.location == i
        m = mukca_metrics(p[rows], data.socket[rows])
        mae, worst, distance = REFERENCE[name]
        print(f"{name}: MAE {m['mae_mm']:.4f} mm, max {m['max_mm']:.4f} mm, centroid distance "
              f"{m['centroid_distances_mm'][0]:.4f} mm")
        assert m['mae_mm'] == pytest.approx(mae, abs=1e-3)
        assert m['max_mm'] == pytest.approx(worst, abs=1e-3)
        assert m['centroid_distances_mm'][0] == pytest.approx(distance, abs=1e-3)
        assert m['distance_error_mm'] == pytest.approx(abs(distance - 50.0), abs=1e-3)
    obs = data.observations()
    everything = mukca_metrics(ball_positions(model, obs.q), obs.sphere, obs.known_distances)
    assert everything['mae_mm'] == pytest.approx(REFERENCE_ALL_MAE, abs=1e-3)


def test_fitting_only_the_ball_reproduces_the_readme(data, model):
    """README: ball-only fit, MAE 0.704 mm, ball (-0.11, -0.23, 166.61) mm in the A7 frame."""
    _, p_flange_tool, _ = fit_spheres(model, data.observations(), BALL, TOOL_NAMES)
    a7_to_tool0 = np.array([0.0, 0.0, 0.126])  # joint_a7-tool0 [m]
    assert_allclose((p_flange_tool + a7_to_tool0) * 1e3, [-0.11, -0.23, 166.61], atol=5e-3)
    mae = location_metrics(model, None, p_flange_tool, data)['mae_mm']
    assert mae == pytest.approx(0.704, abs=1e-3)
