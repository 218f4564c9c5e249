"""`cobot-calib replay BAG --check` for a repeatability-trial bag: RP from the replayed probe.

A trial bag (bags/make_trial_bag.py, bags/trial_close) holds the raw probe output
``/probe/voltage``, proximity_sensor's mark of every probe/average it served on
``/cobot_calib/probe_averages`` (MARKS_TOPIC, cobot_calib_msgs/ProbeAverageMark, ros.marks:
window start t0 as header.stamp, the window's duration, the response and the stamps of the
readings it averaged; the sample bag's JointState marks are read through bags.mark_converter)
and the live, latched
``/repeatability``; next to it ``expected.yaml``: the trial (method, axis, cycles, points), the
probe's calibration table, the final live statistics (``rp``, ``rp_all``, ``mean_distance``,
``mean_deviation``, ``sigma`` [m]) and ``readings``: for each (cycle, point) of the trial the
index of the mark it read, FF_i,n [m] and its direction (eq 15).

The check starts a proximity_sensor on a private ROS_DOMAIN_ID (``use_sim_time: true``, the
bag's calibration table), replays ``/probe/voltage`` with ``/clock`` (bags.player.BagPlayer)
into it and collects the distances it publishes on ``probe/distance``. Then it averages
every recorded window again with the node's own average (core.sensors.probe.average), from
the replayed distances the live window held (by their stamps, in the live order: the live node's best-effort
subscription may have dropped a voltage the recorder kept, and the average leaves it out too).
Each must give the live average to the bit. The trial's readings are those averages corrected
by eq 15 (core ``correct_distance``); the ISO 9283 statistics come from core
``point_statistics`` and are compared, RP_i and RP_all, with expected.yaml and with the last
recorded ``/repeatability``: within TOL_M.

proximity_sensor subscribes best effort with a history of 5 and converts each voltage into one
distance, so the replay is flow-controlled (bags.player.FlowControl): the player keeps at most
WINDOW voltages published whose distance has not come back to the check, so the node's queue
cannot overflow however slowly the machine lets it run, and /clock waits with the player. The
rate (DEFAULT_RATE, at most MAX_RATE) only caps the speed. Until the first distance comes back
the player sends the first voltages again (those sent before the node's subscription has
matched the player are lost): that is the warm-up, an event and not a sleep. A reading can
still be lost on the way in or out (best effort); the conversion is per message and stateless,
so a pass that misses readings the averages need is followed by another pass over the bag, up
to PASSES; each reading is the node's conversion of its voltage whichever pass brought it, so
the result does not depend on the losses. A reading still missing after that is a CheckError.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
import os
from pathlib import Path
import time
from typing import Callable

import numpy as np

from cobot_calib_ros.api import replay_check, replay_harness
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.ros import marks
from cobot_calib_ros.ros.time import header_ns

VOLTAGE_TOPIC = '/probe/voltage'
MARKS_TOPIC = marks.PROBE_AVERAGES_TOPIC
STATS_TOPIC = '/repeatability'
EXPECTED_FILE = replay_check.EXPECTED_FILE
TOL_M = 1e-6
DEFAULT_RATE = 2.0
MAX_RATE = 20.0
PASSES = 4               # replays of the bag at most, until every averaged reading came back
MIN_RATE = 1.0           # a pass after a lossy one goes at half the rate, down to this
WINDOW = 4               # voltages out at most (proximity_sensor's queue holds 5)
DRAIN_TIMEOUT = 1.0      # [s] after a pass without a new distance: the rest is lost
TABLE_KEYS = ('calibration_distance', 'calibration_voltage', 'saturation_margin')


CheckError = replay_check.CheckError


Mark = marks.AverageMark


def read_marks(bag) -> list[Mark]:
    """The bag's MARKS_TOPIC messages as Marks (ros.marks.read_average_mark; an old bag's
    JointState marks come converted, bags.mark_converter)."""
    return [marks.read_average_mark(bag.deserialize(m.rawdata, m.msgtype))
            for m in bag.messages([MARKS_TOPIC])]


def bag_samples(bag, table: dict) -> list[tuple[int, float, int]]:
    """(stamp [ns], distance [m], status) of the bag's voltages, converted offline as
    proximity_sensor converts them (for bags/make_trial_bag.py's completeness check)."""
    from cobot_calib_ros.core.sensors.probe import curve_from_lists, read_distance
    curve = curve_from_lists(table['calibration_distance'], table['calibration_voltage'])
    out = []
    for m in bag.messages([VOLTAGE_TOPIC]):
        msg = bag.deserialize(m.rawdata, m.msgtype)
        reading = read_distance(curve, msg.voltage, table['saturation_margin'])
        out.append((header_ns(msg), reading.distance, reading.status))
    return out


def rebuild_marks(marks: list[Mark], samples) -> list:
    """probe/average's response for each mark, from (stamp [ns], distance, status) samples:
    the readings the live window held, in the live order, through core.sensors.probe.average
    (as proximity_sensor). CheckError naming the first reading not among the samples."""
    from cobot_calib_msgs.srv import AverageProximity

    from cobot_calib_ros.core.sensors.probe import average
    from cobot_calib_ros.ros.convert import fill_average
    by_stamp: dict[int, list] = {}
    for sample in samples:
        by_stamp.setdefault(sample[0], []).append(sample)
    out = []
    for k, mark in enumerate(marks):
        taken: dict[int, int] = {}
        window = []
        for stamp in mark.stamps_ns:
            n = taken.get(stamp, 0)
            found = by_stamp.get(stamp, ())
            if n >= len(found):
                raise LostReading(k, stamp)
            window.append(found[n])
            taken[stamp] = n + 1
        out.append(fill_average(AverageProximity.Response(), average(window, mark.duration)))
    return out


class LostReading(CheckError):
    """A reading a live average held is not among the replayed (or recorded) ones."""

    def __init__(self, mark: int, stamp_ns: int) -> None:
        super().__init__(f'probe/average #{mark}: its reading stamped {stamp_ns} ns is missing')
        self.mark, self.stamp_ns = mark, stamp_ns


def mark_difference(mark: Mark, rebuilt) -> str:
    """'' when a rebuilt average is the recorded one (counts, outcome, distance to the bit),
    else what differs."""
    got = (rebuilt.sample_count, rebuilt.rejected_count, rebuilt.error_code)
    want = (mark.sample_count, mark.rejected_count, mark.error_code)
    if got != want:
        return (f'{got[0]} valid + {got[1]} rejected readings (code {got[2]}) in the window, '
                f'the live average had {want[0]} + {want[1]} (code {want[2]})')
    if mark.ok and rebuilt.distance != mark.distance:
        return (f'distance {rebuilt.distance!r} m, the live average gave {mark.distance!r} m '
                f'({rebuilt.distance - mark.distance:+.3e} m)')
    return ''


def distances(readings: list[dict], rebuilt: list, m: int, n: int) -> np.ndarray:
    """The trial's (m, n) corrected distances [m]: each reading's average, eq (15)."""
    from cobot_calib_ros.core.repeatability import correct_distance
    d = np.full((m, n), math.nan)
    for r in readings:
        average = rebuilt[r['mark']]
        if average.error_code != 0:
            raise CheckError(f'cycle {r["cycle"] + 1}, point {r["point"] + 1}: probe/average '
                             f'#{r["mark"]} was not a valid reading ({average.message})')
        d[r['point'], r['cycle']] = correct_distance(average.distance, float(r['ff_m']),
                                                     r.get('direction') or None)
    return d


def write_expected(path: Path, data: dict) -> None:
    replay_check.write_expected(path, data, comment=(
        f'lengths in metres; readings: mark = index on {MARKS_TOPIC}, ff_m and direction '
        'of eq 15'))


def read_expected(bag_path: str | os.PathLike) -> tuple[Path, dict]:
    path, data = replay_check.load_expected(bag_path)
    missing = [k for k in ('point_names', 'cycles', 'rp', 'rp_all', 'readings')
               if k not in data]
    if missing:
        raise CheckError(f'{path}: missing {", ".join(missing)}')
    m, n = len(data['point_names']), int(data['cycles'])
    if len(data['rp']) != m:
        raise CheckError(f'{path}: rp has {len(data["rp"])} values for {m} points')
    for r in data['readings']:
        if not (0 <= r.get('cycle', -1) < n and 0 <= r.get('point', -1) < m
                and isinstance(r.get('mark'), int)):
            raise CheckError(f'{path}: bad reading {r}')
    return path, data


def is_trial_bag(bag) -> bool:
    """A bag this check applies to: it has probe/average marks."""
    return MARKS_TOPIC in bag.topics


@dataclass
class TrialCheckResult(replay_harness.Verdict):
    code: ErrorCode                 # replay_harness.Verdict: SUCCESS or IMPLAUSIBLE_FIT
    rp_replayed: np.ndarray         # [m]
    rp_all_replayed: float          # [m]
    rp_expected: np.ndarray
    rp_all_expected: float
    rp_recorded: np.ndarray | None  # the last /repeatability in the bag
    rp_all_recorded: float
    worst_m: float                  # largest |difference| over RP_i and RP_all, both refs [m]
    marks: int                      # probe averages rebuilt (all equal the live ones)
    readings: int
    voltages: int                   # replayed and received
    wall_s: float


def run_check(bag_path: str, rate: float = DEFAULT_RATE, say: Callable[[str], None] = print,
              clock_hz: float = 40.0) -> TrialCheckResult:
    """Replay the bag's voltages through proximity_sensor and compare RP; see the module doc."""
    from cobot_calib_ros.bags.reader import open_bag
    from cobot_calib_ros.core.repeatability import point_statistics
    if not 0 < rate <= MAX_RATE:
        raise CheckError(f'a trial bag replays at a finite rate up to {MAX_RATE:g} '
                         f'(proximity_sensor takes the probe best effort); got {rate:g}')
    expected_path, expected = read_expected(bag_path)
    started = time.monotonic()
    with open_bag(bag_path) as bag:
        for topic in (VOLTAGE_TOPIC, MARKS_TOPIC):
            if topic not in bag.topics or not bag.topics[topic].count:
                raise CheckError(f'{bag.path}: nothing on {topic}')
        for warning in bag.warnings:
            say(f'warning: {warning}')
        marks = read_marks(bag)
        recorded = [bag.deserialize(m.rawdata, m.msgtype) for m in bag.messages([STATS_TOPIC])] \
            if STATS_TOPIC in bag.topics else []
        wanted = bag.topics[VOLTAGE_TOPIC].count
        bad = [r['mark'] for r in expected['readings'] if r['mark'] >= len(marks)]
        if bad:
            raise CheckError(f'{expected_path}: readings refer to mark #{bad[0]}, the bag has '
                             f'{len(marks)} marks')
        needed = {stamp for mark in marks for stamp in mark.stamps_ns}
        samples = _replay(bag, expected, rate, clock_hz, wanted, needed, say)
    try:
        rebuilt = rebuild_marks(marks, samples)
    except LostReading as exc:
        lost = len(needed - {x[0] for x in samples})
        raise CheckError(f'{exc} from the replay: {lost} of the {len(needed)} readings the '
                         f'averages need did not come back in {PASSES} passes; replay at a '
                         'lower --rate') from None
    for k, (mark, again) in enumerate(zip(marks, rebuilt)):
        problem = mark_difference(mark, again)
        if problem:
            raise CheckError(f'probe/average #{k} (t0 {mark.t0_ns} ns) replayed: {problem}')
    m, n = len(expected['point_names']), int(expected['cycles'])
    stats = point_statistics(distances(expected['readings'], rebuilt, m, n))
    rp_exp, rp_all_exp = np.array(expected['rp'], dtype=float), float(expected['rp_all'])
    diffs = [np.max(np.abs(stats.rp - rp_exp)), abs(stats.rp_all - rp_all_exp)]
    rp_rec, rp_all_rec = None, math.nan
    if recorded:
        last = recorded[-1]
        rp_rec, rp_all_rec = np.array(last.rp, dtype=float), float(last.rp_all)
        if rp_rec.shape != stats.rp.shape:
            raise CheckError(f'the recorded {STATS_TOPIC} has {rp_rec.size} points, the trial '
                             f'{stats.rp.size}')
        diffs += [np.max(np.abs(stats.rp - rp_rec)), abs(stats.rp_all - rp_all_rec)]
    worst = float(max(diffs))
    code = replay_harness.verdict(bool(np.isfinite(worst) and worst <= TOL_M))
    say(f'rebuilt {len(marks)} probe averages from {len(samples)} replayed readings, all equal '
        f'to the live ones; {len(expected["readings"])} trial readings, {stats.cycles} cycles: '
        f'RP_all {stats.rp_all * 1e3:.6f} mm vs {rp_all_exp * 1e3:.6f} mm in {expected_path}'
        + (f' and {rp_all_rec * 1e3:.6f} mm recorded on {STATS_TOPIC}' if recorded else '')
        + f'; largest difference {worst:.3e} m (tolerance {TOL_M:g})')
    return TrialCheckResult(code, stats.rp, float(stats.rp_all), rp_exp, rp_all_exp, rp_rec,
                            rp_all_rec, worst, len(marks), len(expected['readings']),
                            len(samples), time.monotonic() - started)


def _replay(bag, expected: dict, rate: float, clock_hz: float, wanted: int, needed: set[int],
            say) -> list[tuple[int, float, int]]:
    """Play /probe/voltage into a proximity_sensor, pass after pass until the readings
    stamped ``needed`` [ns] came back (at most PASSES); its probe/distance readings as
    (stamp [ns], distance [m], status), in the order they arrived (all passes)."""
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from cobot_calib_msgs.msg import ProximityReading

    from cobot_calib_ros.api.launcher import NodeSpec
    from cobot_calib_ros.bags.player import FlowControl
    from cobot_calib_ros.core.sensors.probe import ReadingStatus

    params = {}
    table = expected.get('proximity_sensor') or {}
    for key in TABLE_KEYS:
        if key in table:
            value = table[key]
            params[key] = (('[' + ', '.join(repr(float(v)) for v in value) + ']')
                           if isinstance(value, list) else repr(float(value)))
    samples: list[tuple[int, float, int]] = []

    def on_distance(msg: ProximityReading) -> None:
        samples.append((header_ns(msg), msg.distance, ReadingStatus(msg.status)))
    with replay_harness.replay_suite(lambda tmp: [NodeSpec('proximity_sensor', params)],
                                     'cobot_calib_replay_trial_check', say) as harness:
        sub = harness.node.create_subscription(
            ProximityReading, 'probe/distance', on_distance,
            QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=wanted + 100,
                       reliability=ReliabilityPolicy.BEST_EFFORT))
        harness.wait_for(lambda: sub.get_publisher_count() > 0, 'proximity_sensor')
        flow = FlowControl(WINDOW, lambda: len(samples))
        with harness.playing(bag, [VOLTAGE_TOPIC], rate, clock_hz,
                             waits_for='proximity_sensor', flow=flow) as player:
            for attempt in replay_harness.passes(player, rate, PASSES, MIN_RATE):
                before = len(samples)
                result = player.play()
                replay_harness.drain(lambda: len(samples),
                                     lambda: len(samples) >= before + wanted, DRAIN_TIMEOUT)
                missing = len(needed - {x[0] for x in samples})
                say(f'pass {attempt}: replayed {result.published} voltages in '
                    f'{result.wall_s:.2f} s ({result.speed:.1f}x real time, window {WINDOW}'
                    f'{replay_harness.flow_note(result)}), '
                    f'{len(samples) - before}/{wanted} distances back; '
                    + (f'{missing} of the {len(needed)} readings the averages need still '
                       'missing' if missing else
                       f'all {len(needed)} readings the averages need are in'))
                if not missing:
                    break
        return list(samples)


def format_rp(values) -> str:
    return '[' + ', '.join(f'{v * 1e3:.6f}' for v in values) + '] mm'
