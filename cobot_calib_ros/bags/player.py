"""bag_player: replay a bag's topics on rclpy, as ``ros2 bag play`` does.

- Each topic is published with the QoS its recorded publishers offered, when they all offered
  the same (reliability, durability, lifespan, deadline), as keep-last DEPTH (a recording says
  ``history: unknown, depth: 0``, which rclpy refuses); otherwise reliable/volatile keep-last
  DEPTH, and transient local for ``/tf_static`` so latched transforms stay latched.
- Messages go out as the recorded serialized bytes (``Publisher.publish(bytes)``, rclpy's
  publish_raw: no deserialisation; bench_bag measures it against deserialize+publish).
- Timing follows the receive stamps scaled by ``rate``; ``rate`` 0 publishes as fast as the
  loop goes. There is no back-pressure from a subscriber's application to be had: with Fast DDS
  a reliable writer's acknowledgements arrive once per heartbeat period (3 s here, so waiting
  for them every few hundred messages plays slower than real time), and they only say the
  sample reached the reader's history, which a slow subscriber then overwrites (keep-last) all
  the same; a publisher with keep-all history did not block either (measured). A subscriber
  that must see every message needs a history as deep as the bag, a rate it keeps up with
  whatever the load, or flow control.
- Flow control (``flow``; off unless asked for, so plain replay is ``ros2 bag play``): the
  consumers report a running count of the counted messages they have taken (a replay check
  counts what came back from the node under test; another process publishes its count on
  ``~/consumed``, std_msgs/UInt64, given ``window``). The player keeps at most ``window``
  counted messages published and not yet counted: it waits before the next one with /clock
  held at the last message's stamp (a window in sim time cannot pass while the pipeline is
  behind), and the rate is only an upper bound. A window no deeper than the consumer's queue
  cannot overflow it, whatever the load. Until the first is counted, what was sent goes out
  again every RESEND_S (messages sent before a subscription has matched the player on the
  subscriber's side are lost; with each, the newest message of every other topic sent before
  it, such as its camera_info); a count that does not move for WRITE_OFF_S while messages are
  out writes those off as lost (``PlayResult.written_off``), so a message lost on a best-effort
  path cannot stop the replay. play() returns when every counted message is counted or written
  off.
- Without flow control a consumer's count on ``~/consumed`` (if one publishes it) still tells
  the player what was lost: ``PlayResult.lost``, published minus the count at the end.
- Before starting it waits, up to ``wait_subscribers`` seconds, until every topic has a
  subscriber matched to its publisher (and every subscriber the graph knows of is matched):
  a publisher needs 0.02-3.5 s to match one in another process here, and messages sent before
  are lost. After the last message it waits for reliable subscribers' acknowledgements, or the
  last messages would be lost when the process ends.
- ``clock_hz``: publishes /clock (rosgraph_msgs/Clock) from the recorded stamps at that rate of
  wall time, never going back within a pass (a loop starts over from the first stamp, as
  rosbag2 does). ``loop``; ``topics`` to play a subset; ``start_paused`` waits for a call to
  ``~/resume`` (std_srvs/Trigger); ``~/pause`` pauses again.

The node's services are served by a SingleThreadedExecutor on its own thread (``spinning``);
play() runs on the caller's thread.

As its own process (``main``; ``ros2 run cobot_calib_ros bag_player --ros-args -p bag:=DIR
-p rate:=2.0 -p clock_hz:=40.0``, also ``.venv/lib/cobot_calib_ros/bag_player``) it takes the
parameters ``bag``, ``rate``, ``loop``, ``topics``, ``clock_hz`` (0: no /clock),
``start_paused``, ``wait_subscribers`` and ``window`` (flow control with ``~/consumed``; read
at start-up, described in ``ros2 param describe``), plays the bag once (or until shut down
with ``loop``) and exits. Given a Bag from Python (``cobot-calib replay``, the --check
modules) the arguments are the values, and the parameters show them.
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass
import sys
import threading
import time
from typing import Callable, Iterable

from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosReliability
from rosgraph_msgs.msg import Clock
from std_msgs.msg import UInt64
from std_srvs.srv import Trigger

from cobot_calib_ros.bags.errors import BagError
from cobot_calib_ros.bags.metadata import duration_ns
from cobot_calib_ros.bags.reader import Bag, open_bag
from cobot_calib_ros.bags.recorder import declare_strings
from cobot_calib_ros.ros.params import read_once
from cobot_calib_ros.ros.time import ns_to_stamp, NS_PER_S

NODE_NAME = 'bag_player'
DEPTH = 1000                 # keep-last depth of every replay publisher
CLOCK_HZ = 40.0              # rosbag2's default /clock rate
# [s] after the last message. Fast DDS acknowledges once per 3 s heartbeat period, and a
# sample the reader missed is sent again only after it said so at one heartbeat: its ack comes
# a period later. 5 s (one period) ran out once in a loaded test run (a 2x replay of 500
# joint_states: "subscribers did not acknowledge"); three periods cover one repair.
FINAL_ACK_TIMEOUT = 10.0
LATCHED_TOPICS = ('/tf_static',)
SPIN_PERIOD = 0.05           # [s]
RESEND_S = 0.5               # [s] of wall time without a first consumed message: send again
WRITE_OFF_S = 5.0            # [s] of wall time without progress: the messages out are lost
FLOW_POLL_S = 0.002          # [s] between looks at the consumers' count while the window is full
LOST_WAIT = 2.0              # [s] after the end for the consumers' last count (no flow control)


@dataclass
class FlowControl:
    """Back-pressure from the consumers (see the module doc): at most ``window`` messages of
    ``topics`` (None: every topic played) published and not yet counted by ``consumed()``, a
    running count over the player's life (passes and plays included)."""
    window: int
    consumed: Callable[[], int]
    topics: frozenset | None = None

    def __post_init__(self) -> None:
        if self.window < 1:
            raise ValueError('the flow-control window must be >= 1 message')

    def counts(self, topic: str) -> bool:
        return self.topics is None or topic in self.topics


