"""prediction_node on a live graph: fresh Context per test, executors spun until a condition
holds (no sleeps), topics remapped to names no other test on this machine uses.

The node runs on simulated time (use_sim_time) from a /clock the test publishes (remapped as
well), so whether a state is stale depends on its stamp and that clock, never on how long the
test takes: the stamps are set at or after the clock's time T0."""

import math
import os
import pathlib
import signal
import subprocess
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Path
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from tt_prediction.integrate import rollout
from tt_prediction.node import PredictionNode
from tt_prediction.params import ModelParams
from tt_prediction.predict import predict
from tt_ros.executor import EXECUTOR_ENV, StartupError, make_executor
from tt_ros.testing import remap_args, unique_prefix
import yaml

from tt_msgs.msg import BallPrediction, BallState
from tt_ros import testing

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config' / 'prediction.yaml'
GOOD = [1.6, 0.1, 0.3, -6.0, 0.0, 1.5, 0.0, 100.0, 0.0]
COV = np.diag([1e-6] * 3 + [1e-2] * 3 + [100.0] * 3)
T0 = 1_000_000_000_000
"""The simulated time the test's /clock gives the node, ns."""


class Graph(testing.Graph):
    """A prediction node and a test node in one fresh context and executor."""

    def __init__(self, overrides=(), args=None):
        super().__init__(args=args)
        self.prefix = unique_prefix()
        remap = remap_args(self.prefix, ('/ball/state', '/ball/prediction',
                                         '/ball/predicted_path', '/tt/markers', '/clock',
                                         '/diagnostics'))
        self.node = self.add(PredictionNode(
            context=self.context, cli_args=remap,
            parameter_overrides=[rclpy.parameter.Parameter('use_sim_time', value=True),
                                 *overrides]))
        self.test = self.create_node()
        self.clock_pub = self.test.create_publisher(
            Clock, f'{self.prefix}/clock',
            QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.predictions, self.paths = [], []
        self.test.create_subscription(BallPrediction, f'{self.prefix}/ball/prediction',
                                      self.predictions.append, 50)
        self.test.create_subscription(Path, f'{self.prefix}/ball/predicted_path',
                                      self.paths.append, 50)
        self.pub = self.test.create_publisher(BallState, f'{self.prefix}/ball/state',
                                              qos_profile_sensor_data)
        self.spin_until(lambda: self.pub.get_subscription_count() > 0
                        and self.clock_pub.get_subscription_count() > 0
                        and self.test.count_publishers(f'{self.prefix}/ball/prediction') > 0,
                        10.0, 'discovery')
        self.set_clock(T0)

    def set_clock(self, t_ns):
        """Give the node the simulated time ``t_ns`` (ns) and spin until it has it."""
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(t_ns, 1_000_000_000)

        def arrived():
            if self.node.get_clock().now().nanoseconds == t_ns:
                return True
            self.clock_pub.publish(msg)         # best effort, as /clock is: again until seen
            return False

        self.spin_until(arrived, 10.0, f'the node clock at {t_ns} ns')

    def state(self, values, stamp_ns=T0, track_id=1, cov=COV):
        msg = BallState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        msg.header.frame_id = 'table'
        (msg.position.x, msg.position.y, msg.position.z, msg.velocity.x, msg.velocity.y,
         msg.velocity.z, msg.spin.x, msg.spin.y, msg.spin.z) = [float(v) for v in values]
        msg.covariance = np.asarray(cov, dtype=float).ravel().tolist()
        msg.track_id = track_id
        return msg


@pytest.fixture
def graph():
    g = Graph()
    yield g
    g.close()


def ns(t):
    return t.sec * 1_000_000_000 + t.nanosec


def publish_until(graph, make_msg, condition, what, timeout=20.0):
    """Publish states from make_msg(k), each once the node has taken the previous one, until
    condition() holds."""
    deadline = time.monotonic() + timeout
    k = 0
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f'timed out waiting for {what}')
        graph.pub.publish(make_msg(k))
        k += 1
        graph.spin_until(lambda k=k: graph.node.n_received >= k, 10.0, f'state {k}')
        graph.spin_until(lambda: len(graph.predictions) + graph.node.n_dropped
                         >= graph.node.n_received, 10.0, 'its prediction')


