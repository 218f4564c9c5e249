"""Every test session gets its own ROS_DOMAIN_ID and keeps DDS on loopback."""
import os
from pathlib import Path
import sys

import pytest
from hypothesis import settings

# A property test's verdict must not depend on how busy the machine is: hypothesis's default
# 200 ms deadline per example failed test_iso9283 at load 30 (332 ms, DeadlineExceeded).
settings.register_profile('no_deadline', deadline=None)
settings.load_profile('no_deadline')

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
# tools/pg_cluster.py: the throwaway PostgreSQL of test/store (and bench_database)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'tools'))


@pytest.fixture(scope='session', autouse=True)
def domain_id():
    """Reserved before any test runs: a domain that another test's suite used and released
    (test/bags) could otherwise come back as this one, with its dead nodes still in the DDS
    graph for a while ('service ... is not available' instead of 'not found')."""
    import domain_coordinator
    with domain_coordinator.domain_id() as domain:
        os.environ['ROS_DOMAIN_ID'] = str(domain)
        yield domain


# `make test` runs the files on parallel workers (pytest-xdist, --dist loadfile): the files
# that start ROS suites and CLIs run for minutes and mostly wait on processes, so they go out
# first and the quick pure-core files fill the gaps beside them, instead of one of them
# starting last and running alone.
_FIRST = ('cli', 'nodes', 'bags', 'ros')


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    root = Path(__file__).resolve().parent

    def rank(item: pytest.Item) -> int:
        parts = Path(item.fspath).resolve().relative_to(root).parts
        return _FIRST.index(parts[0]) if parts[0] in _FIRST else len(_FIRST)

    items.sort(key=rank)
