"""Client side of the suite: wait until the node suite serves data.

The generic client plumbing (types, fields, calls, graph) is in ros/ (types, fields, calls,
graph), used by the CLI, the demo, the benches, the bags and the tests.
"""
from __future__ import annotations

import contextlib
import os
import time

from rclpy.node import Node

from cobot_calib_ros.ros.calls import call_service, CallError


def wait_for_suite(node: Node, timeout: float = 60.0, executor=None,
                   stop=lambda: False, nodes=None) -> None:
    """Until joint_states and probe readings flow (a short capture and a probe average work),
    or stop(). ``nodes``: the suite's node names when only part of it runs (a flow is waited
    for only where its node runs)."""
    from cobot_calib_msgs.srv import AverageProximity, CaptureJoints
    checks = [(CaptureJoints, 'capture_joints', CaptureJoints.Response.NO_DATA,
               'joint_state_monitor'),
              (AverageProximity, 'probe/average', AverageProximity.Response.NO_DATA,
               'proximity_sensor')]
    checks = [check[:3] for check in checks if nodes is None or check[3] in nodes]
    deadline = time.monotonic() + timeout
    for srv_type, name, no_data in checks:
        client = node.create_client(srv_type, name)
        try:
            while not _flows(node, client, no_data, executor):
                if stop():
                    return
                if time.monotonic() > deadline:
                    raise CallError(f'{name} had no data within {timeout:.0f} s; is the node '
                                    f'suite up (ROS_DOMAIN_ID='
                                    f'{os.environ.get("ROS_DOMAIN_ID", "0")})?')
        finally:
            node.destroy_client(client)


def _flows(node: Node, client, no_data: int, executor) -> bool:
    with contextlib.suppress(CallError):
        response = call_service(node, client, client.srv_type.Request(duration=0.1), 10.0,
                                executor, idempotent=True)
        return response.error_code not in (no_data, getattr(response, 'BAD_REQUEST', -1))
    return False
