"""spin.absent_after: on a domain where other nodes are seen, servers are waited for beyond
the short timeout (a suite still being discovered on a busy machine: CI runs refused
`identify --attach` after 5 s while the suite was up); on an empty domain the answer comes
after the timeout."""
import threading
import time

import pytest
import rclpy
from rclpy.action import ActionServer
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from cobot_calib_msgs.action import CalibrateIntrinsics
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.spin import absent_after, until

ACTION = 'absent_after_test'
LATE = 1.0          # [s] after the wait starts, the server appears
TIMEOUT = 0.2       # [s] absent_after's own timeout: shorter than LATE


@pytest.fixture
def contexts():
    """Contexts on a domain of their own: the session's may have a suite up (test/nodes)."""
    import domain_coordinator
    made = []
    with domain_coordinator.domain_id() as domain:
        def context() -> Context:
            made.append(Context())
            rclpy.init(context=made[-1], domain_id=domain)
            return made[-1]
        yield context
        for context in made:
            rclpy.try_shutdown(context=context)


@pytest.mark.parametrize('starts, absent', [
    (True, []),                 # its node on the graph: the server is waited for
    (False, ['server']),        # no other node: absent after TIMEOUT
])
def test_a_server_of_a_node_on_the_graph_is_waited_for(contexts, starts, absent):
    server_node = f'absent_after_server_{starts}'.lower()    # each case its own names
    client_node = rclpy.create_node('absent_after_client', context=contexts())
    action = f'{ACTION}_{starts}'.lower()
    client = ActionClient(client_node, CalibrateIntrinsics, action)
    go, stop, threads = threading.Event(), threading.Event(), []
    if starts:
        node = rclpy.create_node(server_node, context=contexts())
        executor = SingleThreadedExecutor(context=node.context)
        executor.add_node(node)

        def serve_late():
            go.wait(30.0)
            time.sleep(LATE)
            ActionServer(node, CalibrateIntrinsics, action, lambda g: g.succeed())
            while not stop.is_set():
                executor.spin_once(timeout_sec=0.05)
        threads.append(threading.Thread(target=serve_late, daemon=True))
        threads[-1].start()
        assert until(lambda: server_node in client_node.get_node_names(), 30.0)
    try:
        go.set()
        assert absent_after({'server': client.server_is_ready}, TIMEOUT, client_node) == absent
    finally:
        stop.set()
        for thread in threads:
            thread.join(10.0)
        client.destroy()

