"""`cobot-calib call` of a query service sends its request again when no answer comes: DDS
drops a response written before the server's response writer matched the client's reader
(/user_to_robot waited 120 s on a live server at load 25). A request that changes something
is never sent twice."""
from types import SimpleNamespace

import domain_coordinator
import pytest
from rclpy.task import Future

from cobot_calib_msgs.srv import CalibrateUserFrame, ConvertPoints
from cobot_calib_ros.cli import call
from cobot_calib_ros.ros.calls import CallError
from cobot_calib_ros.ros.session import session


class LosesTheFirstAnswer:
    """A service client whose first request's answer never arrives (as DDS lost it)."""

    def __init__(self, client) -> None:
        self._client, self.srv_name, self.sent = client, client.srv_name, 0

    def service_is_ready(self) -> bool:
        return self._client.service_is_ready()

    def call_async(self, request) -> Future:
        self.sent += 1
        return Future() if self.sent == 1 else self._client.call_async(request)

    def remove_pending_request(self, future) -> None:
        self._client.remove_pending_request(future)


@pytest.fixture
def node(monkeypatch):
    monkeypatch.setattr(call, 'RESEND_AFTER', 0.5)
    with domain_coordinator.domain_id() as domain, session('resend_test',
                                                           domain_id=domain) as (node, _):
        yield node


def _answer(node, srv_type, name: str, args) -> tuple[LosesTheFirstAnswer, object]:
    client = LosesTheFirstAnswer(node.create_client(srv_type, name))
    return client, call._answer(node, client, srv_type.Request(), args, call._Progress(node),
                                query=call._srv(f'cobot_calib_msgs/{srv_type.__name__}')
                                in call.QUERY_TYPES)


def test_a_query_whose_answer_was_lost_is_asked_again(node):
    def convert(request, response):
        response.message = 'converted'
        return response

    node.create_service(ConvertPoints, 'user_to_robot', convert)
    client, response = _answer(node, ConvertPoints, 'user_to_robot',
                               SimpleNamespace(timeout=10.0, answer_timeout=30.0))
    assert response.message == 'converted' and client.sent == 2


def test_a_calibration_is_never_sent_twice(node):
    node.create_service(CalibrateUserFrame, 'calibrate_user_frame',
                        lambda request, response: response)
    client = LosesTheFirstAnswer(node.create_client(CalibrateUserFrame, 'calibrate_user_frame'))
    with pytest.raises(CallError, match='no answer from calibrate_user_frame within 3 s'):
        call._answer(node, client, CalibrateUserFrame.Request(),
                     SimpleNamespace(timeout=10.0, answer_timeout=3.0), call._Progress(node))
    assert client.sent == 1
