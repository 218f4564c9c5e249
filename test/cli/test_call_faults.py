"""`cobot-calib call` against a server that is gone (issue 22.7): real processes, real signals.

A server whose node has left the graph is named within seconds (not after --timeout), and a
server killed while its answer is awaited ends the wait (not forever) naming its node."""
import os
import subprocess
import sys
import time

import pytest

from machine import short_lease
from proc_lines import Lines

SERVICE = '/doomed_capture'
# A node serving SERVICE; its callback prints 'asked', then answers at once (argv[1] 'answer')
# or never (argv[1] 'hang', a hung server). SIGINT: it shuts down and leaves the graph.
SERVER = f'''
import sys, threading, rclpy
from rclpy.executors import ExternalShutdownException
from cobot_calib_msgs.srv import CaptureJoints
rclpy.init()
node = rclpy.create_node('doomed_server')
def serve(request, response):
    print('asked', flush=True)
    if sys.argv[1] == 'hang':
        threading.Event().wait()
    return response
node.create_service(CaptureJoints, '{SERVICE}', serve)
print('serving', flush=True)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
'''
# A node with no service of interest: the graph a client sees is not empty.
BYSTANDER = '''
import rclpy
rclpy.init()
node = rclpy.create_node('bystander')
try:
    rclpy.spin(node)
except KeyboardInterrupt:
    pass
'''


def _python(code: str, *args: str, env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-c', code, *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env or dict(os.environ))


def _call(*args) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, '-m', 'cobot_calib_ros.cli.main', 'call', SERVICE,
                             *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ))


@pytest.fixture
def bystander(domain_id):
    proc = _python(BYSTANDER)
    yield proc
    proc.kill()
    proc.wait()


def _server(mode: str):
    # the hung server is killed: off the graph 6 s later (not after the default 20 s lease)
    proc = _python(SERVER, mode, env=short_lease(dict(os.environ)) if mode == 'hang' else None)
    proc.lines = Lines(proc.stdout)
    try:
        _line(proc, 'serving')
        yield proc
    finally:
        proc.kill()
        proc.wait()


@pytest.fixture
def answering_server(domain_id):
    yield from _server('answer')


@pytest.fixture
def hung_server(domain_id):
    yield from _server('hang')


def _line(server: subprocess.Popen, expected: str, timeout: float = 60.0) -> None:
    """Until the server prints ``expected``. The session's Fast DDS profile sends Fast DDS's
    own errors to stderr (an SHM port another process holds: 'RTPS_TRANSPORT_SHM Error ...
    open_and_lock_file failed', harmless), but a profile without that log section prints them
    on stdout, so the server's first line need not be the one; and its stderr is read only once
    it has exited (a read of a running server's waits for its end)."""
    if server.lines.match(rf'^{expected}$', timeout) is None:
        server.kill()
        pytest.fail(f'no {expected!r} from the server within {timeout} s: '
                    f'{"".join(server.lines.seen)}{server.communicate()[1]}')


def test_a_server_that_left_the_graph_is_named_long_before_the_timeout(bystander,
                                                                      answering_server):
    server = answering_server
    asking = _call('{duration: 0.1}')           # the server is on the graph and answers
    _, err = asking.communicate(timeout=60)
    assert asking.returncode == 0, err
    _line(server, 'asked')
    server.send_signal(2)                       # SIGINT: the node leaves the graph at once
    server.wait(timeout=30)
    started = time.monotonic()
    proc = _call('{duration: 0.1}', '--timeout', '60')
    _, err = proc.communicate(timeout=90)
    waited = time.monotonic() - started
    assert proc.returncode == 1, err
    assert err.startswith(f'no server for {SERVICE}: ') and 'is its node running?' in err, err
    assert 'Traceback' not in err
    assert waited < 20.0, f'{waited:.1f} s: the old client waited the whole 60 s --timeout'


def test_a_server_killed_while_it_is_asked_ends_the_wait_naming_its_node(hung_server):
    server = hung_server
    proc = _call('{duration: 0.1}')             # no --answer-timeout: waits for the answer
    _line(server, 'asked')
    server.kill()                               # kill -9: off the graph when its lease ends
    started = time.monotonic()
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail('call still waiting 60 s after its server was killed')
    assert proc.returncode == 1, err
    assert f'no server for {SERVICE} any more: the doomed_server node is gone' in err, err
    assert 'Traceback' not in err
    assert time.monotonic() - started < 60.0
