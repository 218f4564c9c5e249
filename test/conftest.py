"""Every test session gets its own ROS_DOMAIN_ID and keeps DDS on loopback."""
import os
from pathlib import Path
import sys
import tempfile

import pytest
from hypothesis import settings

# A property test's verdict must not depend on how busy the machine is: hypothesis's default
# 200 ms deadline per example failed test_iso9283 at load 30 (332 ms, DeadlineExceeded).
settings.register_profile('no_deadline', deadline=None)
settings.load_profile('no_deadline')

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
# commands store their results (identify stores every source): never in the user's
# ~/.ros/cobot_calib; a test that looks at its results gives its own data dir
os.environ.setdefault('COBOT_CALIB_DATA', tempfile.mkdtemp(prefix='cobot_calib_test_data_'))
# every process of the session (this one, nodes, commands) announces an infinite DDS lease:
# no lease checks, which can deadlock Fast DDS 2.14.5 (see the file); a test that kills a
# process on purpose gives it a short lease of its own
os.environ.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE',
                      str(Path(__file__).with_name('fastdds_no_lease_check.xml')))
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
