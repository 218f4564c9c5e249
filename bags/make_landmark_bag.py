"""Make bags/landmark_multi_close (see README.md): ``python bags/make_landmark_bag.py [--force]``.

A landmark_multi user frame on the mock Sawyer (cell sawyer_close) with the wrist camera's
images. The suite (mock_robot, joint_state_monitor, user_frame_solver with ``kinematics:
nominal`` and a temporary data_dir, mock_camera, landmark_detector) runs on a private
ROS_DOMAIN_ID (domain_coordinator, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST). This process
records, with the project's own recorder (bags.recorder.BagRecorder, into a temporary bag),
``/wrist_camera/image_raw``, ``/wrist_camera/camera_info``, ``/cobot_calib/captures`` (the
view marks user_frame_solver publishes), ``/user_frame`` and, to tie every view to the image
the solver used, ``/landmarks``. It calls ``calibrate_user_frame`` with ``{method: rigid,
point_names: [P1..P5]}`` (the landmark views are planned around the active user frame), then
``{method: landmark_multi}``.

Then it checks the recording: the landmarks the live solver took (the first message of an image
stamped after each mark that shows the mark's marker, else the last of the first
LANDMARK_IMAGES: core.landmarks.views), fitted again with the core's views.observation and
views.landmark_frame on the nominal chain with the cell's nominal hand-eye as tool, must give
the live frame (to 1e-12 m / rad). It writes the sample bag with only what the fit needs:
for every mark the images the live detector turned into landmarks messages from the first
after the mark up to the one the solver used (an image the live detector dropped is left out:
a replay would otherwise use it), one camera_info per kept image (its own, and the one before
the first image), all marks and the last ``/user_frame``; zstd chunks, Jazzy's metadata
(bags.writer.BagWriter, the recorded QoS and type hashes). ``expected.yaml`` holds the live
result and, per view, the image the solver used.

``--force`` replaces an existing bag; ``--keep DIR`` keeps the full recording there.
"""
from __future__ import annotations

import argparse
import contextlib
import os
from pathlib import Path
import shutil
import sys
import tempfile
import threading
import time

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
from cobot_calib_ros.paths import DEFAULT_CELL  # noqa: E402 - after ROOT is on the path
from cobot_calib_ros.ros.marks import CAPTURES_TOPIC  # noqa: E402

NAME = 'landmark_multi_close'
CELL = DEFAULT_CELL
POINTS = ['P1', 'P2', 'P3', 'P4', 'P5']
METHOD = 'landmark_multi'
KINEMATICS = 'nominal'
IMAGE_TOPIC = '/wrist_camera/image_raw'
INFO_TOPIC = '/wrist_camera/camera_info'
USER_FRAME_TOPIC = '/user_frame'
LANDMARKS_TOPIC = '/landmarks'
RECORDED = [IMAGE_TOPIC, INFO_TOPIC, CAPTURES_TOPIC, USER_FRAME_TOPIC, LANDMARKS_TOPIC]
KEPT = [IMAGE_TOPIC, INFO_TOPIC, CAPTURES_TOPIC, USER_FRAME_TOPIC]
SESSION_FILE = 'session.yaml'   # with --keep: the solver's parameters of the session
ZSTD_LEVEL = 19                 # zstd level of the sample's chunks (the writer's default: 3)
CHUNK_SIZE = 8 << 20            # [bytes] one chunk for the whole sample: 3.27 against 3.38 MB
SUITE = ('mock_robot', 'joint_state_monitor', 'user_frame_solver', 'mock_camera',
         'landmark_detector')


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--force', action='store_true', help='replace an existing bag')
    ap.add_argument('--out', default=str(HERE), help='folder for the bag (default: here)')
    ap.add_argument('--keep', metavar='DIR', help='keep the full recording in DIR')
    ap.add_argument('--from', dest='source', metavar='DIR',
                    help='cut the sample from a recording kept with --keep (no new session)')
    args = ap.parse_args(argv)
    out = Path(args.out) / NAME
    if out.exists():
        if not args.force:
            print(f'{out} exists; --force replaces it', file=sys.stderr)
            return 2
        shutil.rmtree(out)
    if args.source:
        raw = Path(args.source) / 'recording'
        write_sample(raw, out, read_session(raw))
        return 0
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    import domain_coordinator
    with domain_coordinator.domain_id() as domain, \
            tempfile.TemporaryDirectory(prefix='cobot_calib_sample_') as tmp:
        os.environ['ROS_DOMAIN_ID'] = str(domain)
        raw = Path(tmp) / 'recording'
        live = record(raw, Path(tmp), domain)
        if args.keep:
            import yaml
            (raw / SESSION_FILE).write_text(yaml.safe_dump({'params': live['params']}))
            shutil.copytree(raw, Path(args.keep) / raw.name)
        write_sample(raw, out, live)
    return 0


