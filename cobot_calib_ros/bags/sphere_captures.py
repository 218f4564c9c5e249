"""A recorded sphere-coupling session as the core's observations.

kinematic_identifier publishes every collected pose on ``/cobot_calib/captures``
(cobot_calib_msgs/CaptureMark: target = the sphere's name, the averaged joints [rad]; older
bags' JointState marks are read through bags.mark_converter);
a bag of that topic (`cobot-calib record /cobot_calib/captures`) is identified offline by
``cobot-calib identify --source BAG`` and by the ``identify_kinematics`` goal's ``file``.
"""
from __future__ import annotations

from pathlib import Path

from cobot_calib_ros.bags.reader import open_bag
from cobot_calib_ros.core.kinematics.identification import SphereObservations
from cobot_calib_ros.ros.marks import captured_joints, CAPTURES_TOPIC



def is_bag(folder: str | Path) -> bool:
    """A rosbag2 directory (it has metadata.yaml)."""
    return (Path(folder).expanduser() / 'metadata.yaml').is_file()


def sphere_observations(folder: str | Path, cell, model) -> tuple[SphereObservations, int]:
    """(observations, poses) of the bag's captures on ``cell``'s spheres, joints in ``model``'s
    order. BagError for an unreadable bag; ValueError when it holds no usable pose."""
    with open_bag(folder) as bag:
        captures = [bag.deserialize(m.rawdata, m.msgtype) for m in bag.messages([CAPTURES_TOPIC])]
    names = cell.spheres.names if cell.spheres else ()
    rows = [c for c in captures if c.target in names]
    if not rows:
        raise ValueError(f'{folder}: no {CAPTURES_TOPIC} poses on the spheres {list(names)} of '
                         f'cell {cell.name}; record that topic during collect_sphere_data')
    order = list(model.joint_names)
    try:
        q = [captured_joints(c, order) for c in rows]
    except KeyError as e:
        raise ValueError(f'{folder}: a capture lacks joint {e} of {order}') from None
    return SphereObservations(q, [names.index(c.target) for c in rows],
                              cell.spheres.known_distances()), len(rows)
