"""One home for each cross-cutting fact, kept there (issue 16, design item 4).

Each fact below has one module that owns it; a copy anywhere else in the package, bags/ or
bench/ fails here with where it is:
- stamp <-> nanoseconds (``NS_PER_S``, ``sec * 1e9``, ``divmod(.., 10**9)``): ros/time.py;
- the mark topic names (``cobot_calib/captures``, ``cobot_calib/probe_averages``) and their
  encodings: ros/marks.py;
- the default cell name (``sawyer_close``): paths.py (DEFAULT_CELL);
- the node list: nodes/__init__.py (NODES), read by setup.py and api/launcher.py;
- the move timeout: ros/robot_calls.py (MOVE_TIMEOUT);
- the robot list and the robot -> model resolver: core/kinematics/robots.py.
"""
import ast
from pathlib import Path
import re

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / 'cobot_calib_ros'
SOURCES = sorted([*PACKAGE.rglob('*.py'), *(ROOT / 'bags').glob('*.py'),
                  *(ROOT / 'bench').glob('*.py'), ROOT / 'setup.py'])

# A stamp or duration converted by hand: seconds times a billion, or a divmod by it.
STAMP = re.compile(r'1_000_000_000|10 ?\*\* ?9|\* ?1e9\b|/ ?1e9\b|\b1e9 ?\*')
STAMP_HOME = PACKAGE / 'ros' / 'time.py'
STAMP_EXCEPTIONS = {
    # core may not import ros/ (test_layering): the wall-clock record id formats its own
    # nanoseconds, and is the only core code that meets a nanosecond stamp.
    PACKAGE / 'core' / 'ids.py',
}
STRING_HOMES = {
    'cobot_calib/captures': PACKAGE / 'ros' / 'marks.py',
    '/cobot_calib/captures': PACKAGE / 'ros' / 'marks.py',
    'cobot_calib/probe_averages': PACKAGE / 'ros' / 'marks.py',
    '/cobot_calib/probe_averages': PACKAGE / 'ros' / 'marks.py',
    'cobot_calib/markers': PACKAGE / 'ros' / 'markers.py',
    'sawyer_close': PACKAGE / 'paths.py',
}


def _code_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, text) of the lines that are code, not comments or docstrings."""
    tree = ast.parse(path.read_text(), str(path))
    prose = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = getattr(node, 'body', [])
            if body and isinstance(body[0], ast.Expr) and isinstance(
                    getattr(body[0], 'value', None), ast.Constant) and isinstance(
                    body[0].value.value, str):
                prose.update(range(body[0].lineno, body[0].end_lineno + 1))
    return [(n, line.split('#')[0]) for n, line in enumerate(path.read_text().splitlines(), 1)
            if n not in prose]


def _strings(path: Path) -> list[tuple[int, str]]:
    """(line, value) of every string constant in the module (docstrings included: they are
    whole paragraphs, never equal to a topic or cell name)."""
    tree = ast.parse(path.read_text(), str(path))
    return [(node.lineno, node.value) for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str)]


def where(path: Path, line: int) -> str:
    return f'{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:{line}'


def stamp_conversions(paths) -> list[str]:
    return [where(p, n) for p in paths if p != STAMP_HOME and p not in STAMP_EXCEPTIONS
            for n, code in _code_lines(p) if STAMP.search(code)]


def string_copies(paths) -> list[str]:
    return [f'{where(p, n)} {value!r}' for p in paths for n, value in _strings(p)
            if value in STRING_HOMES and STRING_HOMES[value] != p]


def test_stamps_are_converted_in_ros_time_only():
    assert stamp_conversions(SOURCES) == []


def test_topic_names_and_the_default_cell_have_one_home():
    assert string_copies(SOURCES) == []


def test_the_guards_see_a_copy(tmp_path):
    """Not vacuous: an inline conversion and a literal topic are caught, prose is not."""
    bad = tmp_path / 'bad.py'
    bad.write_text('"""Stamps: sec * 1e9 in prose is fine."""\n'
                   "TOPIC = 'cobot_calib/captures'\n"
                   'def f(s):\n    return s.sec * 1_000_000_000 + s.nanosec  # 1e9\n')
    assert stamp_conversions([bad]) == [f'{bad}:4']
    assert string_copies([bad]) == [f"{bad}:2 'cobot_calib/captures'"]


def test_one_node_registry_for_setup_and_the_launcher():
    from cobot_calib_ros.api import launcher
    from cobot_calib_ros.nodes import DRIVER_NODES, NODES
    modules = {p.stem for p in (PACKAGE / 'nodes').glob('*.py')
               if p.stem not in ('__init__', 'job_node')}     # job_node: the nodes' base
    assert set(NODES) == modules
    assert launcher.SUITE + DRIVER_NODES == NODES
    setup = (ROOT / 'setup.py').read_text()
    assert 'NODES = node_registry()' in setup and "'mock_robot'" not in setup


@pytest.mark.parametrize('name', ['MOVE_TIMEOUT', 'NS_PER_S', 'ROBOTS'])
def test_constants_are_defined_once(name):
    pattern = re.compile(rf'^\s*{name}\s*=', re.M)
    homes = [where(p, 1) for p in SOURCES if pattern.search(p.read_text())]
    assert len(homes) == 1, homes