def record(raw: Path, tmp: Path, domain: int) -> dict:
    """Run the session and record it into ``raw``; the live calibrations and the solver's
    parameters."""
    from rclpy.executors import SingleThreadedExecutor
    from cobot_calib_msgs.srv import CalibrateUserFrame, CaptureJoints

    from cobot_calib_ros.ros.calls import call_service, spin_until
    from cobot_calib_ros.ros.session import session
    from cobot_calib_ros.api.launcher import Suite, suite_specs
    from cobot_calib_ros.bags.recorder import BagRecorder

    env = dict(os.environ, COBOT_CALIB_DATA=str(tmp / 'data'))
    suite = Suite(tmp / 'log')
    suite.start(suite_specs(CELL, SUITE, overrides={
        'user_frame_solver': {'kinematics': KINEMATICS, 'data_dir': str(tmp / 'data')}}),
        env=env)
    print(f'suite on ROS_DOMAIN_ID={domain}, logs in {suite.log_dir}', flush=True)
    ros = contextlib.ExitStack()
    node, executor = ros.enter_context(session('landmark_bag_maker', domain_id=domain))
    recorder = BagRecorder(str(raw), RECORDED, report=lambda s: print(s, flush=True),
                           context=node.context)
    rec_executor = SingleThreadedExecutor(context=node.context)
    rec_executor.add_node(recorder)
    running = threading.Event()
    running.set()

    def spin_recorder() -> None:
        while running.is_set() and node.context.ok():
            rec_executor.spin_once(timeout_sec=0.05)
    spinner = threading.Thread(target=spin_recorder, daemon=True)
    spinner.start()
    try:
        calibrate = node.create_client(CalibrateUserFrame, 'calibrate_user_frame')
        if not spin_until(node, calibrate.service_is_ready, 60.0, executor):
            raise SystemExit(f'calibrate_user_frame not available; logs in {suite.log_dir}')
        capture = node.create_client(CaptureJoints, 'capture_joints')
        deadline = time.monotonic() + 60.0      # joint_state_monitor matched to the mock
        while call_service(node, capture, CaptureJoints.Request(duration=0.1), 10.0,
                           executor).error_code != CaptureJoints.Response.SUCCESS:
            if time.monotonic() > deadline:
                raise SystemExit(f'joint_state_monitor gets no joint_states; logs in '
                                 f'{suite.log_dir}')
            spin_until(node, lambda: False, 0.25, executor)
        deadline = time.monotonic() + 60.0
        while set(recorder.subscriptions_by_topic) != set(RECORDED):
            if time.monotonic() > deadline:
                missing = set(RECORDED) - set(recorder.subscriptions_by_topic)
                raise SystemExit(f'no publisher of {sorted(missing)} within 60 s; logs in '
                                 f'{suite.log_dir}')
            spin_until(node, lambda: False, 0.25, executor)
        results = {}
        for method, names in (('rigid', POINTS), (METHOD, [])):
            started = time.monotonic()
            res = call_service(node, calibrate, CalibrateUserFrame.Request(
                method=method, point_names=names, kinematics=KINEMATICS), 180.0, executor)
            if res.error_code != CalibrateUserFrame.Response.SUCCESS:
                raise SystemExit(f'calibrate_user_frame {method}: {res.message}; logs in '
                                 f'{suite.log_dir}')
            results[method] = res.calibration
            print(f'{method}: {res.calibration.id}, rms {res.calibration.rms_residual * 1e3:.4f}'
                  f' mm in {time.monotonic() - started:.1f} s', flush=True)
        spin_until(node, lambda: False, 1.5, executor)     # the last messages reach the recorder
        params = {}
        from rcl_interfaces.srv import GetParameters
        get = node.create_client(GetParameters, '/user_frame_solver/get_parameters')
        names = ['max_rms_error', 'max_scale_error', 'capture_duration']
        answer = call_service(node, get, GetParameters.Request(names=names), 10.0, executor)
        params = {n: float(v.double_value) for n, v in zip(names, answer.values)}
    finally:
        running.clear()
        spinner.join(timeout=2.0)
        recorder.destroy_node()
        ros.close()
        suite.stop()
    return {'calibrations': results, 'params': params}


