"""The one replay harness of the `replay BAG --check` checks.

``replay_suite(specs, ...)`` reserves a private ROS_DOMAIN_ID (domain_coordinator) and a
temporary folder, starts the nodes under test there (api.launcher.Suite, ``use_sim_time``),
and opens a client session on that domain on sim time (ros.session). The check subscribes to
what the nodes publish, waits for them (``wait_for``), then plays the bag (``playing``: a
BagPlayer with /clock whose services are spun, and the client node spun on a thread of its
own meanwhile), drains what comes back and leaves; the player, the session and the suite are
shut down in that order whatever happened.

A check whose nodes take the bag best effort gives the player flow control
(bags.player.FlowControl: it counts what came back from the node, so the node's queue cannot
overflow whatever the load) and replays in passes (``passes``): a pass that lost something on
the best-effort way is followed by another at half the rate, not below ``min(rate, min_rate)``.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
import contextlib
from dataclasses import dataclass, field
import os
from pathlib import Path
import tempfile
import threading
import time

from cobot_calib_ros.core.errors import ErrorCode

# The nodes under test are waited for until they are up or one of them has exited, so a slow
# start on a loaded machine is not a failed check; the limit only ends a wait on a node that
# runs but never comes up (measured: over 30 s to come up at load 30).
STARTUP_LIMIT = 300.0    # [s] for the nodes under test to come up, and to subscribe to the player
SERVICE_TIMEOUT = STARTUP_LIMIT
LOOK_PERIOD = 0.5        # [s] between looks at whether a node under test has exited


class CheckError(RuntimeError):
    """The check could not run (a missing file, a node that did not come up)."""


class Verdict:
    """A check's result beside its figures: ``code`` SUCCESS when the replay gave the recorded
    result within the check's tolerance, IMPLAUSIBLE_FIT when it did not; truthy on SUCCESS,
    as core's results are (no ``ok`` flag beside the causes)."""

    code: ErrorCode

    def __bool__(self) -> bool:
        return self.code == ErrorCode.SUCCESS


def verdict(within_tolerance: bool) -> ErrorCode:
    """The Verdict code of a replayed result that is, or is not, within the tolerance."""
    return ErrorCode.SUCCESS if within_tolerance else ErrorCode.IMPLAUSIBLE_FIT


@dataclass
class ReplaySuite:
    """The nodes under test on their own domain, and the check's client node there."""

    domain: int
    tmp: Path
    suite: object               # api.launcher.Suite
    node: object                # the check's rclpy node (sim time)
    executor: object
    say: Callable[[str], None]
    players: list = field(default_factory=list)

    def failed(self) -> str:
        """'' or '; exited: <node> (<code>): <log tail>' for nodes that have exited."""
        failed = self.suite.failed()
        if not failed:
            return ''
        return '; exited: ' + ', '.join(f'{n} ({c}): {self.suite.log_tail(n, 5)}'
                                        for n, c in failed.items())

    def wait_for(self, done: Callable[[], bool], what: str,
                 timeout: float = STARTUP_LIMIT) -> None:
        """Spin the client node until done(); CheckError '<what> did not come up' with the
        logs' folder as soon as a node under test has exited, or after ``timeout``."""
        from cobot_calib_ros.ros.calls import spin_until
        deadline = time.monotonic() + timeout
        while not spin_until(self.node, done, LOOK_PERIOD, self.executor):
            if self.suite.failed() or time.monotonic() > deadline:
                raise CheckError(f'{what} did not come up; logs in {self.suite.log_dir}'
                                 + self.failed())

    @contextlib.contextmanager
    def playing(self, bag, topics: list[str], rate: float, clock_hz: float,
                waits_for: str = '', flow=None):
        """A BagPlayer of ``topics`` with /clock at ``clock_hz`` (and ``flow`` control), its
        services spun, and the client node spun on a thread of its own while the block runs.
        ``waits_for``: name of the node that must subscribe first (while it runs, up to
        STARTUP_LIMIT), else CheckError."""
        from cobot_calib_ros.bags.player import BagPlayer, spinning
        player = BagPlayer(bag, rate=rate, topics=topics, clock_hz=clock_hz,
                           wait_subscribers=LOOK_PERIOD, report=self.say, flow=flow,
                           context=self.node.context)
        self.players.append(player)
        stop_spinning = spin_in_background(self.executor, self.node.context)
        try:
            with spinning(player):
                if waits_for:
                    deadline = time.monotonic() + STARTUP_LIMIT
                    while player.wait_for_subscribers():
                        if self.suite.failed() or time.monotonic() > deadline:
                            raise CheckError(f'{waits_for} did not subscribe to '
                                             f'{", ".join(topics)}; logs in '
                                             f'{self.suite.log_dir}' + self.failed())
                yield player
        finally:
            stop_spinning()


def passes(player, rate: float, count: int, min_rate: float) -> Iterator[int]:
    """Pass numbers 1..count; before each pass after the first the player's rate is halved,
    not below min(rate, min_rate). The caller breaks when nothing is missing."""
    for number in range(1, count + 1):
        if number > 1:
            player.rate = max(min(rate, min_rate), player.rate / 2)
        yield number


def flow_note(result) -> str:
    """', N sent again, M written off' of a flow-controlled PlayResult ('' when none)."""
    return (f', {result.resent} sent again' if result.resent else '') + (
        f', {result.written_off} written off as lost' if result.written_off else '')


def spin_in_background(executor, context) -> Callable[[], None]:
    """Spin ``executor`` on a thread of its own until the returned function is called."""
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set() and context.ok():
            executor.spin_once(timeout_sec=0.005)
    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()

    def stop_spinning() -> None:
        stop.set()
        spinner.join(timeout=2.0)
    return stop_spinning


def drain(count: Callable[[], int], done: Callable[[], bool], quiet_s: float) -> None:
    """Wait until done(), or count() has not changed for ``quiet_s`` [s] (the rest is lost)."""
    last, quiet = count(), time.monotonic()
    while not done() and time.monotonic() - quiet < quiet_s:
        time.sleep(0.02)
        now = count()
        if now != last:
            last, quiet = now, time.monotonic()


@contextlib.contextmanager
def replay_suite(specs: Callable[[Path], list], client_name: str,
                 say: Callable[[str], None], data_dir: bool = False) -> Iterator[ReplaySuite]:
    """The nodes ``specs(tmp)`` (api.launcher.NodeSpec, each given ``use_sim_time``) on a
    private domain, and the check's client session there; see the module doc. ``data_dir``:
    COBOT_CALIB_DATA=<tmp>/data for the nodes."""
    import domain_coordinator

    from cobot_calib_ros.api.launcher import NodeSpec, Suite
    from cobot_calib_ros.ros.session import session
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    with domain_coordinator.domain_id() as domain, \
            tempfile.TemporaryDirectory(prefix='cobot_calib_check_') as folder:
        tmp = Path(folder)
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
        if data_dir:
            env['COBOT_CALIB_DATA'] = str(tmp / 'data')
        nodes = [NodeSpec(s.name, {'use_sim_time': 'true', **s.params}) for s in specs(tmp)]
        suite = Suite(tmp / 'log')
        suite.start(nodes, env=env)
        say(f'{" and ".join(s.name for s in nodes)} on ROS_DOMAIN_ID={domain} (sim time)')
        harness = None
        try:
            with session(client_name, domain_id=domain, sim_time=True) as (node, executor):
                harness = ReplaySuite(domain, tmp, suite, node, executor, say)
                try:
                    yield harness
                finally:
                    for player in harness.players:
                        player.destroy_node()
        finally:
            suite.stop()
