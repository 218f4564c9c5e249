"""Thin nodes (issue 39 item 2, must-show 1): a JobNode's goal handler, the ``run`` it gives
JobNode._exclusive, is parameters in, one api / core call, the result out: at most 30 lines
(docstring included). An ast scan, and the scan shown to catch a long handler."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

NODES = Path(__file__).resolve().parents[2] / 'cobot_calib_ros' / 'nodes'
MAX_LINES = 30
# the nodes whose procedures have moved into core / api (issue 39.2); every JobNode once the
# others have
THIN = ('camera_calibrator', 'hand_eye_calibrator', 'kinematic_identifier', 'tcp_calibrator')


def long_handlers(source: str, limit: int = MAX_LINES) -> list[str]:
    """'name: lines' for each method given as the run of ``self._exclusive(goal, run, ...)``
    that is longer than ``limit`` lines."""
    tree = ast.parse(source)
    runs = {call.args[1].attr for call in ast.walk(tree)
            if isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute)
            and call.func.attr == '_exclusive' and len(call.args) > 1
            and isinstance(call.args[1], ast.Attribute)}
    return [f'{f.name}: {f.end_lineno - f.lineno + 1}' for f in ast.walk(tree)
            if isinstance(f, ast.FunctionDef) and f.name in runs
            and f.end_lineno - f.lineno + 1 > limit]


@pytest.mark.parametrize('node', THIN)
def test_each_goal_handler_is_at_most_30_lines(node: str) -> None:
    source = (NODES / f'{node}.py').read_text()
    assert 'self._exclusive(' in source
    assert long_handlers(source) == [], f'{node}: move the procedure into core / api'


def test_the_scan_finds_a_long_handler() -> None:
    body = '\n'.join(f'        x{i} = {i}' for i in range(30))
    source = ('class N:\n    def _on(self, goal_handle):\n'
              '        return self._exclusive(goal_handle, self._run, R)\n\n'
              f'    def _run(self, goal_handle):\n{body}\n')
    assert long_handlers(source) == ['_run: 31']
    assert long_handlers(source, limit=31) == []
