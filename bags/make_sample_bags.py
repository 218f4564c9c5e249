"""Make the sample bags in this folder (see README.md): ``python bags/make_sample_bags.py``.

five_point_close: a five-point teach on the mock Sawyer (cell sawyer_close), method rigid.
The suite (mock_robot at 200 Hz, joint_state_monitor, user_frame_solver with the nominal
kinematic model and a temporary data_dir) runs on a private ROS_DOMAIN_ID. This process
records ``/joint_states`` (raw bytes, receive stamps) with bags.writer.BagWriter (mcap, zstd),
touches P1..P5 with the mock (move_to TOUCH), captures each with ``capture_joints`` (HOLD s),
writes each capture as a mark on ``/cobot_calib/captures`` (cobot_calib_msgs/CaptureMark,
ros.marks.capture_mark: header stamp = end of the hold, target = point name, the captured mean
joints and their standard deviation; the bag kept here was made before that message and has
sensor_msgs/JointState marks, read through bags.mark_converter), then calls
``calibrate_user_frame`` (rigid, joint_captures) and writes the live result on ``/user_frame``
(latched) and in ``expected.yaml``.

``--force`` replaces an existing bag. Run from anywhere; uses .venv's python.
"""
from __future__ import annotations

import argparse
import contextlib
import os
from pathlib import Path
import shutil
import sys
import tempfile
import time

from cobot_calib_ros.paths import DEFAULT_CELL

HERE = Path(__file__).resolve().parent
NAME = 'five_point_close'
CELL = DEFAULT_CELL
POINTS = ['P1', 'P2', 'P3', 'P4', 'P5']
METHOD = 'rigid'
HOLD = 0.5                  # [s] capture window
RATE_HZ = 200.0             # mock joint_states rate for the recording
KINEMATICS = 'nominal'
SETTLE = 0.3                # [s] of joint_states kept before and after each hold


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--force', action='store_true', help='replace an existing bag')
    ap.add_argument('--out', default=str(HERE), help='folder for the bags (default: here)')
    args = ap.parse_args(argv)
    out = Path(args.out) / NAME
    if out.exists():
        if not args.force:
            print(f'{out} exists; --force replaces it', file=sys.stderr)
            return 2
        shutil.rmtree(out)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    import domain_coordinator
    with domain_coordinator.domain_id() as domain, \
            tempfile.TemporaryDirectory(prefix='cobot_calib_sample_') as tmp:
        os.environ['ROS_DOMAIN_ID'] = str(domain)
        make(out, Path(tmp), domain)
    return 0


