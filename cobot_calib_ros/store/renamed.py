"""Records stored before issue 39.3 (one name per transform) read with today's names."""
from __future__ import annotations

from typing import Any, Mapping

RENAMED_RESULT_KEYS = {'T_flange_tcp': 'T_flange_tool',   # legacy name: a TCP record's
                       'tool_xyz': 'p_flange_tool'}       # legacy name: a kinematics record's


def with_current_names(record: Mapping[str, Any]) -> Mapping[str, Any]:
    """``record`` itself, or a copy whose result has its old keys renamed (a new key already
    there wins)."""
    result = record.get('result')
    if not isinstance(result, Mapping) or not RENAMED_RESULT_KEYS.keys() & result.keys():
        return record
    result = dict(result)
    for old, new in RENAMED_RESULT_KEYS.items():
        if old in result:
            result.setdefault(new, result.pop(old))
    return {**record, 'result': result}
