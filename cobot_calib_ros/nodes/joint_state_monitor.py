"""joint_state_monitor: buffers joint_states and serves hold-window captures.

joint_states arrive in batches on a ros.batch_reader.BatchReader thread (no executor wake per
message: 1 kHz cost ~25 % of a core through the executor), so a capture that blocks for its
hold window never holds up the 1 kHz stream.

/diagnostics (1 Hz, from a spin.Companion, so a capture never delays it): ``received``
(every message taken from the topic), ``dropped_<reason>`` (malformed ones among them),
``missing_by_stamp`` (gaps in the header stamps at the expected rate: losses and publisher
stalls alike), ``receive_rate_hz`` over the last second, ``no_message_for_ms`` (since the last
message, or since start before the first), and ``mark_stamp_s`` with ``received_before_mark``
(see core.sensors.joint_buffer.StampMarks); every value is an integer. WARN when no
joint_states came for more than NO_DATA_TIMEOUT, or malformed ones did.
"""
from __future__ import annotations

import threading
import time

from cobot_calib_msgs.srv import CaptureJoints
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.sensors.joint_buffer import (HOLD_EXTENSIONS, hold_statistics,
                                                      JointRingBuffer, samples_needed,
                                                      StampGaps, StampMarks)
from cobot_calib_ros.ros import results, spin
from cobot_calib_ros.ros.batch_reader import BatchReader
from cobot_calib_ros.ros.diagnostics import Diagnostics, OK, RateMeter, status_name, WARN
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.joint_state_bytes import JointStateBytes
from cobot_calib_ros.ros.time import now_ns, NS_PER_S, stamp_to_ns, wait_past

STALL_TIMEOUT = 3.0     # [s] of wall time without a new sample: the stream has stopped
# [s] a capture waits for the first joint_states of a node that has had none yet: just
# (re)started, its subscription may not be matched with the publisher (seconds under load);
# with none by then the capture ends at once (NO_DATA), inside a client's 10 s
FIRST_SAMPLE_TIMEOUT = 5.0
NO_DATA_TIMEOUT = 1.0   # [s] of wall time without a message: /diagnostics warns


