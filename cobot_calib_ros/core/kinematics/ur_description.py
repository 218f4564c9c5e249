"""The kinematics YAML of Universal Robots' ROS 2 description (``kinematics_params``).

Universal_Robots_ROS2_Description builds its URDF from a YAML whose ``kinematics:`` mapping
gives the origin of each of the six arm joints (``shoulder`` -> shoulder_pan_joint,
``upper_arm`` -> shoulder_lift_joint, ``forearm`` -> elbow_joint, ``wrist_1`` .. ``wrist_3``),
each ``{x, y, z, roll, pitch, yaw}`` [m, rad] in the URDF origin convention, plus ``hash`` (the
controller's calibration checksum when ur_calibration wrote it). :func:`ur_kinematics` reads
those origins from a (calibrated) UR URDF, :func:`parse_ur_kinematics` reads the YAML back and
:func:`apply_ur_kinematics` puts them into a UR URDF, as the description's xacro does.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import yaml

# YAML key -> URDF joint, in chain order
UR_JOINTS = (('shoulder', 'shoulder_pan_joint'), ('upper_arm', 'shoulder_lift_joint'),
             ('forearm', 'elbow_joint'), ('wrist_1', 'wrist_1_joint'),
             ('wrist_2', 'wrist_2_joint'), ('wrist_3', 'wrist_3_joint'))
_FIELDS = ('x', 'y', 'z', 'roll', 'pitch', 'yaw')

Origins = dict[str, tuple[float, ...]]   # YAML key -> (x, y, z, roll, pitch, yaw)


def ur_prefix(joint_names) -> str | None:
    """The tf_prefix of the six joints of a UR arm (in order; '' for none), None if they are
    not a UR arm's."""
    names = tuple(joint_names)
    if len(names) != len(UR_JOINTS) or not names[0].endswith(UR_JOINTS[0][1]):
        return None
    prefix = names[0][:-len(UR_JOINTS[0][1])]
    return prefix if names == tuple(prefix + joint for _, joint in UR_JOINTS) else None


def is_ur(joint_names) -> bool:
    """Are these the six joints of a UR arm (in order, with one tf_prefix or none)?"""
    return ur_prefix(joint_names) is not None


def _origin(root: ET.Element, joint: str) -> tuple[float, ...]:
    element = root.find(f"joint[@name='{joint}']")
    if element is None:
        raise ValueError(f'the URDF has no joint {joint!r}: not a UR arm description')
    origin = element.find('origin')
    values = []
    for attribute in ('xyz', 'rpy'):
        text = '0 0 0' if origin is None else origin.get(attribute, '0 0 0')
        values += [float(v) for v in text.split()]
    return tuple(values)


def ur_kinematics(urdf_text: str, joint_names=None) -> Origins:
    """The six arm joint origins of a UR URDF, by YAML key (``joint_names``: the chain's, to
    take their tf_prefix); ValueError if one is missing."""
    root = ET.fromstring(urdf_text)
    prefix = (ur_prefix(joint_names) or '') if joint_names is not None else ''
    return {key: _origin(root, prefix + joint) for key, joint in UR_JOINTS}


def ur_kinematics_yaml(origins: Origins, hash_: str, note: str = '') -> str:
    """The ``kinematics_params`` YAML text; ``note`` becomes a leading comment line."""
    kinematics = {key: dict(zip(_FIELDS, (float(v) for v in origins[key])))
                  for key, _ in UR_JOINTS}
    head = ''.join(f'# {line}\n' for line in note.splitlines())
    return head + yaml.safe_dump({'kinematics': {**kinematics, 'hash': hash_}}, sort_keys=False)


def parse_ur_kinematics(text: str, where: str = 'kinematics YAML') -> tuple[Origins, str]:
    """(origins, hash) of a ``kinematics_params`` YAML text; ValueError naming the key."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f'{where}: not YAML ({exc})') from None
    kinematics = data.get('kinematics') if isinstance(data, dict) else None
    if not isinstance(kinematics, dict):
        raise ValueError(f'{where}: expected a top-level "kinematics:" mapping')
    origins = {}
    for key, _ in UR_JOINTS:
        entry = kinematics.get(key)
        if not isinstance(entry, dict):
            raise ValueError(f'{where}: kinematics.{key}: expected {{{", ".join(_FIELDS)}}}')
        values = []
        for field in _FIELDS:
            value = entry.get(field)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise ValueError(f'{where}: kinematics.{key}.{field}: expected a finite number '
                                 f'[m or rad], got {value!r}')
            values.append(float(value))
        origins[key] = tuple(values)
    return origins, str(kinematics.get('hash', ''))


def apply_ur_kinematics(urdf_text: str, origins: Origins) -> str:
    """The UR URDF with its six arm joint origins set from ``origins`` (what the description's
    xacro does with the YAML); everything else kept."""
    root = ET.fromstring(urdf_text, parser=ET.XMLParser(
        target=ET.TreeBuilder(insert_comments=True)))
    for key, joint in UR_JOINTS:
        _origin(root, joint)                   # ValueError if missing
        element = root.find(f"joint[@name='{joint}']")
        origin = element.find('origin')
        if origin is None:
            origin = ET.SubElement(element, 'origin')
        values = origins[key]
        origin.set('xyz', ' '.join(repr(float(v)) for v in values[:3]))
        origin.set('rpy', ' '.join(repr(float(v)) for v in values[3:]))
    return '<?xml version="1.0" ?>\n' + ET.tostring(root, encoding='unicode') + '\n'
