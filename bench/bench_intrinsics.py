"""Camera intrinsics against the truth on the mock camera (cell ur10e_close with a true lens
other than the nominal CameraInfo), in-process (no ROS), over SEEDS draws of the image noise:
the views core.landmarks.intrinsics_views plans, rendered through the true lens at the true
arm's joints, detected with the project's ChArUco detector, calibrated (plumb_bob).

- ``intrinsics_f{x,y}_error_max_pct``: the largest |fx / fx_true - 1| over the seeds [%] (goal
  0.1 %); ``intrinsics_c{x,y}_error_max_px``: the largest principal point error [px] (goal
  0.5 px);
- ``intrinsics_rms_median_px`` / ``intrinsics_heldout_rms_median_px``: reprojection errors of
  the fit and held out (k-fold over views); ``intrinsics_corner_noise_median_px``: the mock's
  corner noise, the RMS distance of the detected corners from the true lens's projection of
  the board's true pose (what the held-out error should come down to);
- ``intrinsics_landmark_frame_{true,nominal,calibrated_max}_{mm,mrad}``: landmark_multi's user
  frame measured on the true robot and hand-eye with the true, the nominal and each seed's
  calibrated intrinsics, against the true user frame; ``..._calibrated_vs_true_max_*``: the
  calibrated intrinsics' frames against the true intrinsics' one (issue 30 must-show 3).
"""
from __future__ import annotations

import sys

import numpy as np

import benchlib
from benchlib import Figures

from cobot_calib_ros.core import frames
from cobot_calib_ros.core.landmarks import views as landmark_views
from cobot_calib_ros.core.landmarks.detect import BoardFinder
from cobot_calib_ros.core.landmarks.intrinsics import calibrate_intrinsics
from cobot_calib_ros.core.landmarks.intrinsics_views import board_view, intrinsics_views
from cobot_calib_ros.core.landmarks.targets import BoardSpec
from cobot_calib_ros.core.user_frame.plausibility import MAX_RMS_ERROR, MAX_SCALE_ERROR
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.sim.camera import DirectCamera, SimCamera
from cobot_calib_ros.sim.robot import DirectRobot, SimRobot
from cobot_calib_ros.sim.scenario import load_simulation, with_true_lens

SEEDS = 5
VIEWS = 54
K_TRUE = np.array([[628.0, 0.0, 380.1], [0.0, 627.2, 236.9], [0.0, 0.0, 1.0]])
D_TRUE = np.array([-0.15, 0.12, 0.0003, -0.0004, -0.05])


def _calibrate(sim, seed: int):
    """(fit, corner noise [px]) of VIEWS planned views on a fresh arm of noise ``seed``."""
    arm = SimRobot(sim, seed_offset=seed)
    scene = SimCamera(sim, arm)
    spec = BoardSpec.parse(sim.cell.landmarks.board)
    finder = BoardFinder(spec)
    plan = intrinsics_views(sim.cell, arm.model, VIEWS, seed, T_base_user=sim.world.T_base_user)
    views, sq = [], []
    for i, q in enumerate(plan):
        arm.set_joints(q)
        view = board_view(f'view{i}', finder.finish(finder.find(scene.render(arm.q))), spec)
        if view is None:
            continue
        views.append(view)
        T = scene.T_optical_targets(arm.q)['board', spec.first_id]
        truth = scene.true_camera.project(view.object_points, frames.to_vector(T)[3:], T[:3, 3])
        sq.append(np.sum((view.image_points - truth) ** 2, axis=1))
    fit = calibrate_intrinsics(views, (sim.cell.camera.width, sim.cell.camera.height),
                               'plumb_bob')
    return fit, float(np.sqrt(np.mean(np.concatenate(sq))))


