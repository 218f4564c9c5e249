"""ros.action_client.ActionClient: feedback that reached the client before the goal's result is
delivered, in order, even when the client did not spin between them (a loaded machine). With
rclpy's own client the result drops the goal's feedback callback and the last two never arrive
(`intrinsics --planned` once printed "7/8 views" before a result of 8 views)."""
import os
import threading
import time

import pytest
import rclpy
from rclpy.action import ActionServer
from rclpy.action import ActionClient as RclpyActionClient
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from cobot_calib_msgs.action import CalibrateIntrinsics
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import spin_until

ACTION = 'action_client_test'
TOTAL = 3


@pytest.fixture
def server():
    """A server whose goal waits for `go`, then sends TOTAL feedbacks and succeeds; its own
    executor in a thread."""
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ['ROS_DOMAIN_ID']))
    node = rclpy.create_node('action_client_test_server', context=context)
    go, finished = threading.Event(), threading.Event()

    def execute(goal_handle):
        go.wait(30.0)
        for views in range(1, TOTAL + 1):
            goal_handle.publish_feedback(CalibrateIntrinsics.Feedback(views=views, total=TOTAL))
        goal_handle.succeed()
        finished.set()
        return CalibrateIntrinsics.Result(views_used=TOTAL)

    action_server = ActionServer(node, CalibrateIntrinsics, ACTION, execute)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield context, go, finished
    finally:
        go.set()
        action_server.destroy()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        thread.join(10.0)


def _feedback_before_a_result_that_came_in_the_same_wake(client_class, server) -> list[int]:
    context, go, finished = server
    node = rclpy.create_node('action_client_test_client', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    client = client_class(node, CalibrateIntrinsics, ACTION)
    views = []
    try:
        assert spin_until(node, client.server_is_ready, 30.0, executor)
        send = client.send_goal_async(CalibrateIntrinsics.Goal(),
                                      feedback_callback=lambda m: views.append(m.feedback.views))
        assert spin_until(node, send.done, 30.0, executor) and send.result().accepted
        result = send.result().get_result_async()
        go.set()                        # the client does not spin while the goal runs
        assert finished.wait(30.0)
        time.sleep(1.0)                 # every feedback and the result reach the client's readers
        assert spin_until(node, result.done, 30.0, executor)
        assert result.result().result.views_used == TOTAL
    finally:
        client.destroy()
        node.destroy_node()
    return views


def test_feedback_queued_before_the_result_is_delivered_in_order(server):
    assert _feedback_before_a_result_that_came_in_the_same_wake(ActionClient, server) == [1, 2, 3]


def test_rclpys_own_client_loses_it(server):
    """Why the project's client exists; when this fails, rclpy was fixed and the subclass can
    go."""
    views = _feedback_before_a_result_that_came_in_the_same_wake(RclpyActionClient, server)
    assert views[-1:] != [TOTAL], views         # measured: [1], the other two dropped
