"""The architecture, enforced: a pure core, the simulation apart from the calibration path.

Static (every import statement of every module, including imports inside functions) and
dynamic (what importing a module really pulls in, in a fresh interpreter).
"""
import ast
import json
from pathlib import Path
import subprocess
import sys

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / 'cobot_calib_ros'
SIMULATION = 'cobot_calib_ros.sim'
# The only modules that may use the simulation: itself, the nodes that stand in for a robot
# and its wrist camera, and `cobot-calib up`, which starts them and checks the scenario first.
MAY_USE_SIMULATION = ('cobot_calib_ros.sim', 'cobot_calib_ros.nodes.mock_robot',
                      'cobot_calib_ros.nodes.mock_camera', 'cobot_calib_ros.cli.up')


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def _type_checking_only(tree: ast.AST) -> set[int]:
    """ids of the nodes under ``if TYPE_CHECKING:``: annotations, never run."""
    skipped = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, 'id', '') == 'TYPE_CHECKING':
            skipped.update(id(n) for child in node.body for n in ast.walk(child))
    return skipped


def imported_names(path: Path) -> set[str]:
    names = set()
    tree = ast.parse(path.read_text(), str(path))
    skipped = _type_checking_only(tree)
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f'{node.module}.{alias.name}' for alias in node.names)
    return names


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob('*.py'))}
CALIBRATION_PATH = sorted(m for m in MODULES if not m.startswith(MAY_USE_SIMULATION))


def _uses(imports: set[str], prefix: str) -> list[str]:
    return sorted(n for n in imports if n == prefix or n.startswith(prefix + '.'))


@pytest.mark.parametrize('module', CALIBRATION_PATH)
def test_no_calibration_path_module_imports_the_simulation(module):
    assert _uses(imported_names(MODULES[module]), SIMULATION) == []


CORE = sorted(m for m in MODULES if m.startswith('cobot_calib_ros.core'))
OUTER_LAYERS = tuple(f'cobot_calib_ros.{layer}' for layer in
                     ('sim', 'store', 'ros', 'nodes', 'api', 'cli'))


@pytest.mark.parametrize('module', CORE)
def test_core_imports_no_ros_no_io_layers_no_simulation(module):
    imports = imported_names(MODULES[module])
    top = {n.split('.')[0] for n in imports}
    assert sorted(t for t in top if t == 'rclpy' or t.endswith('_msgs')) == []
    assert sorted(n for n in imports if n.startswith(OUTER_LAYERS)) == []


def test_pinocchio_is_imported_by_the_ik_module_only():
    users = [m for m, p in MODULES.items() if _uses(imported_names(p), 'pinocchio')]
    assert users == ['cobot_calib_ros.core.kinematics.ik']


def test_the_calibration_nodes_do_not_load_the_simulation_when_imported():
    """Transitively, in a fresh interpreter: what a real-robot deployment would run."""
    nodes = [m for m in CALIBRATION_PATH if m.startswith('cobot_calib_ros.nodes.')]
    assert 'cobot_calib_ros.nodes.user_frame_solver' in nodes
    code = ('import importlib, json, sys\n'
            f'for m in {nodes!r}: importlib.import_module(m)\n'
            'print(json.dumps(sorted(m for m in sys.modules if m.startswith("cobot_calib_ros"))))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True)
    loaded = json.loads(out.stdout)
    assert 'cobot_calib_ros.nodes.repeatability_trial' in loaded
    assert [m for m in loaded if m.startswith(SIMULATION)] == []


def test_the_checks_catch_a_simulation_import(tmp_path):
    """The static check is not vacuous: it sees an import inside a function."""
    bad = tmp_path / 'bad.py'
    bad.write_text('def f():\n    from cobot_calib_ros.sim.robot import SimRobot\n')
    assert _uses(imported_names(bad), SIMULATION) == ['cobot_calib_ros.sim.robot',
                                                      'cobot_calib_ros.sim.robot.SimRobot']
