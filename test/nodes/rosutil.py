"""Calls the node tests make from their client node (`ros` fixture) or through the CLI."""
import os
import subprocess
import sys

from cobot_calib_ros.ros.calls import call_service, spin_until


def call(node, srv_type, name, timeout=10.0, **fields):
    """One service call with the request fields given; the response."""
    client = node.create_client(srv_type, name)
    request = srv_type.Request(**fields)
    try:
        return call_service(node, client, request, timeout, node.executor_for_tests)
    finally:
        node.destroy_client(client)


def listen_late(node, msg_type, topic, profile, done, timeout=10.0) -> list:
    """The messages a new (late-joining) subscriber got until done(messages) or the timeout."""
    got = []
    sub = node.create_subscription(msg_type, topic, got.append, profile)
    try:
        spin_until(node, lambda: done(got), timeout, node.executor_for_tests)
    finally:
        node.destroy_subscription(sub)
    return got


def cli_command(*args) -> list[str]:
    return [sys.executable, '-m', 'cobot_calib_ros.cli.main', *args]


def cli(*args, timeout=30.0) -> subprocess.CompletedProcess:
    """Run `cobot-calib ARGS` on the session's domain; its completed process."""
    return subprocess.run(cli_command(*args), capture_output=True, text=True,
                          timeout=timeout, env=dict(os.environ))