def test_a_state_gives_a_prediction_stamped_with_the_state_and_a_path(graph):
    # The covariance is propagated in a worker thread: its result comes with a later
    # prediction of the same track.
    t0 = T0
    msgs = []

    def make(k):
        msgs.append(graph.state(GOOD, stamp_ns=t0 + k * 25_000_000, track_id=7))
        return msgs[-1]

    publish_until(graph, make, lambda: graph.predictions and graph.paths
                  and any(graph.predictions[-1].hit_covariance), 'uncertainty')
    first = graph.predictions[0]
    assert first.zone_probabilities[first.bounce_zone] == 1.0     # before any propagation
    msg, out = msgs[-1], graph.predictions[-1]
    stamp = ns(msg.header.stamp)
    expected = predict(GOOD)                     # the same ball, times relative to the stamp
    assert out.header.stamp == msg.header.stamp and out.track_id == 7
    assert out.status == 'ok' and out.bounce_valid and out.hit_valid
    assert ns(out.bounce_time) - stamp == pytest.approx(expected.bounce.t * 1e9, abs=2)
    assert ns(out.hit_time) - stamp == pytest.approx(expected.hit.t * 1e9, abs=2)
    assert out.hit_point.x == -1.5 and out.hit_plane_x == -1.5
    assert out.bounce_half == -1 and out.bounce_zone == expected.bounce.zone
    # Uncertainty from the covariance: a distribution over the areas, a symmetric covariance.
    assert sum(out.zone_probabilities) == pytest.approx(1.0)
    assert out.zone_probabilities_half == -1
    assert max(out.zone_probabilities) == out.zone_probabilities[out.bounce_zone]
    cov = np.asarray(out.hit_covariance).reshape(3, 3)
    np.testing.assert_allclose(cov, cov.T, atol=1e-15)
    assert cov[1, 1] > 0.0 and out.hit_time_std > 0.0
    # The path follows at path_rate_hz (10 Hz) of the states' stamps (25 ms apart): due at
    # states 0, 4, 8, ...; the path worker builds the latest one due (a request waiting while
    # it is busy is replaced), so a path carries the stamp of one of those states.
    path = graph.paths[0]
    assert (ns(path.header.stamp) - t0) % 100_000_000 == 0 and path.header.frame_id == 'table'
    assert ns(path.header.stamp) <= ns(msgs[-1].header.stamp)
    first = path.poses[0].pose.position
    assert (first.x, first.y, first.z) == pytest.approx(GOOD[:3])
    assert path.poses[-1].pose.position.x >= -1.5


def test_a_prediction_carries_nothing_over_from_the_one_before(graph):
    # A full prediction (bounce, hit, propagated uncertainty), then a ball of another track
    # that flies wide of the table: no bounce, no hit, every area 0 (off the table).
    t0 = T0
    publish_until(graph, lambda k: graph.state(GOOD, stamp_ns=t0 + k * 25_000_000, track_id=7),
                  lambda: graph.predictions and any(graph.predictions[-1].hit_covariance),
                  'a prediction with its uncertainty')
    n = len(graph.predictions)
    wide = [1.6, 1.5, 0.3, -6.0, 0.0, 1.5, 0.0, 0.0, 0.0]            # 0.74 m beside the table
    assert predict(wide).bounce is None and predict(wide).hit is None
    graph.pub.publish(graph.state(wide, track_id=8))
    graph.spin_until(lambda: len(graph.predictions) > n, 10.0, 'the wide ball')
    out = graph.predictions[-1]
    assert out.track_id == 8 and out.status == predict(wide).status
    assert not out.bounce_valid and not out.hit_valid
    assert ns(out.bounce_time) == 0 and ns(out.hit_time) == 0
    for v in (out.bounce_point, out.hit_point, out.hit_velocity, out.hit_spin):
        assert (v.x, v.y, v.z) == (0.0, 0.0, 0.0)
    assert out.bounce_zone == 0 and out.bounce_half == 0
    assert list(out.zone_probabilities) == [1.0] + [0.0] * 9
    assert not any(out.hit_covariance) and out.hit_time_std == 0.0


def test_a_ball_past_the_plane_carries_no_hit_uncertainty(graph):
    # The track's last propagated uncertainty, a hit's, went out with its first no_hit
    # messages past the plane (hit_valid false, hit_time_std 0.4 ms; a walk-through).
    publish_until(graph, lambda k: graph.state(GOOD, stamp_ns=T0 + k * 25_000_000, track_id=9),
                  lambda: graph.predictions and any(graph.predictions[-1].hit_covariance),
                  'a prediction with its uncertainty')
    before = predict(GOOD)
    t_past = before.hit.t + 0.02
    _, samples = rollout(np.array(GOOD), ModelParams(), sample_times=[t_past],
                         stop_at_plane=False)
    n = len(graph.predictions)
    graph.pub.publish(graph.state(samples[0], stamp_ns=T0 + round(t_past * 1e9), track_id=9))
    graph.spin_until(lambda: len(graph.predictions) > n, 10.0, 'the ball past the plane')
    out = graph.predictions[-1]
    assert out.track_id == 9 and not out.hit_valid
    assert not any(out.hit_covariance) and out.hit_time_std == 0.0


