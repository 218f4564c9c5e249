"""The architecture, enforced: a pure core, the simulation apart from the calibration path,
a table of which package may import which, and no file access in core.

Static (every import statement of every module, including imports inside functions) and
dynamic (what importing a module really pulls in, in a fresh interpreter).
"""
import ast
import json
from pathlib import Path
import re
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


def imported_names(path: Path, type_checking: bool = False) -> set[str]:
    """Every module (and module.name) ``path`` imports, inside functions too; imports under
    ``if TYPE_CHECKING:`` only with ``type_checking``."""
    names = set()
    tree = ast.parse(path.read_text(), str(path))
    skipped = set() if type_checking else _type_checking_only(tree)
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


# Which package may import which (the top-level modules paths and loaders count as packages).
# core is pure; loaders read files for it; ros is the ROS plumbing over core; bags is rosbag2
# I/O on ros; nodes, api and cli sit on top, cli over api.
ALLOWED = {
    'core': set(),
    'paths': set(),
    'loaders': {'core'},
    'sim': {'core', 'loaders'},
    'store': {'core', 'paths'},
    'ros': {'core'},
    'bags': {'core', 'ros'},
    # sim: the mocks only (above); api: a kind's one store-and-activate path, which the node
    # and the CLI verb both call (issue 39.2)
    'nodes': {'api', 'core', 'loaders', 'paths', 'ros', 'store', 'sim'},
    'api': {'core', 'loaders', 'paths', 'ros', 'store', 'bags'},
    'cli': {'api', 'core', 'loaders', 'paths', 'ros', 'store', 'bags', 'sim'},
}
# Edges that bend the table, each with its reason; remove the line when the bend is gone.
EXCEPTIONS = {
    # type-only (TYPE_CHECKING) TrialData / TrialStore: a TrialSink port in core replaces it
    ('cobot_calib_ros.core.repeatability.trial', 'store'),
    # nodes.NODES, the registry of the node modules the launcher starts (setup.py reads it too)
    ('cobot_calib_ros.api.launcher', 'nodes'),
    # a bag of sphere captures as the identification's input (review 5252a67 section 4.1:
    # acceptable; the parsing sits next to the mark protocol, ros.marks)
    ('cobot_calib_ros.nodes.kinematic_identifier', 'bags'),
    # the one loader of identification sources (issue 28.5) recognises them by their look and
    # reads each where it is written: a collection folder by store.collections, a bag's
    # sphere captures by bags.sphere_captures
    ('cobot_calib_ros.loaders.sources', 'store'),
    ('cobot_calib_ros.loaders.sources', 'bags'),
}


def package_of(module: str) -> str:
    parts = module.split('.')
    return parts[1] if len(parts) > 1 else parts[0]


def layering_bends(modules: dict[str, Path]) -> list[str]:
    """'module -> package' for every import of the package that ALLOWED and EXCEPTIONS do not
    permit (type-only imports included)."""
    bends = set()
    for module, path in modules.items():
        own = package_of(module)
        for name in imported_names(path, type_checking=True):
            if not name.startswith('cobot_calib_ros.'):
                continue
            other = package_of(name)
            if other != own and other not in ALLOWED[own] and (module, other) not in EXCEPTIONS:
                bends.add(f'{module} -> {other}')
    return sorted(bends)


def test_every_package_is_in_the_table():
    assert {package_of(m) for m in MODULES} - {'cobot_calib_ros'} == set(ALLOWED)


def test_packages_import_only_what_the_table_allows():
    assert layering_bends(MODULES) == []


def test_every_exception_is_still_needed():
    """An exception whose bend is gone must leave the list."""
    used = {(m, package_of(n)) for m, p in MODULES.items()
            for n in imported_names(p, type_checking=True) if n.startswith('cobot_calib_ros.')}
    assert sorted(EXCEPTIONS - used) == []


def test_the_table_catches_a_bend(tmp_path):
    """bags -> api (the cycle of 5252a67) and core -> store under TYPE_CHECKING are caught."""
    bags = tmp_path / 'player.py'
    bags.write_text('def f():\n    from cobot_calib_ros.api.client import import_type\n')
    core = tmp_path / 'trial.py'
    core.write_text('from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n'
                    '    from cobot_calib_ros.store.trials import TrialStore\n')
    assert layering_bends({'cobot_calib_ros.bags.player': bags,
                           'cobot_calib_ros.core.fake': core}) == [
        'cobot_calib_ros.bags.player -> api', 'cobot_calib_ros.core.fake -> store']


# File access in core: the core parses text and arrays; loaders (and store) read the files.
FILE_IO = re.compile(r'\bopen\(|\.read_text\(|\.write_text\(|\.read_bytes\(|\.write_bytes\(|'
                     r'np\.loadtxt\(|np\.savetxt\(|np\.load\(|np\.save\(|\.iterdir\(|'
                     r'\.glob\(|\.exists\(\)|\.is_file\(\)|\.is_dir\(\)|imread\(|imwrite\(|'
                     r'FileStorage\((?![^)]*FILE_STORAGE_MEMORY)')


def file_access(path: Path) -> list[str]:
    """'line: code' of every file access in ``path`` (comments left out)."""
    return [f'{n}: {line.strip()}' for n, line in enumerate(path.read_text().splitlines(), 1)
            if FILE_IO.search(line.split('#')[0])]


@pytest.mark.parametrize('module', CORE)
def test_core_does_no_file_io(module):
    assert file_access(MODULES[module]) == []


def test_the_file_check_sees_a_read(tmp_path):
    bad = tmp_path / 'bad.py'
    bad.write_text("def f(p):\n    t = p.read_text()  # fine in a comment: open(\n"
                   "    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)\n"
                   "    ok = cv2.FileStorage(t, cv2.FILE_STORAGE_MEMORY)\n")
    assert file_access(bad) == ['2: t = p.read_text()  # fine in a comment: open(',
                                '3: fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)']


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
