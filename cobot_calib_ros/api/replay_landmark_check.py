"""`cobot-calib replay BAG --check` for a landmark bag: the user frame from the replayed images.

A landmark bag (bags/make_landmark_bag.py, bags/landmark_multi_close) holds the wrist camera's
``/wrist_camera/image_raw`` and ``/wrist_camera/camera_info`` around every view of a
``landmark_multi`` calibration, the view marks user_frame_solver published on
``/cobot_calib/captures`` (MARKS_TOPIC, cobot_calib_msgs/CaptureMark, ros.marks: header.stamp =
the ROS time after which landmarks count, target = ``landmark_<id>``, the captured joints [rad]
in the model's joint order and their standard deviation; the sample bag's JointState marks are
read through bags.mark_converter) and the live, latched
``/user_frame``; next to it ``expected.yaml``: T_base_user (the calibration's matrix), method,
kinematics, hand_eye, cell, calibration id, rms, the solver's max_rms_error / max_scale_error
and, per view, the stamp of the image the live solver used.

The check starts a landmark_detector on a private ROS_DOMAIN_ID (``use_sim_time: true``, the
bag's cell), replays the images and camera_info with ``/clock`` (bags.player.BagPlayer) and
collects the ``landmarks`` it publishes. Each mark is paired as the live views do
(core.landmarks.views.measure_frame): among the landmarks messages of images stamped after the
mark, in stamp order, the first that
shows the mark's marker, else the last of the first LANDMARK_IMAGES. The mark's joints go
through the model's chain (``kinematics``; the nominal model) with the hand-eye as tool (the
cell's nominal one: ``hand_eye: nominal``), and the frame is fitted with the core's
views.observation and views.landmark_frame, as the live solver does (:func:`fit_frame`). The
frame must be within TOL_M and TOL_RAD of expected.yaml's.

landmark_detector takes images best effort and keeps only the newest when it falls behind
(one slot before its search), so the replay is flow-controlled (bags.player.FlowControl): the
player publishes the next image only when the previous one came back as a landmarks message
(WINDOW 1), so no image is replaced however slowly the machine lets the detector run; the rate
(DEFAULT_RATE, at most MAX_RATE) only caps the speed. Until the first landmarks come back the
player sends the first camera_info and image again (the warm-up: an event, not a sleep). Every
image must come back as a landmarks message: a pass that misses some (lost on the best-effort
way) is followed by another pass, of the images still missing and their camera_info, at half
the rate (not below MIN_RATE), up to PASSES. Detection is per image and deterministic, so which
pass brought an image's landmarks does not change the result.
"""
from __future__ import annotations

from dataclasses import dataclass
import re
import threading
import time
from typing import Callable

import numpy as np

from cobot_calib_ros.api import replay_check, replay_harness
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.ros.marks import CAPTURES_TOPIC as MARKS_TOPIC
from cobot_calib_ros.ros.time import header_ns

IMAGE_TOPIC = '/wrist_camera/image_raw'
INFO_TOPIC = '/wrist_camera/camera_info'
USER_FRAME_TOPIC = '/user_frame'
EXPECTED_FILE = replay_check.EXPECTED_FILE
TOL_M = 1e-6
TOL_RAD = 1e-6
DEFAULT_RATE = 2.0
MAX_RATE = 20.0
PASSES = 4
MIN_RATE = 0.5
WINDOW = 1               # images out at most: the detector keeps only the newest
DRAIN_TIMEOUT = 2.0      # [s] after a pass without a new landmarks message: the rest is lost
DEFAULT_MAX_RMS = 1e-3   # user_frame_solver's defaults, when expected.yaml does not say
DEFAULT_MAX_SCALE = 0.01
MARKER = re.compile(r'landmark_(\d+)$')


CheckError = replay_check.CheckError


def marker_of(mark) -> int:
    """The marker a view mark was planned for (target ``landmark_<id>``)."""
    found = MARKER.match(mark.target)
    if not found:
        raise CheckError(f'mark target {mark.target!r} is not landmark_<id>')
    return int(found.group(1))


