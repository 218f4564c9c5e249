"""Waits that end on a timeout, timed (the tests show which event ended them, not when):

- ``wait_past_stall_ms``: ros.time.wait_past on a real condition with stall 0.3 s and
  nothing arriving after two samples: how long after the last sample it gives up (300 ms
  and the thread's wake-up);
- ``orphan_capture_refused_s``: calibrate_user_frame with point names on a user_frame_solver
  with no robot on its domain: how long until it refuses with CAPTURE_FAILED
  (test/nodes/test_user_frame_solver.py); it waits ros.robot_calls.SERVER_WAIT (5 s) for
  move_to.
"""
from __future__ import annotations

import threading
import time

from cobot_calib_msgs.srv import CalibrateUserFrame

import benchlib
from benchlib import BenchFailed, Figures
from cobot_calib_ros import paths
from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros.time import wait_past

STALL_S = 0.3


def run() -> Figures:
    figures = {'wait_past_stall_ms': (1e3 * wait_past_stall(), 'ms')}
    figures['orphan_capture_refused_s'] = (orphan_refusal(figures), 's')
    return figures


def wait_past_stall() -> float:
    """Seconds from the last sample to wait_past's return (t1 never reached)."""
    condition, state = threading.Condition(), {'stamp': 0.0, 'count': 0, 'at': 0.0}

    def feed() -> None:
        for stamp in (0.5, 1.0):
            time.sleep(0.05)
            with condition:
                state.update(stamp=stamp, count=state['count'] + 1, at=time.monotonic())
                condition.notify_all()
    feeder = threading.Thread(target=feed)
    with condition:
        feeder.start()
        wait_past(condition, lambda: (state['stamp'], state['count']), 9.0, STALL_S)
        ended = time.monotonic()
    feeder.join()
    return ended - state['at']


def orphan_refusal(figures: Figures) -> float:
    spec = launcher.NodeSpec('user_frame_solver', {
        'cell_file': str(paths.cell_file(paths.DEFAULT_CELL))}, namespace='orphan')
    with benchlib.private_domain() as (domain, env), \
            benchlib.running_suite('orphan', [spec], env) as suite, \
            benchlib.ros_node('bench_waits', domain) as ros:
        client = ros.node.create_client(CalibrateUserFrame, '/orphan/calibrate_user_frame')
        benchlib.wait_for_service(ros, suite, 'user_frame_solver', client)
        seconds, res = benchlib.timed_call(
            ros, client, CalibrateUserFrame.Request(point_names=['P1', 'P2', 'P3']), 60.0)
    if res.error_code != CalibrateUserFrame.Response.CAPTURE_FAILED:
        raise BenchFailed(f'expected CAPTURE_FAILED, got {res.error_code}: {res.message}',
                          figures)
    return seconds


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
