"""A node's input, connected or not: one log line when its subscription gets its first
publisher and when it loses its last; and the messages it lost before its callback took
them (:class:`LostMessages`).

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


UNKNOWN_SEQUENCE = 2 ** 64 - 1
"""rmw's publication sequence number where the middleware gives none
(RMW_MESSAGE_INFO_SEQUENCE_NUMBER_UNSUPPORTED)."""


class LostMessages:
    """Messages an input lost before its callback took them: a queue full (a reliable
    subscription's depth, a best-effort one's), or a best-effort sample the network lost.
    They are the gaps in the publisher's sequence numbers (the message info's
    ``publication_sequence_number``, which Fast DDS gives), counted while the topic has one
    publisher: two publishers' numbers interleave, and one started again starts from 1."""

    def __init__(self):
        self.count = 0
        """Messages lost so far."""
        self.publishers = lambda: 1
        """() -> the topic's publishers now (:func:`subscribe_input` sets it)."""
        self._last = None

    def taken(self, sequence):
        """The callback took the message numbered ``sequence``."""
        if sequence == UNKNOWN_SEQUENCE:
            return
        last, self._last = self._last, sequence
        if last is not None and sequence > last + 1 and self.publishers() == 1:
            self.count += sequence - last - 1


def subscribe_input(node, msg_type, topic, callback, qos, lost=None):
    """``node.create_subscription(msg_type, topic, callback, qos)`` with :func:`input_events`;
    without them, and a warning, on a middleware that has no matched events (bringup then
    waits its limit for the line). The lines name the topic as resolved: namespace and
    remapping applied (the subscription is made with ``topic`` as given: rcl remaps it once).
    ``lost``: a :class:`LostMessages` that counts what this input loses (the subscription then
    takes each message's info).
    """
    name = node.resolve_topic_name(topic)
    take = callback
    if lost is not None:
        lost.publishers = lambda: node.count_publishers(name)

        def take(msg, info):
            lost.taken(info['publication_sequence_number'])
            callback(msg)

    try:
        return node.create_subscription(msg_type, topic, take, qos,
                                        event_callbacks=input_events(node, name))
    except UnsupportedEventTypeError:
        node.get_logger().warning(f'{name}: this middleware does not report matched '
                                  'publishers; no connected line')
        return node.create_subscription(msg_type, topic, take, qos)