class JointStateMonitor(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__('joint_state_monitor', **kwargs)
        p = self._declare_parameters()
        self._rate = p['expected_rate_hz']
        self._buffer = JointRingBuffer(p['joint_names'] or None,
                                       int(p['buffer_duration'] * self._rate) + 1)
        self._lock = threading.Lock()
        self._new_sample = threading.Condition(self._lock)
        self._gaps = StampGaps(self._rate)
        self._marks = StampMarks()                  # every message taken, by stamp second
        self._last_arrival = self._started = time.monotonic()
        self._dropped_reported = 0
        self._rate_meter = RateMeter()
        self._receiver = spin.Companion(self, 'receiver')
        self._diagnostics = Diagnostics(self._receiver.node, hardware_id='joint_states',
                                        name=status_name(self), update=self._diagnose)
        # taken as bytes: those of the buffer's joints in the usual layout are read directly
        # (JointStateBytes), any other message deserialized (7.1 % of a core at 1 kHz before)
        self._layout: JointStateBytes | None = None     # once the buffer knows its joints
        self._reader = BatchReader(
            self, 'joint_states', JointState, 'joint_states', QoSProfile(
                depth=p['qos_depth'], reliability=ReliabilityPolicy.RELIABLE),
            self._on_joint_states, raw=True)
        self.create_service(CaptureJoints, 'capture_joints', self._on_capture)

    def destroy_node(self):
        self._reader.destroy()
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

    def _on_joint_states(self, batch: list[bytes]) -> None:
        # Windows are in publish time (header stamps, node clock): samples queued during a
        # motion and delivered late must not count as the hold that follows it.
        rows = []
        for data in batch:
            stamp_ns, names, positions = self._read(data)
            self._marks.add(stamp_ns // NS_PER_S)
            rows.append(((stamp_ns or now_ns(self)) * 1e-9, names, positions))
        self._last_arrival = time.monotonic()
        whys = []
        with self._lock:
            for stamp, names, positions in rows:
                why = self._buffer.add(stamp, names, positions)
                if why is None:
                    self._gaps.add(stamp)
                else:
                    whys.append(why)
            self._new_sample.notify_all()
        if whys:
            self.get_logger().warning(
                f'dropped a malformed joint_states message ({whys[-1].value}); '
                f'{sum(self._buffer.rejected.values())} dropped so far',
                throttle_duration_sec=5.0)

    def _read(self, data: bytes) -> tuple[int, list[str], tuple | list]:
        """(header stamp [ns], names, positions) of one serialized JointState."""
        layout = self._layout
        if layout is None and self._buffer.joint_names:
            layout = self._layout = JointStateBytes(self._buffer.joint_names)
        if layout is not None:
            fast = layout.unpack(data)
            if fast is not None:
                return fast[0], layout.names, fast[1]
        msg = deserialize_message(data, JointState)
        return stamp_to_ns(msg.header.stamp), list(msg.name), msg.position.tolist()

    def _on_capture(self, request, response):
        duration = request.duration or self.get_parameter('capture_duration').value
        if not 0.0 < duration <= self.get_parameter('buffer_duration').value:
            return results.answer(response, ErrorCode.INVALID_INPUT, (
                f'duration {duration} s must be > 0 and within the buffer '
                f'({self.get_parameter("buffer_duration").value} s)'))
        with self._lock:
            streaming = self._new_sample.wait_for(lambda: self._buffer.count > 0,
                                                  FIRST_SAMPLE_TIMEOUT)
        fraction = self.get_parameter('min_sample_fraction').value
        needed = samples_needed(duration, self._rate, fraction)
        start_ns = self._window_start(request.start)
        if isinstance(start_ns, str):
            return results.answer(response, ErrorCode.INVALID_INPUT, start_ns)
        times, positions, names, windows = self._hold(start_ns * 1e-9, duration, needed,
                                                      streaming)
        capture = hold_statistics(
            times, positions, duration, self._rate, fraction,
            self.get_parameter('max_joint_std').value, names, window_s=windows * duration)
        results.answer(response, capture.code, capture.message)
        response.name, response.position = names, capture.mean.tolist()
        response.std = capture.std.tolist()
        response.sample_count = capture.count
        response.window = capture.span
        if not capture.ok:
            self.get_logger().warning(f'capture_joints refused: {capture.message}')
        return response

    def _window_start(self, start) -> int | str:
        """A capture's window start [ns]: the request's ``start`` stamp, or now when it is
        zero; why not (a str) when it is further ahead of this node's clock than its buffer
        (the hold would wait that long)."""
        now, start_ns = now_ns(self), stamp_to_ns(start)
        ahead, buffer_s = (start_ns - now) * 1e-9, self.get_parameter('buffer_duration').value
        if ahead > buffer_s:
            return (f'start is {ahead:.3f} s ahead of this node\'s clock (more than its buffer, '
                    f'{buffer_s} s): give a start already reached, or none (zero) for the '
                    'request\'s arrival')
        return start_ns or now

    def _hold(self, t0: float, duration: float, needed: int, streaming: bool):
        """(times, positions, joint names, windows held) of the samples stamped from ``t0``
        over ``duration`` [s], the hold going on by whole windows (HOLD_EXTENSIONS at most)
        while it has fewer than ``needed``."""
        with self._lock:
            for windows in range(1, HOLD_EXTENSIONS + 2 if streaming else 2):
                t1 = t0 + windows * duration
                # a wait that ends at once is no stopped stream: this thread, woken late on a
                # loaded machine, can find the next window's samples all there (a CI run
                # refused a thinned stream after 2 windows as "stopped")
                going = streaming and wait_past(
                    self._new_sample, lambda: (self._buffer.latest_time, self._buffer.count),
                    t1, STALL_TIMEOUT)
                times, positions = self._buffer.window(t0, t1)
                if len(times) >= needed or not going:
                    break                   # enough, or the stream has stopped
            return times, positions, list(self._buffer.joint_names or []), windows

    def _diagnose(self) -> None:
        """The /diagnostics status, just before each publication (receiver thread)."""
        with self._lock:
            dropped = {f'dropped_{r.value}': n for r, n in self._buffer.rejected.items()}
            missing = self._gaps.missing
        received = self._marks.count
        age = time.monotonic() - self._last_arrival
        level, message = self._health(received, sum(dropped.values()), age)
        mark_s, before_mark = self._marks.mark
        self._diagnostics.set(
            level, message, received=received, **dropped, missing_by_stamp=missing,
            receive_rate_hz=round(self._rate_meter.rate_hz(received)),
            no_message_for_ms=round(age * 1e3),
            mark_stamp_s=mark_s, received_before_mark=before_mark)

    def _health(self, received: int, dropped: int, age: float) -> tuple[bytes, str]:
        """(level, message): WARN without data for NO_DATA_TIMEOUT, or on new malformed ones."""
        new_dropped, self._dropped_reported = dropped - self._dropped_reported, dropped
        if not received and time.monotonic() - self._started > NO_DATA_TIMEOUT:
            return WARN, 'no joint_states received yet; is the robot driver publishing?'
        if received and age > NO_DATA_TIMEOUT:
            return WARN, f'no joint_states for {age:.1f} s; is the robot driver publishing?'
        if new_dropped:
            return WARN, (f'dropped {new_dropped} malformed joint_states since the last '
                          'report (see dropped_*)')
        return (OK, 'receiving joint_states') if received else (OK, 'starting')

def main(args=None) -> None:
    spin.run(JointStateMonitor, args)


if __name__ == '__main__':
    main()
