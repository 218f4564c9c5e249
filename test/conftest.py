"""Every test session gets its own ROS_DOMAIN_ID and keeps DDS on loopback."""
import atexit
import os
import random
from pathlib import Path
import shutil
import sys
import tempfile
import xml.etree.ElementTree as ET

import domain_coordinator
import domain_coordinator.impl
import pytest
from hypothesis import settings

# A property test's verdict must not depend on how busy the machine is: hypothesis's default
# 200 ms deadline per example failed test_iso9283 at load 30 (332 ms, DeadlineExceeded).
settings.register_profile('no_deadline', deadline=None)
settings.load_profile('no_deadline')

PROFILES_NS = 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'


def _session_dds_profile(directory: Path) -> Path:
    """test/fastdds_no_lease_check.xml with Fast DDS's own log in ``directory``/fastdds.log: a
    busy machine's harmless 'RTPS_TRANSPORT_SHM Error ... open_and_lock_file failed' (an SHM
    port another process holds) would otherwise be in the stderr of any process a test
    compares (the product's profile sends it to stderr, test/api/test_dds_profile.py)."""
    def q(tag: str) -> str:
        return f'{{{PROFILES_NS}}}{tag}'
    ET.register_namespace('', PROFILES_NS)
    tree = ET.parse(Path(__file__).with_name('fastdds_no_lease_check.xml'))
    consumer = tree.getroot().find(f'{q("log")}/{q("consumer")}')
    for child in list(consumer):
        consumer.remove(child)
    ET.SubElement(consumer, q('class')).text = 'FileConsumer'
    for name, value in (('filename', str(directory / 'fastdds.log')), ('append', 'TRUE')):
        prop = ET.SubElement(consumer, q('property'))
        ET.SubElement(prop, q('name')).text = name
        ET.SubElement(prop, q('value')).text = value
    out = directory / 'fastdds_no_lease_check.xml'
    tree.write(out, encoding='utf-8', xml_declaration=True)
    return out


os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
# what the session writes outside pytest's tmp_path, removed when it ends
SESSION_DIR = Path(tempfile.mkdtemp(prefix='cobot_calib_test_'))
atexit.register(shutil.rmtree, SESSION_DIR, ignore_errors=True)
# commands store their results (identify stores every source): never in the user's
# ~/.ros/cobot_calib; a test that looks at its results gives its own data dir
if 'COBOT_CALIB_DATA' not in os.environ:
    os.environ['COBOT_CALIB_DATA'] = str(SESSION_DIR / 'data')
    (SESSION_DIR / 'data').mkdir()
# every process of the session (this one, nodes, commands) announces an infinite DDS lease:
# no lease checks, which can deadlock Fast DDS 2.14.5 (see the file); a test that kills a
# process on purpose gives it a short lease of its own
if 'FASTRTPS_DEFAULT_PROFILES_FILE' not in os.environ:
    os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(_session_dds_profile(SESSION_DIR))
# tools/pg_cluster.py: the throwaway PostgreSQL of test/store (and bench_database)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'tools'))


class _RotatingDomains:
    """domain_coordinator's selector for this process: it goes on from where the last domain
    was taken (from a random start), where the package's own starts at 1 for every call. So a
    domain a test has just released is not handed to the next test at once: a participant of
    the last test that outlives it (an in-process context's rmw participant ends when the last
    handle does) was seen by the next one on the same domain (test_mock_camera's rest test
    found an image subscriber it never made, fresh-clone run 15). The port bind of
    domain_coordinator still makes each domain one holder's."""

    _next = random.randrange(100)

    def __call__(self) -> int:
        domain = _RotatingDomains._next % 100 + 1
        _RotatingDomains._next += 1
        return domain


domain_coordinator.impl.default_selector = _RotatingDomains


@pytest.fixture(scope='session', autouse=True)
def domain_id():
    """Reserved before any test runs: a domain that another test's suite used and released
    (test/bags) could otherwise come back as this one, with its dead nodes still in the DDS
    graph for a while ('service ... is not available' instead of 'not found')."""
    with domain_coordinator.domain_id() as domain:
        os.environ['ROS_DOMAIN_ID'] = str(domain)
        yield domain


# The test files that take longest, longest first (fresh-clone run 9, seconds of one worker):
# `make test` runs them before every other file (pytest-xdist --dist loadfile with
# --no-loadscope-reorder hands files out in collection order). By default xdist sorts files
# by their number of tests, which put these one-test files last: the iiwa 7's first day
# (290 s) then ran alone at the end while the other worker idled.
SLOWEST_FILES = (
    'test/nodes/test_first_day_iiwa7.py',
    'test/nodes/test_first_day_sawyer.py',
    'test/nodes/test_first_day_ur10e.py',
    'test/cli/test_up.py',
    'test/cli/test_identify_faults.py',
)
# test/nodes' session suite (its conftest) stops when a worker's next test does not use it, and
# starts again for the next one that does: 9 node processes, ~10 s of CPU and 15-40 s of the
# worker's time on a loaded machine. Fresh-clone run G started it 10 times, once because
# test_repeatability_trial has five tests of its own suites in the middle.
SESSION_SUITE_DIR = 'test/nodes/'


def _file(item) -> str:
    return item.nodeid.split('::', 1)[0]


def _uses_session_suite(item) -> bool:
    return _file(item).startswith(SESSION_SUITE_DIR) and 'suite' in item.fixturenames


def pytest_collection_modifyitems(session, config, items):
    """SLOWEST_FILES first; then every other file in collection order, except that the files
    with tests of test/nodes' session suite come as one block where the first of them is, each
    with those tests first: a worker then runs them one after the other on one suite."""
    slow = {path: i for i, path in enumerate(SLOWEST_FILES)}
    suite_files = {_file(item) for item in items if _uses_session_suite(item)}
    first: dict[str, int] = {}
    for item in items:
        first.setdefault(_file(item), len(first))
    block = min((first[path] for path in suite_files), default=0)

    def key(item) -> tuple:
        path = _file(item)
        return (slow.get(path, len(slow)), block if path in suite_files else first[path],
                first[path], not _uses_session_suite(item))
    items.sort(key=key)        # stable: the collection order within equal keys


def pytest_sessionstart(session):
    """The Fast DDS segments of processes killed before this session (api.fastdds_shm): a
    killed suite leaves 16 MB each, and once they filled the machine's memory."""
    _remove_stale_segments(session)


def pytest_sessionfinish(session):
    """And those of the processes this session's tests killed on purpose or at a timeout."""
    _remove_stale_segments(session, min_age=5.0)


def _remove_stale_segments(session, **kwargs) -> None:
    if not hasattr(session.config, 'workerinput'):       # once, in the controlling process
        from cobot_calib_ros.api.fastdds_shm import remove_stale_segments
        remove_stale_segments(**kwargs)
