"""A node's input, connected or not: one log line when its subscription gets its first
publisher and when it loses its last.

DDS discovery between two processes can take a second or two after both are up (measured:
strike_node matched prediction_node's /ball/prediction ~1.8 s after prediction_node was
ready, on this 2-core machine). Whatever is published before that is lost for a volatile
subscription. The line tells a user which link is up; bringup waits for it before it starts
a video file source (``tt_tools.bringup``), so that the first ball finds the chain connected.
"""

from rclpy.event_handler import SubscriptionEventCallbacks, UnsupportedEventTypeError

CONNECTED = 'connected'
"""The word of the line ``<topic>: connected (<n> publisher(s))``."""
DISCONNECTED = 'no publisher left'
"""The line ``<topic>: no publisher left``."""


def input_events(node, topic):
    """Event callbacks for ``node``'s subscription of ``topic`` (``create_subscription(...,
    event_callbacks=...)``) that log ``<topic>: connected (<n> publisher(s))`` when it gets
    its first matched publisher and ``<topic>: no publisher left`` when the last one goes."""

    def matched(info):
        if info.current_count > 0 and info.current_count == info.current_count_change:
            node.get_logger().info(f'{topic}: {CONNECTED} ({info.current_count} '
                                   f'publisher{"s" if info.current_count > 1 else ""})')
        elif info.current_count == 0 and info.current_count_change < 0:
            node.get_logger().info(f'{topic}: {DISCONNECTED}')

    return SubscriptionEventCallbacks(matched=matched)


def subscribe_input(node, msg_type, topic, callback, qos):
    """``node.create_subscription(msg_type, topic, callback, qos)`` with :func:`input_events`;
    without them, and a warning, on a middleware that has no matched events (bringup then
    waits its limit for the line). The lines name the topic as resolved: namespace and
    remapping applied (the subscription is made with ``topic`` as given: rcl remaps it once).
    """
    name = node.resolve_topic_name(topic)
    try:
        return node.create_subscription(msg_type, topic, callback, qos,
                                        event_callbacks=input_events(node, name))
    except UnsupportedEventTypeError:
        node.get_logger().warning(f'{name}: this middleware does not report matched '
                                  'publishers; no connected line')
        return node.create_subscription(msg_type, topic, callback, qos)
