"""Every test session gets its own ROS_DOMAIN_ID and keeps DDS on loopback."""
import os

import pytest

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'


@pytest.fixture(scope='session')
def domain_id():
    import domain_coordinator
    with domain_coordinator.domain_id() as domain:
        os.environ['ROS_DOMAIN_ID'] = str(domain)
        yield domain
