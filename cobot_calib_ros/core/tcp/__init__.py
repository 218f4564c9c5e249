"""The tool centre point (issue 30): the tool tip brought to one fixed point from N orientations.

- :mod:`.solve`: position ([R_i | -I][t; c] = -p_i by SVD with a rank test naming approaches
  too alike, then a robust refinement), orientation from elongator points (ABB's 5- and
  6-point methods), and the gate a result must pass to become active;
- :mod:`.touches`: the approach plan and the touch procedure over a core.robot_port.RobotPort
  (tcp_calibrator over ROS, the bench and the tests over the simulation).
"""
from cobot_calib_ros.core.tcp.solve import (GateLimits, gate_problem, solve_position,
                                            solve_tcp, TcpPosition, TcpSolution, too_alike,
                                            tool_orientation)

__all__ = ['GateLimits', 'gate_problem', 'solve_position', 'solve_tcp', 'TcpPosition',
           'TcpSolution', 'too_alike', 'tool_orientation']
