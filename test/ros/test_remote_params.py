"""ros.remote_params: an unanswered parameter request is sent again (a server that had not yet
matched the client's reply reader dropped its answer, and `demo --attach` waited out its 15 s
in a loaded test run), and a node that never answers is still refused at the timeout. A fake
parameter client and executor: which request is answered is scripted, not timed."""
import time

import pytest
import rclpy.parameter_client
from rcl_interfaces.msg import ParameterType, ParameterValue

from cobot_calib_ros.ros import calls, remote_params
from cobot_calib_ros.ros.calls import CallError


class Future:
    def __init__(self, answer=None):
        self.answer = answer

    def done(self) -> bool:
        return self.answer is not None

    def result(self):
        return self.answer


class ScriptedClient:
    """get_parameters answers the requests whose index is in ``answered`` (None: never)."""
    answered: set[int] = set()

    def __init__(self, node, target) -> None:
        self.requests = 0

    def services_are_ready(self) -> bool:
        return True

    def get_parameters(self, names):
        index, self.requests = self.requests, self.requests + 1
        if index not in self.answered:
            return Future()
        return Future(type('Response', (), {'values': [ParameterValue(
            type=ParameterType.PARAMETER_STRING, string_value='sawyer_close')]})())


class Executor:
    def spin_once(self, timeout_sec: float) -> None:
        time.sleep(timeout_sec)


@pytest.fixture
def remote(monkeypatch):
    monkeypatch.setattr(rclpy.parameter_client, 'AsyncParameterClient', ScriptedClient)
    monkeypatch.setattr(calls, 'ASK_AGAIN', 0.1)
    node = type('Node', (), {'executor': Executor()})()
    return remote_params.RemoteParameters(node, 'user_frame_solver', timeout=2.0)


def test_a_dropped_answer_is_asked_for_again(remote, monkeypatch):
    monkeypatch.setattr(ScriptedClient, 'answered', {1})
    assert remote.get('cell_file').string_value == 'sawyer_close'
    assert remote._client.requests == 2


def test_a_node_that_never_answers_is_refused_at_the_timeout(remote, monkeypatch):
    monkeypatch.setattr(ScriptedClient, 'answered', set())
    start = time.monotonic()
    with pytest.raises(CallError, match='user_frame_solver did not answer get cell_file '
                                        'within 2 s'):
        remote.get('cell_file')
    assert 1.9 <= time.monotonic() - start < 10.0
    assert remote._client.requests >= 2


class ScriptedService:
    """A service client whose requests listed in ``answered`` (0-based) get an answer."""

    srv_name = '/get_ground_truth'

    def __init__(self, answered) -> None:
        self.answered, self.requests, self.forgotten = answered, 0, []

    def service_is_ready(self) -> bool:
        return True

    def call_async(self, request):
        index, self.requests = self.requests, self.requests + 1
        return Future(f'answer {index}') if index in self.answered else Future()

    def remove_pending_request(self, future) -> None:
        self.forgotten.append(future)


@pytest.mark.parametrize('idempotent, answer, requests', [(True, 'answer 1', 2),
                                                            (False, None, 1)])
def test_an_idempotent_call_whose_answer_was_dropped_is_sent_again(monkeypatch, idempotent,
                                                                   answer, requests):
    """The first answer is dropped: a query is asked again and answered; any other request is
    sent once and refused at the timeout, its pending request removed."""
    monkeypatch.setattr(calls, 'ASK_AGAIN', 0.1)
    client = ScriptedService(answered={1})
    node = type('Node', (), {'executor': Executor()})()
    if answer is None:
        with pytest.raises(CallError, match='did not answer within 1.0 s'):
            calls.call_service(node, client, object(), 1.0, idempotent=idempotent)
    else:
        assert calls.call_service(node, client, object(), 1.0, idempotent=idempotent) == answer
    assert client.requests == requests and len(client.forgotten) == 1
