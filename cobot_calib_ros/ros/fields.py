"""Filling a message from YAML data, as `ros2 service call` / `ros2 topic pub` do."""
from __future__ import annotations

import importlib
import math
import re
from typing import Any


class FieldError(ValueError):
    """A request value that does not fit its field; str() names the field path."""


def set_fields(msg: Any, values: Any) -> Any:
    """Fill a message from YAML data as `ros2 service call` does, converting each value to its
    field's type first (int -> float, 'nan' / '1e9' -> float, nested messages, sequences)
    so nothing unfit reaches the C setters; raises FieldError naming the field path."""
    return _fill(msg, {} if values is None else values, '')


def _fill(msg: Any, values: Any, path: str) -> Any:
    if not isinstance(values, dict):
        raise FieldError(f'{path or "request"}: expected a mapping of {_type_label(msg)} '
                         f'fields like {{{next(iter(_slots(msg)), "field")}: ...}}, '
                         f'got {_shown(values)}')
    slots = _slots(msg)
    for key, value in values.items():
        where = f'{path}.{key}' if path else str(key)
        if key not in slots:
            raise FieldError(f'{where}: no such field; {_type_label(msg)} has: '
                             f'{", ".join(slots) or "no fields"}')
        setattr(msg, key, _convert(slots[key], value, where))
    return msg


def _slots(msg: Any) -> dict:
    """Field name -> rosidl_parser.definition type, in field order."""
    return dict(zip(msg.get_fields_and_field_types(), msg.SLOT_TYPES))


def _type_label(msg: Any) -> str:
    return type(msg).__name__.replace('_Request', ' request').replace('_Response', ' response')


def _convert(slot, value: Any, path: str) -> Any:
    from rosidl_parser import definition as d
    if isinstance(slot, d.NamespacedType):
        return _fill(_message_class(slot)(), value, path)
    if isinstance(slot, d.AbstractNestedType):
        return _sequence(slot, value, path)
    if isinstance(slot, d.AbstractGenericString):
        return _string(slot, value, path)
    if isinstance(slot, d.BasicType):
        return _basic(slot.typename, value, path)
    raise FieldError(f'{path}: unsupported field type {type(slot).__name__}')


def _message_class(slot):
    module = importlib.import_module('.'.join(slot.namespaces))
    return getattr(module, slot.name)


def _sequence(slot, value: Any, path: str) -> list:
    from rosidl_parser import definition as d
    if isinstance(value, (bytes, bytearray)) and getattr(slot.value_type, 'typename', '') in (
            'octet', 'uint8'):
        value = list(value)
    if not isinstance(value, (list, tuple)):
        raise FieldError(f'{path}: expected a list like [1, 2], got {_shown(value)}')
    if isinstance(slot, d.Array) and len(value) != slot.size:
        raise FieldError(f'{path}: expected exactly {slot.size} values, got {len(value)}')
    if isinstance(slot, d.BoundedSequence) and len(value) > slot.maximum_size:
        raise FieldError(f'{path}: expected at most {slot.maximum_size} values, '
                         f'got {len(value)}')
    return [_convert(slot.value_type, v, f'{path}[{i}]') for i, v in enumerate(value)]


def _string(slot, value: Any, path: str) -> str:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = str(value)                  # as ros2 does: `id: 20261121` is the string
    if not isinstance(value, str):
        raise FieldError(f'{path}: expected a string, got {_shown(value)}')
    limit = getattr(slot, 'maximum_size', None)
    if limit is not None and len(value) > limit:
        raise FieldError(f'{path}: expected at most {limit} characters, got {len(value)}')
    return value


_INT_BITS = {'int8': (8, True), 'int16': (16, True), 'int32': (32, True), 'int64': (64, True),
             'uint8': (8, False), 'uint16': (16, False), 'uint32': (32, False),
             'uint64': (64, False), 'short': (16, True), 'long': (32, True),
             'long long': (64, True), 'unsigned short': (16, False),
             'unsigned long': (32, False), 'unsigned long long': (64, False)}
_FLOAT32_MAX = 3.4028234663852886e38
_TRUE, _FALSE = ('true', 'yes', 'on'), ('false', 'no', 'off')


def _basic(typename: str, value: Any, path: str) -> Any:
    if typename in ('float', 'double', 'long double'):
        return _float(typename, value, path)
    if typename in _INT_BITS:
        return _int(typename, value, path)
    if typename == 'boolean':
        return _bool(value, path)
    if typename == 'octet':
        return bytes([_int('uint8', value, path)])
    if typename in ('char', 'wchar'):
        if isinstance(value, str) and len(value) == 1:
            return value
        raise FieldError(f'{path}: expected one character, got {_shown(value)}')
    raise FieldError(f'{path}: unsupported field type {typename}')


def _float(typename: str, value: Any, path: str) -> float:
    number = _parse_float(value)
    if number is None:
        raise FieldError(f'{path}: expected a float, got {_shown(value)}')
    if typename == 'float' and math.isfinite(number) and abs(number) > _FLOAT32_MAX:
        raise FieldError(f'{path}: expected a float32 within +-3.4e38, got {_shown(value)}')
    return number


def _parse_float(value: Any) -> float | None:
    """int, float, or a YAML string PyYAML leaves alone: 'nan', '.inf', '1e9'."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        try:
            return float(value)
        except OverflowError:
            return None
    if not isinstance(value, str):
        return None
    text = re.sub(r'^([+-]?)\.(nan|inf)$', r'\1\2', value.strip().lower())   # YAML .nan
    try:
        return float(text)
    except ValueError:
        return None


def _int(typename: str, value: Any, path: str) -> int:
    bits, signed = _INT_BITS[typename]
    low, high = (-2 ** (bits - 1), 2 ** (bits - 1) - 1) if signed else (0, 2 ** bits - 1)
    number = _parse_int(value)
    if number is None:
        raise FieldError(f'{path}: expected an integer, got {_shown(value)}')
    if not low <= number <= high:
        raise FieldError(f'{path}: expected a {typename} in [{low}, {high}], got {number}')
    return number


def _parse_int(value: Any) -> int | None:
    """int, a whole float (2.0, 1e3) or such a string."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value
    if isinstance(value, str) and re.fullmatch(r'\s*[+-]?\d+\s*', value):
        return int(value)                               # exact, even beyond 2**53
    number = _parse_float(value)
    if number is None or not math.isfinite(number) or not number.is_integer():
        return None
    return int(number)


def _bool(value: Any, path: str) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.strip().lower() in _TRUE + _FALSE:
        return value.strip().lower() in _TRUE
    raise FieldError(f'{path}: expected true or false, got {_shown(value)}')


def _shown(value: Any) -> str:
    """A value as the user typed it (YAML-ish), short."""
    text = 'null' if value is None else repr(value)
    return text if len(text) <= 40 else text[:37] + '...'
