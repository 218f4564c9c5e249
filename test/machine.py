"""How busy this machine is, for the assertions that only hold on an unloaded one."""
import os


def machine_unloaded() -> bool:
    """The 1-minute load average is below the number of cores: nothing else competes with the
    suite's 1 kHz streams and its processes' start and exit. On a loaded machine starved
    streams are real (retries then show in /diagnostics and results), and a node's exit can
    outlast the launcher's SIGINT wait (it then gets SIGTERM after its teardown)."""
    return os.getloadavg()[0] < (os.cpu_count() or 1)
