"""The ROS graph as a client sees it: discovery snapshots, publishers, a matching QoS."""
from __future__ import annotations

import time

from rclpy.action.graph import get_action_names_and_types
from rclpy.node import Node

from cobot_calib_ros.ros.calls import spin_until

GRAPH_POLL = 0.1          # [s] between graph snapshots
# [s] unchanged graph that ends a discovery wait (after its minimum): a participant whose
# discovery traffic was missed shows at its next periodic announcement (Fast DDS: every 3 s),
# so a graph that changed within the last period may still grow: a `list` ended 0.5 s after
# its 6 s minimum without /mock_robot (fresh-clone run U, 3 test workers)
GRAPH_SETTLE = 3.5
# Fast DDS finds most remote nodes within 0.1 s, but often one or two only when their next
# periodic discovery traffic comes (every 3 s): measured here (2 CPUs under load), the last
# suite node showed up as late as 3.5 s after start, after gaps of up to 2.4 s with no change
# at all, so "unchanged for a while" alone ends too early. Wait this long at least (4 s missed
# nodes of the 9-process suite when three `list` ran at once).
DISCOVERY_MIN_WAIT = 6.0  # [s]
_PARAMETER_SERVICES = ('_parameters', '_parameter_types', 'describe_parameters',
                       'set_parameters_atomically', 'get_type_description')


def graph(node: Node, max_wait: float = 10.0, min_wait: float = DISCOVERY_MIN_WAIT,
          settle: float = GRAPH_SETTLE, done=None) -> dict[str, dict[str, list[str]]]:
    """Nodes, topics, services and actions with their types, once discovery is over: the
    graph has been unchanged for `settle` s after at least `min_wait` s and names every node
    whose parameter services it has found (unlisted_nodes), or done(graph); at most
    `max_wait` s."""
    start = time.monotonic()
    current, changed = graph_now(node), start
    while not (done is not None and done(current)):
        now = time.monotonic()
        if now - start >= max_wait or (now - start >= min_wait and now - changed >= settle
                                       and not unlisted_nodes(node, current)):
            break
        spin_until(node, lambda: False, min(GRAPH_POLL, max_wait - (now - start)))
        latest = graph_now(node)
        if latest != current:
            current, changed = latest, time.monotonic()
    return current


def unlisted_nodes(node: Node, found: dict) -> list[str]:
    """Nodes whose parameter services discovery has found but that ``found`` (a graph_now)
    does not name yet: a node's name comes from its participant's ros_discovery_info sample,
    its services from endpoint discovery, and either can come seconds after the other on a
    loaded machine (a `list` once missed /user_frame_solver after its 6 s wait)."""
    own = node.get_fully_qualified_name()
    suffix = '/get_parameters'
    named = {n[:-len(suffix)] for n, _ in node.get_service_names_and_types()
             if n.endswith(suffix)}
    return sorted(n for n in named - set(found['nodes']) - {own}
                  if not n.rsplit('/', 1)[-1].startswith('_'))


def graph_now(node: Node) -> dict[str, dict[str, list[str]]]:
    """What discovery has found so far (hidden nodes and parameter services left out)."""
    own = node.get_fully_qualified_name()
    nodes = sorted(f'{ns.rstrip("/")}/{n}' for n, ns in node.get_node_names_and_namespaces()
                   if not n.startswith('_'))      # hidden nodes, as ros2 node list does
    topics = {n: t for n, t in node.get_topic_names_and_types()
              if not any(h in n for h in ('/_action/', '/rosout', '/parameter_events'))}
    services = {n: t for n, t in node.get_service_names_and_types()
                if '/_action/' not in n and not n.startswith(own + '/')
                and not n.rsplit('/', 1)[-1].endswith(_PARAMETER_SERVICES)}
    actions = dict(get_action_names_and_types(node))
    return {'nodes': {n: [] for n in nodes if n != own}, 'topics': topics,
            'services': services, 'actions': actions}


def wait_for_publishers(node: Node, topic: str, timeout: float,
                        settle: float = 0.3) -> list:
    """The topic's publishers once one is discovered and no other showed up for `settle` s
    (empty if none within `timeout` s)."""
    deadline = time.monotonic() + timeout
    found: list = []

    def seen() -> bool:
        found[:] = node.get_publishers_info_by_topic(topic)
        return bool(found)
    if not spin_until(node, seen, timeout):
        return []
    while time.monotonic() < deadline:
        count = len(found)
        spin_until(node, lambda: False, min(settle, deadline - time.monotonic()))
        if seen() and len(found) == count:
            break
    return found


def subscription_qos(publishers: list, depth: int = 100):
    """QoS that matches every publisher, as `ros2 topic echo` picks it: best effort if any
    publisher is best effort, transient local only if all of them are."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    qos = QoSProfile(depth=depth)
    if any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in publishers):
        qos.reliability = ReliabilityPolicy.BEST_EFFORT
    if publishers and all(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
                          for p in publishers):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
    return qos


def is_hidden(topic: str) -> bool:
    """A hidden topic, as ros2 topic list hides it (a name part starting with '_')."""
    return any(part.startswith('_') for part in topic.split('/'))


def new_topics(node: Node, taken, skipped, wanted: set[str] | None,
               include_hidden: bool = False) -> list[str]:
    """Topics on the graph not yet ``taken`` or ``skipped``: the ``wanted`` ones, or every
    topic (hidden ones only if ``include_hidden``) when ``wanted`` is None. The recorder and
    the live view take topics as they appear."""
    return [name for name, _types in node.get_topic_names_and_types()
            if name not in taken and name not in skipped
            and (name in wanted if wanted is not None else include_hidden or not is_hidden(name))]
