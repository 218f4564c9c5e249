"""Vendor frame formats against the golden vector of wave3-facts section 6 (computed with scipy
there; the matrix here from the closed-form Z-Y-X product), round trips to 1e-9, and the
gimbal-lock, angle-wrap, quaternion-sign and near-pi cases."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cobot_calib_ros.core.vendor_frames import (FORMATS, from_values, paste_text,
                                                quaternion_wxyz, to_values, zyx_angles)

MM = 1e-3
GOLDEN_R = np.array([[0.813798, -0.440970, 0.378522],
                     [0.469846, 0.882564, 0.018028],
                     [-0.342020, 0.163176, 0.925417]])
GOLDEN = {
    'kuka': (500.0, -200.0, 300.0, 30.0, 20.0, 10.0),
    'abb': (500.0, -200.0, 300.0, 0.951549, 0.038135, 0.189308, 0.239298),
    'fanuc': (500.0, -200.0, 300.0, 10.0, 20.0, 30.0),
    'ur': (0.5, -0.2, 0.3, 0.077525, 0.384852, 0.486479),
    'yaskawa': (500.0, -200.0, 300.0, 10.0, 20.0, 30.0),
}
EXACT = ('kuka', 'fanuc', 'yaskawa')       # golden values given exactly (not rounded to 1e-6)


def _zyx_by_hand(a, b, c):
    """Rz(a) Ry(b) Rx(c) written out element by element (angles in degrees)."""
    ca, sa, cb, sb, cc, sc = (f(math.radians(x)) for x in (a, b, c) for f in (math.cos,
                                                                                 math.sin))
    return np.array([[ca * cb, ca * sb * sc - sa * cc, ca * sb * cc + sa * sc],
                     [sa * cb, sa * sb * sc + ca * cc, sa * sb * cc - ca * sc],
                     [-sb, cb * sc, cb * cc]])


def _golden_T():
    T = np.eye(4)
    T[:3, :3] = _zyx_by_hand(30.0, 20.0, 10.0)
    T[:3, 3] = (0.5, -0.2, 0.3)
    return T


def test_closed_form_matrix_is_the_tabulated_golden_matrix():
    assert np.allclose(_zyx_by_hand(30.0, 20.0, 10.0), GOLDEN_R, atol=5e-7)


@pytest.mark.parametrize('fmt', list(FORMATS))
def test_golden_frame_gives_the_tabulated_values(fmt):
    values = to_values(_golden_T(), fmt)
    tolerance = 1e-9 if fmt in EXACT else 5e-7      # abb/ur golden values have 6 decimals
    assert np.allclose(values, GOLDEN[fmt], rtol=0, atol=tolerance), (values, GOLDEN[fmt])


@pytest.mark.parametrize('fmt', list(FORMATS))
def test_golden_values_give_the_golden_frame(fmt):
    T = from_values(GOLDEN[fmt], fmt)
    tolerance = 1e-12 if fmt in EXACT else 1e-6
    assert np.allclose(T, _golden_T(), rtol=0, atol=tolerance)


@pytest.mark.parametrize('fmt', EXACT)
def test_euler_formats_round_trip_to_1e9(fmt):
    values = GOLDEN[fmt]
    assert np.allclose(to_values(from_values(values, fmt), fmt), values, rtol=0, atol=1e-9)


@pytest.mark.parametrize('fmt', list(FORMATS))
def test_frame_round_trips_through_every_format(fmt):
    rng = np.random.default_rng(3)
    for _ in range(200):
        T = np.eye(4)
        T[:3, :3] = _zyx_by_hand(*rng.uniform(-180, 180, 3))
        T[:3, 3] = rng.uniform(-2, 2, 3)
        back = from_values(to_values(T, fmt), fmt)
        assert np.max(np.abs(back[:3, 3] - T[:3, 3])) / MM < 1e-9       # mm
        assert np.max(np.abs(back[:3, :3] - T[:3, :3])) < 1e-12


@pytest.mark.parametrize('b', [90.0, -90.0])
def test_gimbal_lock_keeps_the_frame_and_sets_c_to_zero(b):
    T = np.eye(4)
    T[:3, :3] = _zyx_by_hand(40.0, b, 15.0)     # only a -+ c is defined at b = +-90
    T[:3, 3] = (0.1, 0.2, 0.3)
    x, y, z, a, b_out, c = to_values(T, 'kuka')
    assert (b_out, c) == (b, 0.0)
    assert a == pytest.approx(40.0 - 15.0 if b > 0 else 40.0 + 15.0, abs=1e-9)
    assert np.allclose(from_values((x, y, z, a, b_out, c), 'kuka'), T, rtol=0, atol=1e-12)
    w, p, r = to_values(T, 'fanuc')[3:]
    assert (w, p, r) == (c, b_out, a)
    values = (100.0, 200.0, 300.0, 25.0, b, 0.0)           # c = 0: the values round-trip
    assert np.allclose(to_values(from_values(values, 'kuka'), 'kuka'), values, rtol=0,
                       atol=1e-9)


def test_angles_are_wrapped_to_minus_180_exclusive_180_inclusive():
    assert zyx_angles(_zyx_by_hand(180.0, 0.0, -180.0)) == pytest.approx((180.0, 0.0, 180.0))
    assert to_values(from_values((0, 0, 0, 270.0, 10.0, -190.0), 'kuka'), 'kuka')[3:] == \
        pytest.approx((-90.0, 10.0, 170.0), abs=1e-9)


def test_abb_quaternion_scalar_first_and_non_negative():
    q = quaternion_wxyz(_zyx_by_hand(179.0, 0.0, 0.0))
    assert q[0] >= 0 and q[3] > 0.99
    q = quaternion_wxyz(_zyx_by_hand(-179.0, 0.0, 0.0))    # scipy may give w < 0 here
    assert q[0] >= 0 and q[3] < -0.99
    q = quaternion_wxyz(_zyx_by_hand(180.0, 0.0, 0.0))     # w = 0: first non-zero part > 0
    assert q == pytest.approx((0.0, 0.0, 0.0, 1.0), abs=1e-12)
    minus = from_values((1, 2, 3, *(-np.array(GOLDEN['abb'][3:]))), 'abb')
    assert np.allclose(minus, from_values((1, 2, 3, *GOLDEN['abb'][3:]), 'abb'), atol=1e-15)


@pytest.mark.parametrize('angle', [math.pi - 1e-9, math.pi - 1e-6, math.pi])
def test_ur_rotation_vector_near_pi(angle):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    values = (0.4, -0.1, 0.25, *(axis * angle))
    T = from_values(values, 'ur')
    back = to_values(T, 'ur')
    assert np.linalg.norm(back[3:]) == pytest.approx(angle, abs=1e-9)
    if angle < math.pi:
        assert np.allclose(back, values, rtol=0, atol=1e-9)
    else:                           # at pi, v and -v are the same rotation
        assert np.allclose(np.abs(back), np.abs(values), rtol=0, atol=1e-9)
    assert np.allclose(from_values(back, 'ur'), T, rtol=0, atol=1e-12)


def test_paste_text_is_the_controller_syntax():
    T = _golden_T()
    kuka = paste_text(T, 'kuka', index=3, comment='user frame rigid-1')
    assert kuka == ('; user frame rigid-1\nBASE_DATA[3]={X 500.0000,Y -200.0000,Z 300.0000,'
                    'A 30.000000,B 20.000000,C 10.000000}\n')
    abb = paste_text(T, 'abb', name='wobj_cell')
    assert abb.startswith('PERS wobjdata wobj_cell:=[FALSE,TRUE,"",[[500.0000,-200.0000,'
                          '300.0000],[0.951548')
    assert abb.rstrip().endswith(']],[[0,0,0],[1,0,0,0]]];')
    ur = paste_text(T, 'ur').splitlines()
    assert ur[0].startswith('cell_frame = p[0.5000000, -0.2000000, 0.3000000, 0.0775')
    assert '# pendant (mm, rad): X 500.0000 Y -200.0000 Z 300.0000' in ur[1]
    fanuc = paste_text(T, 'fanuc', index=2).splitlines()
    assert fanuc[0].endswith('X 500.0000 Y -200.0000 Z 300.0000 W 10.000000 P 20.000000 '
                             'R 30.000000')
    assert fanuc[-1] == 'UFRAME[2]=PR[52] ;'
    yaskawa = paste_text(T, 'yaskawa').splitlines()
    assert 'Rx 10.000000 Ry 20.000000 Rz 30.000000' in yaskawa[0]
    org, xx = (np.array(line.split(': ')[1].split(), dtype=float) for line in yaskawa[1:3])
    assert np.allclose(org, (500, -200, 300)) and np.allclose(xx - org, GOLDEN_R[:, 0] * 100,
                                                              atol=1e-4)


@pytest.mark.parametrize('call, message', [
    (lambda: to_values(np.eye(4), 'staubli'), 'unknown vendor format'),
    (lambda: from_values((1, 2, 3), 'kuka'), 'expected 6 finite values'),
    (lambda: from_values((1, 2, 3, 0, 0, math.nan), 'kuka'), 'expected 6 finite values'),
    (lambda: from_values((1, 2, 3, 2, 0, 0, 0), 'abb'), 'not unit length'),
    (lambda: to_values(np.diag([1.1, 1, 1, 1]), 'kuka'), 'not a rigid transform'),
])
def test_bad_input_says_what_to_do(call, message):
    with pytest.raises(ValueError, match=message):
        call()
