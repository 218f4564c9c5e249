"""`cobot-calib view`: stream the suite's topics to Foxglove or Lichtblick, no ROS install needed.

A Foxglove WebSocket server (foxglove-sdk) on 127.0.0.1:8765 by default: open
ws://127.0.0.1:8765 in the Foxglove app or Lichtblick (Open connection -> Foxglove WebSocket).
Both names of the protocol are accepted (foxglove.sdk.v1, foxglove.websocket.v1: Lichtblick
and older Foxglove releases). Every topic on the exported ROS_DOMAIN_ID is offered (ros2msg
schema, cdr messages), the calibration markers on cobot_calib/markers included, and subscribed
on ROS only while a window shows it (no camera images rendered for nobody); latched topics are
sent once to each window that subscribes. Ctrl-C stops it.
"""
from __future__ import annotations

import sys

from cobot_calib_ros.cli.common import EXIT_OK, EXIT_USAGE, add_intermixed_parser, fail

DEFAULT_PORT = 8765


def add_parser(subparsers):
    p = add_intermixed_parser(
        subparsers, 'view', help='stream the suite\'s topics to Foxglove / Lichtblick '
        '(WebSocket on loopback)', description=__doc__.split('\n\n')[0])
    p.add_argument('topics', nargs='*', metavar='TOPIC',
                   help='topics to stream (default: every topic, except hidden ones)')
    p.add_argument('--host', default='127.0.0.1',
                   help='address to listen on (default 127.0.0.1: this machine only)')
    p.add_argument('--port', type=int, default=DEFAULT_PORT,
                   help=f'port (default {DEFAULT_PORT}; 0: any free one, printed)')
    return p


def run(args) -> int:
    if not 0 <= args.port <= 65535:
        return fail(f'view: --port {args.port}: give 0..65535', EXIT_USAGE)
    from cobot_calib_ros.ros import spin
    from cobot_calib_ros.api.live_view import LiveView

    def say(text: str) -> None:
        print(text, flush=True)

    def make_node():
        view = LiveView(args.host, args.port, args.topics, report=say)
        say(f'view: ws://{args.host}:{view.port} (Foxglove / Lichtblick: open a Foxglove '
            'WebSocket connection there; Ctrl-C stops)')
        return view
    try:
        spin.run(make_node, args=[sys.argv[0]])
    except (RuntimeError, OSError) as exc:   # the port is taken, the address is not ours
        return fail(f'view: cannot serve on {args.host}:{args.port}: {exc}; pick another '
                    '--port')
    return EXIT_OK
