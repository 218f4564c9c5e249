"""The run_trial client: send a trial goal, follow its feedback, cancel it on Ctrl-C."""
from __future__ import annotations

import time

from cobot_calib_ros.core.errors import ErrorCode, Failure


class TrialClient:
    """Sends run_trial goals and prints the progress (one rclpy node).

    Ctrl-C cancels the goal and raises TrialClient.Stopped. The wait ends with a CallError when
    the repeatability_trial node is gone from the graph for GONE_AFTER s (a crashed node: after
    the DDS lease, 20 s) or restarted meanwhile (ros.calls.ServerWatch), or sends no feedback for ``stall_timeout`` s (it sends one at least
    every 2 s while it runs, so silence means it is hung or frozen).
    """

    GONE_AFTER = 3.0        # [s] the action server unseen before the node counts as gone
    CANCEL_WAIT = 5.0       # [s] for the cancel to be acknowledged, then for the trial to stop
    STALL_TIMEOUT = 30.0    # [s] without feedback (the node's heartbeat: 2 s)

    class Stopped(KeyboardInterrupt):
        """Ctrl-C during a trial, after the goal was canceled; ``line`` says how to resume."""

        def __init__(self, line: str) -> None:
            super().__init__(line)
            self.line = line

    def __init__(self, say, stall_timeout: float = STALL_TIMEOUT,
                 each_reading: bool = True) -> None:
        from cobot_calib_ros.ros.action_client import ActionClient
        from cobot_calib_msgs.action import RunTrial
        from cobot_calib_ros.ros.session import session
        self._session = session('cobot_calib_trial_client')   # Ctrl-C: ours, to cancel
        self.node, self.executor = self._session.__enter__()
        self.RunTrial = RunTrial
        self._client = ActionClient(self.node, RunTrial, 'run_trial')
        self._say, self._stall_timeout = say, stall_timeout
        self._each_reading = each_reading    # a line per reading, not only per cycle
        self._interrupts = 0
        self._last = None           # the latest feedback
        self._reading = None        # (cycle, point) of the latest reading printed
        self._heard = 0.0           # time.monotonic() of the latest feedback
        self._seen = 0.0            # time.monotonic() the action server was last seen

    def close(self) -> None:
        self._session.__exit__(None, None, None)

    @staticmethod
    def request_problem(method: str, axis: str, cycles: int, trial_id: str) -> Failure | None:
        """None if the node would accept this goal ('' / 0 = not given), else an INVALID_INPUT
        Failure saying why not: the same core checks the node's goal callback makes (a
        rejected goal carries no reason)."""
        from cobot_calib_ros.core.repeatability.trial import goal_problem
        from cobot_calib_ros.store.files import check_id
        problem = goal_problem(method, axis, cycles)
        if problem is not None or not trial_id:
            return problem
        try:
            check_id(trial_id)
        except ValueError as e:
            return Failure(ErrorCode.INVALID_INPUT, f'trial id: {e}')
        return None

    def unknown_trial(self, trial_id: str) -> Failure | None:
        """None if ``trial_id`` is stored in the data dir of the repeatability_trial node (or
        that node does not answer: the goal will say so), else a NO_DATA Failure 'no trial X;
        unfinished: ...' (a resume of a trial that is not there would start a fresh one under
        that id)."""
        from cobot_calib_ros import paths, store
        from cobot_calib_ros.ros.calls import CallError
        from cobot_calib_ros.ros.remote_params import read_parameter
        try:
            root = paths.data_dir(read_parameter(self.node, 'repeatability_trial', 'data_dir',
                                                 10.0))
        except CallError:
            return None
        trials = store.open(root).trials
        stored = trials.list_trials()
        if any(meta['id'] == trial_id for meta in stored):
            return None
        unfinished = [meta['id'] for meta in stored if meta['status'] != 'done']
        return Failure(ErrorCode.NO_DATA, f'no trial {trial_id} in {trials.directory}; unfinished: '
                f'{", ".join(unfinished) if unfinished else "none"} (leave --trial-id out to '
                'start a new trial)')

    def run(self, method: str, axis: str, cycles: int, trial_id: str = '',
            layout: str = '', timeout: float | None = None):
        """Run (or resume) a trial to its end; its result (see RunTrial.action for '' / 0).
        CallError: rejected, node gone, no progress, timeout; TrialClient.Stopped: Ctrl-C."""
        import signal
        import threading
        from cobot_calib_ros.ros.calls import CallError
        from cobot_calib_ros.core.repeatability.trial import new_trial_id
        problem = self.request_problem(method, axis, cycles, trial_id)
        if problem is not None:
            raise CallError(f'rejected: {problem.message}')
        trial_id = trial_id or new_trial_id(method, axis)    # known before any feedback
        goal = self.RunTrial.Goal(trial_id=trial_id, method=method, axis=axis,
                                  cycles=cycles, layout=layout)
        self._interrupts = 0
        main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, self._on_sigint) if main else None
        try:       # Ctrl-C only counts here (the waits look): no KeyboardInterrupt in rclpy
            return self._follow(self._send(goal), trial_id, timeout)
        finally:
            if main:
                signal.signal(signal.SIGINT, previous)

    def _on_sigint(self, *_) -> None:
        self._interrupts += 1

    def _spin(self, done, timeout: float) -> bool:
        """Spin until done() or a Ctrl-C, at most ``timeout`` s; returns done()."""
        from cobot_calib_ros.ros.calls import spin_until
        spin_until(self.node, lambda: done() or self._interrupts > 0, timeout)
        return done()

    def _send(self, goal):
        from cobot_calib_ros.ros.calls import CallError
        if not self._spin(self._client.server_is_ready, 10.0):
            if self._interrupts:
                raise self.Stopped(f'trial {goal.trial_id} not started (Ctrl-C)')
            raise CallError('action run_trial is not available; is the node suite up '
                            '(cobot-calib up) on the same ROS_DOMAIN_ID?')
        self._last = self._reading = None
        self._heard = self._seen = time.monotonic()
        from cobot_calib_ros.ros.suite_nodes import suite_watch
        suite_watch(self.node)          # the launcher's news of node exits, from before the goal
        self._sent = time.time()
        send = self._client.send_goal_async(goal, feedback_callback=self._feedback)
        self._answered(send, goal.trial_id)
        if not send.result().accepted:
            raise CallError('rejected by repeatability_trial: most likely a trial is already '
                            'running (its log says why)')
        return send.result()

    def _answered(self, send, trial_id: str) -> None:
        """Wait for the goal response (even after a Ctrl-C: to cancel the goal): 10 s, or as
        long as feedback for the goal shows the node took it and is alive."""
        from cobot_calib_ros.ros.calls import CallError, spin_until
        deadline = time.monotonic() + 10.0
        while not spin_until(self.node, send.done, 0.25):
            if self._gone():
                raise CallError(self._gone_line(trial_id))
            silent = self._last is None or self._late(trial_id, None, None)
            if silent and time.monotonic() > deadline:
                raise CallError('run_trial did not answer the goal within 10 s')

    def _follow(self, handle, trial_id: str, timeout: float | None):
        from cobot_calib_ros.ros.calls import CallError, ResultWait, ServerWatch
        watch = ServerWatch(self.node, self._client, self._sent)   # exited, gone: goal lost
        result = ResultWait(handle)
        deadline = None if timeout is None else time.monotonic() + timeout
        resume = f'resume it with: cobot-calib trial --trial-id {trial_id}'
        while not self._spin(result.done, 0.25):
            if self._interrupts:
                return self._stop(handle, result, trial_id, watch)
            result.ask_again_if_ended()
            ended = watch.ended()
            if ended:
                raise CallError(f'{ended}; trial {trial_id} is stored up to its last '
                                f'reading: {resume}')
            late = self._late(trial_id, deadline, timeout)
            if late:
                raise CallError(f'{late}; trial {trial_id} {self._cancel(handle)}: check the '
                                f'node log, then {resume}')
        if result.lost():
            raise CallError(f'{watch.lost_line()}; trial {trial_id} is stored up to its last '
                            f'reading: {resume}')
        return result.result().result

    def _gone(self) -> bool:
        """The action server has been out of the graph for GONE_AFTER s."""
        now = time.monotonic()
        if self._client.server_is_ready():
            self._seen = now
        return now - self._seen > self.GONE_AFTER

    def _gone_line(self, trial_id: str) -> str:
        return (f'the repeatability_trial node is gone (run_trial unavailable for '
                f'{self.GONE_AFTER:.0f} s); trial {trial_id} is stored up to its last reading: '
                f'restart the suite (cobot-calib up), then resume it with: cobot-calib trial '
                f'--trial-id {trial_id}')

    def _late(self, trial_id: str, deadline: float | None, timeout: float | None) -> str:
        """'' while the node keeps talking and the deadline is ahead, else which is not."""
        if time.monotonic() - self._heard > self._stall_timeout:
            return (f'no feedback from repeatability_trial for {self._stall_timeout:.0f} s '
                    '(node hung?)')
        if deadline is not None and time.monotonic() > deadline:
            return f'trial {trial_id} did not finish within {timeout:.0f} s'
        return ''

    def _cancel(self, handle) -> str:
        """Cancel the goal, wait briefly for the answer; what became of the trial."""
        cancel = handle.cancel_goal_async()
        if self._spin(cancel.done, self.CANCEL_WAIT) and cancel.result().goals_canceling:
            return 'canceled'
        return ('not canceled (no answer to the cancel within '
                f'{self.CANCEL_WAIT:.0f} s: it may go on if the node recovers)')

    def _stop(self, handle, result, trial_id: str, watch):
        """Ctrl-C: cancel the goal, wait briefly for the node to acknowledge it and stop.
        ``watch``: the goal's ServerWatch (a restarted node lost the goal: nothing to stop)."""
        from action_msgs.msg import GoalStatus
        self._interrupts = 0                             # a second Ctrl-C ends the waits
        cancel = handle.cancel_goal_async()
        acknowledged = self._spin(cancel.done, self.CANCEL_WAIT) and bool(
            cancel.result().goals_canceling)
        if acknowledged:
            self._spin(result.done, self.CANCEL_WAIT)
        lost = result.done() and result.lost()
        if result.done() and not lost and result.result().status != GoalStatus.STATUS_CANCELED:
            return result.result().result                # it ended before the cancel came
        if lost or (not acknowledged and watch.restarted()):
            raise self.Stopped(f'{watch.lost_line()}; trial {trial_id} is stored up to its '
                               f'last reading: resume it with: cobot-calib trial --trial-id '
                               f'{trial_id}')
        raise self.Stopped(self._stopped_line(trial_id, acknowledged, result.done()))

    def _stopped_line(self, trial_id: str, acknowledged: bool, stopped: bool) -> str:
        resume = f'resume it with: cobot-calib trial --trial-id {trial_id}'
        if stopped:
            return f'trial {trial_id} stopped{self._where()}; {resume}'
        if acknowledged:
            return (f'trial {trial_id} is stopping (cancel acknowledged){self._where()}; '
                    f'{resume}')
        return (f'trial {trial_id}: cancel not acknowledged within {self.CANCEL_WAIT:.0f} s, '
                f'it may still be running (cobot-calib echo repeatability); {resume}')

    def _where(self) -> str:
        if self._last is None:
            return ''
        s = self._last.statistics
        return (f' in cycle {self._last.cycle + 1}/{s.cycles_total} ({s.method}, '
                f'{s.axis} axis)')

    def _feedback(self, msg) -> None:
        fb, previous = msg.feedback, self._last
        self._last, self._heard = fb, time.monotonic()
        s = fb.statistics
        if previous is None:                  # the first one, sent before the robot moves
            self._say(self._started_line(fb))
        if self._each_reading and fb.point_name and (fb.cycle, fb.point_index) != self._reading:
            self._reading = (fb.cycle, fb.point_index)       # not a heartbeat's repeat
            self._say(f'  cycle {fb.cycle + 1}/{s.cycles_total} {fb.point_name}: '
                      f'{fb.distance * 1e3:.4f} mm')
        if previous is not None and s.cycles_done != previous.statistics.cycles_done \
                and s.cycles_done >= 2:
            self._say(f'  {s.method}: cycle {s.cycles_done}/{s.cycles_total}  '
                      f'RP_all {s.rp_all_mm:.4f} mm')

    @staticmethod
    def _started_line(fb) -> str:
        """What the node is running: for a resume, the stored method, axis and cycles."""
        s = fb.statistics
        what = f'{s.method}, {s.axis} axis, {s.cycles_total} cycles'
        if not fb.resumed:
            return f'trial {s.trial_id}: {what}'
        return (f'resuming trial {s.trial_id}: {what}, from cycle {fb.cycle + 1} '
                f'({s.cycles_done} complete)')
