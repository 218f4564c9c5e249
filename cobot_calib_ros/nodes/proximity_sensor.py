"""proximity_sensor: probe voltage -> distance [m] with range checks, and window averages.

Averaging windows are in publish time (header stamps, node clock: use_sim_time works), so
readings taken during a motion and delivered late never count as the hold that follows it.

/diagnostics (1 Hz, from the receiving companion, so a long probe/average never delays it):
``readings``, ``below_range`` / ``above_range`` / ``invalid`` counts, ``last_distance_m``,
``last_voltage_v``, ``reading_rate_hz`` over the last second, ``last_reading_age_s``. WARN when
no probe/voltage came for more than NO_DATA_TIMEOUT.

Marks on ``cobot_calib/probe_averages`` (ros.marks: PROBE_AVERAGES, its encoding there): one
per probe/average served, so a recording can tie each reading of a trial to the probe readings
it averaged (bags/make_trial_bag.py, api.replay_trial_check). A reading the subscription
dropped (best effort, ros.qos.PROBE_READINGS) is not among them, so a replay can average
exactly the readings this node did. The window and its average are core.sensors.probe's
``average_window`` and ``average`` (a replay and the in-process robot use the same);
ros.convert's ``fill_average`` maps the result to the response.
"""
from __future__ import annotations

from collections import Counter, deque
import math
import threading
import time

from cobot_calib_msgs.msg import ProbeAverageMark, ProbeVoltage, ProximityReading
from cobot_calib_msgs.srv import AverageProximity
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.core.sensors.probe import (average, average_window, curve_from_lists,
                                                read_distance, ReadingStatus)
from cobot_calib_ros.ros import marks, qos, results, spin
from cobot_calib_ros.ros.batch_reader import BatchReader
from cobot_calib_ros.ros.convert import fill_average
from cobot_calib_ros.ros.diagnostics import Diagnostics, OK, RateMeter, status_name, WARN
from cobot_calib_ros.ros.params import declare, read_once
from cobot_calib_ros.ros.time import now_ns, stamp_or_now_ns, wait_past

# [s] of wall time without a new reading: the probe stream has stopped. As joint_state_monitor's:
# at load ~30 on 2 cores the probe's publisher was starved for more than 1 s at times (3 of
# 150 probe/average 0.08 s answered "no probe readings" with 1 s, its late readings on the way).
STALL_TIMEOUT = 3.0
NO_DATA_TIMEOUT = 1.0   # [s] of wall time without probe/voltage: /diagnostics warns