def read_session(raw: Path) -> dict:
    """What record() returns, from a recording kept with --keep: the calibrations from its
    /user_frame messages (the rigid one first, the landmark one last)."""
    import yaml
    from cobot_calib_ros.bags.reader import open_bag
    with open_bag(raw) as bag:
        frames = [bag.deserialize(m.rawdata, m.msgtype) for m in bag.messages([USER_FRAME_TOPIC])]
    rigid = [f for f in frames if f.method == 'rigid']
    landmark = [f for f in frames if f.method == METHOD]
    if not rigid or not landmark:
        raise SystemExit(f'{raw}: no rigid and {METHOD} calibrations on {USER_FRAME_TOPIC}')
    params = yaml.safe_load((raw / SESSION_FILE).read_text())['params']
    return {'calibrations': {'rigid': rigid[-1], METHOD: landmark[-1]}, 'params': params}


@contextlib.contextmanager
def zstd_level(level: int):
    """mcap's writer compresses chunks with zstandard.compress (level 3); the noisy camera
    images take a higher level to stay well under 4 MB (level 19: 6.5 MB of images in
    3.3 MB). Readers do not care about the level."""
    import mcap.writer
    import zstandard
    saved = mcap.writer.zstandard

    class Zstd:
        @staticmethod
        def compress(data: bytes) -> bytes:
            return zstandard.ZstdCompressor(level=level).compress(data)
    mcap.writer.zstandard = Zstd
    try:
        yield
    finally:
        mcap.writer.zstandard = saved


