"""--json output stays parseable when a native library writes to stdout (Fast DDS logs its
RTPS_TRANSPORT_SHM errors with std::cout; one such line broke `list --json` in a CI run)."""
import json
import subprocess
import sys

SCRIPT = '''
import json, os, sys
from cobot_calib_ros.cli import list_cmd, main

def noisy_run(args):
    os.write(1, b"[RTPS_TRANSPORT_SHM Error] Failed init_port\\n")   # as C++ std::cout does
    print(json.dumps({"nodes": [], "json": args.json}))
    return 0

list_cmd.run = noisy_run
sys.exit(main.main(sys.argv[1:]))
'''


def run(*argv):
    return subprocess.run([sys.executable, '-c', SCRIPT, 'list', *argv],
                          capture_output=True, text=True, timeout=60)


def test_native_stdout_goes_to_stderr_under_json():
    out = run('--json')
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout) == {'nodes': [], 'json': True}
    assert 'Failed init_port' in out.stderr


def test_without_json_stdout_is_left_alone():
    out = run()
    assert out.returncode == 0, out.stderr
    assert 'Failed init_port' in out.stdout
