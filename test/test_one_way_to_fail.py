"""One way to fail (issue 39 item 1): a check of data answers ``Failure | None`` (or raises
core.errors.Refusal deep inside), never '' or a reason string. An ast scan of the product
flags every function that can return '' (a literal, either branch of ``x if c else ''``, the
last operand of an ``or``), returns ``str | None`` under a name that says problem / reason /
why, or is a ``*_problem`` typed ``-> str``; the functions whose text is text by nature are
listed below, each with why. The scan is shown to catch each shape."""
from __future__ import annotations

import ast
import functools
from pathlib import Path
import re

import pytest

PRODUCT = Path(__file__).resolve().parents[1] / 'cobot_calib_ros'
REASON_NAME = re.compile(r'problem|reason|why')

# 'module path:function' -> why its '' or text is not a data problem's answer
TEXT_BY_NATURE = {
    # names, labels, keys and identifiers
    'bags/interfaces.py:installed_type_hash': 'a type hash (\'\': not installed)',
    'bags/interfaces.py:type_hash': 'a type hash',
    'bags/metadata.py:qos_text': 'the QoS profile text of a bag\'s metadata',
    'cli/call.py:_service_node': 'a node name',
    'cli/up.py:_robot_of': 'a robot model name (\'\': the file did not read; checked before)',
    'core/rig.py:tool_label': 'a label in reports',
    'ros/calls.py:action_server_node': 'a node name',
    'store/calibrations.py:scope_of': 'a record\'s scope key (\'\': the one scope)',
    'store/database.py:current_revision': 'a migration revision',
    'store/repository.py:database_url': 'a database url',
    # notes and printed lines: a result is still good with them
    'api/trial.py:_where': 'a fragment of a printed line',
    'cli/experiment.py:_retries_line': 'a printed line',
    'cli/history.py:_active_mark': 'a printed mark',
    'core/landmarks/intrinsics.py:message': 'feedback: the views still missing',
    'core/provenance.py:missing_prerequisites': 'a note on a good result measured through '
                                                'nominal prerequisites, not a refusal',
    'core/user_frame/robust.py:notes': 'notes on a fit',
    'loaders/sources.py:partial_note': 'a note on partial data',
    'store/kinematics.py:unseen_tool_note': 'a note on a good result',
    # stored data and the store's warnings (text kept in records and warnings lists)
    'store/calibrations.py:stored_gate_problem': 'a record\'s gate_problem field (data)',
    'store/folders.py:meta_problem': 'the store\'s warning for an unreadable folder',
    # a report of another program or process, not a check of data
    'api/replay_harness.py:failed': 'the log tails of nodes that exited, for an error text',
    'api/replay_trial_check.py:mark_difference': 'a replay check\'s report of what differs '
                                                 'from the recording (its CheckError text)',
    'api/trial.py:_late': 'a link state (no feedback, deadline passed): a CallError\'s text',
    'cli/call.py:refusal': 'the line `call` prints of another interface\'s answer',
    'ros/calls.py:ended': 'a link state (node exited, goal lost): a CallError\'s text',
    'ros/robot_calls.py:missing': 'servers not in the graph: a CallError\'s text',
    # left as they are on purpose
    'core/kinematics/planning.py:too_few_poses': 'the planner is being changed on another '
                                                 'branch this wave (issue 39 brief)',
    'core/kinematics/planning.py:stop_reason': 'the planner (as above); a stop is not a failure',
}


def _may_be_empty(value: ast.AST) -> bool:
    if isinstance(value, ast.Constant):
        return value.value == ''
    if isinstance(value, ast.IfExp):
        return _may_be_empty(value.body) or _may_be_empty(value.orelse)
    if isinstance(value, ast.BoolOp) and isinstance(value.op, ast.Or):
        return _may_be_empty(value.values[-1])
    return False


def _own_returns(function: ast.AST) -> list[ast.Return]:
    """The function's returns, not those of functions and lambdas inside it."""
    inner = {id(n) for child in ast.walk(function) if child is not function and
             isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
             for n in ast.walk(child)}
    return [n for n in ast.walk(function)
            if isinstance(n, ast.Return) and n.value is not None and id(n) not in inner]


def reason_strings(source: str) -> list[str]:
    """The functions of a module that answer a check with '' or a reason string."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        returns = ast.unparse(node.returns) if node.returns is not None else ''
        optional_text = re.fullmatch(r'str \| None|None \| str|Optional\[str\]', returns)
        if any(_may_be_empty(r.value) for r in _own_returns(node)) or \
                (REASON_NAME.search(node.name) and optional_text) or \
                (node.name.endswith('problem') and returns == 'str'):
            found.append(node.name)
    return found


@functools.cache
def _product_functions() -> tuple[str, ...]:
    return tuple(sorted(f'{path.relative_to(PRODUCT).as_posix()}:{name}'
                  for path in PRODUCT.rglob('*.py')
                  for name in reason_strings(path.read_text())))


def test_no_check_in_the_product_answers_with_a_reason_string() -> None:
    flagged = [f for f in _product_functions() if f not in TEXT_BY_NATURE]
    assert flagged == [], (
        'these return \'\' or a reason string: return Failure | None with an ErrorCode (or '
        'raise core.errors.Refusal deep inside); if the text is text by nature, list it in '
        'TEXT_BY_NATURE with why')


def test_the_allow_list_names_only_functions_that_exist_and_are_flagged() -> None:
    assert sorted(set(TEXT_BY_NATURE) - set(_product_functions())) == []


@pytest.mark.parametrize('source, expected', [
    ("def p(x) -> str:\n    if x:\n        return 'bad'\n    return ''\n", ['p']),
    ("def p(x):\n    return '' if x else 'bad'\n", ['p']),
    ("def p(x):\n    return (x and 'bad') or ''\n", ['p']),
    ("def why_not(x) -> str | None:\n    return None if x else 'bad'\n", ['why_not']),
    ("def size_problem(x) -> str:\n    return other(x)\n", ['size_problem']),
    ("class C:\n    def problem(self) -> str:\n        return ''\n", ['problem']),
    # what passes: Failure | None, text that is never empty, an inner function's ''
    ("def p(x) -> Failure | None:\n    return None if x else Failure(E.INVALID_INPUT, 'bad')\n",
     []),
    ("def line(x) -> str:\n    return f'{x} m'\n", []),
    ("def outer(xs):\n    def inner(x):\n        return ''\n    return [inner(x) for x in xs]\n",
     ['inner']),
])
def test_the_scan_catches_every_shape_of_a_reason_string(source: str, expected: list) -> None:
    assert reason_strings(source) == expected