def write_sample(raw: Path, out: Path, live: dict) -> None:
    """Check the recording against the live frame; write the light sample bag and
    expected.yaml."""
    import numpy as np

    from cobot_calib_ros.api import replay_check, replay_landmark_check as check
    from cobot_calib_ros.bags.reader import open_bag
    from cobot_calib_ros.bags.writer import BagWriter
    from cobot_calib_ros.core.frames import transform_error
    from cobot_calib_ros.ros.time import header_ns

    cal = live['calibrations'][METHOD]
    rigid = live['calibrations']['rigid']
    params = live['params']
    with open_bag(raw) as bag:
        counts = {t: bag.topics[t].count for t in RECORDED if t in bag.topics}
        print(f'recorded: {counts}', flush=True)
        marks = [bag.deserialize(m.rawdata, m.msgtype) for m in bag.messages([CAPTURES_TOPIC])]
        landmarks = [bag.deserialize(m.rawdata, m.msgtype)
                     for m in bag.messages([LANDMARKS_TOPIC])]
        frames = [bag.deserialize(m.rawdata, m.msgtype) for m in bag.messages([USER_FRAME_TOPIC])]
        images = {}                 # header stamp -> BagMessage
        for m in bag.messages([IMAGE_TOPIC]):
            images.setdefault(header_ns(bag.deserialize(m.rawdata, m.msgtype)), m)
        infos = [(header_ns(bag.deserialize(m.rawdata, m.msgtype)), m)
                 for m in bag.messages([INFO_TOPIC])]
        if not frames or frames[-1].id != cal.id:
            raise SystemExit(f'the last {USER_FRAME_TOPIC} recorded is not {cal.id}')
        # which images the live solver looked at and used (views.measure_frame's rule)
        picks = check.pair(marks, landmarks)
        processed = sorted(header_ns(lm) for lm in landmarks)
        wanted, dropped = set(), 0
        for k, (mark, (used, _)) in enumerate(zip(marks, picks)):
            looked = [s for s in processed if header_ns(mark) < s <= used]
            lost = [s for s in looked if s not in images]
            if lost:
                raise SystemExit(f'mark #{k}: the recorder lost the image stamped {lost[0]}; '
                                 'make the bag again')
            wanted.update(looked)
            dropped += sum(1 for s in images if header_ns(mark) < s < used and s not in looked)
        print(f'{len(marks)} marks; {len(wanted)} images kept; {dropped} image(s) between a '
              'mark and the one used never reached the live solver (left out)', flush=True)
        # the live landmarks, fitted again by the check's own code: the live frame exactly
        fit = check.fit_frame(marks, [lm for _, lm in picks], cell_name=CELL,
                              max_rms_error=params['max_rms_error'],
                              max_scale_error=params['max_scale_error'])
        T_live = np.array(replay_check.matrix(cal))
        dt, dr = transform_error(np.asarray(fit.fit.M), T_live)
        print(f'offline fit of the live landmarks vs the live frame: {dt:.3e} m, {dr:.3e} rad',
              flush=True)
        if dt > 1e-12 or dr > 1e-12:
            raise SystemExit('the live landmarks do not give the live frame again; not written')
        first = min(wanted)
        before = [m for s, m in infos
                  if m.timestamp_ns < images[first].timestamp_ns and s not in wanted]
        kept_infos = [m for s, m in infos if s in wanted] + before[-1:]
        with zstd_level(ZSTD_LEVEL):
            writer = BagWriter(out, compression='zstd', chunk_size=CHUNK_SIZE,
                               flush_period=1e9)
            count = write_rows(writer, bag, images, wanted, kept_infos)

    write_expected(out, cal, rigid, params, marks, picks)
    size = sum(p.stat().st_size for p in out.iterdir())
    print(f'{out}: {count} messages ({len(wanted)} images, {len(kept_infos)} camera_info, '
          f'{len(marks)} marks, 1 user frame), {size} bytes', flush=True)


def write_rows(writer, bag, images: dict, wanted: set[int], kept_infos: list) -> int:
    """The kept images and camera_info, every mark and the last /user_frame, in receive
    order, with the recorded QoS and type hashes; the message count."""
    try:
        for topic in KEPT:
            info = bag.topics[topic]
            writer.add_topic(topic, info.type, info.offered_qos, type_hash=info.type_hash)
        rows = [images[s] for s in wanted] + kept_infos
        rows += list(bag.messages([CAPTURES_TOPIC]))
        rows += list(bag.messages([USER_FRAME_TOPIC]))[-1:]
        for m in sorted(rows, key=lambda m: m.timestamp_ns):
            writer.write(m.topic, m.rawdata, m.timestamp_ns, m.timestamp_ns)
    finally:
        writer.close()
    return writer.message_count


def write_expected(out: Path, cal, rigid, params: dict, marks: list, picks: list) -> None:
    from cobot_calib_ros.api import replay_check, replay_landmark_check as check
    check.write_expected(out / check.EXPECTED_FILE, {
        'T_base_user': replay_check.matrix(cal),
        'rms_residual': float(cal.rms_residual),
        'method': METHOD,
        'kinematics': str(cal.kinematics or KINEMATICS),
        'hand_eye': 'nominal',
        'cell': CELL,
        'calibration_id': cal.id,
        'max_rms_error': params['max_rms_error'],
        'max_scale_error': params['max_scale_error'],
        'planned_by': {'method': 'rigid', 'point_names': POINTS, 'calibration_id': rigid.id,
                       'T_base_user': replay_check.matrix(rigid)},
        'views': [{'mark': k, 'marker': check.marker_of(mark), 'image_stamp_ns': s,
                   'markers_seen': sorted(lm.id for lm in msg.landmarks
                                          if lm.kind == lm.KIND_MARKER)}
                  for k, (mark, (s, msg)) in enumerate(zip(marks, picks))],
    })


if __name__ == '__main__':
    sys.exit(main())
