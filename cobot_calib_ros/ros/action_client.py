"""rclpy's ActionClient, with every feedback that came before a goal's result delivered.

rclpy (Jazzy) handles one wake's data in a fixed order: the result response first, then one
feedback message. Setting the result fires the result future's done callback, which drops the
goal's feedback callback, so a feedback taken in the same wake, and any still queued behind it,
are never delivered: the client's progress stops one or more steps short of the end ("7/8
views" before the result of 8 views). That happens whenever the client did not spin between the
last feedback and the result: a loaded machine, a repaired DDS sample. This client delivers the
queued feedback first, in order, then the result.
"""
from __future__ import annotations

from rclpy.action import ActionClient as _RclpyActionClient


class ActionClient(_RclpyActionClient):
    """rclpy's ActionClient; a wake that brings a result delivers the feedback before it."""

    async def execute(self, taken_data):
        if 'result' in taken_data:
            feedback = [taken_data.pop('feedback')] if 'feedback' in taken_data else []
            feedback += self._queued_feedback()
            for message in feedback:
                await super().execute({'feedback': message})
        await super().execute(taken_data)

    def _queued_feedback(self) -> list:
        """The feedback messages the reader holds now (rclpy takes one per wake)."""
        queued = []
        while (message := self._client_handle.take_feedback(
                self._action_type.Impl.FeedbackMessage)) is not None:
            queued.append(message)
        return queued
