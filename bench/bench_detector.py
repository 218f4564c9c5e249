"""landmark_detector end to end: images from this process, landmarks back, the node apart.

For each target (the cell's single markers: four 50 mm markers seen from 0.4 m; the cell's
ChArUco board seen from 0.35 m) one landmark_detector process runs on a private domain,
configured for that target alone (``board:=none`` or ``dictionary:=none``). For each resolution
(752x480, and 1280x800 with the same lens scaled) the bench renders frames with sim.camera
(noise, blur, light of the sawyer_close cell) and publishes them with their camera_info from a
paced thread at the goal rate (markers 100 Hz, boards 30 Hz; sensor-data QoS, as a camera
driver), BENCH_DETECTOR_SECONDS (default 5) after a warm-up, and takes the landmarks back:

- ``detector_<res>_<target>_fps``: landmarks messages received per second for the images sent
  in that time (goals at 1280x800: markers >= 100, boards >= 30);
- ``detector_<res>_<target>_dropped_percent``: images sent without a landmarks message back,
  split by the node's /diagnostics counts (between its first and last report in the window)
  into ``dds_dropped_percent`` (never reached its callback), of which
  ``dds_lost_in_transport_percent`` DDS reported lost on the way (the reader's message_lost
  events) and ``dds_not_reported_lost_percent`` the rest: replaced in the reader's queue
  (IMAGE_QUEUE_DEPTH) before the executor took them, or lost on the way without an event
  (seen at 100 Hz with the reading process starved: a 50-deep reader lost 10 % so), and
  ``queue_dropped_percent`` (of those it took, dropped from its own queue, FRAME_QUEUE_DEPTH,
  while it was behind);
- ``detector_<res>_<target>_latency_p50_ms``: publish to landmarks received;
- ``detector_<res>_<target>_detect_ms``: the node's own time per image (its /diagnostics
  ``detect_ms_mean``: OpenCV's search + refinement, poses and message). The node runs the two
  stages on two threads, one image in each, so its capacity is above 1000 / detect_ms (up to
  1000 / the slower stage);
- ``detector_<res>_<target>_found``: landmarks per message (4 markers or 1 board expected).

Every process runs with the product's Fast DDS profile (api.dds_profile.large_data_env:
config/fastdds_large_images.xml, shared-memory segments large enough for a 1 MB frame).
BENCH_DETECTOR_FASTDDS_PROFILE=<file> publishes with that profile instead ('' without one);
the node keeps the product's. Fast DDS reads the profile at a process's first participant:
the variable applies to ``python bench/bench_detector.py`` alone, not in run_all's process
(which takes the product's from its start).
"""
from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field
import os
import threading
import time

from cobot_calib_msgs.msg import Landmarks
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

import benchlib
from benchlib import BenchFailed, Figures, Ros
from cobot_calib_ros import paths
from cobot_calib_ros.api import launcher
from cobot_calib_ros.api.dds_profile import large_data_env, PROFILE_ENV
from cobot_calib_ros.core import frames, kinematics
from cobot_calib_ros.paths import cell_file
from cobot_calib_ros.ros.images import gray_to_image, model_to_camera_info
from cobot_calib_ros.ros.time import ns_to_stamp, stamp_to_ns
from cobot_calib_ros.sim.camera import Renderer, scaled_camera, SimCamera
from cobot_calib_ros.sim.robot import SimRobot
from cobot_calib_ros.sim.scenario import load_simulation

CELL = paths.DEFAULT_CELL
NODE = 'landmark_detector'
RESOLUTIONS = ((752, 480), (1280, 800))
# target -> (node parameters, goal rate [Hz], camera above user (x, y) [m] or the board, height)
TARGETS = {
    'markers': ({'board': 'none'}, 100.0, (0.25, 0.175), 0.40),
    'board': ({'dictionary': 'none'}, 30.0, None, 0.35),
}
FRAMES = 4              # different noise, cycled
WARMUP_S = 2.0
STATUS = f'{NODE}: health'