def shows(msg, marker_id: int) -> bool:
    """A landmarks message shows the single marker ``marker_id``."""
    return any(lm.id == marker_id and lm.kind == lm.KIND_MARKER for lm in msg.landmarks)


def pair(marks: list, landmarks: list) -> list[tuple[int, object]]:
    """For each mark, (image stamp [ns], landmarks message) as measure_frame takes it:
    among the messages stamped after the mark, in stamp order, the first showing the mark's
    marker, else the last of the first LANDMARK_IMAGES. CheckError if there is none."""
    from cobot_calib_ros.core.landmarks.views import LANDMARK_IMAGES
    ordered = sorted(((header_ns(m), m) for m in landmarks), key=lambda x: x[0])
    out = []
    for k, mark in enumerate(marks):
        t0, marker = header_ns(mark), marker_of(mark)
        seen = [x for x in ordered if x[0] > t0][:LANDMARK_IMAGES]
        if not seen:
            raise CheckError(f'mark #{k} ({mark.target}): no landmarks message of an '
                             'image stamped after it')
        out.append(next((x for x in seen if shows(x[1], marker)), seen[-1]))
    return out


def fit_frame(marks: list, landmarks: list, *, cell_name: str, kinematics: str = 'nominal',
              max_rms_error: float = DEFAULT_MAX_RMS,
              max_scale_error: float = DEFAULT_MAX_SCALE, method: str = 'landmark_multi'):
    """The landmark frame from the view marks and the landmarks message paired with each, as
    the live solver fits it (core.landmarks.views.measure_frame): T_base_optical = FK of
    the mark's joints on the model's chain with the cell's nominal hand-eye as tool, then
    views.observation per marker and views.landmark_frame. A LandmarkFit; CheckError when the
    fit fails."""
    from cobot_calib_ros import paths
    from cobot_calib_ros.core import kinematics as kin
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.core.landmarks import views
    from cobot_calib_ros.core.rig import Rig
    from cobot_calib_ros.ros import convert
    if kinematics != 'nominal':
        raise CheckError(f'kinematics {kinematics!r}: a landmark bag is checked on the nominal '
                         'model only')
    cell = load_cell(paths.cell_file(cell_name))
    model = kin.model_for(cell)
    chain = Rig(cell, model=model).chain('camera')      # the cell's nominal hand-eye
    order = list(model.joint_names)
    observations = []
    for k, (mark, msg) in enumerate(zip(marks, landmarks)):
        if list(mark.joint_names) != order:
            raise CheckError(f'mark #{k}: joints {list(mark.joint_names)}, the model has {order}')
        T_base_optical = kin.fk(chain, np.array(mark.position_rad, dtype=float))
        observations += [views.observation(lm.id, T_base_optical,
                                           convert.pose_to_matrix(lm.pose.pose),
                                           lm.pose.covariance)
                         for lm in msg.landmarks if lm.kind == lm.KIND_MARKER]
    result = views.landmark_frame(method, cell, observations, max_rms_error=max_rms_error,
                                  max_scale_error=max_scale_error)
    if not result:
        raise CheckError(f'the landmark fit failed: {result.message}')
    return result


write_expected = replay_check.write_expected
read_expected = replay_check.read_expected


def is_landmark_bag(bag) -> bool:
    """A bag this check applies to: camera images and view marks."""
    return IMAGE_TOPIC in bag.topics and MARKS_TOPIC in bag.topics


@dataclass
class LandmarkCheckResult(replay_harness.Verdict):
    code: ErrorCode                 # replay_harness.Verdict: SUCCESS or IMPLAUSIBLE_FIT
    translation_m: float
    rotation_rad: float
    T_replayed: np.ndarray
    T_expected: np.ndarray
    rms_replayed: float
    rms_expected: float
    marks: int
    images: int                     # images in the bag, all turned into landmarks
    passes: int
    pairing_differs: list           # marks whose image differs from expected.yaml's views
    wall_s: float
    report: str = ''


