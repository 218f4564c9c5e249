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


# -- a node's goal and service handlers: parameters in, one call, message out (issue 39.2) ---

MAX_HANDLER_LINES = 30


def _self_method(node: ast.AST) -> str | None:
    """``self._x`` -> '_x'; a lambda or partial calling ``self._x(...)`` -> '_x'."""
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and \
            node.value.id == 'self':
        return node.attr
    if isinstance(node, ast.Lambda) and isinstance(node.body, ast.Call):
        return _self_method(node.body.func)
    if isinstance(node, ast.Call) and ast.unparse(node.func).endswith('partial') and node.args:
        return _self_method(node.args[0])
    return None


def _registered(call: ast.Call) -> ast.AST | None:
    """The callback an ActionServer(...) (execute_callback) or a create_service(...) call
    registers, else None."""
    name = call.func.attr if isinstance(call.func, ast.Attribute) else \
        call.func.id if isinstance(call.func, ast.Name) else ''
    position = {'ActionServer': (3, 'execute_callback'), 'create_service': (2, 'callback')}
    if name not in position:
        return None
    index, keyword = position[name]
    given = [k.value for k in call.keywords if k.arg == keyword]
    return given[0] if given else call.args[index] if len(call.args) > index else None


def _lines(function: ast.FunctionDef) -> int:
    """A function's lines, def to end, without its docstring."""
    body = function.body
    docstring = body and isinstance(body[0], ast.Expr) and \
        isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str)
    skipped = body[0].end_lineno - body[0].lineno + 1 if docstring else 0
    return function.end_lineno - function.lineno + 1 - skipped


def handler_sizes(source: str) -> dict[str, int]:
    """{method: lines} of every goal and service handler a module registers, and of the run a
    handler hands to JobNode._exclusive (the goal's real handler)."""
    tree = ast.parse(source)
    methods = {f.name: f for f in ast.walk(tree) if isinstance(f, ast.FunctionDef)}
    handlers = {_self_method(callback) for call in ast.walk(tree)
                if isinstance(call, ast.Call) and (callback := _registered(call)) is not None}
    handlers.discard(None)
    runs = {_self_method(arg) for name in handlers if name in methods
            for call in ast.walk(methods[name]) if isinstance(call, ast.Call)
            and _self_method(call.func) == '_exclusive' for arg in call.args}
    return {name: _lines(methods[name]) for name in sorted((handlers | runs) - {None})
            if name in methods}


@pytest.mark.parametrize('path', sorted(NODES.glob('*.py')), ids=lambda p: p.name)
def test_every_handler_of_a_node_is_at_most_30_lines(path: Path) -> None:
    over = {name for name, lines in handler_sizes(path.read_text()).items()
            if lines > MAX_HANDLER_LINES}
    assert not over, (
        f'{path.name}: handlers over {MAX_HANDLER_LINES} lines: '
        f'{ {n: handler_sizes(path.read_text())[n] for n in over} }; a handler reads the goal '
        'and parameters, makes one api/core call and fills the result (ros/results)')


def test_the_handler_scan_finds_every_way_a_handler_is_registered() -> None:
    body = '\n'.join(f'        x = {i}' for i in range(31))
    source = (
        'class N:\n'
        '    def __init__(self):\n'
        '        ActionServer(self, A, "a", execute_callback=self._goal)\n'
        '        ActionServer(self, A, "b", lambda h: self._follow(h, 1))\n'
        '        self._c.node.create_service(S, "s", self._on_s)\n'
        '        self.create_service(S, "t", callback=functools.partial(self._on_t, 1))\n'
        '        self.create_timer(1.0, self._tick)\n'
        '    def _goal(self, h):\n'
        '        return self._exclusive(h, self._run, A.Result)\n'
        f'    def _run(self, h):\n        """doc\n        string"""\n{body}\n'
        f'    def _follow(self, h, c):\n{body}\n'
        '    def _on_s(self, q, r):\n        return r\n'
        '    def _on_t(self, q, r):\n        return r\n'
        f'    def _tick(self):\n{body}\n')
    assert handler_sizes(source) == {'_follow': 32, '_goal': 2, '_on_s': 2, '_on_t': 2,
                                     '_run': 32}
