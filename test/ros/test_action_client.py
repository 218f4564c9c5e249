"""ros.action_client.ActionClient: feedback that reached the client before the goal's result is
delivered, in order, even when the client did not spin between them (a loaded machine). With
rclpy's own client the result drops the goal's feedback callback and the last two never arrive
(`intrinsics --planned` once printed "7/8 views" before a result of 8 views)."""
import os
import threading
import time

import pytest
import rclpy
from action_msgs.msg import GoalStatus
from rclpy.action import ActionServer, GoalResponse
from rclpy.action import ActionClient as RclpyActionClient
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from cobot_calib_msgs.action import CalibrateIntrinsics
from cobot_calib_ros.ros import action_client
from cobot_calib_ros.ros.action_client import ActionClient
from cobot_calib_ros.ros.calls import CallError, run_action, spin_until

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


def _losing_first(client_class, answer: str = 'goal'):
    """``client_class`` whose first ``answer`` ('goal': the goal's acceptance, 'result') is
    lost on the way: rmw_fastrtps drops a goal answer when the server has not matched a new
    client's reply reader yet, and a server torn down right after sending a result lost it
    (spin.RESULT_LINGER)."""
    class Losing(client_class):
        lost = 0

        async def execute(self, taken_data):
            if answer in taken_data and not self.lost:
                self.lost += 1
                taken_data.pop(answer)
            await super().execute(taken_data)
    return Losing


@pytest.fixture
def counting_server(request):
    """A server that runs each goal it accepts at once (counted) or rejects every goal
    (request.param == 'reject'), or forgets each goal as soon as it ended ('forgets': no
    result kept, as a restarted server knows no goal of the old one); its own executor in a
    thread."""
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ['ROS_DOMAIN_ID']))
    node = rclpy.create_node('action_client_counting_server', context=context)
    runs = []

    def execute(goal_handle):
        runs.append(bytes(goal_handle.goal_id.uuid))
        goal_handle.succeed()
        return CalibrateIntrinsics.Result(views_used=len(runs))

    reject = getattr(request, 'param', '') == 'reject'
    kept = 0 if getattr(request, 'param', '') == 'forgets' else 900     # [s] rclpy's default
    action_server = ActionServer(node, CalibrateIntrinsics, ACTION, execute,
                                 goal_callback=lambda goal: (GoalResponse.REJECT if reject
                                                             else GoalResponse.ACCEPT),
                                 result_timeout=kept)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield context, runs
    finally:
        action_server.destroy()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        thread.join(10.0)


def _send_with_the_first_answer_lost(client_class, context, wait: float):
    """The goal handle a client whose first goal answer is lost gets within ``wait`` s (None
    if none), and the client's own node's log warnings."""
    node = rclpy.create_node('action_client_losing_client', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    client = _losing_first(client_class)(node, CalibrateIntrinsics, ACTION)
    try:
        assert spin_until(node, client.server_is_ready, 30.0, executor)
        send = client.send_goal_async(CalibrateIntrinsics.Goal())
        if not spin_until(node, send.done, wait, executor):
            return None, None
        handle = send.result()
        if not handle.accepted:
            return handle, None
        result = handle.get_result_async()
        assert spin_until(node, result.done, 30.0, executor)
        return handle, result.result()
    finally:
        client.destroy()
        node.destroy_node()


def test_a_goal_whose_acceptance_was_lost_is_found_and_runs_once(counting_server, monkeypatch):
    monkeypatch.setattr(action_client, 'ASK_AGAIN', 0.5)
    context, runs = counting_server
    handle, result = _send_with_the_first_answer_lost(ActionClient, context, 10.0)
    assert handle is not None and handle.accepted
    assert runs == [bytes(handle.goal_id.uuid)]             # the server ran it once
    assert result.status == GoalStatus.STATUS_SUCCEEDED and result.result.views_used == 1


def test_rclpys_own_client_waits_for_the_lost_acceptance(counting_server):
    """Why the re-send exists: rclpy's client never learns that its goal runs."""
    context, runs = counting_server
    handle, _ = _send_with_the_first_answer_lost(RclpyActionClient, context, 3.0)
    assert handle is None and len(runs) == 1


@pytest.mark.parametrize('counting_server', ['reject'], indirect=True)
def test_a_rejection_whose_answer_was_lost_is_still_a_rejection(counting_server, monkeypatch):
    monkeypatch.setattr(action_client, 'ASK_AGAIN', 0.5)
    context, runs = counting_server
    handle, _ = _send_with_the_first_answer_lost(ActionClient, context, 10.0)
    assert handle is not None and not handle.accepted and runs == []


def _run_with_the_first_result_lost(context, timeout: float):
    node = rclpy.create_node('action_client_losing_result', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    client = _losing_first(ActionClient, 'result')(node, CalibrateIntrinsics, ACTION)
    try:
        return run_action(node, client, CalibrateIntrinsics.Goal(), timeout, executor=executor)
    finally:
        client.destroy()
        node.destroy_node()


def test_a_result_whose_answer_was_lost_is_asked_for_again(counting_server):
    """The status says the goal ended, the answer does not come: run_action asks again
    (calls.ResultWait) and gets it, where it waited out its whole timeout."""
    context, runs = counting_server
    started = time.monotonic()
    status, result = _run_with_the_first_result_lost(context, 20.0)
    assert status == GoalStatus.STATUS_SUCCEEDED and result.views_used == 1 and len(runs) == 1
    assert time.monotonic() - started < 10.0


@pytest.mark.parametrize('counting_server', ['forgets'], indirect=True)
def test_a_server_that_does_not_know_the_goal_is_a_lost_goal_not_a_result(counting_server):
    """Asked again, the server answers STATUS_UNKNOWN with a default result (error code 0):
    run_action says the goal is lost. Taken as the result, `cobot-calib trial` once exited 0
    after its node was killed and restarted (the new one answered the result request)."""
    context, runs = counting_server
    with pytest.raises(CallError, match='goal lost'):
        _run_with_the_first_result_lost(context, 20.0)
    assert len(runs) == 1