def replay_qos(topic: str, offered: list[Qos], depth: int = DEPTH) -> QoSProfile:
    """The profile to publish a recorded topic with (see the module doc)."""
    profile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
    same = {(p.reliability, p.durability, p.deadline, p.lifespan) for p in offered}
    if len(same) == 1:
        p = offered[0]
        if p.reliability == QosReliability.BEST_EFFORT:
            profile.reliability = ReliabilityPolicy.BEST_EFFORT
        if p.durability == QosDurability.TRANSIENT_LOCAL:
            profile.durability = DurabilityPolicy.TRANSIENT_LOCAL
        for name, value in (('deadline', p.deadline), ('lifespan', p.lifespan)):
            ns = duration_ns(value)
            if ns is not None:
                setattr(profile, name, Duration(nanoseconds=ns))
    elif topic in LATCHED_TOPICS:
        profile.durability = DurabilityPolicy.TRANSIENT_LOCAL
    return profile


@dataclass
class PlayResult:
    published: int = 0               # messages published (all passes)
    passes: int = 0                  # complete passes over the bag
    wall_s: float = 0.0              # [s] from the first message to the last of the last
                                     # pass, paused time left out
    bag_s: float = 0.0               # [s] of recorded time played (all passes)
    unacknowledged: tuple = ()       # topics whose subscribers did not acknowledge at the end
    resent: int = 0                  # flow control: sent again before the first was consumed
    written_off: int = 0             # flow control: counted messages never reported consumed
                                     # (written off as lost on the way), all plays so far
    lost: int | None = None          # without flow control: published - the consumers' count
                                     # on ~/consumed at the end; None: no count came

    @property
    def speed(self) -> float:
        """Recorded time played per wall time (the real-time factor)."""
        return self.bag_s / self.wall_s if self.wall_s > 0 else float('inf')


