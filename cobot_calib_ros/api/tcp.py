"""Client side of the TCP calibration (tcp_calibrator's ``calibrate_tcp``): used by
``cobot-calib tcp``."""
from __future__ import annotations

TCP_TIMEOUT = 1200.0   # [s] for the whole calibration (an operator confirms every touch)


def calibrate_tcp(node, goal, timeout: float = TCP_TIMEOUT, feedback=None, executor=None):
    """Run calibrate_tcp with ``goal`` (CalibrateTcp.Goal) to its end; the result (CallError
    if the action is missing or does not finish in time; a failed calibration comes back with
    its error_code)."""
    from cobot_calib_msgs.action import CalibrateTcp
    from cobot_calib_ros.ros.action_client import ActionClient
    from cobot_calib_ros.ros.calls import run_action
    client = ActionClient(node, CalibrateTcp, 'calibrate_tcp')
    try:
        _, result = run_action(node, client, goal, timeout, feedback, executor)
    finally:
        client.destroy()
    return result
