"""The one way nodes declare parameters: a description that names the unit, and a range."""
from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node


def declare(node: Node, name: str, default, description: str,
            lo: float | None = None, hi: float | None = None, read_only: bool = False):
    """Declare ``name`` with its description (unit in brackets) and, given lo/hi, its range;
    returns the value it starts with (default, or from --params-file / -p)."""
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if lo is not None and hi is not None:
        if isinstance(default, int) and not isinstance(default, bool):
            descriptor.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi))]
        else:
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(lo),
                                                                  to_value=float(hi))]
    return node.declare_parameter(name, default, descriptor).value


def read_once(node: Node, name: str, default, description: str,
              lo: float | None = None, hi: float | None = None):
    """A parameter the node reads at start-up only: set it with -p / --params-file; a later
    set_parameters is refused (read-only) instead of succeeding and doing nothing."""
    return declare(node, name, default, f'{description} (read at start-up; restart the node '
                   'to change it)', lo, hi, read_only=True)
