"""`cobot-calib replay BAG --check` of a sphere-coupling bag: identify again, compare.

A sphere bag (bags/make_sphere_bag.py) holds only ``/cobot_calib/captures``: every pose
kinematic_identifier collected (sensor_msgs/JointState, frame_id = the sphere's name,
position = the joints averaged over the hold). Next to it ``expected.json``: the live
``cobot-calib identify --json`` report and the ``cell`` it ran on.

The check identifies the bag's poses offline with the node's own core job
(api.identification.identify_source, as ``identify --source BAG`` does) and compares with
``expected.json``: the same dropped parameters, the same identified ones, every value within
TOL (measured on bags/iiwa_spheres: 0, bit for bit). The captures are the identification's
whole input (the node reads them from the bag, not from a stream), so nothing is replayed
over DDS.
"""
from __future__ import annotations

from dataclasses import dataclass
import json
import os
from pathlib import Path
import time
from typing import Callable

from cobot_calib_ros.api import replay_check, replay_harness
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.ros.marks import CAPTURES_TOPIC

EXPECTED_FILE = 'expected.json'
TOL = 1e-9          # [m] or [rad] per identified parameter


CheckError = replay_check.CheckError     # the check could not run (expected.json missing...)


def is_sphere_bag(bag) -> bool:
    """A bag this check applies to: captures and nothing else (a teach bag also has
    /joint_states, a landmark bag images)."""
    return set(bag.topics) == {CAPTURES_TOPIC}


def read_expected(bag_path: str | os.PathLike) -> tuple[Path, dict]:
    """(path, report) of the bag's expected.json; CheckError when unreadable or incomplete."""
    path, text = replay_check.expected_text(bag_path, EXPECTED_FILE)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CheckError(f'{path}: not JSON: {exc}') from None
    missing = [k for k in ('cell', 'dropped', 'identified') if not isinstance(data, dict)
               or k not in data and not (k == 'dropped' and 'dropped_parameters' in data)]
    if missing:
        raise CheckError(f'{path}: missing {", ".join(missing)}')
    return path, data


def dropped_names(report: dict) -> list[str]:
    """The dropped parameters of an identify report; an expected.json recorded before the
    one report shape lists them as ``dropped_parameters``."""
    if 'dropped' in report:
        return [d['name'] for d in report['dropped']]
    return list(report['dropped_parameters'])


@dataclass
class SphereCheckResult(replay_harness.Verdict):
    code: ErrorCode     # replay_harness.Verdict: SUCCESS or IMPLAUSIBLE_FIT
    poses: int
    worst: float                # largest |replayed - expected| over the identified values
    worst_name: str
    differences: list[str]      # what differs besides the values (dropped or identified sets)
    wall_s: float
    report: str


def run_check(bag_path: str, say: Callable[[str], None] = print) -> SphereCheckResult:
    """Identify the bag's captures, compare with expected.json; see the module doc."""
    from cobot_calib_ros.api.identification import identify_source, IdentificationFailed
    started = time.monotonic()
    path, expected = read_expected(bag_path)
    try:
        got = identify_source(bag_path, cell=str(expected['cell']))
    except (KeyError, ValueError, IdentificationFailed) as exc:
        raise CheckError(f'{bag_path}: {exc}') from None
    differences = []
    dropped, live_dropped = dropped_names(got), dropped_names(expected)
    if dropped != live_dropped:
        differences.append(f'dropped {dropped}, expected {live_dropped}')
    mine = {p['name']: p['value'] for p in got['identified']}
    live = {p['name']: p['value'] for p in expected['identified']}
    if list(mine) != list(live):
        differences.append(f'identified {list(mine)}, expected {list(live)}')
    gaps = {n: abs(mine[n] - live[n]) for n in mine.keys() & live.keys()}
    worst_name = max(gaps, key=gaps.get, default='')
    worst = gaps.get(worst_name, float('inf'))
    code = replay_harness.verdict(not differences and worst <= TOL)
    report = (f'identified {got["rows"]} poses of {bag_path} on cell {expected["cell"]}: '
              f'{len(mine)} parameters, largest difference from {path} {worst:.3e}'
              + (f' ({worst_name})' if worst > 0 else '') + f' (tolerance {TOL:g})'
              + ''.join(f'; {d}' for d in differences))
    say(report)
    return SphereCheckResult(code, int(got['rows']), worst, worst_name, differences,
                             time.monotonic() - started, report)
