"""Interface definitions for bags, without rclpy: .msg texts, rosbag2's ros2msg schema text,
RIHS01 type hashes and the rosbags typestore that decodes our messages.

Definitions come from the installed interface packages (``<prefix>/share/<pkg>/msg/*.msg``)
of every prefix in $AMENT_PREFIX_PATH and of this interpreter's prefix (the venv, where the
PyPI wheels and ``make`` install them; AMENT_PREFIX_PATH is not set there).

- ``full_text`` builds the schema text as rosbag2's LocalMessageDefinitionSource does (Jazzy):
  the type's .msg file, then each dependency, depth first in sorted order, after a line of 80
  ``=`` and ``MSG: <pkg>/<Name>`` (the name as the field spells it). A reader needs the
  dependencies (``std_msgs/Header`` ...) to decode the type.
- ``type_hash`` is the RIHS01 hash rosidl generated at build time (``<Name>.json`` beside the
  .msg), which is what rcl reports for a publisher; rosbags' hash_rihs01 is the fallback.
- ``typestore()`` is rosbags' Jazzy store plus this project's own interface packages
  (cobot_calib_msgs, tf2_msgs) read from their installed .msg files.
"""
from __future__ import annotations

import functools
import json
import os
from pathlib import Path
import re
import sys

from rosbags.typesys import Stores, get_types_from_msg, get_typestore

# rosbag2_cpp/src/rosbag2_cpp/message_definitions/local_message_definition_source.cpp
TYPE_NAME = re.compile(r'^([a-zA-Z0-9_]+)/(?:msg/|srv/)?([a-zA-Z0-9_]+)$')
MSG_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
PRIMITIVES = frozenset({'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
                        'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string'})
SEPARATOR = '=' * 80 + '\n'
MAX_DEPTH = 50

# The project's own interface packages, registered into the typestore from their .msg files.
OWN_PACKAGES = ('cobot_calib_msgs', 'tf2_msgs')


class DefinitionNotFound(LookupError):
    """No installed .msg file for a type."""


def prefixes() -> list[Path]:
    """Install prefixes to search: $AMENT_PREFIX_PATH, then this interpreter's prefix."""
    found = [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    for extra in (Path(sys.prefix),):
        if extra not in found:
            found.append(extra)
    return found


@functools.lru_cache(maxsize=None)
def share_dir(package: str) -> Path | None:
    """``<prefix>/share/<package>`` of the first prefix that has it."""
    for prefix in prefixes():
        candidate = prefix / 'share' / package
        if candidate.is_dir():
            return candidate
    return None


def split_type(typename: str) -> tuple[str, str, str]:
    """'pkg/msg/Name' or 'pkg/Name' -> ('pkg', 'msg', 'Name')."""
    parts = typename.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f'not a ROS interface type name: {typename!r}')
    return parts[0], parts[1], parts[2]


def interface_file(typename: str, suffix: str = '.msg') -> Path | None:
    """The installed definition file of a type (``.msg``, ``.json``), or None."""
    package, kind, name = split_type(typename)
    share = share_dir(package)
    if share is None:
        return None
    path = share / kind / f'{name}{suffix}'
    return path if path.is_file() else None


@functools.lru_cache(maxsize=None)
def msg_text(typename: str) -> str:
    """The .msg file of a type, verbatim; DefinitionNotFound if not installed."""
    path = interface_file(typename)
    if path is None:
        raise DefinitionNotFound(f'no installed .msg file for {typename}')
    return path.read_text()


def _dependencies(text: str, package: str) -> list[str]:
    found = set()
    for match in MSG_FIELD_TYPE.finditer(text):
        name = match.group(1)
        if name in PRIMITIVES:
            continue
        found.add(name if '/' in name else f'{package}/{name}')
    return sorted(found)


@functools.lru_cache(maxsize=None)
def full_text(typename: str) -> str:
    """The ros2msg schema text rosbag2 (Jazzy) stores for a type; DefinitionNotFound if the
    type or one of its dependencies has no installed .msg file."""
    seen: set[str] = set()

    def append(name: str, depth: int) -> str:
        if depth <= 0:
            raise DefinitionNotFound(f'definition of {typename} nests too deep')
        match = TYPE_NAME.match(name)
        if match is None:
            raise DefinitionNotFound(f'type name {name!r} not understood')
        package = match.group(1)
        text = msg_text(f'{package}/msg/{match.group(2)}')
        result = text
        for dep in _dependencies(text, package):
            if dep not in seen:
                seen.add(dep)
                result += '\n' + SEPARATOR + f'MSG: {dep}\n' + append(dep, depth - 1)
        return result

    return append(typename, MAX_DEPTH)


@functools.lru_cache(maxsize=None)
def installed_type_hash(typename: str) -> str:
    """The RIHS01 hash rosidl generated for an installed type ('' when not installed)."""
    path = interface_file(typename, '.json')
    if path is None:
        return ''
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return ''
    full = '/'.join(split_type(typename))
    for entry in data.get('type_hashes', []):
        if entry.get('type_name') == full:
            return entry.get('hash_string', '')
    return ''


def type_hash(typename: str, store=None) -> str:
    """RIHS01 hash of a type: rosidl's (installed .json), else rosbags' from ``store`` (or the
    default typestore), else ''."""
    found = installed_type_hash(typename)
    if found:
        return found
    store = store if store is not None else typestore()
    try:
        return store.hash_rihs01(typename)
    except Exception:  # noqa: BLE001 - rosbags raises several kinds for unknown types
        return ''


def own_types() -> dict:
    """Field definitions of the project's own interface packages from their .msg files."""
    types: dict = {}
    for package in OWN_PACKAGES:
        share = share_dir(package)
        if share is None:
            continue
        for path in sorted((share / 'msg').glob('*.msg')):
            types.update(get_types_from_msg(path.read_text(), f'{package}/msg/{path.stem}'))
    return types


@functools.lru_cache(maxsize=1)
def _base_fielddefs() -> dict:
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(own_types())
    return dict(store.fielddefs)


def typestore():
    """A new rosbags typestore: Jazzy's types plus cobot_calib_msgs and tf2_msgs as installed."""
    store = get_typestore(Stores.EMPTY)
    store.register(_base_fielddefs())
    return store