def make(out: Path, tmp: Path, domain: int) -> None:
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    from cobot_calib_msgs.msg import UserFrameCalibration
    from cobot_calib_msgs.srv import CalibrateUserFrame, CaptureJoints, HandGuide

    from cobot_calib_ros.ros.calls import call_service, spin_until
    from cobot_calib_ros.ros.session import session
    from cobot_calib_ros.ros import marks
    from cobot_calib_ros.ros.time import s_to_ns
    from cobot_calib_ros.api.launcher import NodeSpec, Suite
    from cobot_calib_ros import paths
    from cobot_calib_ros.bags import metadata
    from cobot_calib_ros.bags.writer import BagWriter
    from cobot_calib_ros.api import replay_check

    from cobot_calib_ros.bags import interfaces
    store = interfaces.typestore()

    def cdr(msg, msgtype: str) -> bytes:
        # as Fast DDS sends it: rclpy's serialize_message leaves padding bytes uninitialised
        # and may add stray bytes at the end, which rosbags refuses (test/bags/bagutil.py)
        raw = serialize_message(msg)
        try:
            return store.serialize_cdr(store.deserialize_cdr(raw, msgtype), msgtype)
        except Exception:  # noqa: BLE001 - ends in an empty sequence: trim the stray bytes
            for end in range(len(raw) - 1, 3, -1):
                try:
                    return store.serialize_cdr(store.deserialize_cdr(raw[:end], msgtype),
                                               msgtype)
                except Exception:  # noqa: BLE001
                    continue
            raise

    env = dict(os.environ, COBOT_CALIB_DATA=str(tmp / 'data'))
    cell = str(paths.cell_file(CELL))
    suite = Suite(tmp / 'log')
    suite.start([
        NodeSpec('mock_robot', {'cell_file': cell, 'publish_rate_hz': str(RATE_HZ)}),
        NodeSpec('joint_state_monitor', {'expected_rate_hz': str(RATE_HZ)}),
        NodeSpec('user_frame_solver', {'cell_file': cell, 'kinematics': KINEMATICS,
                                       'data_dir': str(tmp / 'data')}),
    ], env=env)
    ros = contextlib.ExitStack()
    node, executor = ros.enter_context(session('sample_bag_maker', domain_id=domain))
    writer = BagWriter(out, compression='zstd')
    try:
        writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [metadata.qos()])
        writer.add_topic(replay_check.CAPTURES_TOPIC, marks.CAPTURE_TYPE,
                         [metadata.qos()])
        writer.add_topic('/user_frame', 'cobot_calib_msgs/msg/UserFrameCalibration',
                         [metadata.qos(durability='transient_local')])
        recording = [False]

        def on_joint_state(data: bytes, info: dict) -> None:
            if recording[0]:
                writer.write('/joint_states', data, info['received_timestamp'],
                             info['source_timestamp'])
        node.create_subscription(JointState, 'joint_states', on_joint_state,
                                 QoSProfile(depth=1000,
                                            reliability=ReliabilityPolicy.RELIABLE), raw=True)
        capture = node.create_client(CaptureJoints, 'capture_joints')
        calibrate = node.create_client(CalibrateUserFrame, 'calibrate_user_frame')
        hand_guide = node.create_client(HandGuide, 'mock_robot/hand_guide')
        for client in (capture, calibrate):
            if not spin_until(node, client.service_is_ready, 30.0, executor):
                raise SystemExit(f'{client.srv_name} not available; logs in {suite.log_dir}')
        deadline = time.monotonic() + 30.0      # joint_state_monitor matched to the mock
        while call_service(node, capture, CaptureJoints.Request(duration=0.1), 10.0,
                           executor).error_code != CaptureJoints.Response.SUCCESS:
            if time.monotonic() > deadline:
                raise SystemExit(f'joint_state_monitor gets no joint_states; logs in '
                                 f'{suite.log_dir}')
        captures = []
        for name in POINTS:
            result = call_service(node, hand_guide, HandGuide.Request(point_name=name), 60.0,
                                  executor)
            if result.error_code != HandGuide.Response.SUCCESS:
                raise SystemExit(f'touch {name}: {result.message}')
            recording[0] = True
            spin_until(node, lambda: False, SETTLE, executor)
            start_ns = time.time_ns()       # the monitor opens its window on arrival
            res = call_service(node, capture, CaptureJoints.Request(duration=HOLD),
                               HOLD + 10.0, executor)
            end_ns = start_ns + s_to_ns(HOLD)
            if res.error_code != CaptureJoints.Response.SUCCESS:
                raise SystemExit(f'capture {name}: {res.message}')
            mark = marks.capture_mark(name, res.name, res.position, res.std, end_ns)
            captures.append(mark)
            spin_until(node, lambda: False, SETTLE, executor)
            recording[0] = False
            writer.write(replay_check.CAPTURES_TOPIC, cdr(mark, marks.CAPTURE_TYPE),
                         end_ns, end_ns)
            # (written after the hold's samples: mcap orders by log time when read)
            print(f'{name}: {res.sample_count} samples, largest spread '
                  f'{max(res.std) * 1e6:.2f} urad', flush=True)
        request = CalibrateUserFrame.Request(
            method=METHOD, point_names=POINTS, kinematics=KINEMATICS,
            joint_captures=[JointState(name=list(c.joint_names), position=list(c.position_rad))
                            for c in captures])
        res = call_service(node, calibrate, request, 60.0, executor)
        if res.error_code != CalibrateUserFrame.Response.SUCCESS:
            raise SystemExit(f'calibrate_user_frame: {res.message}')
        cal: UserFrameCalibration = res.calibration
        now = time.time_ns()
        writer.write('/user_frame', cdr(cal, 'cobot_calib_msgs/msg/UserFrameCalibration'), now,
                     now)
        replay_check.write_expected(out / replay_check.EXPECTED_FILE, {
            'T_base_user': replay_check.matrix(cal),
            'rms_residual': float(cal.rms_residual),
            'method': METHOD,
            'kinematics': KINEMATICS,
            'point_names': POINTS,
            'hold_s': HOLD,
            'joint_states_hz': RATE_HZ,
            'cell': CELL,
            'calibration_id': cal.id,
        })
        print(f'calibration {cal.id}: rms {cal.rms_residual * 1e3:.4f} mm', flush=True)
    finally:
        writer.close()
        ros.close()
        suite.stop()
    size = sum(p.stat().st_size for p in out.iterdir())
    print(f'{out}: {writer.message_count} messages, {size} bytes')


if __name__ == '__main__':
    sys.exit(main())
