"""tools/install_deps.sh (make setup's venv): pip's venv kept in a cache and restored as hard
links into the next venv, its own path put back in the new venv's scripts; a cached venv that
does not pass the check is dropped and pip runs. Real venvs and pip, with an empty lock (no
download) and a check of our own (COBOT_CALIB_VENV_CHECK) in place of the lock's imports."""
import os
from pathlib import Path
import subprocess
import sys

SCRIPT = Path(__file__).resolve().parents[2] / 'tools' / 'install_deps.sh'


def _install(venv: Path, lock: Path, cache: Path, check: str = 'import sys'
             ) -> subprocess.CompletedProcess:
    python = getattr(sys, '_base_executable', sys.executable)
    return subprocess.run(['bash', str(SCRIPT), python, str(venv), str(lock)],
                          capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, COBOT_CALIB_VENV_CACHE=str(cache),
                                   COBOT_CALIB_VENV_CHECK=check))


def test_a_second_venv_comes_from_the_cache_with_its_own_paths(tmp_path):
    lock, cache = tmp_path / 'requirements.lock', tmp_path / 'cache'
    lock.write_text('# nothing pinned\n')
    first = _install(tmp_path / 'one' / '.venv', lock, cache)
    assert first.returncode == 0, first.stderr
    assert 'venv kept in the cache' in first.stdout and 'from the venv cache' not in first.stdout
    (entry,) = cache.iterdir()
    assert (entry / 'made_in').read_text().strip() == str(tmp_path / 'one' / '.venv')

    second = _install(tmp_path / 'two' / '.venv', lock, cache)
    assert second.returncode == 0, second.stderr
    assert f'from the venv cache ({entry})' in second.stdout
    venv = tmp_path / 'two' / '.venv'
    pip = (venv / 'bin' / 'pip').read_text()
    assert pip.startswith(f'#!{venv}/bin/python') and str(tmp_path / 'one') not in pip
    # a hard link of the cache's file, which keeps the first venv's path
    site = next((venv / 'lib').glob('python3*/site-packages'))
    pip_package = next(site.glob('pip-*.dist-info')) / 'METADATA'
    cached = entry / 'venv' / pip_package.relative_to(venv)
    assert os.stat(pip_package).st_ino == os.stat(cached).st_ino
    assert str(tmp_path / 'one') in (entry / 'venv' / 'bin' / 'pip').read_text()
    ran = subprocess.run([str(venv / 'bin' / 'pip'), '--version'], capture_output=True,
                         text=True, timeout=60)
    assert ran.returncode == 0 and str(site) in ran.stdout, ran.stdout + ran.stderr


def test_a_cached_venv_that_fails_the_check_is_dropped_and_pip_installs(tmp_path):
    lock, cache = tmp_path / 'requirements.lock', tmp_path / 'cache'
    lock.write_text('# nothing pinned\n')
    assert _install(tmp_path / 'one' / '.venv', lock, cache).returncode == 0
    (entry,) = cache.iterdir()
    broken = _install(tmp_path / 'two' / '.venv', lock, cache, check='import no_such_module')
    assert broken.returncode == 0, broken.stderr
    assert f'the cached venv {entry} does not import its packages; dropped' in broken.stderr
    assert 'venv kept in the cache' in broken.stdout       # pip's new venv replaces it
    assert (entry / 'made_in').read_text().strip() == str(tmp_path / 'two' / '.venv')
    assert (tmp_path / 'two' / '.venv' / 'bin' / 'python').exists()
