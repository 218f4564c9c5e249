"""api.live_view in this process, against a publisher node of the test's own (issue 31 items 6
and 7): each client's subprotocol, latched messages once per connection, and a volatile topic
subscribed on ROS only while a window shows it."""
import threading
import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import deserialize_message
from std_msgs.msg import String

from cobot_calib_ros.api.live_view import LiveView
from cobot_calib_ros.ros import qos
from foxglove_ws import FoxgloveClient

LATCHED, STREAM = '/live_view_test/latched', '/live_view_test/stream'
GRAPH_TIMEOUT = 20.0


def wait_until(condition, timeout: float) -> bool:
    """The graph is DDS's: the fixture's thread spins the nodes, this only looks."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


@pytest.fixture(scope='module')
def view():
    """(LiveView, the publisher node, the stream's publisher), spun in a thread."""
    context = Context()
    rclpy.init(context=context)
    source = rclpy.create_node('live_view_test_source', context=context)
    latched = source.create_publisher(String, LATCHED, qos.LATCHED)
    latched.publish(String(data='the frame'))
    stream = source.create_publisher(String, STREAM, 10)
    source.create_timer(0.1, lambda: stream.publish(String(data='an image')))
    live = LiveView('127.0.0.1', 0, [LATCHED, STREAM], report=lambda _: None, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(source)
    executor.add_node(live)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)
    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        assert set(live.channels) == {LATCHED, STREAM}, live.channels
        yield live, latched, stream
    finally:
        stop.set()
        thread.join(5)
        live.destroy_node()
        source.destroy_node()
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize('offered', [('foxglove.websocket.v1',), ('foxglove.sdk.v1',),
                                     ('foxglove.sdk.v1', 'foxglove.websocket.v1')])
def test_each_client_connects_with_the_subprotocol_it_offers(view, offered):
    """Lichtblick and older Foxglove releases offer foxglove.websocket.v1 alone (HTTP 400 from
    foxglove-sdk 0.30.3 by itself), Foxglove's app foxglove.sdk.v1."""
    live, _, _ = view
    client = FoxgloveClient('127.0.0.1', live.port, protocols=offered)
    try:
        assert client.protocol == offered[0]
        channel, data = client.message(LATCHED, 10.0)
    finally:
        client.close()
    assert (channel['encoding'], channel['schemaName']) == ('cdr', 'std_msgs/msg/String')
    assert deserialize_message(data, String).data == 'the frame'


def _latched_in(client: FoxgloveClient, timeout: float, enough: int | None = None) -> list[str]:
    """The latched topic's messages that reach ``client`` within ``timeout`` s (or the first
    ``enough``)."""
    return [deserialize_message(p, String).data
            for p in client.collect(LATCHED, timeout, enough)]


def test_a_latched_message_arrives_once_per_connection(view):
    live, _, _ = view
    for _connection in range(2):
        client = FoxgloveClient('127.0.0.1', live.port)
        try:
            assert _latched_in(client, 3.0) == ['the frame']
        finally:
            client.close()


def test_a_volatile_topic_is_subscribed_only_while_a_window_shows_it(view):
    """What keeps mock_camera from rendering images for a view nobody watches."""
    live, latched, stream = view
    # the view's subscriptions are known to the publishers once its latched one is (+0.5 s)
    assert wait_until(lambda: latched.get_subscription_count() == 1, GRAPH_TIMEOUT)
    time.sleep(0.5)
    assert stream.get_subscription_count() == 0
    client = FoxgloveClient('127.0.0.1', live.port)
    try:
        _, data = client.message(STREAM, 10.0)
        assert deserialize_message(data, String).data == 'an image'
        assert stream.get_subscription_count() == 1
    finally:
        client.close()
    assert wait_until(lambda: stream.get_subscription_count() == 0, GRAPH_TIMEOUT), \
        'the view still subscribes to the stream after its only window closed'
    assert live.viewers[STREAM] == 0


def test_each_open_window_gets_each_latched_message_once(view):
    """A window that subscribes gets the kept message, the one already open nothing again; a
    new message reaches both once. Last in this module: it publishes a second message."""
    live, latched, _ = view
    first = FoxgloveClient('127.0.0.1', live.port)
    second = None
    try:
        assert _latched_in(first, 3.0, enough=1) == ['the frame']
        second = FoxgloveClient('127.0.0.1', live.port)
        assert _latched_in(second, 3.0) == ['the frame']       # and no second copy
        assert _latched_in(first, 0.5) == []
        latched.publish(String(data='the frame, moved'))
        assert _latched_in(first, 3.0) == _latched_in(second, 3.0) == ['the frame, moved']
    finally:
        first.close()
        if second is not None:
            second.close()
