"""`cobot-calib demo --json` on the session's suite: issue 3's comparison, scored on truth."""
import json

import pytest

from cobot_calib_ros.core.user_frame import LIMIT_FACTOR
from rosutil import cli


@pytest.fixture(scope='module')
def demo(ros):
    out = cli('demo', '--json', '--attach', timeout=180)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    return result, {m['name']: m for m in result['methods']}


def test_every_method_is_reported_in_si_derived_mm(demo):
    result, methods = demo
    assert list(methods) == ['three_point', 'five_point_lsq', 'rigid', 'robust']
    for m in methods.values():
        assert {'frame_error_mm', 'frame_error_mrad', 'residual_rms_mm',
                'point_error_max_mm'} <= set(m)
        assert len(m['point_error_mm']) == 5
    # per-point noise from sawyer_close.yaml, by hand: repeatability 0.018 mm (1 + 50 d^2),
    # d^2 = 0.1^2 + 0.075^2 at the four corners (0.03206 mm), 0 at P5 (0.018 mm): RMS
    # sqrt((4 * 0.03206^2 + 0.018^2) / 5) = 0.02979 mm; with touch 0.020 mm: hypot = 0.03588
    assert result['noise_sigma_mm'] == pytest.approx(0.03588, abs=5e-5)
    # the frame origin is ~0.25 m from the points: rotation noise dominates its translation
    assert result['noise_sigma_mm'] < result['estimation_limit_mm'] < 0.2


def test_rigid_frame_noise_part_is_within_the_estimation_limit(demo):
    result, methods = demo
    rigid = methods['rigid']
    assert rigid['frame_error_noise_mm'] < LIMIT_FACTOR * result['estimation_limit_mm']
    assert rigid['frame_error_noise_mrad'] < LIMIT_FACTOR * result['estimation_limit_mrad']
    # what is left is the systematic part: kinematic errors and table, a few tenths of a mm
    assert 0.05 < rigid['frame_error_systematic_mm'] < 0.6


def test_five_points_position_better_than_three_as_in_the_paper(demo):
    _, methods = demo
    assert methods['five_point_lsq']['point_error_max_mm'] < \
        methods['three_point']['point_error_max_mm']
    assert methods['rigid']['point_error_max_mm'] < methods['three_point']['point_error_max_mm']
    assert methods['rigid']['residual_rms_mm'] < methods['three_point']['residual_rms_mm']
