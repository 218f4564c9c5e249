"""ROS interface types by name, and messages as plain Python data."""
from __future__ import annotations

import array
import importlib
from typing import Any

import numpy as np


def import_type(type_name: str):
    """'sensor_msgs/msg/JointState' (or 'sensor_msgs/JointState') -> the Python class;
    ValueError with what is missing if it is not installed here."""
    parts = type_name.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f'not a ROS type name: {type_name!r} (like pkg/msg/Name)')
    try:
        module = importlib.import_module(f'{parts[0]}.{parts[1]}')
    except ImportError:
        raise ValueError(f'unknown type {type_name!r}: no interface package {parts[0]!r} '
                         f'with {parts[1]}/ here') from None
    if not hasattr(module, parts[2]):
        raise ValueError(f'unknown type {type_name!r}: {parts[0]}/{parts[1]} has no '
                         f'{parts[2]!r}')
    return getattr(module, parts[2])


def service_type_name(type_name: str) -> str:
    """'pkg/Name' or 'pkg/srv/Name' -> 'pkg/srv/Name' (as the graph lists services)."""
    parts = type_name.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'srv', parts[1]]
    if len(parts) != 3 or parts[1] != 'srv' or not all(parts):
        raise ValueError(f'not a service type name: {type_name!r} (like pkg/srv/Name)')
    return '/'.join(parts)


def import_service(type_name: str):
    """The service class of 'pkg/srv/Name' (or 'pkg/Name'); ValueError if not one."""
    srv = import_type(service_type_name(type_name))
    if not hasattr(srv, 'Request'):
        raise ValueError(f'{type_name} is not a service type')
    return srv


def to_dict(msg: Any) -> Any:
    """A ROS message (or field value) as plain Python data, in field order."""
    if hasattr(msg, 'get_fields_and_field_types'):
        return {f: to_dict(getattr(msg, f)) for f in msg.get_fields_and_field_types()}
    if isinstance(msg, (list, tuple, array.array, np.ndarray)):
        return [to_dict(v) for v in msg]
    if isinstance(msg, (bytes, bytearray)):
        return list(msg)
    if isinstance(msg, np.generic):
        return msg.item()
    return msg