class ProximitySensor(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__('proximity_sensor', **kwargs)
        self._declare_parameters()
        self._curve = curve_from_lists(self._p('calibration_distance'),
                                       self._p('calibration_voltage'))
        self._margin = self._p('saturation_margin')
        self._lock = threading.Condition()
        self._recent: deque = deque(maxlen=20000)   # (stamp [ns], distance, status)
        self._pub = self.create_publisher(ProximityReading, 'probe/distance',
                                          qos_profile_sensor_data)
        self._statuses: Counter = Counter()         # readings by ReadingStatus
        self._last_reading: tuple[float, float] | None = None   # (distance [m], voltage [V])
        self._last_arrival = self._started = time.monotonic()
        self._rate_meter = RateMeter()
        self._receiver = spin.Companion(self, 'receiver')
        self._diagnostics = Diagnostics(self._receiver.node, hardware_id='probe',
                                        name=status_name(self), update=self._diagnose)
        # in batches on a thread of its own (ros.batch_reader): an executor wake per reading
        # cost 8-11 % of a core at 200 Hz (issue 23)
        self._reader = BatchReader(self, 'voltage', ProbeVoltage, 'probe/voltage',
                                   qos.PROBE_READINGS, self._on_voltages)
        self._marks = self.create_publisher(ProbeAverageMark, marks.PROBE_AVERAGES, 100)
        self.create_service(AverageProximity, 'probe/average', self._on_average)
        self.get_logger().info(
            f'probe range {self._curve.min_range * 1e3:.2f}-{self._curve.max_range * 1e3:.2f} mm')

    def _declare_parameters(self) -> None:
        read_once(self, 'calibration_distance', [0.0002, 0.0022],
                  'Calibration table: gaps [m], increasing')
        read_once(self, 'calibration_voltage', [-1.6, -17.6],
                  'Calibration table: sensor output at those gaps [V]')
        read_once(self, 'saturation_margin', 2.0e-6,
                  'Readings this close to a range end count as saturated [m]', 0.0, 1e-3)
        declare(self, 'average_duration', 0.2, 'Default window of probe/average [s]',
                0.001, 60.0)

    def destroy_node(self):
        self._reader.destroy()
        self._receiver.destroy()
        return super().destroy_node()

    def _p(self, name: str):
        return self.get_parameter(name).value

    def _on_voltages(self, batch: list[ProbeVoltage]) -> None:
        publish = self._pub.get_subscription_count() > 0     # idle: 200 Hz for nobody
        for msg in batch:
            self._on_voltage(msg, publish)

    def _on_voltage(self, msg: ProbeVoltage, publish: bool) -> None:
        reading = read_distance(self._curve, msg.voltage, self._margin)
        if publish:
            self._pub.publish(ProximityReading(
                header=msg.header, distance=reading.distance, voltage=msg.voltage,
                min_range=self._curve.min_range, max_range=self._curve.max_range,
                status=int(reading.status)))
        self._last_reading = (reading.distance, msg.voltage)
        self._last_arrival = time.monotonic()
        stamp = stamp_or_now_ns(self, msg.header.stamp)
        with self._lock:
            # counted with the append, under the lock: a probe/average that read the count
            # between the two took the append's notify for "nothing new" and answered no
            # readings while they were arriving (issue 31.5, at load 30+)
            self._statuses[reading.status] += 1
            self._recent.append((stamp, reading.distance, reading.status))
            self._lock.notify_all()
        if reading.status == ReadingStatus.INVALID:
            self.get_logger().warning('non-finite probe voltage dropped',
                                      throttle_duration_sec=5.0)

    def _diagnose(self) -> None:
        """The /diagnostics status, just before each publication (receiver thread)."""
        readings = sum(self._statuses.values())
        age = time.monotonic() - self._last_arrival
        distance, voltage = self._last_reading or (float('nan'), float('nan'))
        self._diagnostics.set(
            *self._health(readings, age), readings=readings,
            below_range=self._statuses[ReadingStatus.BELOW_RANGE],
            above_range=self._statuses[ReadingStatus.ABOVE_RANGE],
            invalid=self._statuses[ReadingStatus.INVALID],
            last_distance_m=f'{distance:.7f}', last_voltage_v=f'{voltage:.4f}',
            reading_rate_hz=f'{self._rate_meter.rate_hz(readings):.1f}',
            last_reading_age_s=f'{age:.3f}' if readings else 'never')

    def _health(self, readings: int, age: float) -> tuple[bytes, str]:
        """(level, message): WARN without probe/voltage for more than NO_DATA_TIMEOUT."""
        if not readings:
            if time.monotonic() - self._started > NO_DATA_TIMEOUT:
                return WARN, 'no probe/voltage received yet; is the probe publishing?'
            return OK, 'starting'
        if age > NO_DATA_TIMEOUT:
            return WARN, f'no probe/voltage for {age:.1f} s; is the probe publishing?'
        return OK, 'receiving probe/voltage'

    def _on_average(self, request, response):
        duration = request.duration or self._p('average_duration')
        if not 0.0 < duration <= 60.0:
            return results.answer(response, ErrorCode.INVALID_INPUT,
                                  f'duration {duration} s must be in (0, 60]')
        t0_ns = now_ns(self)
        with self._lock:
            wait_past(self._lock, self._newest, t0_ns * 1e-9 + duration, STALL_TIMEOUT)
            window = average_window(self._recent, t0_ns, duration)
        response.min_range, response.max_range = self._curve.min_range, self._curve.max_range
        fill_average(response, average(window, duration))
        self._marks.publish(marks.average_mark(t0_ns, duration, response, window))
        return response

    def _newest(self) -> tuple[float, int]:
        """(newest reading's stamp [s], readings received so far), with self._lock held."""
        return (self._recent[-1][0] * 1e-9 if self._recent else -math.inf,
                sum(self._statuses.values()))


def main(args=None) -> None:
    spin.run(ProximitySensor, args)


if __name__ == '__main__':
    main()