def _landmark_frame(sim, camera):
    """landmark_multi's T_base_user with ``camera``'s intrinsics, measured on the true robot
    with the true hand-eye (only the intrinsics differ)."""
    arm = SimRobot(sim, seed_offset=0)
    model = arm.model
    fit = landmark_views.measure_frame(
        'landmark_multi', sim.cell, DirectRobot(arm, sim.probe),
        DirectCamera(SimCamera(sim, arm), arm, camera=camera),
        T_base_user_guess=sim.world.T_base_user,
        plan_chain=model.chain(tool=sim.cell.camera.T_flange_optical),
        chain=model.chain(arm.true_parameters, tool=sim.camera.T_flange_optical),
        capture_duration=0.1, max_rms_error=MAX_RMS_ERROR, max_scale_error=MAX_SCALE_ERROR)
    if not fit:
        raise benchlib.BenchFailed(f'landmark_multi failed: {fit.message}', {})
    return fit.fit.T_base_user


def _mm_mrad(T, T_ref) -> tuple[float, float]:
    distance, angle = frames.transform_error(T, T_ref)
    return distance * 1e3, angle * 1e3


def run() -> Figures:
    sim = with_true_lens(load_simulation(cell_file('ur10e_close')), K_TRUE, D_TRUE)
    fx, fy, cx, cy, rms, heldout, noise, gates = [], [], [], [], [], [], [], []
    cameras = []
    for seed in range(SEEDS):
        fit, corner_noise = _calibrate(sim, seed)
        cameras.append(fit.camera)
        K = fit.camera.K
        fx.append(abs(K[0, 0] / K_TRUE[0, 0] - 1) * 100)
        fy.append(abs(K[1, 1] / K_TRUE[1, 1] - 1) * 100)
        cx.append(abs(K[0, 2] - K_TRUE[0, 2]))
        cy.append(abs(K[1, 2] - K_TRUE[1, 2]))
        rms.append(fit.rms_px)
        heldout.append(fit.heldout_rms_px)
        noise.append(corner_noise)
        gates.append(fit.gate_problem == '')
    figures: Figures = {
        'intrinsics_fx_error_max_pct': (max(fx), '%'),
        'intrinsics_fy_error_max_pct': (max(fy), '%'),
        'intrinsics_cx_error_max_px': (max(cx), 'px'),
        'intrinsics_cy_error_max_px': (max(cy), 'px'),
        'intrinsics_rms_median_px': (float(np.median(rms)), 'px'),
        'intrinsics_heldout_rms_median_px': (float(np.median(heldout)), 'px'),
        'intrinsics_corner_noise_median_px': (float(np.median(noise)), 'px'),
        'intrinsics_gate_passed': (int(sum(gates)), 'count'),
        'intrinsics_seeds': (SEEDS, 'count'),
        'intrinsics_views': (VIEWS, 'count'),
    }
    scene = SimCamera(sim, SimRobot(sim))
    truth = sim.world.T_base_user
    with_true = _landmark_frame(sim, scene.true_camera)
    calibrated = [_landmark_frame(sim, camera) for camera in cameras]
    for name, T in (('true', with_true), ('nominal', _landmark_frame(sim, scene.camera))):
        mm, mrad = _mm_mrad(T, truth)
        figures[f'intrinsics_landmark_frame_{name}_mm'] = (mm, 'mm')
        figures[f'intrinsics_landmark_frame_{name}_mrad'] = (mrad, 'mrad')
    errors = np.array([_mm_mrad(T, truth) for T in calibrated])
    figures['intrinsics_landmark_frame_calibrated_max_mm'] = (float(errors[:, 0].max()), 'mm')
    figures['intrinsics_landmark_frame_calibrated_max_mrad'] = (float(errors[:, 1].max()),
                                                                'mrad')
    apart = np.array([_mm_mrad(T, with_true) for T in calibrated])
    figures['intrinsics_landmark_frame_calibrated_vs_true_max_mm'] = (float(apart[:, 0].max()),
                                                                      'mm')
    figures['intrinsics_landmark_frame_calibrated_vs_true_max_mrad'] = (
        float(apart[:, 1].max()), 'mrad')
    return figures


if __name__ == '__main__':
    sys.exit(benchlib.main(run))
