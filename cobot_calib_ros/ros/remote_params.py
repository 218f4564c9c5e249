"""Another node's parameters through its parameter services, as `ros2 param` reads and sets them
(rclpy's AsyncParameterClient, waited on with ros.calls.spin_until)."""
from __future__ import annotations

import time
from typing import Any

from cobot_calib_ros.ros import calls
from cobot_calib_ros.ros.calls import CallError, first_answer, spin_until


class RemoteParameters:
    """The parameters of node ``target`` seen from ``node``: '/ns/mock_robot', or a relative
    name ('mock_robot') in ``node``'s namespace, as service names resolve. Every call raises
    CallError when the node does not answer within ``timeout`` [s]."""

    def __init__(self, node, target: str, timeout: float = 5.0) -> None:
        from rclpy.parameter_client import AsyncParameterClient
        self.node, self.timeout, self.target = node, timeout, target
        self._client = AsyncParameterClient(node, target)

    def names(self) -> list[str]:
        """Every declared parameter, sorted."""
        return sorted(self._answer(lambda c: c.list_parameters(), 'list').result.names)

    def get(self, name: str):
        """The rcl_interfaces ParameterValue of ``name`` (type PARAMETER_NOT_SET: not declared)."""
        from rcl_interfaces.msg import ParameterValue
        values = self._answer(lambda c: c.get_parameters([name]), f'get {name}').values
        return values[0] if values else ParameterValue()    # rclpy answers none if undeclared

    def set(self, name: str, value: Any) -> tuple[bool, str]:
        """(successful, reason) of setting ``name`` to the Python ``value``."""
        from rclpy.parameter import Parameter
        response = self._answer(lambda c: c.set_parameters([Parameter(name, value=value)]),
                                f'set {name}')
        return response.results[0].successful, response.results[0].reason

    def _answer(self, send, what: str):
        deadline = time.monotonic() + self.timeout
        if not spin_until(self.node, self._client.services_are_ready, self.timeout):
            raise CallError(f'node {self.target} offers no parameter services within '
                            f'{self.timeout:g} s (is it running? see `cobot-calib list`)')
        # parameter requests are idempotent: sent again while unanswered (calls.ASK_AGAIN)
        answered = first_answer(self.node, lambda: send(self._client),
                                deadline - time.monotonic(), calls.ASK_AGAIN)
        if answered is None:
            raise CallError(f'{self.target} did not answer {what} within {self.timeout:g} s')
        return answered.result()


def read_parameter(node, target: str, name: str, timeout: float = 5.0):
    """The Python value of parameter ``name`` of node ``target``; CallError when the node does
    not answer or has no such parameter."""
    from rclpy.parameter import parameter_value_to_python
    from rcl_interfaces.msg import ParameterType
    remote = RemoteParameters(node, target, timeout)
    value = remote.get(name)
    if value.type == ParameterType.PARAMETER_NOT_SET:
        raise CallError(f'{remote.target} has no parameter {name!r}')
    return parameter_value_to_python(value)
