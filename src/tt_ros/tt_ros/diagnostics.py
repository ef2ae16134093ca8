"""A node's status on /diagnostics (diagnostic_msgs/DiagnosticArray), once a second of the
machine's steady clock, as diagnostic_updater publishes one: what ``ros2 topic echo
/diagnostics``, rqt_robot_monitor and diagnostic_aggregator read.

A status is (level, message, values): ``DiagnosticStatus.OK`` or ``WARN``, one line, and a
mapping of key to value (each value sent as its ``str``). The clock is steady so that a node on
simulated time (a bag played with ``--clock``) reports while /clock stands still.
"""

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType

DIAGNOSTICS_TOPIC = '/diagnostics'
PERIOD_S = 1.0
"""Time between two reports, s of the steady clock (diagnostic_updater's default)."""
OK, WARN = DiagnosticStatus.OK, DiagnosticStatus.WARN


def diagnostic_array(stamp, name, hardware_id, level, message, values):
    """A DiagnosticArray of one DiagnosticStatus, stamped ``stamp`` (builtin_interfaces/Time)."""
    status = DiagnosticStatus(name=name, hardware_id=hardware_id, level=level, message=message)
    status.values = [KeyValue(key=key, value=str(value)) for key, value in values.items()]
    msg = DiagnosticArray(status=[status])
    msg.header.stamp = stamp
    return msg


def report_status(node, what, hardware_id, status):
    """Publish ``status()`` (level, message, values) on /diagnostics every PERIOD_S of the
    steady clock, named ``'<node>: <what>'`` as diagnostic_updater names a status, the node by
    its full name (``robot1/prediction_node`` in /robot1: two robots' statuses had one name on
    the absolute /diagnostics; a walk-through, 6 Dec 2026); the timer."""
    name = f"{node.get_fully_qualified_name().lstrip('/')}: {what}"
    pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)

    def tick():
        level, message, values = status()
        pub.publish(diagnostic_array(node.get_clock().now().to_msg(), name, hardware_id, level,
                                     message, values))

    return node.create_timer(PERIOD_S, tick, clock=Clock(clock_type=ClockType.STEADY_TIME))


def percentile_values(key, p50_ms, p99_ms):
    """The values ``<key>_p50_ms`` and ``<key>_p99_ms`` of a time's median and p99, ms."""
    return {f'{key}_p50_ms': f'{p50_ms:.3f}', f'{key}_p99_ms': f'{p99_ms:.3f}'}


class CountsStatus:
    """The status of a node that counts what it did: ``report(counts)`` gives (level, the
    counts since the previous report, values): WARN when one of the counts named in
    ``warn_on`` grew since then, and as the values the totals ``counts`` with the callback's
    median and p99 over its latest calls (``work``, a :class:`tt_ros.worktime.CallbackTimes`).
    """

    def __init__(self, warn_on, work):
        self.warn_on, self.work = warn_on, work
        self._last = {}

    def report(self, counts):
        new = {key: value - self._last.get(key, 0) for key, value in counts.items()}
        self._last = dict(counts)
        level = WARN if any(new[key] for key in self.warn_on) else OK
        return level, new, {**counts, **percentile_values('callback',
                                                          *self.work.percentiles_ms())}
