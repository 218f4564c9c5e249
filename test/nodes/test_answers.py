"""One way to fail (issue 39 item 1, must-show 1): no node sets an interface's result constant
itself; it answers with a cause (core.errors.ErrorCode) through ros/results, the one place that
knows each interface's numbers. An ast scan of cobot_calib_ros/nodes, and the scan shown to
catch each way a constant could come back."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

NODES = Path(__file__).resolve().parents[2] / 'cobot_calib_ros' / 'nodes'
RESULT_PARTS = ('Result', 'Response')


def _foreign(tree: ast.Module) -> set[str]:
    """Names imported from other interface packages (control_msgs' FollowJointTrajectory: a
    driver's controller, whose numbers mock_robot imitates and robot_adapter reads; they are
    the controller's, not the suite's)."""
    return {alias.asname or alias.name for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module
            and node.module.split('.')[0].endswith('_msgs')
            and not node.module.startswith('cobot_calib_msgs') for alias in node.names}


def _is_results_class(node: ast.AST, foreign: set[str], aliases: set[str]) -> bool:
    """``X.Result`` / ``X.Response`` of an interface X of the suite (any name but a foreign
    one: ``from ... import CalibrateTcp as Action``, ``Collect, Identify = ...`` included), or
    a name bound to one."""
    if isinstance(node, ast.Name):          # a parameter named Result (JobNode._exclusive's)
        return node.id in aliases or node.id in RESULT_PARTS
    return (isinstance(node, ast.Attribute) and node.attr in RESULT_PARTS
            and not (isinstance(node.value, ast.Name) and node.value.id in foreign))


def _bindings(node: ast.Assign):
    """(target, value) pairs of an assignment, tuples unpacked."""
    for target in node.targets:
        if isinstance(target, ast.Tuple) and isinstance(node.value, ast.Tuple):
            yield from zip(target.elts, node.value.elts)
        else:
            yield target, node.value


def raw_answers(source: str) -> list[str]:
    """'line: what' for every result constant a module's code names, and every number it
    writes into an ``error_code`` itself."""
    tree = ast.parse(source)
    foreign = _foreign(tree)
    aliases = {t.id for node in ast.walk(tree) if isinstance(node, ast.Assign)
               for t, value in _bindings(node)
               if isinstance(t, ast.Name) and _is_results_class(value, foreign, set())}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr.isupper() and \
                _is_results_class(node.value, foreign, aliases):
            found.append(f'{node.lineno}: {ast.unparse(node)}')
        numbers = []
        if isinstance(node, ast.keyword) and node.arg == 'error_code':
            numbers = [node.value]
        elif isinstance(node, ast.Assign):
            numbers = [value for t, value in _bindings(node)
                       if isinstance(t, ast.Attribute) and t.attr == 'error_code']
        found += [f'{v.lineno}: error_code = {ast.unparse(v)}' for v in numbers
                  if isinstance(v, ast.Constant) and isinstance(v.value, int)]
    return sorted(found, key=lambda s: int(s.split(':')[0]))


@pytest.mark.parametrize('path', sorted(NODES.glob('*.py')), ids=lambda p: p.name)
def test_no_node_sets_an_interface_constant_itself(path: Path) -> None:
    assert raw_answers(path.read_text()) == [], (
        f'{path.name} answers with interface constants; give the cause (core.errors.ErrorCode) '
        'to ros.results.answer / fill / code, or to JobNode._end')


@pytest.mark.parametrize('source, expected', [
    ('from cobot_calib_msgs.action import CalibrateTcp as Action\n'
     'r.error_code = Action.Result.REJECTED\n', ['2: Action.Result.REJECTED']),
    ('from cobot_calib_msgs.srv import SetActiveCalibration\n'
     'Choice = SetActiveCalibration\n'
     'Out = Choice.Response\n'
     'x = Out.NO_CALIBRATION\n', ['4: Out.NO_CALIBRATION']),
    ('from cobot_calib_msgs.action import MoveTo\n'
     'self._end(g, r, MoveTo.Result.CANCELED, "m")\n', ['2: MoveTo.Result.CANCELED']),
    ('from cobot_calib_msgs.action import CollectSphereData, IdentifyKinematics\n'
     'Collect, Identify = CollectSphereData, IdentifyKinematics\n'
     'code = {1: Collect.Result.CANCELED}\n', ['3: Collect.Result.CANCELED']),
    ('R = Foo.Result\nresponse.error_code, response.message = 3, "bad"\n'
     'Result(error_code=0)\nx = R.BUSY\ny = Result.INVALID_GOAL\n',
     ['2: error_code = 3', '3: error_code = 0', '4: R.BUSY', '5: Result.INVALID_GOAL']),
    # what is allowed: causes, request constants, other packages' and the results calls
    ('from cobot_calib_msgs.action import MoveTo\n'
     'from control_msgs.action import FollowJointTrajectory\n'
     'from cobot_calib_ros.core.errors import ErrorCode\n'
     'if goal.target_type == MoveTo.Goal.TARGET_POSE: pass\n'
     'results.answer(result, ErrorCode.CANCELED, "canceled")\n'
     'code != FollowJointTrajectory.Result.SUCCESSFUL\n'
     'r.error_code = results.code("MoveTo", ErrorCode.SUCCESS)\n', []),
])
def test_the_scan_catches_every_way_a_constant_comes_back(source: str, expected: list) -> None:
    assert raw_answers(source) == expected
