"""ros.session: one client node and its executor, on the process's domain or a private one."""
import os

import domain_coordinator
from std_msgs.msg import String

from cobot_calib_ros.ros.calls import spin_until
from cobot_calib_ros.ros.session import session


def test_a_private_domain_session_on_sim_time_talks_to_itself_and_shuts_down():
    got = []
    with domain_coordinator.domain_id() as domain, \
            session('test_session', domain_id=domain, sim_time=True) as (node, executor):
        context = node.context
        assert context.get_domain_id() == domain
        assert node.get_parameter('use_sim_time').value is True
        assert node in executor.get_nodes()
        node.create_subscription(String, 'session_echo', got.append, 10)
        pub = node.create_publisher(String, 'session_echo', 10)
        assert spin_until(node, lambda: pub.get_subscription_count() > 0, 10.0)
        pub.publish(String(data='hello'))
        # spin_until spins the session's executor (the node's own) when none is given
        assert spin_until(node, lambda: bool(got), 10.0)
    assert [m.data for m in got] == ['hello']
    assert not context.ok()


def test_a_default_session_uses_the_process_domain_and_wall_time():
    with session('test_session_default') as (node, _):
        assert node.context.get_domain_id() == int(os.environ.get('ROS_DOMAIN_ID', '0'))
        assert node.get_parameter('use_sim_time').value is False
        context = node.context
    assert not context.ok()