def test_each_path_has_the_poses_of_its_own_flight():
    # A long flight, then a short one (the ball already near the plane), then the long one
    # again: every path has the poses of its prediction, none left over from the one before.
    with Graph(overrides=[rclpy.parameter.Parameter('path_rate_hz', value=0.0)]) as g:
        near = [-1.0, 0.0, 0.3, -6.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        balls = [GOOD, near, GOOD]
        t0 = T0
        for k, ball in enumerate(balls):
            g.pub.publish(g.state(ball, stamp_ns=t0 + k * 1_000_000, track_id=k))
            g.spin_until(lambda k=k: len(g.paths) > k, 10.0, f'path {k}')
        for ball, path in zip(balls, g.paths, strict=True):
            expected = predict(ball, path_dt=0.02).path
            got = [(q.pose.position.x, q.pose.position.y, q.pose.position.z) for q in path.poses]
            assert len(got) == len(expected)
            np.testing.assert_allclose(got, expected, atol=1e-12)
            stamps = [ns(q.header.stamp) - ns(path.header.stamp) for q in path.poses]
            np.testing.assert_allclose(stamps, np.arange(len(got)) * 20_000_000, atol=1)
        assert len(g.paths[1].poses) < len(g.paths[0].poses)


def test_bad_and_stale_states_publish_nothing(graph):
    stale_ns = round(graph.node.get_parameter('stale_after_s').value * 1e9)
    assert stale_ns > 0                                               # the default drops
    bad = [
        graph.state([math.nan, 0, 0.3, -6, 0, 1, 0, 0, 0]),
        graph.state([0.5, 0.0, -0.1, -6, 0, 1, 0, 0, 0]),            # below the table
        graph.state([1.0, 0.0, 0.3, 0, 0, 0, 0, 0, 0]),               # at rest
        graph.state(GOOD, stamp_ns=T0 - stale_ns - 1_000),            # older than stale_after_s
        graph.state(GOOD, stamp_ns=T0 - 3 * stale_ns),
        # More than MAX_LEAD_S (1 s) ahead of the clock: the clocks disagree (such a state
        # was predicted and struck 100 s ahead).
        graph.state(GOOD, stamp_ns=T0 + 1_000_001_000, track_id=4),
    ]
    # As old as stale_after_s, not older: kept; and a state stamped at the clock's time; and
    # one 1 s ahead.
    good = [graph.state(GOOD, stamp_ns=T0 - stale_ns + 1_000, track_id=2),
            graph.state(GOOD, track_id=3),
            graph.state(GOOD, stamp_ns=T0 + 999_999_000, track_id=5)]
    for k, msg in enumerate(bad + good):     # one at a time: the QoS keeps the last 5 only
        graph.pub.publish(msg)
        graph.spin_until(lambda k=k: graph.node.n_received == k + 1, 10.0, f'state {k}')
    graph.spin_until(lambda: len(graph.predictions) == len(good), 10.0, 'the good states')
    # Messages of one publisher arrive in order: anything for the bad ones would come first.
    assert [p.header.stamp for p in graph.predictions] == [m.header.stamp for m in good]
    assert graph.node.n_dropped == len(bad) and graph.node.n_predicted == len(good)
    # The clock moves on: the same state is now too old.
    graph.set_clock(T0 + stale_ns)
    graph.pub.publish(good[0])
    graph.spin_until(lambda: graph.node.n_received == len(bad + good) + 1, 10.0,
                     'the late state')
    assert graph.node.n_dropped == len(bad) + 1 and len(graph.predictions) == len(good)


def test_each_kind_of_dropped_state_is_said_at_most_once_a_second(graph, monkeypatch):
    # One throttle for every reason: a stream of stale states hid the states of a camera
    # frame dropped beside them (a ROS user's walk-through, 6 Dec 2026).
    said = []
    monkeypatch.setattr(graph.node.warn, '_log', said.append)
    stale = graph.state(GOOD, stamp_ns=T0 - 3 * round(
        graph.node.get_parameter('stale_after_s').value * 1e9))
    camera = graph.state(GOOD)
    camera.header.frame_id = 'camera'
    sent = [stale, camera, stale, graph.state([math.nan, 0, 0.3, -6, 0, 1, 0, 0, 0]), camera]
    for k, msg in enumerate(sent):
        graph.pub.publish(msg)
        graph.spin_until(lambda k=k: graph.node.n_received == k + 1, 10.0, f'state {k}')
    assert graph.node.n_dropped == len(sent)
    kinds = [line.split(': ')[1].split(' ')[0] for line in said]
    assert kinds == ['stale', 'frame', 'position'], said
    # The stale states had a valid header: their stamps are the exit line's.
    assert '; stamps ' in graph.node.work_summary()


def test_the_exit_line_of_a_node_whose_states_were_all_in_another_frame_says_so(graph):
    # It said 'no valid stamp' for states stamped right but in frame 'world' (a walk-through).
    world = graph.state(GOOD)
    world.header.frame_id = 'world'
    graph.pub.publish(world)
    graph.spin_until(lambda: graph.node.n_received == 1, 10.0, 'the state')
    assert graph.node.n_dropped == 1
    assert '; no state with a valid header (stamp, frame); ' in graph.node.work_summary()


def test_states_received_late_are_counted_in_the_exit_line(graph):
    # At 1 kHz from another process the node fell 94-133 ms behind (its queue full) and its
    # exit line read as if all were well. A state 0.2 s old (not stale: 0.5 s) is late.
    from tt_prediction.node import LATE_S
    graph.pub.publish(graph.state(GOOD, stamp_ns=T0 - round(4 * LATE_S * 1e9), track_id=2))
    graph.pub.publish(graph.state(GOOD, stamp_ns=T0 - round(0.5 * LATE_S * 1e9), track_id=3))
    graph.spin_until(lambda: len(graph.predictions) == 2, 10.0, 'both predictions')
    assert graph.node.n_late == 1
    assert graph.node.work_summary().endswith(
        f'; 1 received more than {LATE_S * 1e3:.0f} ms after their stamp; 0 lost in the input '
        'queue')


def test_a_state_stamped_ahead_of_the_node_clock_is_predicted_and_warned_of(graph,
                                                                           monkeypatch):
    # 0.9 s ahead (under the 1 s that drops it) was struck 'ok' without a word, its hit time
    # 0.9 s late: an exposure cannot come after its state's arrival (a walk-through). 25 ms
    # ahead is a bag's /clock at 40 Hz behind the states played with it, and says nothing.
    said = []
    monkeypatch.setattr(graph.node.warn, '_log', said.append)
    graph.pub.publish(graph.state(GOOD, stamp_ns=T0 + 900_000_000, track_id=2))
    graph.pub.publish(graph.state(GOOD, stamp_ns=T0 + 25_000_000, track_id=3))
    graph.spin_until(lambda: len(graph.predictions) == 2, 10.0, 'both predictions')
    assert len(said) == 1 and 'stamped 900 ms ahead of the node clock' in said[0], said


def test_a_state_ahead_by_less_than_a_step_of_the_simulated_clock_is_not_warned_of(graph,
                                                                                  monkeypatch):
    # ros2 bag play -r 2 --clock: /clock at 40 Hz of wall time steps by 50 ms of bag time, and
    # states 53 ms ahead of it were told as clocks that disagree (a walk-through, 7 Dec 2026).
    said = []
    monkeypatch.setattr(graph.node.warn, '_log', said.append)
    step = 50_000_000
    for k in range(1, 7):             # the first at the clock: the node knows no step yet
        graph.set_clock(T0 + k * step)
        ahead = 60_000_000 if k > 1 else 0
        graph.pub.publish(graph.state(GOOD, stamp_ns=T0 + k * step + ahead, track_id=2))
        graph.spin_until(lambda k=k: graph.node.n_received == k, 10.0, f'state {k}')
    assert said == [] and graph.node.n_dropped == 0
    # Ahead by more than the step and 50 ms: the clocks disagree.
    graph.pub.publish(graph.state(GOOD, stamp_ns=T0 + 6 * step + 150_000_000, track_id=3))
    graph.spin_until(lambda: graph.node.n_received == 7, 10.0, 'the state ahead')
    assert len(said) == 1 and 'stamped 150 ms ahead of the node clock (more than the 100 ms' \
        in said[0], said


def test_sparse_states_do_not_widen_the_margin_of_a_simulated_clock(graph, monkeypatch):
    # States 0.5 s apart see the clock step by 0.5 s between them: that is their gap, not
    # /clock's step, and had let states up to 0.55 s ahead pass without a word.
    said = []
    monkeypatch.setattr(graph.node.warn, '_log', said.append)
    for k in range(1, 5):
        graph.set_clock(T0 + k * 500_000_000)
        ahead = 120_000_000 if k > 1 else 0
        graph.pub.publish(graph.state(GOOD, stamp_ns=T0 + k * 500_000_000 + ahead, track_id=k))
        graph.spin_until(lambda k=k: graph.node.n_received == k, 10.0, f'state {k}')
    assert len(said) == 1, said                     # warned of, once every 5 s
    assert 'stamped 120 ms ahead of the node clock (more than the 50 ms it may lag)' in said[0]


def test_a_state_from_before_the_clock_went_back_is_said_so_not_a_clock_disagreement(
        graph, monkeypatch):
    # ros2 bag play --loop --clock: the next pass's /clock can reach the node before the last
    # state of this pass (another topic), which was then dropped as 'the clocks disagree'.
    said = []
    monkeypatch.setattr(graph.node.warn, '_log', said.append)
    end = T0 + 5_000_000_000
    graph.set_clock(end)
    graph.pub.publish(graph.state(GOOD, stamp_ns=end, track_id=2))
    graph.spin_until(lambda: len(graph.predictions) == 1, 10.0, "the pass's prediction")
    graph.set_clock(T0)                             # the bag starts over
    graph.pub.publish(graph.state(GOOD, stamp_ns=end + 10_000_000, track_id=2))
    graph.pub.publish(graph.state(GOOD, stamp_ns=end + 200_000_000, track_id=3))
    graph.spin_until(lambda: graph.node.n_received == 3, 10.0, 'both states')
    assert graph.node.n_dropped == 2 and len(graph.predictions) == 1
    assert len(said) == 2, said          # each kind once a second
    assert 'which went back from' in said[0] and 'a bag played again' in said[0], said
    # Further ahead than the clock ever was: that is a clock that disagrees.
    assert 'the clocks disagree' in said[1] and '5.200 s ahead' in said[1], said
    # And so is one stamped as the earlier pass's last, once the new pass has run 2 s.
    reasons = []
    monkeypatch.setattr(graph.node, '_drop', reasons.append)
    graph.set_clock(T0 + 2_000_000_000)
    graph.pub.publish(graph.state(GOOD, stamp_ns=end + 10_000_000, track_id=4))
    graph.spin_until(lambda: graph.node.n_received == 4, 10.0, 'the state 3 s ahead')
    assert len(reasons) == 1 and reasons[0].endswith('the clocks disagree'), reasons


def test_the_exit_lines_stamps_are_the_earliest_and_latest_valid_ones(graph):
    # Its stamps were the first and the last state received: a dropped state stamped 0 after
    # the others made it read 'stamps <first> to 0.000000000 s'.
    stamps = [T0 - 2_000_000, T0 - 5_000_000]           # received out of order
    for k, stamp_ns in enumerate(stamps):
        graph.pub.publish(graph.state(GOOD, stamp_ns=stamp_ns, track_id=6 + k))
    graph.pub.publish(graph.state(GOOD, stamp_ns=0, track_id=8))
    graph.spin_until(lambda: graph.node.n_received == 3, 10.0, 'the three states')
    assert graph.node.n_dropped == 1
    low, high = (f'{ns // 10**9}.{ns % 10**9:09d}' for ns in (min(stamps), max(stamps)))
    assert f'; stamps {low} to {high} s;' in graph.node.work_summary()


def test_diagnostics_report_the_counts_and_warn_of_a_dropped_state(graph):
    # /diagnostics once a second of the steady clock (this node's /clock stands still): the
    # totals, WARN for the report that first counts the dropped state, OK for the next.
    reports = []
    graph.test.create_subscription(DiagnosticArray, f'{graph.prefix}/diagnostics',
                                   lambda m: reports.extend(m.status), 10)
    graph.pub.publish(graph.state(GOOD, track_id=2))
    graph.pub.publish(graph.state([math.nan, 0, 0.3, -6, 0, 1, 0, 0, 0], track_id=3))

    def values(status):
        return {kv.key: kv.value for kv in status.values}

    graph.spin_until(lambda: any(values(r)['states_received'] == '2' for r in reports), 10.0,
                     'a report counting both states')
    first = next(k for k, r in enumerate(reports) if values(r)['states_received'] == '2')
    status = reports[first]
    assert status.name == 'prediction_node: predictions'
    got = values(status)
    assert {k: got[k] for k in ('states_received', 'predictions_published', 'states_dropped',
                                'states_late', 'states_lost')} == {
        'states_received': '2', 'predictions_published': '1', 'states_dropped': '1',
        'states_late': '0', 'states_lost': '0'}
    assert 0 < float(got['callback_p50_ms']) <= float(got['callback_p99_ms'])
    assert status.level == DiagnosticStatus.WARN and ', 1 dropped, ' in status.message
    graph.spin_until(lambda: len(reports) > first + 1, 10.0, 'the next report')
    assert reports[first + 1].level == DiagnosticStatus.OK
    assert reports[first + 1].message.startswith('0 states, 0 predictions, 0 dropped, 0 ')


def test_a_state_without_a_stamp_is_dropped_on_a_wall_clock(graph):
    # Stamped 0 (`ros2 topic pub` without header: {stamp: now}) on a node whose clock reads
    # today: taken for another time base, its time checks were switched off and it was
    # predicted, and struck, for 1970.
    graph.set_clock(1_790_000_000 * 10**9)
    graph.pub.publish(graph.state(GOOD, stamp_ns=0))
    graph.pub.publish(graph.state(GOOD, stamp_ns=1_790_000_000 * 10**9, track_id=2))
    graph.spin_until(lambda: len(graph.predictions) == 1, 10.0, 'the stamped state')
    assert graph.node.n_received == 2 and graph.node.n_dropped == 1
    assert graph.predictions[0].track_id == 2


def test_a_track_id_used_again_by_a_later_ball_is_a_new_track(graph):
    # perception_node numbers its tracks from 1 again when it restarts: the node remembered
    # the first ball's bounce as past and predicted the new ball as after it (double_bounce,
    # no hit point: no stroke). The same state 2 s later gives the same prediction.
    first = graph.state(GOOD)
    graph.pub.publish(first)
    graph.spin_until(lambda: len(graph.predictions) == 1, 10.0, 'the first prediction')
    graph.set_clock(T0 + 2_000_000_000)
    graph.pub.publish(graph.state(GOOD, stamp_ns=T0 + 2_000_000_000))
    graph.spin_until(lambda: len(graph.predictions) == 2, 10.0, 'the second prediction')
    a, b = graph.predictions
    assert a.status == b.status == 'ok' and a.hit_valid and b.hit_valid
    assert ns(b.hit_time) - ns(a.hit_time) == 2_000_000_000
    assert (b.hit_point.y, b.hit_point.z) == (a.hit_point.y, a.hit_point.z)


def test_a_ball_thrown_again_under_the_same_id_within_the_gap_is_a_new_track(graph):
    # A user's stream: ball 5 for 0.4 s (past its bounce), 0.6 s without it, then a new ball
    # 5 from the far end. Within TRACK_GAP_S, the node kept the first ball's bounce as past:
    # every prediction of the second was double_bounce, no hit point, no stroke.
    first = predict(GOOD)
    t_last = first.bounce.t + 0.05
    _, samples = rollout(np.array(GOOD), ModelParams(), sample_times=[t_last])
    graph.pub.publish(graph.state(GOOD, track_id=5))
    graph.spin_until(lambda: len(graph.predictions) == 1, 10.0, 'the first prediction')
    graph.pub.publish(graph.state(samples[0], stamp_ns=T0 + round(t_last * 1e9), track_id=5))
    graph.spin_until(lambda: len(graph.predictions) == 2, 10.0, 'past the bounce')
    again = T0 + round((t_last + 0.6) * 1e9)
    graph.set_clock(again)
    graph.pub.publish(graph.state(GOOD, stamp_ns=again, track_id=5))
    graph.spin_until(lambda: len(graph.predictions) == 3, 10.0, 'the new ball')
    a, _, b = graph.predictions
    assert b.status == 'ok' and b.hit_valid and b.bounce_valid
    assert ns(b.hit_time) - ns(a.hit_time) == again - T0


def test_the_track_forgotten_first_is_the_one_updated_longest_ago():
    # Nine ids, the first updated all along: it kept its remembered bounce (it was the
    # oldest created, and forgotten when the ninth came).
    from tt_prediction.node import MAX_TRACKS
    with Graph() as g:
        g.pub.publish(g.state(GOOD, track_id=1))
        g.spin_until(lambda: len(g.predictions) == 1, 10.0, 'the first prediction')
        remembered = g.node.tracks[1]
        for k in range(2, MAX_TRACKS + 2):
            g.pub.publish(g.state(GOOD, stamp_ns=T0 + k * 1_000_000, track_id=k))
            g.pub.publish(g.state(GOOD, stamp_ns=T0 + k * 1_000_000, track_id=1))
            g.spin_until(lambda k=k: len(g.predictions) == 2 * k - 1, 10.0, f'track {k}')
        assert g.node.tracks.get(1) is remembered and 2 not in g.node.tracks
        assert len(g.node.tracks) == MAX_TRACKS


@pytest.mark.parametrize('cov', [-np.eye(9), np.zeros((9, 9)), np.eye(9) * 1e300],
                         ids=['negative', 'all zeros', '1e300'])
def test_a_bad_covariance_still_gives_the_prediction(graph, cov):
    # All zeros is a publisher's 'unknown' (BallState): propagated, it gave a hit covariance
    # of 1e-32 m^2 that strike_node took as a known, exact position. 1e300 was propagated
    # too: 90 % off the table, and a hit covariance narrower than for 0.01 m^2.
    t0 = T0
    publish_until(graph, lambda k: graph.state(GOOD, stamp_ns=t0 + k * 25_000_000, cov=cov),
                  lambda: graph.node.n_bad_covariance >= 1 and len(graph.predictions) >= 2,
                  'the covariance to be rejected')
    for out in graph.predictions:
        assert out.status == 'ok'
        assert out.zone_probabilities[out.bounce_zone] == 1.0     # the nominal zone only
        assert not any(out.hit_covariance)


def test_max_rate_skips_states_by_their_stamps():
    with Graph(overrides=[rclpy.parameter.Parameter('max_rate_hz', value=100.0)]) as g:
        t0 = T0
        for k in range(11):                                  # 500 Hz by the stamps
            g.pub.publish(g.state(GOOD, stamp_ns=t0 + k * 2_000_000))
            g.spin_until(lambda k=k: g.node.n_received == k + 1, 10.0, f'state {k}')
        g.spin_until(lambda: len(g.predictions) == g.node.n_predicted, 10.0, 'predictions')
        assert [ns(p.header.stamp) - t0 for p in g.predictions] == [0, 10_000_000, 20_000_000]


def test_max_rate_holds_for_each_track_apart():
    # Two balls at once, their states interleaved at 500 Hz each: a rate shared by the
    # tracks gave every prediction to the ball whose states came first (the other: none).
    g = Graph(overrides=[rclpy.parameter.Parameter('max_rate_hz', value=100.0)])
    other = list(GOOD)
    other[1] = -0.4
    try:
        t0 = T0
        for k in range(11):
            for track_id, values, offset in ((1, GOOD, 0), (2, other, 1_000_000)):
                g.pub.publish(g.state(values, stamp_ns=t0 + k * 2_000_000 + offset,
                                      track_id=track_id))
            g.spin_until(lambda k=k: g.node.n_received == 2 * (k + 1), 10.0, f'states {k}')
        g.spin_until(lambda: len(g.predictions) == g.node.n_predicted, 10.0, 'predictions')
        for track_id, offset in ((1, 0), (2, 1_000_000)):
            assert [ns(p.header.stamp) - t0 - offset for p in g.predictions
                    if p.track_id == track_id] == [0, 10_000_000, 20_000_000], track_id
    finally:
        g.close()


def test_the_config_file_sets_the_parameters():
    with Graph(args=['--ros-args', '--params-file', str(CONFIG)]) as g:
        expected = yaml.safe_load(CONFIG.read_text())['prediction_node']['ros__parameters']
        for name, value in expected.items():
            assert g.node.get_parameter(name).value == value, name


def test_a_bad_model_file_stops_the_node_with_a_one_line_reason(tmp_path):
    model = tmp_path / 'model.yaml'
    model.write_text('ball: [1, 2]\n')
    with pytest.raises(StartupError, match='^model_file: .*model.yaml'):
        Graph(overrides=[rclpy.parameter.Parameter('model_file', value=str(model))])


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_the_node_process_shuts_down_cleanly_on_a_signal(sig):
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    env.pop(EXECUTOR_ENV, None)             # the default executor
    # Topics of its own: a node on /ball/state would take the states of any other graph on
    # this machine, and be stopped in the middle of their work (a flake check saw its path
    # worker publish after the signal had shut the context down).
    remap = remap_args(unique_prefix(), ('/ball/state', '/ball/prediction',
                                         '/ball/predicted_path', '/tt/markers'))
    proc = subprocess.Popen([sys.executable, '-m', 'tt_prediction.node', *remap], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # Started once it logs its topics (after compiling or loading the kernels).
        line = ''
        deadline = time.monotonic() + 120
        while 'predicting' not in line and time.monotonic() < deadline:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, 'node exited early'
        proc.send_signal(sig)
        rest, _ = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, rest
    assert 'Traceback' not in rest


def test_the_executor_is_chosen_by_name_and_a_bad_name_is_one_line():
    context = rclpy.context.Context()
    rclpy.init(context=context, args=[])
    try:
        assert isinstance(make_executor('single', context), SingleThreadedExecutor)
        # rclpy 7.1.6 (constraints.txt) has the events executor (rclpy >= 7.1.4): its C++
        # class, not the fallback.
        events = make_executor('events', context)
        assert type(events).__name__ == 'EventsExecutor'
        assert not isinstance(events, SingleThreadedExecutor)
        with pytest.raises(ValueError, match="TT_EXECUTOR='multi' is not one of: events, "
                                             'single'):
            make_executor('multi', context)
    finally:
        rclpy.try_shutdown(context=context)
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', EXECUTOR_ENV: 'multi'}
    out = subprocess.run([sys.executable, '-m', 'tt_prediction.node'], env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode != 0 and 'Traceback' not in out.stderr
    assert out.stderr.strip().splitlines()[-1].endswith('is not one of: events, single')


def _past_its_bounce(graph, track_id, between):
    """Track ``track_id``: GOOD, then the same ball 60 and 70 ms after its bounce with
    ``between`` (values, stamp offset from the first of those, s) published in between;
    returns the first prediction and the last (the ball 70 ms after its bounce)."""
    before = predict(GOOD)
    t1 = before.bounce.t + 0.06
    graph.pub.publish(graph.state(GOOD, track_id=track_id))
    graph.spin_until(lambda: graph.node.n_received == 1, 10.0, 'the first state')
    _, samples = rollout(np.array(GOOD), ModelParams(), sample_times=[t1, t1 + 0.01])
    sent = [(samples[0], 0.0), between, (samples[1], 0.01)]
    for k, (values, offset) in enumerate(sent, start=2):
        graph.pub.publish(graph.state(values, stamp_ns=T0 + round((t1 + offset) * 1e9),
                                      track_id=track_id))
        graph.spin_until(lambda k=k: graph.node.n_received == k, 10.0, f'state {k}')
    graph.spin_until(lambda: graph.predictions and graph.predictions[-1].header.stamp
                     == graph.state(GOOD, stamp_ns=T0 + round((t1 + 0.01) * 1e9)).header.stamp,
                     10.0, 'the last prediction')
    return graph.predictions[0], graph.predictions[-1]


def test_a_late_state_is_dropped_and_its_track_keeps_its_bounce(graph):
    # Best effort delivers out of order (and a second publisher may lag): a state of the
    # ball 10 ms older than the track's last, past the bounce, was taken for a new ball; the
    # track lost its bounce and every later state was no_bounce, no hit, no stroke.
    _, samples = rollout(np.array(GOOD), ModelParams(),
                         sample_times=[predict(GOOD).bounce.t + 0.05])
    first, last = _past_its_bounce(graph, 3, (samples[0], -0.01))
    assert graph.node.n_dropped == 1 and len(graph.predictions) == 3
    assert list(graph.node.tracks) == [3]
    assert last.status == 'ok' and last.bounce_time == first.bounce_time
    assert ns(last.hit_time) == pytest.approx(ns(first.hit_time), abs=1000)


@pytest.mark.parametrize('bad', ['nan', 'fast'])
def test_an_invalid_state_past_the_bounce_is_dropped_and_its_track_keeps_its_bounce(graph,
                                                                                      bad):
    # One state of the ball with a NaN velocity (or 45 m/s) 5 ms after one past its bounce:
    # it became the track's last before it was found invalid, the next state was no longer
    # on its path, and the bounce was forgotten (no_bounce, then miss, for the rest of the
    # flight: a walk-through, 6 Dec 2026).
    _, samples = rollout(np.array(GOOD), ModelParams(),
                         sample_times=[predict(GOOD).bounce.t + 0.065])
    invalid = samples[0].copy()
    invalid[3] = math.nan if bad == 'nan' else -45.0
    first, last = _past_its_bounce(graph, 5, (invalid, 0.005))
    assert graph.node.n_dropped == 1 and len(graph.predictions) == 3
    assert last.status == 'ok' and last.bounce_time == first.bounce_time
    assert ns(last.hit_time) == pytest.approx(ns(first.hit_time), abs=1000)


def test_a_state_delivered_twice_is_predicted_once(graph):
    # A redelivered state (its stamp the track's last) was predicted and published again.
    graph.pub.publish(graph.state(GOOD, track_id=6))
    graph.pub.publish(graph.state(GOOD, track_id=6))
    graph.spin_until(lambda: graph.node.n_received == 2, 10.0, 'both states')
    graph.spin_until(lambda: graph.predictions, 10.0, 'the prediction')
    assert (graph.node.n_dropped, graph.node.n_predicted) == (1, 1)


@pytest.mark.parametrize('ahead', [0.005, 0.05])
def test_one_state_off_the_path_is_an_outlier_and_the_track_keeps_its_bounce(graph, ahead):
    # One state 1 m to the side (a mismatched detection) between two of the ball past its
    # bounce: it started a new track, and the ball's next state, far from it, another one:
    # the bounce was lost for the rest of the flight (no_bounce, no hit). Stamped 50 ms
    # after the first, 40 ms after the next (a review): that one was then out of order.
    _, samples = rollout(np.array(GOOD), ModelParams(),
                         sample_times=[predict(GOOD).bounce.t + 0.06 + ahead])
    outlier = samples[0].copy()
    outlier[1] += 1.0
    first, last = _past_its_bounce(graph, 4, (outlier, ahead))
    assert last.status == 'ok' and last.bounce_time == first.bounce_time
    assert ns(last.hit_time) == pytest.approx(ns(first.hit_time), abs=1000)


def test_a_ball_past_its_second_bounce_on_the_robots_half_stays_double_bounce():
    # A short ball (first seen past the net) bounces at x = -0.16 and again at -0.75 before
    # the plane at -1.2: the node said double_bounce until the second bounce, then, from a
    # state rising off it, an ordinary hit (status ok) for the arm to strike (tt-predict's
    # replay did the same; a new user's walk-through).
    short = np.array([0.3, 0.0, 0.25, -2.2, 0.0, 0.0, 0.0, -50.0, 0.0])
    events, _ = rollout(short, ModelParams(), t_max=1.5, stop_at_net=False, max_bounces=3,
                        stop_at_plane=False)
    first, second = events[0].t, events[1].t
    assert events[0].state[0] < 0.0 and -1.2 < events[1].state[0] < 0.0
    times = [0.16, first + 0.06, 0.5 * (first + second), second + 0.06, second + 0.12]
    _, states = rollout(short, ModelParams(), sample_times=times, stop_at_net=False,
                        max_bounces=3, stop_at_plane=False)
    with Graph([rclpy.parameter.Parameter('hit_plane_x', value=-1.2)]) as g:
        for k, (t, values) in enumerate(zip(times, states, strict=True), start=1):
            g.pub.publish(g.state(values, stamp_ns=T0 + round(t * 1e9), track_id=7))
            g.spin_until(lambda k=k: len(g.predictions) == k, 10.0, f'prediction {k}')
        statuses = [p.status for p in g.predictions]
        assert statuses == ['double_bounce'] * 5
        assert not any(p.hit_valid for p in g.predictions)
        assert all(p.bounce_time == g.predictions[0].bounce_time for p in g.predictions)
        # Without the track's memory the state after the second bounce is a hit.
        assert predict(states[3], hit_plane_x=-1.2, bounced=True).status == 'ok'


def test_a_track_followed_past_its_bounce_keeps_its_hit(graph):
    t0 = T0
    before = predict(GOOD)
    graph.pub.publish(graph.state(GOOD, stamp_ns=t0, track_id=3))
    graph.spin_until(lambda: graph.predictions, 10.0, 'the first prediction')
    # The same ball 60 ms after its bounce, as perception would report it.
    t1 = before.bounce.t + 0.06
    _, samples = rollout(GOOD, ModelParams(), sample_times=[t1])
    graph.pub.publish(graph.state(samples[0], stamp_ns=t0 + round(t1 * 1e9), track_id=3))
    graph.spin_until(lambda: len(graph.predictions) == 2, 10.0, 'the second prediction')
    first, after = graph.predictions
    assert after.status == 'ok'
    assert after.bounce_valid and after.bounce_time == first.bounce_time
    assert ns(after.hit_time) == pytest.approx(ns(first.hit_time), abs=1000)     # 1 us
    assert after.hit_point.y == pytest.approx(first.hit_point.y, abs=1e-6)
    assert after.hit_point.z == pytest.approx(first.hit_point.z, abs=1e-6)
    # Another track with the same state has not been seen bouncing: no bounce ahead of it.
    graph.pub.publish(graph.state(samples[0], stamp_ns=t0 + round(t1 * 1e9), track_id=4))
    graph.spin_until(lambda: len(graph.predictions) == 3, 10.0, 'the third prediction')
    assert graph.predictions[2].status == 'no_bounce'


def test_a_tracker_that_smooths_over_the_bounce_keeps_the_balls_hit():
    """Another tracker's states on /ball/state: positions of the ball at 180 Hz, velocities
    from a quadratic through each state's 3 neighbours either side, as a tracker that does
    not model the bounce gives them (smoothed over its kink). One state just after the bounce,
    still foreseeing one ahead, moved the track's bounce on, and the ball's later states,
    past no bounce it knew of, were no_bounce for the rest of the flight: no hit, no stroke
    (a walk-through, 6 Dec 2026: 45 of mpi_launcher's 88 tracks). Every state from 30 ms
    after the bounce to the plane must give the hit, where the ball's flight puts it."""
    bounce_t = predict(GOOD).bounce.t
    hit = predict(GOOD, hit_plane_x=-1.2)
    times = np.arange(0.0, hit.hit.t, 1 / 180)
    _, samples = rollout(np.array(GOOD), ModelParams(), sample_times=times)
    positions = samples[:, :3]
    states = []
    for i in range(3, len(times) - 3):
        window = slice(i - 3, i + 4)
        fit = np.polyfit(times[window] - times[i], positions[window], 2)
        states.append((times[i], np.concatenate([positions[i], fit[1], np.zeros(3)])))
    with Graph([rclpy.parameter.Parameter('hit_plane_x', value=-1.2)]) as g:
        for k, (t, values) in enumerate(states, start=1):
            g.pub.publish(g.state(values, stamp_ns=T0 + round(t * 1e9), track_id=8))
            g.spin_until(lambda k=k: g.node.n_received == k, 10.0, f'state {k}')
        g.spin_until(lambda: len(g.predictions) + g.node.n_dropped >= len(states), 10.0,
                     'the predictions')
        after = [p for p in g.predictions if ns(p.header.stamp) > T0 + (bounce_t + 0.03) * 1e9]
        assert after and [p.status for p in after] == ['ok'] * len(after)
        for p in after:
            assert ns(p.hit_time) == pytest.approx(T0 + hit.hit.t * 1e9, abs=5e6)   # 5 ms
            assert p.hit_point.y == pytest.approx(hit.hit.state[1], abs=0.02)
            assert p.hit_point.z == pytest.approx(hit.hit.state[2], abs=0.02)
