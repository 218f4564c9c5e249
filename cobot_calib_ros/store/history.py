"""A cell's history: each stored result against the previous one, with its own uncertainty.

User frames: the frame's translation and rotation change with their standard errors and the
drift verdict of core.drift (the change's covariance from the two results' shared points when
they measured the same ones, else the sum of the two fits' covariances). Kinematic
calibrations (per robot): each identified parameter's change in units of its combined
standard error. TCPs (per tool): the TCP's move and turn on the flange against its
standard error. Used by ``cobot-calib history`` and by user_frame_solver's drift status on
/diagnostics.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
import math
from typing import Any

import numpy as np

from cobot_calib_ros.core.drift import (change_covariance, DriftLimits, frame_change,
                                        FrameChange)


@dataclass(frozen=True)
class Step:
    """One result and its change since the previous one of its kind (None for the first)."""

    record: Mapping[str, Any]
    previous_id: str
    change: FrameChange | None


def user_frame_change(previous: Mapping[str, Any], new: Mapping[str, Any],
                      limits: DriftLimits = DriftLimits()) -> FrameChange:
    """The change of the user frame from record ``previous`` to ``new`` and its verdict; its
    message says so when the two were touched with different TCP calibrations (the change
    then holds the tool's)."""
    T_prev = np.array(previous['result']['T_base_user'], dtype=float)
    T_new = np.array(new['result']['T_base_user'], dtype=float)
    shared = _shared_points(previous, new)
    if shared is not None:
        cov = change_covariance(T_prev, *shared)
    else:
        cov = _covariance(previous) + _covariance(new)
    change = frame_change(T_prev, T_new, cov, limits, since=str(previous['id']))
    tcp_before, tcp_now = previous.get('tcp', ''), new.get('tcp', '')
    if tcp_before and tcp_now and tcp_before != tcp_now:
        change = replace(change, message=(
            f'{change.message}; touched with TCP {tcp_now}, {previous["id"]} with TCP '
            f'{tcp_before}: the change holds the tool\'s'))
    return change


def user_frame_steps(records: Sequence[Mapping[str, Any]],
                     limits: DriftLimits = DriftLimits()) -> list[Step]:
    """Each record (oldest first, rejected ones skipped) against the one before it."""
    steps, previous = [], None
    for record in sorted(records, key=lambda r: (r['stamp_ns'], r['id'])):
        if record.get('gate_problem'):
            continue
        change = None if previous is None else user_frame_change(previous, record, limits)
        steps.append(Step(record, '' if previous is None else previous['id'], change))
        previous = record
    return steps


def tcp_steps(records: Sequence[Mapping[str, Any]],
              limits: DriftLimits = DriftLimits()) -> list[tuple[str, Step]]:
    """(tool, step) of each TCP record (oldest first, rejected ones skipped) against the
    previous one of its tool: the TCP's move and turn in the flange frame, with the standard
    error of the two solves (their position covariances; the z / x direction's from the
    residuals over the elongation)."""
    steps, previous = [], {}
    for record in sorted(records, key=lambda r: (r['stamp_ns'], r['id'])):
        if record.get('gate_problem'):
            continue
        tool = str(record.get('tool', ''))
        prev = previous.get(tool)
        change = None
        if prev is not None:
            change = frame_change(_tcp(prev), _tcp(record),
                                  _tcp_covariance(prev) + _tcp_covariance(record), limits,
                                  what=f'TCP of {tool}', since=str(prev['id']))
        steps.append((tool, Step(record, '' if prev is None else prev['id'], change)))
        previous[tool] = record
    return steps


def _tcp(record) -> np.ndarray:
    return np.array(record['result']['T_flange_tool'], dtype=float)


def _tcp_covariance(record) -> np.ndarray:
    """(6, 6): the TCP position's covariance; its direction's from the elongator touches (none
    without: the rotation is identity, not measured)."""
    result = record['result']
    cov = np.zeros((6, 6))
    position = np.array(result.get('covariance') or np.full((3, 3), np.inf), dtype=float)
    cov[:3, :3] = position if position.shape == (3, 3) else np.full((3, 3), np.inf)
    elongation = float(record.get('inputs', {}).get('elongation') or 0.0)
    if result.get('orientation_method', 'none') != 'none' and elongation > 0:
        rms = math.sqrt(float(np.mean(np.square(result.get('residuals_mm') or [0.0]))) / 3.0)
        cov[3:, 3:] = np.eye(3) * 2.0 * (rms * 1e-3 / elongation) ** 2
    return cov


@dataclass(frozen=True)
class ParameterChange:
    name: str
    change: float
    sigma: float          # combined standard error of the two identifications (inf: unknown)

    @property
    def z(self) -> float:
        return abs(self.change) / self.sigma if self.sigma > 0 else math.inf


def kinematic_changes(previous: Mapping[str, Any], new: Mapping[str, Any]
                      ) -> list[ParameterChange]:
    """The identified parameters both calibrations freed, their change and standard error."""
    def table(record):
        result = record['result']
        std = result.get('std') or [math.inf] * len(result.get('free', []))
        return {n: (float(v), float(s)) for n, v, s in zip(
            result.get('free', []), result.get('values') or [], std)}
    before, after = table(previous), table(new)
    return [ParameterChange(name, after[name][0] - before[name][0],
                            math.hypot(after[name][1], before[name][1]))
            for name in after if name in before]


def _shared_points(previous, new):
    """(p_prev, p_new) of the points both measured, in the same order; None if < 3."""
    try:
        names_prev = list(previous['inputs']['point_names'])
        names_new = list(new['inputs']['point_names'])
        p_prev = np.array(previous['inputs']['points_base'], dtype=float)
        p_new = np.array(new['inputs']['points_base'], dtype=float)
    except (KeyError, TypeError, ValueError):
        return None
    common = [n for n in names_new if n in names_prev]
    if len(common) < 3 or p_prev.shape != (len(names_prev), 3) or \
            p_new.shape != (len(names_new), 3):
        return None
    return (p_prev[[names_prev.index(n) for n in common]],
            p_new[[names_new.index(n) for n in common]])


def _covariance(record) -> np.ndarray:
    cov = np.array(record['result'].get('covariance') or np.full((6, 6), np.inf), dtype=float)
    return cov if cov.shape == (6, 6) else np.full((6, 6), np.inf)
