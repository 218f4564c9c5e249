"""The simulated wrist camera's render time (sim.camera.Renderer), per resolution.

The camera of the default cell looks straight down from 0.40 m at user (0.25, 0.175) m on the
true robot (four markers and the board in view); every target is drawn RENDERS times after one
untimed render (textures built, caches warm):

- ``render_<w>x<h>_median_ms``, ``render_<w>x<h>_min_ms``: at the cell's 752x480 (goal: a
  median <= 10 ms, so that mock_camera keeps its rate beside the suite) and with the same lens
  scaled to 1280x800.
"""
from __future__ import annotations

import time

import numpy as np

import benchlib
from benchlib import Figures
from cobot_calib_ros import paths
from cobot_calib_ros.sim.camera import Renderer, scaled_camera, SimCamera
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

RESOLUTIONS = ((752, 480), (1280, 800))
RENDERS = 30


def run() -> Figures:
    sim = load_simulation(paths.cell_file(paths.DEFAULT_CELL))
    scene = SimCamera(sim, SimRobot(sim))
    q = scene.joints_looking_down((0.25, 0.175), 0.40)
    targets = [(scene.targets[key][0], T) for key, T in scene.T_optical_targets(q).items()]
    figures: Figures = {}
    for width, height in RESOLUTIONS:
        renderer = Renderer(scaled_camera(scene.camera, width, height), sim.camera)
        renderer.render(targets)
        times = []
        for _ in range(RENDERS):
            start = time.perf_counter()
            renderer.render(targets)
            times.append(time.perf_counter() - start)
        figures[f'render_{width}x{height}_median_ms'] = (1e3 * float(np.median(times)), 'ms')
        figures[f'render_{width}x{height}_min_ms'] = (1e3 * min(times), 'ms')
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
