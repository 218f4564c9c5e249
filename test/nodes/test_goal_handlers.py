"""Issue 39 must-show 1, its second half, for the nodes whose procedures moved into core and api
(issue 39.2: TCP, hand-eye, intrinsics): a goal handler (``_run``, what the action server's
execute callback runs under JobNode._exclusive) is parameters in, one api call, the message out
through JobNode._end: at most MAX_LINES lines, nested callbacks included. An ast scan of the
node modules, and the scan shown to catch a longer one."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

NODES = Path(__file__).resolve().parents[2] / 'cobot_calib_ros' / 'nodes'
THIN = ('tcp_calibrator', 'hand_eye_calibrator', 'camera_calibrator')
MAX_LINES = 30


def handler_lengths(source: str) -> dict[str, int]:
    """'Class._run' -> its lines (docstring and nested functions included)."""
    return {f'{cls.name}.{f.name}': f.end_lineno - f.lineno + 1
            for cls in ast.walk(ast.parse(source)) if isinstance(cls, ast.ClassDef)
            for f in cls.body if isinstance(f, ast.FunctionDef) and f.name == '_run'}


@pytest.mark.parametrize('name', THIN)
def test_the_goal_handler_is_at_most_30_lines(name: str) -> None:
    lengths = handler_lengths((NODES / f'{name}.py').read_text())
    assert lengths, f'{name} has no goal handler _run'
    assert all(n <= MAX_LINES for n in lengths.values()), (
        f'{name}: {lengths}: a goal handler reads the goal and parameters, makes one api call '
        'and fills the result; move the procedure into core and its storing into api/<kind>.py')


def test_the_scan_catches_a_long_handler() -> None:
    body = '\n'.join(f'        x{i} = {i}' for i in range(MAX_LINES))
    source = f'class Node:\n    def _run(self, goal_handle):\n{body}\n'
    assert handler_lengths(source) == {'Node._run': MAX_LINES + 1}
