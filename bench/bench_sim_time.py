"""Windows in ROS time against wall time: captures and probe averages on a /clock at 2x and
0.5x (test/nodes/test_sim_time.py tests the windows' stamps; what they take of wall time and
how many samples they hold depend on the machine).

mock_robot, joint_state_monitor and proximity_sensor run with ``use_sim_time`` on a private
domain; this process publishes /clock (ros.sim_clock) at each rate and, after a 0.1 s capture
(the monitor's first samples on that clock), asks for a 0.5 s capture and a 0.4 s probe
average, each timed from request to response:

- ``sim_time_<rate>x_capture_wall_s`` (rate 2 or 0_5; 0.25 s at 2x, 1.0 s at 0.5x on an
  unloaded machine) and ``_capture_samples`` (joint_states at 1 kHz of wall time: ~250 and ~1000);
- ``sim_time_<rate>x_probe_wall_s`` (0.2 s, 0.8 s) and ``_probe_samples`` (200 Hz of wall
  time: ~40, ~160; readings in and out of range, the probe rests where mock_robot starts);
- ``sim_time_load_average_1min``.
"""
from __future__ import annotations

import time

from cobot_calib_msgs.srv import AverageProximity, CaptureJoints

import benchlib
from benchlib import BenchFailed, Figures
from cobot_calib_ros.api import launcher
from cobot_calib_ros.ros.sim_clock import SimClock

RATES = (2.0, 0.5)
# the samples a window holds are measured, not judged: no NO_DATA for a starved stream
NODES = (('mock_robot', {'time_scale': '0.2'}),
         ('joint_state_monitor', {'min_sample_fraction': '0.01'}), ('proximity_sensor', {}))


def run() -> Figures:
    figures: Figures = {}
    specs = [launcher.NodeSpec(name, dict(params, use_sim_time='true'))
             for name, params in NODES]
    with benchlib.private_domain() as (domain, env), \
            benchlib.ros_node('bench_sim_time', domain) as ros:
        clock = SimClock(ros.node)
        try:
            with benchlib.running_suite('sim_time', specs, env) as suite:
                capture = ros.node.create_client(CaptureJoints, 'capture_joints')
                probe = ros.node.create_client(AverageProximity, 'probe/average')
                benchlib.wait_for_service(ros, suite, 'joint_state_monitor', capture)
                benchlib.wait_for_service(ros, suite, 'proximity_sensor', probe)
                for rate in RATES:
                    clock.rate = rate
                    name = f'sim_time_{rate:g}x'.replace('.', '_')
                    figures.update(windows(ros, capture, probe, name))
        finally:
            clock.stop()
    figures['sim_time_load_average_1min'] = (benchlib.load_average_1min(), 'load')
    return figures


def windows(ros, capture, probe, prefix: str) -> Figures:
    benchlib.timed_call(ros, capture, CaptureJoints.Request(duration=0.1), 30.0)
    seconds, joints = benchlib.timed_call(ros, capture, CaptureJoints.Request(duration=0.5),
                                          30.0)
    if joints.error_code != CaptureJoints.Response.SUCCESS:
        raise BenchFailed(f'{prefix}: capture_joints: {joints.message}')
    figures: Figures = {f'{prefix}_capture_wall_s': (seconds, 's'),
                        f'{prefix}_capture_samples': (joints.sample_count, 'count')}
    seconds, average = benchlib.timed_call(ros, probe, AverageProximity.Request(duration=0.4),
                                           30.0)
    if average.error_code == AverageProximity.Response.NO_DATA:
        raise BenchFailed(f'{prefix}: probe/average: {average.message}', figures)
    figures[f'{prefix}_probe_wall_s'] = (seconds, 's')
    figures[f'{prefix}_probe_samples'] = (average.sample_count + average.rejected_count,
                                          'count')
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
