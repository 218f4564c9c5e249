"""joint_state_monitor: buffers joint_states and serves hold-window captures.

joint_states arrives on a spin.Companion, so a capture that blocks for its hold
window never holds up the 1 kHz stream.
"""
from __future__ import annotations

import threading

from cobot_calib_msgs.srv import CaptureJoints
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from cobot_calib_ros.core.sensors.joint_buffer import hold_statistics, JointRingBuffer
from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.time import now_ns, stamp_or_now_ns

STALL_TIMEOUT = 3.0     # [s] of wall time without a new sample: the stream has stopped


class JointStateMonitor(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__('joint_state_monitor', **kwargs)
        p = self._declare_parameters()
        self._rate = p['expected_rate_hz']
        self._buffer = JointRingBuffer(p['joint_names'] or None,
                                       int(p['buffer_duration'] * self._rate) + 1)
        self._lock = threading.Lock()
        self._new_sample = threading.Condition(self._lock)
        self._gaps = 0
        self._last_stamp = None
        self._receiver = spin.Companion(self, 'receiver')
        self._receiver.node.create_subscription(
            JointState, 'joint_states', self._on_joint_state,
            QoSProfile(depth=p['qos_depth'], reliability=ReliabilityPolicy.RELIABLE))
        self.create_service(CaptureJoints, 'capture_joints', self._on_capture)
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_timer(1.0, self._publish_diagnostics)

    def destroy_node(self):
        self._receiver.destroy()
        return super().destroy_node()

    def _declare_parameters(self) -> dict:
        values = {
            'expected_rate_hz': read_once(self, 'expected_rate_hz', 1000.0,
                                          'Nominal joint_states rate [Hz]', 1.0, 10000.0),
            'buffer_duration': read_once(self, 'buffer_duration', 10.0,
                                         'Ring buffer length [s]', 1.0, 600.0),
            'capture_duration': declare(self, 'capture_duration', 1.0,
                                        'Default hold window of capture_joints [s]', 0.01, 60.0),
            'min_sample_fraction': declare(
                self, 'min_sample_fraction', 0.5,
                'Refuse a capture with fewer than this fraction of the expected samples [1]',
                0.0, 1.0),
            'max_joint_std': declare(
                self, 'max_joint_std', 1.0e-4,
                'Refuse a capture when a joint spreads more than this: moving [rad]', 0.0, 1.0),
            'qos_depth': read_once(self, 'qos_depth', 1000,
                                   'joint_states subscription queue depth [messages]', 1,
                                   100000),
            'joint_names': read_once(self, 'joint_names', [''],
                                     'Expected joint names; empty = take them from the '
                                     'first message'),
        }
        values['joint_names'] = [n for n in values['joint_names'] if n]
        return values

    def _on_joint_state(self, msg: JointState) -> None:
        # Windows are in publish time (header stamps, node clock): samples queued during a
        # motion and delivered late must not count as the hold that follows it.
        stamp = stamp_or_now_ns(self, msg.header.stamp) * 1e-9
        with self._lock:
            why = self._buffer.add(stamp, list(msg.name), list(msg.position))
            if why is None:
                self._count_gap(stamp)
                self._new_sample.notify_all()
        if why is not None:
            self.get_logger().warning(
                f'dropped a malformed joint_states message ({why.value}); '
                f'{sum(self._buffer.rejected.values())} dropped so far',
                throttle_duration_sec=5.0)

    def _count_gap(self, stamp: float) -> None:
        """Missing samples inferred from header stamps (the publisher's nominal period)."""
        if self._last_stamp is not None:
            missing = round((stamp - self._last_stamp) * self._rate) - 1
            self._gaps += max(0, missing)
        self._last_stamp = stamp

    def _on_capture(self, request, response):
        duration = request.duration or self.get_parameter('capture_duration').value
        if not 0.0 < duration <= self.get_parameter('buffer_duration').value:
            response.error_code = CaptureJoints.Response.BAD_REQUEST
            response.message = (f'duration {duration} s must be > 0 and within the buffer '
                                f'({self.get_parameter("buffer_duration").value} s)')
            return response
        t0 = now_ns(self) * 1e-9
        t1 = t0 + duration
        with self._lock:
            self._wait_until(t1)
            times, positions = self._buffer.window(t0, t1)
            names = list(self._buffer.joint_names or [])
        capture = hold_statistics(
            times, positions, duration, self._rate,
            self.get_parameter('min_sample_fraction').value,
            self.get_parameter('max_joint_std').value, names)
        response.error_code = {'': CaptureJoints.Response.SUCCESS,
                               'no_data': CaptureJoints.Response.NO_DATA,
                               'moving': CaptureJoints.Response.MOVING}[capture.reason]
        response.message = capture.message
        response.name = names
        response.position = capture.mean.tolist()
        response.std = capture.std.tolist()
        response.sample_count = capture.count
        response.window = capture.span
        if not capture.ok:
            self.get_logger().warning(f'capture_joints refused: {capture.message}')
        return response

    def _wait_until(self, t1: float) -> None:
        """Until a sample stamped at or after t1 [s] arrives (the window is over in ROS time,
        whatever its rate to wall time), or the stream stalls. Holds self._lock."""
        count = self._buffer.count
        while self._buffer.latest_time < t1:
            self._new_sample.wait(timeout=STALL_TIMEOUT)
            if self._buffer.count == count:
                return                  # nothing new for STALL_TIMEOUT: no data
            count = self._buffer.count

    def _publish_diagnostics(self) -> None:
        with self._lock:
            values = {'received': self._buffer.count, 'missing_by_stamp': self._gaps,
                      **{f'dropped_{r.value}': n for r, n in self._buffer.rejected.items()}}
        status = DiagnosticStatus(
            level=DiagnosticStatus.OK, name=f'{self.get_name()}: joint_states',
            message='ok', hardware_id='joint_states',
            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        if any(v for k, v in values.items() if k.startswith('dropped_')):
            status.level, status.message = DiagnosticStatus.WARN, 'malformed messages dropped'
        self._diag_pub.publish(DiagnosticArray(status=[status]))


def main(args=None) -> None:
    spin.run(JointStateMonitor, args)


if __name__ == '__main__':
    main()
