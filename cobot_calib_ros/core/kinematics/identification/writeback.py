"""What an identification of a measurement file is written back as: the model's parameter vector
(joint offsets folded into the joint placements, so a URDF or a DH table carries them) and the
parameters its measurement kind cannot see.

A measurement of one point on the tool (one marker, a ball on spheres or planes) fits that
point's position in the flange beside the arm: a turn of the last joint's frame, or a shift
along its axis, moves the point like a change of that position, so the last joint's placement
parameters it drops are not seen, and every other tool centre and every tool orientation
carries their error. Spheres and
planes measure relative positions: the base's placement is not seen either (a user frame touched
with the arm is not affected; the base in the world is).
"""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cobot_calib_ros.core.kinematics.model import placement

Array = NDArray[np.float64]
TOOL_NOTE = ('one point on the tool cannot see it: every other tool centre and the tool\'s '
             'orientation carry its error')
BASE_NOTE = ('spheres and planes see no base frame: the base placement in the world stays '
             'nominal; a user frame touched with the arm is not affected')


def model_parameters(errors, names, values) -> Array:
    """(P,) parameters of ``errors.model`` with the identified ``names`` at ``values`` and each
    joint offset folded into its joint's placement (``P Rz(offset)``, ``P Tz(offset)`` for a
    prismatic joint). ValueError for a compliance, which no URDF or DH table holds."""
    from cobot_calib_ros.core.kinematics.identification import compliance
    springs = [n for n in names if n.startswith(compliance.PREFIX)]
    if springs:
        raise ValueError(f'{", ".join(springs)}: a joint compliance is not a URDF or DH '
                         'parameter; identify with a geometric model (--model full / mdh / '
                         'offsets) to write the result back')
    model = errors.model
    params, offsets = errors.parameters(tuple(names), np.asarray(values, dtype=float))
    prismatic = np.zeros(len(offsets), bool) if np.size(model.prismatic) == 0 else \
        np.asarray(model.prismatic, bool)
    width = model.fields_per_joint
    for j in np.flatnonzero(offsets):
        row = params[j * width:(j + 1) * width]
        if model.kind == 'mdh':
            row[3 if prismatic[j] else 2] += offsets[j]          # d or theta
            continue
        from cobot_calib_ros.core.kinematics.urdf import rpy_from_matrix
        P = placement(model.kind, row)
        if prismatic[j]:
            row[:3] = P[:3, 3] + P[:3, 2] * offsets[j]
        else:
            c, s = np.cos(offsets[j]), np.sin(offsets[j])
            row[3:] = rpy_from_matrix(P[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0],
                                                            [0.0, 0.0, 1.0]]))
    return params


def _joint_of(model, name: str) -> int:
    if name.startswith('offset_'):
        return model.joint_names.index(name[len('offset_'):])
    return model.parameter_names.index(name) // model.fields_per_joint


def unseen(model, kind: str, points_on_tool: int, dropped) -> list[dict]:
    """The dropped parameters (``[{name, reason}]``) the measurement ``kind`` cannot see by
    its nature, each {name, reason, affects: 'tool' or 'base'}: the last joint's with
    one point on the tool (``points_on_tool`` markers; a ball: 1), the first joint's with
    spheres or planes."""
    out = []
    last = len(model.joint_names) - 1
    for d in dropped:
        name = d['name']
        try:
            joint = _joint_of(model, name)
        except ValueError:
            continue
        if joint == last and points_on_tool == 1:
            out.append({'name': name, 'reason': TOOL_NOTE, 'affects': 'tool'})
        elif joint == 0 and kind in ('spheres', 'plane'):
            out.append({'name': name, 'reason': BASE_NOTE, 'affects': 'base'})
    return out