def run_check(bag_path: str, rate: float = DEFAULT_RATE, say: Callable[[str], None] = print,
              clock_hz: float = 40.0) -> LandmarkCheckResult:
    """Replay the bag's images through landmark_detector, fit, compare; see the module doc."""
    from cobot_calib_ros.core.frames import transform_error
    from cobot_calib_ros.bags.reader import open_bag
    if not 0 < rate <= MAX_RATE:
        raise CheckError(f'a landmark bag replays at a finite rate up to {MAX_RATE:g} '
                         f'(landmark_detector takes images best effort); got {rate:g}')
    expected_path, expected = read_expected(bag_path)
    method = str(expected.get('method', 'landmark_multi'))
    if str(expected.get('hand_eye', 'nominal')) != 'nominal':
        raise CheckError(f'{expected_path}: hand_eye {expected["hand_eye"]!r}; only the '
                         "cell's nominal hand-eye can be checked")
    started = time.monotonic()
    with open_bag(bag_path) as bag:
        for topic in (IMAGE_TOPIC, INFO_TOPIC, MARKS_TOPIC):
            if topic not in bag.topics or not bag.topics[topic].count:
                raise CheckError(f'{bag.path}: nothing on {topic}')
        for warning in bag.warnings:
            say(f'warning: {warning}')
        marks = [bag.deserialize(m.rawdata, m.msgtype) for m in bag.messages([MARKS_TOPIC])]
        stamps = {(m.topic, m.timestamp_ns): header_ns(bag.deserialize(m.rawdata, m.msgtype))
                  for m in bag.messages([IMAGE_TOPIC, INFO_TOPIC])}
        needed = {s for (topic, _), s in stamps.items() if topic == IMAGE_TOPIC}
        received, passes = _replay(bag, expected, rate, clock_hz, needed, stamps, say)
    landmarks = [received[s] for s in sorted(needed)]
    pairs = pair(marks, landmarks)
    views = expected.get('views') or []
    differs = [k for k, (s, _) in enumerate(pairs)
               if k < len(views) and int(views[k]['image_stamp_ns']) != s]
    fit = fit_frame(marks, [msg for _, msg in pairs], cell_name=str(expected.get('cell')),
                    kinematics=str(expected.get('kinematics', 'nominal')),
                    max_rms_error=float(expected.get('max_rms_error', DEFAULT_MAX_RMS)),
                    max_scale_error=float(expected.get('max_scale_error', DEFAULT_MAX_SCALE)),
                    method=method)
    T = np.asarray(fit.fit.M, dtype=float)
    dt, dr = transform_error(T, expected['T_base_user'])
    code = replay_harness.verdict(bool(dt <= TOL_M and dr <= TOL_RAD and np.isfinite(dt)
                                       and np.isfinite(dr)))
    report = (f'replayed {len(needed)} images through landmark_detector ({passes} pass'
              f'{"es" if passes > 1 else ""}), {len(marks)} views paired'
              + (f' ({len(differs)} with another image than the live solver: marks {differs})'
                 if differs else ' with the images the live solver used')
              + f'; {method} frame (rms {fit.fit.rms * 1e3:.4f} mm) vs {expected_path}: '
              f'translation differs by {dt:.3e} m (tolerance {TOL_M:g}), rotation by '
              f'{dr:.3e} rad (tolerance {TOL_RAD:g})')
    say(report)
    return LandmarkCheckResult(code, dt, dr, T, expected['T_base_user'], float(fit.fit.rms),
                               float(expected.get('rms_residual', float('nan'))), len(marks),
                               len(needed), passes, differs, time.monotonic() - started, report)


def check(bag_path: str, rate: float | None = None, say: Callable[[str], None] = print
          ) -> LandmarkCheckResult:
    """The result for the CLI, its report with both matrices when it failed; CheckError when
    the check cannot run."""
    result = run_check(bag_path, DEFAULT_RATE if rate is None else rate, say=say)
    if not result:
        result.report += ('\n  replayed:\n' + format_matrix(result.T_replayed)
                          + '\n  expected:\n' + format_matrix(result.T_expected))
    return result


