"""How long the tests wait for node processes on a loaded machine, and how busy it is.

The bounds are waits on an event (a service up, a process exited): they cost nothing when
the event comes early, so they are set for the worst load seen (2 cores, load average 25).
"""
import os

# [s] for node processes to come up: 9 processes' cold imports took over 30 s at load 25
STARTUP_TIMEOUT = 120.0
# [s] for a node to exit after Suite.stop's SIGINT: a teardown outlasted the launcher's
# default 5 s at load 10-25, and the SIGTERM that followed failed the exit-code assertions
STOP_TIMEOUT = 30.0


def machine_unloaded() -> bool:
    """The 1-minute load average is below the number of cores: nothing else competes with the
    suite's 1 kHz streams and its processes' start and exit. On a loaded machine starved
    streams are real (retries then show in /diagnostics and results), and a node's exit can
    outlast the launcher's SIGINT wait (it then gets SIGTERM after its teardown).
    Only test/cli/test_up.py still asks; bench/ prints what depends on the load."""
    return os.getloadavg()[0] < (os.cpu_count() or 1)


def short_lease(env: dict) -> dict:
    """``env`` for a process a test kills: its DDS participant announces a 6 s lease, so its
    peers drop it from the graph ~6 s after a kill -9, not after Fast DDS's default 20 s
    (what the product waits for is the node leaving the graph, not the lease's length)."""
    from pathlib import Path
    return dict(env, FASTRTPS_DEFAULT_PROFILES_FILE=str(
        Path(__file__).with_name('fastdds_lease_6s.xml')))
