"""Bags: the real rosbag2 test bags, JointState/own messages as CDR, small bag helpers."""
import os
from pathlib import Path
import sys

import pytest

HERE = Path(__file__).resolve().parent
REAL_BAGS = HERE.parent / 'data' / 'rosbag2-test-bags'
sys.path.insert(0, str(HERE))


@pytest.fixture
def real_bag():
    """Path of one of rosbag2's test bags: real_bag('mcap', 'talker')."""
    def path(storage: str, name: str) -> Path:
        return REAL_BAGS / storage / name
    return path


@pytest.fixture(scope='module')
def bag_domain():
    """A ROS domain of this module's own (domain_coordinator), away from the session's (where
    test/nodes runs mock_robot's /joint_states and test_sim_time a /clock): (domain id, the
    environment for child processes)."""
    import domain_coordinator
    with domain_coordinator.domain_id() as domain:
        yield domain, dict(os.environ, ROS_DOMAIN_ID=str(domain),
                           ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
