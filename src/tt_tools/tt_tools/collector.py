"""An rclpy node that watches the graph and collects the robot's outputs (demo, tests, bench).

Messages are converted on arrival into plain dicts of numpy arrays (``to_record``), so the
analysis in ``demo_report`` needs no ROS.
"""

import time

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy

from tt_msgs.msg import BallPrediction, BallState, StrikeCommand
from tt_tools.rosutil import leave_graph, run_waiting


def stamp_s(stamp):
    """builtin_interfaces/Time -> seconds (float)."""
    return stamp.sec + 1e-9 * stamp.nanosec


def _vec(v):
    return np.array([v.x, v.y, v.z])


def state_record(msg):
    """BallState -> dict (t, track, p, v, w, cov (9, 9))."""
    return {'t': stamp_s(msg.header.stamp), 'track': msg.track_id, 'p': _vec(msg.position),
            'v': _vec(msg.velocity), 'w': _vec(msg.spin),
            'cov': np.asarray(msg.covariance, dtype=float).reshape(9, 9)}


def prediction_record(msg):
    """BallPrediction -> dict."""
    return {'t': stamp_s(msg.header.stamp), 'track': msg.track_id, 'status': msg.status,
            'bounce_valid': msg.bounce_valid, 'bounce_t': stamp_s(msg.bounce_time),
            'bounce_p': _vec(msg.bounce_point), 'bounce_zone': msg.bounce_zone,
            'bounce_half': msg.bounce_half, 'hit_valid': msg.hit_valid,
            'hit_t': stamp_s(msg.hit_time), 'hit_p': _vec(msg.hit_point),
            'hit_v': _vec(msg.hit_velocity), 'hit_w': _vec(msg.hit_spin)}


def command_record(msg):
    """StrikeCommand -> dict."""
    return {'t': stamp_s(msg.header.stamp), 'track': msg.track_id, 'status': msg.status,
            'feasible': msg.feasible, 'reason': msg.reason, 'hit_t': stamp_s(msg.hit_time),
            'hit_p': _vec(msg.hit_point), 'normal': _vec(msg.racket_normal),
            'racket_v': _vec(msg.racket_velocity), 'racket_p': _vec(msg.racket_position),
            'landing_p': _vec(msg.landing_point), 'landing_zone': msg.landing_zone,
            'target_zone': msg.target_zone, 'in_zone_probability': msg.in_zone_probability}


TOPICS = {'/ball/state': (BallState, state_record),
          '/ball/prediction': (BallPrediction, prediction_record),
          '/strike/command': (StrikeCommand, command_record)}


class Collector:
    """Own context, node and executor; ``spin_once`` returns False so it chains in conditions."""

    def __init__(self, image_topics=(), name='tt_collector', topics=tuple(TOPICS)):
        self.image_topics = tuple(image_topics)
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.records = {topic: [] for topic in topics}
        self.arrival = {topic: [] for topic in topics}
        self.last_arrival = time.monotonic()
        self._count = 0                  # messages taken, all topics
        # Best effort matches every publisher (reliable ones too); depth covers a burst.
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
        for topic in topics:
            msg_type, convert = TOPICS[topic]
            self.node.create_subscription(msg_type, topic, self._callback(topic, convert), qos)

    def _callback(self, topic, convert):
        def callback(msg):
            self._count += 1
            now = time.monotonic()
            self.records[topic].append(convert(msg))
            self.arrival[topic].append(time.time())
            self.last_arrival = now
        return callback

    def spin_once(self, timeout=0.02):
        """Take every message waiting (waiting up to ``timeout`` s for the first one), so a
        caller polling a condition never falls behind the graph. Returns False."""
        self.executor.spin_once(timeout_sec=timeout)
        run_waiting(self.executor, lambda: self._count)
        return False

    def graph_ready(self, state_subscribers=3):
        """True once perception listens to every camera topic, prediction and strike listen to
        their inputs, and the recorder listens to the outputs. ``state_subscribers``: the
        subscriptions of /ball/state there must be (prediction, the recorder, this collector;
        2 before perception starts: the recorder subscribes once it sees a publisher)."""
        node = self.node
        return (all(node.count_subscribers(t) >= 1 for t in self.image_topics)
                and node.count_subscribers('/ball/state') >= state_subscribers
                and node.count_subscribers('/ball/prediction') >= 3
                and node.count_subscribers('/strike/command') >= 2
                and node.count_publishers('/strike/command') >= 1)

    def watch_diagnostics(self, name, topic='/diagnostics'):
        """A dict of the key/values of the statuses called ``name`` on ``topic``
        (diagnostic_msgs/DiagnosticArray), updated as they arrive (newest values win)."""
        from diagnostic_msgs.msg import DiagnosticArray

        values = {}

        def on_diagnostics(msg):
            for status in msg.status:
                if status.name == name:
                    values.update({kv.key: kv.value for kv in status.values})

        self.node.create_subscription(DiagnosticArray, topic, on_diagnostics, 10)
        return values

    def quiet_for(self, seconds):
        return time.monotonic() - self.last_arrival > seconds

    def outputs(self):
        return {topic: list(records) for topic, records in self.records.items()}

    def close(self):
        leave_graph(self.executor, self.node, self.context)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