def format_matrix(T: np.ndarray) -> str:
    return '\n'.join('    [' + ', '.join(f'{v: .9f}' for v in row) + ']' for row in T)


class _Missing:
    """The bag as BagPlayer sees it, with only the images (and their camera_info) that have
    not come back yet: a later pass replays only those."""

    def __init__(self, bag, stamps: dict, missing: set[int]) -> None:
        self._bag, self._stamps, self._missing = bag, stamps, missing
        self.path, self.topics, self.warnings = bag.path, bag.topics, bag.warnings

    def select(self, topics=None):
        return self._bag.select(topics)

    def messages(self, topics=None, start_ns=None, stop_ns=None):
        return (m for m in self._bag.messages(topics, start_ns, stop_ns)
                if self._stamps.get((m.topic, m.timestamp_ns)) in self._missing)


def _replay(bag, expected: dict, rate: float, clock_hz: float, needed: set[int], stamps: dict,
            say) -> tuple[dict, int]:
    """Play the images and camera_info into a landmark_detector, pass after pass until every
    image stamped ``needed`` came back as a landmarks message (at most PASSES; a later pass
    plays only the images still missing, with their camera_info): ({image stamp [ns]: the first
    landmarks message for it}, passes). ``stamps``: (topic, log time) -> header stamp."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from cobot_calib_msgs.msg import Landmarks

    from cobot_calib_ros import paths
    from cobot_calib_ros.api.launcher import NodeSpec
    from cobot_calib_ros.bags.player import FlowControl

    received: dict[int, object] = {}
    arrived = [0]                   # landmarks messages, duplicates included (flow control)
    lock = threading.Lock()

    def on_landmarks(msg: Landmarks) -> None:
        with lock:
            received.setdefault(header_ns(msg), msg)
            arrived[0] += 1

    def missing() -> set[int]:
        with lock:
            return needed - set(received)
    cell = str(paths.cell_file(str(expected.get('cell', paths.DEFAULT_CELL))))
    with replay_harness.replay_suite(
            lambda tmp: [NodeSpec('landmark_detector', {'cell_file': cell})],
            'cobot_calib_replay_landmark_check', say) as harness:
        sub = harness.node.create_subscription(
            Landmarks, 'landmarks', on_landmarks,
            QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        harness.wait_for(lambda: sub.get_publisher_count() > 0, 'landmark_detector')
        passes = 0
        flow = FlowControl(WINDOW, lambda: arrived[0], frozenset([IMAGE_TOPIC]))
        with harness.playing(bag, [IMAGE_TOPIC, INFO_TOPIC], rate, clock_hz,
                             waits_for='landmark_detector', flow=flow) as player:
            for passes in replay_harness.passes(player, rate, PASSES, MIN_RATE):
                if passes > 1:
                    player.bag = _Missing(bag, stamps, missing())
                result = player.play()
                replay_harness.drain(lambda: len(received), lambda: not missing(),
                                     DRAIN_TIMEOUT)
                lost = len(missing())
                say(f'pass {passes}: replayed {result.published} messages in '
                    f'{result.wall_s:.2f} s ({result.speed:.1f}x real time, rate '
                    f'{player.rate:g}, window {WINDOW}{replay_harness.flow_note(result)}); '
                    + (f'{lost} of {len(needed)} images without landmarks yet'
                       if lost else f'landmarks of all {len(needed)} images in'))
                if not lost:
                    break
        lost = sorted(missing())
        if lost:
            raise CheckError(f'{len(lost)} of {len(needed)} images (first stamped {lost[0]} ns) '
                             f'gave no landmarks in {PASSES} passes; replay at a lower --rate; '
                             f'logs in {harness.suite.log_dir}')
        with lock:
            return dict(received), passes
