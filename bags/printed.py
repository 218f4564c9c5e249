"""The bag-making scripts' waits: until `cobot-calib up` says 'ready' and `record` says it
records each topic (their output goes to a log file, read again until the lines are there)."""
from __future__ import annotations

from pathlib import Path
import subprocess
import time

POLL = 0.1          # [s] between reads of the log


def start_logged(command: list[str], env: dict, log: Path) -> subprocess.Popen:
    """``command`` with its stdout and stderr in ``log``."""
    with open(log, 'w') as out:
        return subprocess.Popen(command, env=env, stdout=out, stderr=subprocess.STDOUT)


def wait_printed(proc: subprocess.Popen, log: Path, starts: list[str], timeout: float) -> None:
    """Until a line of ``log`` starts with each of ``starts``; SystemExit with the log's tail
    if ``proc`` (a `cobot-calib VERB ...`) exits first or ``timeout`` [s] passes."""
    deadline = time.monotonic() + timeout
    while True:
        lines = log.read_text(errors='replace').splitlines()
        missing = [s for s in starts if not any(line.startswith(s) for line in lines)]
        if not missing:
            return
        if proc.poll() is not None or time.monotonic() > deadline:
            why = (f'exited with {proc.returncode}' if proc.poll() is not None
                   else f'not within {timeout:g} s')
            raise SystemExit(f'cobot-calib {proc.args[3]}: no line {missing} ({why}):\n'
                             + '\n'.join(lines[-20:]))
        time.sleep(POLL)
