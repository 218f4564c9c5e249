"""core.landmarks.intrinsics_views / hand_eye view planning: every planned view checked for
the arm's reach and the board in the image before the robot moves, another azimuth chosen where
the planned one cannot be reached (issue 36 item 4: `intrinsics --planned` on sawyer_close
failed at view 19 of 20)."""
from __future__ import annotations

import numpy as np
import pytest

from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.core.landmarks import hand_eye
from cobot_calib_ros.core.landmarks.hand_eye import (board_in_image, board_view_setup,
                                                     hand_eye_views)
from cobot_calib_ros.core.landmarks.intrinsics_views import IMAGE_MARGIN_PX, intrinsics_views
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.scenario import load_simulation

SAWYER = load_simulation(cell_file('sawyer_close'))
MODEL = kinematics.model_for(SAWYER.cell)


@pytest.mark.parametrize('count', [20, 54])
def test_the_readme_counts_on_the_sawyer_give_every_view_reachable_with_the_board_seen(count):
    T_base_user = SAWYER.world.T_base_user
    views = intrinsics_views(SAWYER.cell, MODEL, count, 0, T_base_user=T_base_user)
    assert len(views) == count
    size, T_base_board, chain, camera = board_view_setup(SAWYER.cell, MODEL, T_base_user)
    for q in views:
        assert np.all(q >= chain.lower) and np.all(q <= chain.upper)
        T = kinematics.fk(chain, q)
        assert board_in_image(frames.invert(T) @ T_base_board, size, camera, IMAGE_MARGIN_PX)
    # view 19 aims the board's centre at the image's top-left; the planned azimuth has no
    # reach there, so it looks from another: its camera is not where the golden step put it
    centre = frames.apply(T_base_board, [size[0] / 2, size[1] / 2, 0.0])
    seen_from = [frames.invert(T_base_board)[:3, :3] @ (kinematics.fk(chain, q)[:3, 3] - centre)
                 for q in views]
    azimuth_19 = np.degrees(np.arctan2(seen_from[18][1], seen_from[18][0])) % 360.0
    planned = (18 * 0.382 % 1.0) * 360.0
    assert abs((azimuth_19 - planned + 180.0) % 360.0 - 180.0) > 36.0


def test_views_that_can_never_be_reached_are_refused_naming_the_view_and_the_limit(
        monkeypatch):
    monkeypatch.setattr(hand_eye, 'MAX_ATTEMPTS_PER_VIEW', 10)     # 2 x 200 IK failures: 20 s
    far = frames.make_transform(np.eye(3), [3.0, 0.0, 0.0]) @ SAWYER.world.T_base_user
    with pytest.raises(ValueError, match=r'view 1 of 20 .*no convergence'):
        intrinsics_views(SAWYER.cell, MODEL, 20, 0, T_base_user=far)
    with pytest.raises(ValueError, match=r'view 1 of 12 .*no convergence'):
        hand_eye_views(SAWYER.cell, MODEL, 12, 0, T_base_user=far)
