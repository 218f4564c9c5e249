"""Validation helpers: Table 5 statistics, rigid registration, absolute errors, Table 6 text."""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.kinematics.identification import (
    absolute_errors, error_stats, register_rigid, table6, tool_frames)
from cobot_calib_ros.core.kinematics.plans import uniform_configurations
from cobot_calib_ros.core.kinematics.model import iiwa7, sawyer


def parse_table(text: str) -> tuple[str, np.ndarray]:
    """Header line and the numeric columns after the first of every other line."""
    header, *lines = text.splitlines()
    return header, np.array([[float(v) for v in line.split()[1:]] for line in lines])


def test_error_stats_on_fixed_numbers():
    stats = error_stats([0.001, 0.002, 0.003, 0.006])  # metres
    assert stats == pytest.approx({'mean_m': 3e-3, 'std_m': np.sqrt(3.5) * 1e-3,
                                   'min_m': 1e-3, 'max_m': 6e-3})
    with pytest.raises(ValueError, match='finite'):
        error_stats([0.001, np.nan])
    with pytest.raises(ValueError, match='at least one'):
        error_stats([])


def test_table6_mdh_round_trip():
    """iiwa7 at the paper's Table 6 values (its rows 0-6 are our rows 1-7)."""
    model = iiwa7()
    paper = np.array([[0.0, 0.0, 0.0, 340.0], [-1.570759, 0.000061, 0.000062, 0.000062],
                      [1.571575, 0.000056, -0.000490, 400.574635],
                      [1.569842, 0.000061, 0.000061, 0.000063],
                      [-1.570623, 0.000062, 0.000059, 400.629881],
                      [-1.571451, 0.000062, 0.000061, 0.0],
                      [1.571136, 0.0, 0.0, 125.505736]])
    params = (paper * [1.0, 1e-3, 1.0, 1e-3]).ravel()
    text = table6(model, params)
    print(text)
    header, values = parse_table(text)
    assert header.split() == ['i', 'alpha', '[rad]', 'a', '[mm]', 'theta', '[rad]', 'd', '[mm]']
    assert [line.split()[0] for line in text.splitlines()[1:]] == [str(i) for i in range(1, 8)]
    assert values.shape == (7, 4)
    assert values == pytest.approx(paper, abs=5e-7)


def test_table6_origin_model_round_trip():
    model = sawyer()
    text = table6(model, model.nominal)
    _, values = parse_table(text)
    lines = text.splitlines()[1:]
    assert [line.split()[0] for line in lines] == list(model.joint_names)
    assert values.shape == (7, 6)
    assert values == pytest.approx(model.rows() * [1e3, 1e3, 1e3, 1.0, 1.0, 1.0], abs=5e-7)


def test_register_rigid_and_absolute_errors():
    model = iiwa7()
    tool = np.array([0.03, -0.01, 0.06])
    q = uniform_configurations(model, 30, 2)
    T = frames.from_xyz_rpy([1.0, 2.0, -0.5], [0.3, -0.2, 1.0])
    p_base = tool_frames(model, None, tool, q)[:, :3, 3]
    p_world = frames.apply(T, p_base)
    assert register_rigid(p_base, p_world) == pytest.approx(T, abs=1e-12)
    assert absolute_errors(model, model.nominal, tool, q, p_world).max() < 1e-12
    assert absolute_errors(model, model.nominal, tool, q, p_world, T).max() < 1e-12
    # given the wrong frame, the errors show it; registration absorbs it
    shifted = frames.from_xyz_rpy([1.0, 2.0, -0.499], [0.3, -0.2, 1.0])
    errors = absolute_errors(model, model.nominal, tool, q, p_world, shifted)
    assert errors == pytest.approx(np.full(30, 1e-3), abs=1e-12)
    # a tool 1 mm longer: registration cannot absorb it everywhere
    longer = absolute_errors(model, model.nominal, tool + [0, 0, 0.001], q, p_world)
    assert 1e-4 < longer.max() < 2e-3
    with pytest.raises(ValueError, match='m >= 3'):
        register_rigid(p_base[:2], p_world[:2])