@dataclass
class Run:
    """Stamps [ns] sent in the measured window with their send times, and what came back."""

    sent: dict[int, float] = field(default_factory=dict)
    received: dict[int, tuple[float, int]] = field(default_factory=dict)  # stamp -> (t, found)
    measuring: bool = False
    detect_ms: list[float] = field(default_factory=list)
    # t, frames_in, dropped (node's queue), lost_in_transport
    counts: list[tuple[float, int, int, int]] = field(default_factory=list)

    def on_landmarks(self, msg: Landmarks) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        if stamp in self.sent:
            self.received[stamp] = (time.perf_counter(), len(msg.landmarks))

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == STATUS and self.measuring:
                values = {kv.key: kv.value for kv in status.values}
                if values.get('detect_ms_mean', 'nan') != 'nan':
                    self.detect_ms.append(float(values['detect_ms_mean']))
                self.counts.append((time.perf_counter(), int(values.get('frames_in', 0)),
                                    int(values.get('dropped', 0)),
                                    int(values.get('lost_in_transport', 0))))

    def node_figures(self) -> Figures:
        """Where the images went, from the node's counts between two of its reports."""
        if len(self.counts) < 2:
            return {}
        (t0, in0, drop0, lost0), (t1, in1, drop1, lost1) = self.counts[0], self.counts[-1]
        sent = sum(t0 <= t < t1 for t in self.sent.values())
        received = in1 - in0
        not_taken, lost = max(0, sent - received), lost1 - lost0
        return {
            'dds_dropped_percent': (100.0 * not_taken / max(sent, 1), '%'),
            'dds_lost_in_transport_percent': (100.0 * lost / max(sent, 1), '%'),
            'dds_not_reported_lost_percent': (
                100.0 * max(0, not_taken - lost) / max(sent, 1), '%'),
            'queue_dropped_percent': (100.0 * (drop1 - drop0) / max(received, 1), '%'),
        }


def frames_for(scene: SimCamera, target: str, width: int, height: int):
    """(Image messages, CameraInfo) of the target seen at the given resolution."""
    sim = scene.sim
    _, _, xy, height_m = TARGETS[target]
    if xy is None:
        xy = sim.cell.landmarks.board_pose[:2]
    T = sim.world.T_base_user @ frames.make_transform(frames.rot_x(np.pi), [*xy, height_m])
    q = kinematics.solve_ik_with_restarts(scene.chain, T, sim.cell.home, sim.cell.home).q
    camera = scaled_camera(scene.camera, width, height)
    renderer = Renderer(camera, sim.camera)
    kind = 'marker' if target == 'markers' else 'board'
    poses = [(scene.targets[key][0], T) for key, T in scene.T_optical_targets(q).items()
             if key[0] == kind]
    frame_id = sim.cell.camera.frame_id
    images = [gray_to_image(renderer.render(poses), frame_id) for _ in range(FRAMES)]
    return images, model_to_camera_info(camera, frame_id)


def publish_paced(ros: Ros, images, info, rate: float, seconds: float, run: Run,
                  measure_from: float) -> None:
    """Publish images (with camera_info) at ``rate`` for ``seconds``; those sent after
    ``measure_from`` s are recorded in ``run``."""
    image_pub = ros.node.create_publisher(Image, 'wrist_camera/image_raw',
                                          qos_profile_sensor_data)
    info_pub = ros.node.create_publisher(CameraInfo, 'wrist_camera/camera_info',
                                         qos_profile_sensor_data)
    stop = threading.Event()

    def loop() -> None:
        start = time.perf_counter()
        k = 0
        while not stop.is_set():
            deadline = start + k / rate
            if deadline - start >= seconds:
                return
            delay = deadline - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            msg = images[k % len(images)]
            ns = time.time_ns()
            msg.header.stamp = info.header.stamp = ns_to_stamp(ns)
            if deadline - start >= measure_from:
                run.sent[ns] = time.perf_counter()
            info_pub.publish(info)
            image_pub.publish(msg)
            k += 1

    if not ros.spin_until(lambda: image_pub.get_subscription_count() > 0,
                          benchlib.STARTUP_TIMEOUT):
        raise BenchFailed(f'{NODE} did not subscribe to wrist_camera/image_raw within '
                          f'{benchlib.STARTUP_TIMEOUT:.0f} s')
    thread = threading.Thread(target=loop, daemon=True, name='camera')
    thread.start()
    ros.spin_for(measure_from)
    run.measuring = True
    ros.spin_until(lambda: not thread.is_alive(), seconds + 5.0)
    stop.set()
    thread.join()
    run.measuring = False
    ros.spin_for(1.0)                   # the last landmarks
    ros.node.destroy_publisher(image_pub)
    ros.node.destroy_publisher(info_pub)