class BagPlayer(Node):
    """Publishes a bag's messages; see the module doc. With ``bag`` None every setting comes
    from the node's parameters (and the player opens and closes the bag itself)."""

    def __init__(self, bag: Bag | None = None, *, rate: float = 1.0, loop: bool = False,
                 topics: Iterable[str] | None = None, clock_hz: float | None = None,
                 start_paused: bool = False, wait_subscribers: float = 2.0,
                 depth: int = DEPTH, report: Callable[[str], None] | None = None,
                 flow: FlowControl | None = None, window: int = 0,
                 node_name: str = NODE_NAME, **node_kwargs) -> None:
        self._own_bag = None
        if bag is not None:                 # refused before any rclpy set-up
            classes = self._select(bag, rate, topics)
        super().__init__(node_name, start_parameter_services=bag is None, **node_kwargs)
        values = self._declare_parameters(bag, rate, loop, topics, clock_hz, start_paused,
                                          wait_subscribers, window)
        if bag is None:
            path, rate, loop, topics, clock_hz, start_paused, wait_subscribers, window = values
            if not path:
                raise BagError('parameter bag: give the bag to play (-p bag:=DIR)')
            bag = self._own_bag = open_bag(path)
            for warning in bag.warnings:
                self.get_logger().warning(warning)
            classes = self._select(bag, rate, topics or None)
        self.rate = rate
        self.loop = loop
        self.clock_period_ns = int(NS_PER_S / clock_hz) if clock_hz else 0
        self.wait_subscribers = wait_subscribers
        self.report = report or self.get_logger().info
        self.publishers_by_topic = {
            t: self.create_publisher(classes[t], t, replay_qos(t, bag.topics[t].offered_qos,
                                                               depth))
            for t in self.topics}
        self._reliable = [p for p in self.publishers_by_topic.values()
                          if p.qos_profile.reliability == ReliabilityPolicy.RELIABLE]
        self._clock_pub = (self.create_publisher(Clock, '/clock', 10) if clock_hz else None)
        self._last_clock_ns = -1
        self._next_clock_wall = 0
        self._paused = threading.Event()
        if start_paused:
            self._paused.set()
        self._stop = threading.Event()
        self.create_service(Trigger, '~/resume', self._on_resume)
        self.create_service(Trigger, '~/pause', self._on_pause)
        self._reported = -1             # the consumers' count on ~/consumed; -1: none came
        if flow is None:                # flow control by ~/consumed, or counting the lost
            self.create_subscription(UInt64, '~/consumed', self._on_consumed,
                                     QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
            if window > 0:
                flow = FlowControl(int(window), lambda: max(0, self._reported))
        self.flow = flow
        self._sent = 0                  # counted messages published (flow control)
        self._written_off = 0
        # before anything was consumed: the counted messages sent, each after the newest
        # message of every other topic sent before it (a camera_info before its image), to
        # send again; (topic, bytes)
        self._unanswered: list = []
        self._lead_in: dict = {}        # topic -> bytes, not counted, since the last counted
        self._answered = False          # something was consumed (or written off)

    def _select(self, bag: Bag, rate: float, topics) -> dict:
        """Check the settings against the bag; the message class of each topic to play."""
        if rate < 0:
            raise ValueError('rate must be >= 0 (0: as fast as possible)')
        self.bag = bag
        self.topics = bag.select(topics)
        if not self.topics or not sum(bag.topics[t].count for t in self.topics):
            which = ' on ' + ', '.join(self.topics) if topics is not None else ''
            raise BagError(f'{bag.path}: no messages{which} to replay')
        return {t: _message_class(bag, t) for t in self.topics}

    def _declare_parameters(self, bag, rate, loop, topics, clock_hz, start_paused,
                            wait_subscribers, window) -> tuple:
        """Declare the parameters (the arguments as defaults); their values, in order."""
        return (
            read_once(self, 'bag', str(bag.path) if bag is not None else '',
                      'Bag directory, or a .mcap/.db3 file, to play'),
            read_once(self, 'rate', float(rate),
                      'Speed factor [1] on the recorded timing; 0 = as fast as possible',
                      0.0, 1e6),
            read_once(self, 'loop', bool(loop), 'Start over at the end, until shut down'),
            declare_strings(self, 'topics', topics, 'Topics to play; empty = all'),
            read_once(self, 'clock_hz', float(clock_hz or 0.0),
                      '/clock from the recorded stamps, this often per second of wall time '
                      '[Hz]; 0 = no /clock', 0.0, 1e4),
            read_once(self, 'start_paused', bool(start_paused),
                      'Wait for a call to ~/resume (std_srvs/Trigger) before playing'),
            read_once(self, 'wait_subscribers', float(wait_subscribers),
                      'Longest wait for subscribers to match before playing [s]', 0.0, 3600.0),
            read_once(self, 'window', int(window),
                      'Flow control: at most this many messages published and not yet '
                      'reported consumed on ~/consumed (std_msgs/UInt64, the consumers\' '
                      'running count); 0 = none, as ros2 bag play', 0, 1_000_000))

    def destroy_node(self):
        try:
            return super().destroy_node()
        finally:
            if self._own_bag is not None:
                self._own_bag.close()
                self._own_bag = None

    # -- services -------------------------------------------------------------------------------

    def _on_resume(self, request, response):
        response.success = self._paused.is_set()
        response.message = 'resumed' if response.success else 'was not paused'
        self._paused.clear()
        return response

    def _on_consumed(self, msg: UInt64) -> None:
        self._reported = max(self._reported, int(msg.data))

    def _on_pause(self, request, response):
        response.success = not self._paused.is_set()
        response.message = 'paused' if response.success else 'already paused'
        self._paused.set()
        return response

    def stop(self) -> None:
        """Ends play() from another thread."""
        self._stop.set()

    @property
    def paused(self) -> bool:
        return self._paused.is_set()

    # -- playing --------------------------------------------------------------------------------

    def wait_for_subscribers(self) -> list[str]:
        """Wait (up to wait_subscribers s) until every topic has a matched subscriber and every
        subscriber the graph shows is matched; the topics still without one."""
        deadline = time.monotonic() + self.wait_subscribers
        while True:
            missing = [t for t, p in self.publishers_by_topic.items()
                       if p.get_subscription_count() < max(1, self.count_subscribers(t))]
            if not missing or time.monotonic() >= deadline or self._stop.is_set():
                return missing
            time.sleep(0.02)

    def play(self) -> PlayResult:
        """Wait for subscribers (and for ~/resume if paused), then publish; returns when the
        bag is played (every pass with loop: only stop() or Ctrl-C end it)."""
        missing = self.wait_for_subscribers()
        if missing and self.wait_subscribers > 0:
            self.report(f'no subscriber matched within {self.wait_subscribers:g} s on: '
                        + ', '.join(missing) + '; playing anyway')
        if self._paused.is_set():
            self.report(f'paused: call {self.get_fully_qualified_name()}/resume '
                        '(std_srvs/srv/Trigger) to start')
        result = PlayResult()
        started = None
        while not self._stop.is_set():
            first_wall = self._play_pass(result)
            started = started if started is not None else first_wall
            if first_wall is None:          # nothing was published (stopped)
                break
            result.passes += 1
            if not self.loop:
                break
        if self.flow is not None:
            self._await_window(result, self._last_clock_ns, room=1)    # all consumed
            result.written_off = self._written_off
        if started is not None:
            result.wall_s = (self._last_publish_wall - started - self._paused_ns) / NS_PER_S
        result.unacknowledged = self._wait_acknowledged(FINAL_ACK_TIMEOUT)
        if self.flow is None and (self._reported >= 0 or self.count_publishers(
                self.resolve_topic_name('~/consumed'))):
            deadline = time.monotonic() + LOST_WAIT
            while self._reported < result.published and time.monotonic() < deadline:
                time.sleep(FLOW_POLL_S)
            result.lost = max(0, result.published - max(0, self._reported))
        return result

    def _play_pass(self, result: PlayResult) -> int | None:
        """One pass over the bag; the wall time [ns] its pacing started from, just before its
        first message (None if stopped before one). Not the time after that message's publish:
        the pass's speed is measured from where it is paced from, or a slow first publish
        made a 4x replay read 4.12x."""
        rate = self.rate
        first_stamp = base_wall = first_wall = None
        self._last_clock_ns = -1
        previous = None
        publishers = self.publishers_by_topic
        flow = self.flow
        for message in self.bag.messages(self.topics):
            if self._stop.is_set():
                break
            stamp = message.timestamp_ns
            if self._paused.is_set():
                held = self._hold(previous if previous is not None else stamp)
                if base_wall is not None:
                    base_wall += held
            now = time.monotonic_ns()
            if first_stamp is None:
                first_stamp, base_wall = stamp, now
                paced_from = now
            while rate > 0 and not self._stop.is_set():
                target = base_wall + int((stamp - first_stamp) / rate)
                if now >= target - 100_000:             # 0.1 ms early at most: no spin-wait
                    break
                if self._paused.is_set():
                    base_wall += self._hold(previous if previous is not None else stamp)
                else:
                    self._tick_clock(now, first_stamp + int((now - base_wall) * rate), stamp)
                    time.sleep(min(target - now, self._clock_sleep(now), 50_000_000) / NS_PER_S)
                now = time.monotonic_ns()
            if self._stop.is_set():
                break
            counted = flow is not None and flow.counts(message.topic)
            # the window checked here first: _await_window for every message cost a tenth
            # of the replay's time at full speed
            if counted and self._sent - flow.consumed() - self._written_off >= flow.window:
                held = self._await_window(result, previous if previous is not None else stamp)
                if base_wall is not None:
                    base_wall += held
                if self._stop.is_set():
                    break
            if self._clock_pub is not None:
                self._tick_clock(time.monotonic_ns(), stamp, stamp)
            publishers[message.topic].publish(message.rawdata)
            if flow is not None and not self._answered:
                self._lead_in[message.topic] = message.rawdata
                if counted:
                    self._unanswered += self._lead_in.items()
                    self._lead_in = {}
            if counted:
                self._sent += 1
            self._last_publish_wall = time.monotonic_ns()
            if first_wall is None:
                first_wall = paced_from
            result.published += 1
            if previous is not None and stamp > previous:
                result.bag_s += (stamp - previous) / NS_PER_S
            previous = stamp
        return first_wall

    def _await_window(self, result: PlayResult, stamp: int, room: int | None = None) -> int:
        """Flow control: wait until fewer than ``room`` (the window) counted messages are out,
        /clock held at ``stamp``; the wall time [ns] waited. Before the first is consumed,
        what was sent goes out again every RESEND_S; WRITE_OFF_S without progress writes the
        messages out off as lost."""
        flow = self.flow
        room = flow.window if room is None else room
        start = time.monotonic_ns()
        consumed = flow.consumed()
        since = resent = start
        while not self._stop.is_set():
            self._written_off = min(self._written_off, max(0, self._sent - consumed))
            if self._sent - consumed - self._written_off < room:
                break
            now = time.monotonic_ns()
            self._tick_clock(now, stamp, stamp)
            if now - since > WRITE_OFF_S * NS_PER_S:
                self._written_off = self._sent - consumed
                self._answer()
                since = now
            elif not self._answered and now - resent > RESEND_S * NS_PER_S:
                for topic, data in self._unanswered:    # nothing has come back yet
                    self.publishers_by_topic[topic].publish(data)
                result.resent += len(self._unanswered)
                resent = now
            time.sleep(FLOW_POLL_S)
            latest = flow.consumed()
            if latest != consumed:
                consumed, since = latest, time.monotonic_ns()
                self._answer()
        return time.monotonic_ns() - start

    def _answer(self) -> None:
        """The path to the consumers works (or is given up on): no more sending again."""
        self._answered = True
        self._unanswered, self._lead_in = [], {}

    def _hold(self, stamp: int) -> int:
        """While paused: keep /clock at ``stamp``; the wall time [ns] spent paused."""
        start = time.monotonic_ns()
        while self._paused.is_set() and not self._stop.is_set():
            now = time.monotonic_ns()
            self._tick_clock(now, stamp, stamp)
            time.sleep(min(0.05, self._clock_sleep(now) / NS_PER_S))
        held = time.monotonic_ns() - start
        if self._last_publish_wall:
            self._paused_ns += held                 # after the first message: not playing
        return held

    def _clock_sleep(self, now: int) -> int:
        if self._clock_pub is None:
            return 50_000_000
        return max(0, self._next_clock_wall - now)

    def _tick_clock(self, now: int, playback_ns: int, cap_ns: int) -> None:
        """Publish /clock when one is due: the playback time, capped at the next message's
        stamp and never below the last one sent."""
        if self._clock_pub is None or now < self._next_clock_wall:
            return
        value = max(self._last_clock_ns, min(playback_ns, cap_ns))
        self._last_clock_ns = value
        self._next_clock_wall = now + self.clock_period_ns
        self._clock_pub.publish(Clock(clock=ns_to_stamp(value)))

    def _wait_acknowledged(self, timeout: float) -> tuple:
        """Wait for reliable subscribers' acknowledgements; the topics still waiting."""
        late = []
        for publisher in self._reliable:
            if publisher.get_subscription_count() and not publisher.wait_for_all_acked(
                    Duration(nanoseconds=int(timeout * NS_PER_S))):
                late.append(publisher.topic_name)
        return tuple(late)

    _last_publish_wall = 0
    _paused_ns = 0


def _message_class(bag: Bag, topic: str):
    from cobot_calib_ros.ros.types import import_type
    msgtype = bag.topics[topic].type
    try:
        return import_type(msgtype)
    except ValueError as exc:
        raise BagError(f'{bag.path}: cannot replay {topic}: {exc}; leave the topic out '
                       '(--topics)') from None


@contextlib.contextmanager
def spinning(node: Node):
    """Serve ``node``'s services on a SingleThreadedExecutor thread while the block runs."""
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    running = threading.Event()
    running.set()

    def spin() -> None:
        while running.is_set() and node.context.ok():
            try:
                executor.spin_once(timeout_sec=SPIN_PERIOD)
            except Exception:  # noqa: BLE001 - the context went down under us
                if running.is_set() and node.context.ok():
                    raise
                return

    thread = threading.Thread(target=spin, daemon=True, name='bag_player_services')
    thread.start()
    try:
        yield executor
    finally:
        running.clear()
        thread.join(timeout=2.0)
        if not thread.is_alive():
            executor.shutdown(timeout_sec=1.0)


def main(args=None) -> None:
    """``ros2 run cobot_calib_ros bag_player --ros-args -p bag:=DIR [-p rate:=R ...]``: play
    the bag (once, or until Ctrl-C with loop) and exit; 1 on a bag problem."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    rclpy.init(args=args)
    player = None
    code = 0
    try:
        player = BagPlayer()
        log = player.get_logger()
        count = sum(player.bag.topics[t].count for t in player.topics)
        log.info(f'replaying {player.bag.path}: {count} messages on {len(player.topics)} '
                 f'topics, rate {player.rate:g} (0 = as fast as possible)')
        if player.flow is None:
            log.info('no window: a subscriber slower than the replay loses what overflows its '
                     'history (counted if it publishes its count on ~/consumed)')
        with spinning(player):
            result = player.play()
        log.info(f'published {result.published} messages in {result.wall_s:.3f} s '
                 f'({result.speed:.2f}x real time)')
        if result.written_off:
            log.warning(f'{result.written_off} messages never counted on ~/consumed')
        if result.lost:
            log.warning(f'lost: {result.lost} of {result.published} (not counted on '
                        '~/consumed)')
        if result.unacknowledged:
            log.warning('subscribers did not acknowledge the last messages on '
                        + ', '.join(result.unacknowledged))
    except (KeyboardInterrupt, ExternalShutdownException):
        if player is not None:
            player.stop()
    except (BagError, ValueError) as exc:
        print(f'bag_player: {exc}', file=sys.stderr)
        code = 1
    finally:
        if player is not None:
            player.destroy_node()
        rclpy.try_shutdown()
    if code:
        sys.exit(code)


if __name__ == '__main__':
    main()
