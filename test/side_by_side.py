"""`cobot-calib` commands run at once: a CLI call's time is mostly its interpreter's start and
its wait for the graph, so calls that only read or wait need not queue behind each other."""
import os
import subprocess
import sys


def cli_side_by_side(*commands, env: dict | None = None,
                     timeout: float = 120.0) -> list[subprocess.CompletedProcess]:
    """`cobot-calib ARGS` for each ARGS of ``commands``, started together; their completed
    processes in the same order (each within ``timeout`` s, or TimeoutExpired)."""
    procs = [subprocess.Popen([sys.executable, '-m', 'cobot_calib_ros.cli.main', *args],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=dict(os.environ) if env is None else env)
             for args in commands]
    done = []
    try:
        for proc in procs:
            out, err = proc.communicate(timeout=timeout)
            done.append(subprocess.CompletedProcess(proc.args, proc.returncode, out, err))
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    return done
