"""Every message of one fast topic, taken in batches on a thread of its own.

An executor wakes once per message: for 1 kHz joint_states rclpy's SingleThreadedExecutor spent
~25 % of a core on that alone (joint_state_monitor, issue 23). A BatchReader's subscription lives
on a hidden helper node that no executor spins; its thread waits for the first message, lets
``period`` seconds of messages gather in the subscription's queue (its QoS depth must hold them),
takes them all and hands them to ``on_batch`` in arrival order, so the per-wake cost is paid once
per batch. Nothing is lost that the queue holds; each message is delayed by at most ``period``.

BATCH_PERIOD (bench_joint_states, joint_state_monitor at 1 kHz, load 6-9, % of one core): 5 ms
8.9-11.1 %, 10 ms 7.1-7.5 % (capture_joints overhead p50 6-7 ms), 20 ms 6.1-7.4 %.
"""
from __future__ import annotations

from collections.abc import Callable
import threading
import time

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile

from cobot_calib_ros.ros import spin
from cobot_calib_ros.ros.time import s_to_ns

BATCH_PERIOD = 0.01     # [s] messages gather this long after the first one wakes the thread


class BatchReader:
    """``node``'s namespace and context; the helper node is named ``_<node>_<name>``.
    ``on_batch(messages)`` runs on the reader's thread; ``raw``: the messages as serialized
    bytes (for a reader that parses them itself, ros.joint_state_bytes)."""

    def __init__(self, node: Node, name: str, msg_type, topic: str, qos: QoSProfile,
                 on_batch: Callable[[list], None], period: float = BATCH_PERIOD,
                 raw: bool = False) -> None:
        self._context = node.context
        self.node = Node(f'_{node.get_name()}_{name}', namespace=node.get_namespace(),
                         context=node.context, start_parameter_services=False)
        self._sub = self.node.create_subscription(msg_type, topic, lambda _: None, qos,
                                                  raw=raw)
        self._on_batch = on_batch
        self._period = period
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name=f'{name}_reader')
        self._thread.start()

    def destroy(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)      # it wakes every WAKE_PERIOD
        self.node.destroy_node()

    def _run(self) -> None:
        sub = self._sub
        wait_set = _rclpy.WaitSet(1, 0, 0, 0, 0, 0, self._context.handle)
        timeout_ns = s_to_ns(spin.WAKE_PERIOD)
        while not self._stop.is_set() and self._context.ok():
            try:
                batch = self._take_batch(sub, wait_set, timeout_ns)
            except Exception:  # noqa: BLE001 - the context went down under the wait
                if self._context.ok():
                    raise
                return
            if not batch:
                continue
            try:
                self._on_batch(batch)
            except Exception as exc:  # noqa: BLE001 - a bad batch must not end the stream
                self.node.get_logger().error(f'{len(batch)} messages not handled: {exc!r}',
                                             throttle_duration_sec=5.0)

    def _take_batch(self, sub, wait_set, timeout_ns: int) -> list:
        """The messages queued once one has come and ``period`` has passed ([] after
        timeout_ns without any)."""
        with sub.handle:
            wait_set.clear_entities()
            wait_set.add_subscription(sub.handle)
            wait_set.wait(timeout_ns)
            if not wait_set.get_ready_entities('subscription'):
                return []
        time.sleep(self._period)            # let a batch gather (GIL released)
        batch = []
        with sub.handle:
            while True:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
                if taken is None:
                    return batch
                batch.append(taken[0])
