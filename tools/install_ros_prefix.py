"""Lay out the venv like a ROS install prefix (what colcon --symlink-install would do).

pip's editable install puts console scripts in <venv>/bin and skips data_files. `ros2 run`
looks for executables in <prefix>/lib/<package>/ and ament_index finds the package through
share/ament_index. This writes a launcher per node there and symlinks share/<package> to the
checkout's package.xml and config/.
Usage: python tools/install_ros_prefix.py VENV_DIR
"""
from importlib.metadata import entry_points
from pathlib import Path
import sys

PACKAGE = 'cobot_calib_ros'
REPO = Path(__file__).resolve().parent.parent


def install_node_launchers(venv: Path) -> int:
    lib_dir = venv / 'lib' / PACKAGE
    lib_dir.mkdir(parents=True, exist_ok=True)
    nodes = [ep for ep in entry_points(group='console_scripts')
             if ep.value.startswith(f'{PACKAGE}.nodes.')]
    for ep in nodes:
        module, func = ep.value.split(':')
        script = lib_dir / ep.name
        script.write_text(f'#!{venv / "bin" / "python"}\nimport sys\n'
                          f'from {module} import {func}\nsys.exit({func}())\n')
        script.chmod(0o755)
    return len(nodes)


def link(target: Path, link_path: Path) -> None:
    if link_path.is_symlink() or link_path.exists():
        link_path.unlink()
    link_path.symlink_to(target)


def install_share(venv: Path) -> None:
    index = venv / 'share' / 'ament_index' / 'resource_index' / 'packages'
    index.mkdir(parents=True, exist_ok=True)
    (index / PACKAGE).touch()
    share = venv / 'share' / PACKAGE
    share.mkdir(parents=True, exist_ok=True)
    link(REPO / 'package.xml', share / 'package.xml')
    link(REPO / 'config', share / 'config')


def main() -> None:
    venv = Path(sys.argv[1]).resolve()
    count = install_node_launchers(venv)
    install_share(venv)
    print(f'{count} node executables in {venv / "lib" / PACKAGE}; share/{PACKAGE} linked')


if __name__ == '__main__':
    main()