def measure(ros: Ros, images, info, rate: float, seconds: float) -> Figures:
    run = Run()
    subs = [ros.node.create_subscription(Landmarks, 'landmarks', run.on_landmarks,
                                         QoSProfile(depth=100,
                                                    reliability=ReliabilityPolicy.RELIABLE)),
            ros.node.create_subscription(DiagnosticArray, '/diagnostics', run.on_diagnostics,
                                         50)]
    try:
        publish_paced(ros, images, info, rate, WARMUP_S + seconds, run, WARMUP_S)
    finally:
        for sub in subs:
            ros.node.destroy_subscription(sub)
    sent, got = len(run.sent), len(run.received)
    if not got:
        raise BenchFailed(f'no landmarks back for {sent} images')
    latency = [t - run.sent[s] for s, (t, _) in run.received.items()]
    return run.node_figures() | {
        'fps': (got / seconds, 'Hz'),
        'dropped_percent': (100.0 * (sent - got) / max(sent, 1), '%'),
        'latency_p50_ms': (1e3 * float(np.median(latency)), 'ms'),
        'detect_ms': (float(np.median(run.detect_ms)) if run.detect_ms else float('nan'),
                      'ms'),
        'found': (float(np.mean([n for _, n in run.received.values()])), 'count'),
    }


@contextmanager
def fastdds_profile(path: str | None):
    """$FASTRTPS_DEFAULT_PROFILES_FILE for this process (and the nodes started meanwhile, which
    the launcher gives the large-image transports in any case): the product's (None), ``path``
    or unset (''); restored afterwards (run_all runs every bench in one process)."""
    old = os.environ.get(PROFILE_ENV)
    if path is None:
        os.environ[PROFILE_ENV] = large_data_env()[PROFILE_ENV]
    elif path:
        os.environ[PROFILE_ENV] = path
    else:
        os.environ.pop(PROFILE_ENV, None)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(PROFILE_ENV, None)
        else:
            os.environ[PROFILE_ENV] = old


def run() -> Figures:
    with fastdds_profile(os.environ.get('BENCH_DETECTOR_FASTDDS_PROFILE')):
        return run_targets(float(os.environ.get('BENCH_DETECTOR_SECONDS', '5')))


def run_targets(seconds: float) -> Figures:
    sim = load_simulation(cell_file(CELL))
    scene = SimCamera(sim, SimRobot(sim))
    figures: Figures = {}
    for target, (params, rate, _, _) in TARGETS.items():
        spec = launcher.NodeSpec(NODE, {'cell_file': str(cell_file(CELL)), **params})
        with benchlib.private_domain() as (domain, env), \
                benchlib.running_suite(f'detector_{target}', [spec], env) as suite, \
                benchlib.ros_node('bench_detector', domain) as ros:
            for width, height in RESOLUTIONS:
                images, info = frames_for(scene, target, width, height)
                try:
                    result = measure(ros, images, info, rate, seconds)
                except BenchFailed as exc:
                    raise BenchFailed(f'{target} {width}x{height}: {exc} (log: '
                                      f'{suite.log_dir})', figures) from exc
                figures.update({f'detector_{width}x{height}_{target}_{name}': value
                                for name, value in result.items()})
                if suite.failed():
                    raise BenchFailed(f'{NODE} exited: {suite.failed()}', figures)
    figures['detector_load_average_1min'] = (benchlib.load_average_1min(), 'load')
    return figures


if __name__ == '__main__':
    raise SystemExit(benchlib.main(run))
