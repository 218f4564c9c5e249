"""Lay out the venv like a ROS install prefix (what colcon --symlink-install would do).

setup.cfg sends the console scripts to <prefix>/lib/<package>/, where `ros2 run` looks, but
pip's editable install skips data_files: this registers the package in the ament index,
symlinks share/<package> to the checkout's package.xml and config/, and links the
cobot-calib CLI into <venv>/bin.
Usage: python tools/install_ros_prefix.py VENV_DIR
"""
from pathlib import Path
import sys

PACKAGE = 'cobot_calib_ros'
REPO = Path(__file__).resolve().parent.parent


def link_cli(venv: Path) -> None:
    """Put the CLI on the venv's PATH (setup.cfg sends every script to lib/<package>)."""
    cli = venv / 'lib' / PACKAGE / 'cobot-calib'
    if not cli.exists():
        raise SystemExit(f'{cli} missing: did `pip install -e .` run with setup.cfg?')
    link(cli, venv / 'bin' / 'cobot-calib')


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
    install_share(venv)
    link_cli(venv)
    nodes = sorted(p.name for p in (venv / 'lib' / PACKAGE).iterdir() if p.name != 'cobot-calib')
    print(f'ros2 run executables in lib/{PACKAGE}: {", ".join(nodes)}; share/{PACKAGE} linked')


if __name__ == '__main__':
    main()
