"""rclpy's ActionClient, with every feedback that came before a goal's result delivered, and a
goal whose acceptance was lost on the way still found.

Feedback: rclpy (Jazzy) handles one wake's data in a fixed order: the result response first,
then one feedback message. Setting the result fires the result future's done callback, which
drops the goal's feedback callback, so a feedback taken in the same wake, and any still queued
behind it, are never delivered: the client's progress stops one or more steps short of the end
("7/8 views" before the result of 8 views). That happens whenever the client did not spin
between the last feedback and the result: a loaded machine, a repaired DDS sample. This client
delivers the queued feedback first, in order, then the result.

Acceptance: rmw_fastrtps drops a service's answer when the server has not yet matched the new
client's reply reader within 100 ms ("failed to send response (timeout): client will not
receive response"); the client's own server_is_ready said yes. A fresh client's goal then ran
on the server while the client waited out its accept timeout ("did not answer the goal within
10 s", a fresh-clone test run at load 8). So an unanswered goal request is sent again every
ASK_AGAIN s with the same goal id: a server accepts a goal id once and rejects it when sent
again (rclpy's and rclcpp_action's servers check goal_exists), and its status topic lists
every goal it accepted. A goal the status lists, or a re-sent one rejected and then listed,
gets a goal handle as if its acceptance had arrived.
"""
from __future__ import annotations

import contextlib
import weakref

from rclpy.action import ActionClient as _RclpyActionClient
from rclpy.action.client import ClientGoalHandle
from rclpy.exceptions import InvalidHandle
from rclpy.task import Future

# [s] an unanswered request is sent again this often (a goal here, an idempotent query in
# ros.calls and ros.spin): see the module docstring for why answers get lost (a query's client
# once waited out its whole timeout: one process's `demo --attach`, 15 s, in a loaded test run)
ASK_AGAIN = 2.0
GOAL_ASKS = 5     # a goal request is sent at most this often: callers wait 10 s for it


class ActionClient(_RclpyActionClient):
    """rclpy's ActionClient; a wake that brings a result delivers the feedback before it, and
    a goal whose acceptance was lost is found (module docstring)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._sends: dict[bytes, _GoalSend] = {}     # goal id -> its request, while unanswered

    def send_goal_async(self, goal, feedback_callback=None, goal_uuid=None) -> Future:
        """rclpy's send_goal_async; the request is sent again while unanswered (_GoalSend)."""
        goal_id = goal_uuid if goal_uuid is not None else self._generate_random_uuid()
        first = super().send_goal_async(goal, feedback_callback, goal_id)
        return _GoalSend(self, goal, goal_id, first).answer

    async def execute(self, taken_data):
        if 'status' in taken_data and self._sends:
            for status in taken_data['status'].status_list:
                send = self._sends.get(bytes(status.goal_info.goal_id.uuid))
                if send is not None:
                    send.listed(status)
        if 'result' in taken_data:
            feedback = [taken_data.pop('feedback')] if 'feedback' in taken_data else []
            feedback += self._queued_feedback()
            for message in feedback:
                await super().execute({'feedback': message})
        await super().execute(taken_data)

    def destroy(self) -> None:
        for send in list(self._sends.values()):
            send.end()
        super().destroy()

    def _queued_feedback(self) -> list:
        """The feedback messages the reader holds now (rclpy takes one per wake)."""
        queued = []
        while (message := self._client_handle.take_feedback(
                self._action_type.Impl.FeedbackMessage)) is not None:
            queued.append(message)
        return queued


class _GoalSend:
    """One goal's request, sent again every ASK_AGAIN s (up to GOAL_ASKS times) while no answer
    came; ``answer`` is the future of its goal handle.

    The first answer settles it, with two exceptions. A re-sent request's rejection may be the
    server's "that goal id exists": the status topic says which (listed: accepted, found;
    not listed one ASK_AGAIN later: rejected). And a goal the status lists while its
    acceptance is ASK_AGAIN late was accepted: found without waiting for a re-send."""

    def __init__(self, client: ActionClient, goal, goal_id, first: Future) -> None:
        self._client, self._goal, self._goal_id = client, goal, goal_id
        self._key = bytes(goal_id.uuid)
        self.answer = Future()
        self._requests = [first]
        self._status = None             # the goal's entry in the server's status, once seen
        self._rejected_again = None     # a re-send's rejection, until the status says which
        client._sends[self._key] = self
        first.add_done_callback(self._answered)
        self._timer = client._node.create_timer(ASK_AGAIN, self._tick,
                                                callback_group=client.callback_group)
        self.answer.add_done_callback(lambda _: self.end())   # settled or given up by its caller

    def listed(self, status) -> None:
        """The server's status lists the goal: it was accepted."""
        self._status = status
        if self._rejected_again is not None or len(self._requests) > 1:
            self._settle(self._found())

    def _tick(self) -> None:
        if self.answer.done() or self.answer.cancelled():
            self.end()
        elif self._status is not None:
            self._settle(self._found())
        elif self._rejected_again is not None:      # not listed since: a real rejection
            self._settle(self._rejected_again)
        elif len(self._requests) >= GOAL_ASKS:
            self.end()                  # the caller's own timeout reports it
        else:
            with contextlib.suppress(InvalidHandle):  # the client was destroyed meanwhile
                request = _RclpyActionClient.send_goal_async(self._client, self._goal,
                                                             None, self._goal_id)
                self._requests.append(request)
                request.add_done_callback(self._answered)

    def _answered(self, request: Future) -> None:
        if self.answer.done() or not request.done():
            return
        handle = request.result()
        if handle.accepted or request is self._requests[0]:
            self._settle(handle)
        elif self._status is not None:             # rejected as a duplicate of an accepted goal
            self._settle(self._found())
        else:
            self._rejected_again = handle

    def _found(self) -> ClientGoalHandle:
        """A goal handle for the accepted goal whose acceptance never arrived."""
        response = self._client._action_type.Impl.SendGoalService.Response(
            accepted=True, stamp=self._status.goal_info.stamp)
        handle = ClientGoalHandle(self._client, self._goal_id, response)
        self._client._goal_handles[self._key] = weakref.ref(handle)
        self._client._node.get_logger().warning(
            f'{self._client._action_name}: the goal\'s acceptance was lost on the way (a new '
            'client not yet matched by the server); found it in the server\'s goal status')
        return handle

    def _settle(self, handle: ClientGoalHandle) -> None:
        self.end()
        if not self.answer.done():
            self.answer.set_result(handle)

    def end(self) -> None:
        """No more re-sends; the requests left unanswered are forgotten (a late answer to one
        is then ignored, not taken for a second goal)."""
        self._client._sends.pop(self._key, None)
        if self._timer is not None:
            self._client._node.destroy_timer(self._timer)
            self._timer = None
        for request in self._requests:
            if not request.done():
                self._client._remove_pending_goal_request(request)
                request.cancel()
