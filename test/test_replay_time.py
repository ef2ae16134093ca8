"""Time that works for recorded data (issue 17 item 2), on live `ros2 run` processes.

- A session bag of ball states replayed with ``ros2 bag play --clock`` (at a quarter of its
  speed: on a loaded 2-core machine the nodes' hiccups then stay well inside the default
  0.5 s stale limit of bag time) into prediction_node and strike_node with ``use_sim_time``:
  every state that reaches the node gets its prediction and the balls are struck, whether the
  bag was recorded on the states' own time base or (as the demo's session once was) on the
  wall clock while the states carry the recording's synthetic stamps.
- A rig of video files: perception_node publishes the video time on /clock
  (``publish_clock``), prediction_node runs on it (``use_sim_time``) with the default stale
  check, and every state gets its prediction (before: all dropped as stale).

Each test runs in a ROS domain of its own (the /clock topic is global); it waits on
conditions (messages counted, a process ended), never on sleeps.
"""

import re
import time

import numpy as np
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from tt_ros.bagfile import BagWriter
from tt_ros.messages import set_time, stamp_ns
from tt_ros.testing import Graph, unique_domain
from tt_tools.procs import ProcessGroup, wait_until

from tt_msgs.msg import BallPrediction, BallState, StrikeCommand

pytestmark = pytest.mark.graph

STAMP_BASE_NS = 1_700_000_000 * 10**9    # the demo recording's time zero (2023)
RATE_HZ = 150.0
TIMEOUT_S = 120.0
MAX_LOST = 6
"""States of a replay after the first one the node receives that it may not receive (best
effort, see below)."""
BALL_STATES = 40
"""States of each ball (track) in the session bag."""


class Listener(Graph):
    """Counts /ball/state and /ball/prediction in the test's domain."""

    def __init__(self, domain, states=True):
        super().__init__(domain_id=domain)
        self.node = self.create_node('listen')
        deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.states, self.predictions, self.commands = [], [], []
        if states:
            self.node.create_subscription(BallState, '/ball/state', self.states.append, deep)
        self.node.create_subscription(BallPrediction, '/ball/prediction',
                                      self.predictions.append, QoSProfile(depth=1000))
        self.node.create_subscription(StrikeCommand, '/strike/command',
                                      self.commands.append, QoSProfile(depth=1000))

    def spin(self):
        """Spin once (up to 0.05 s); False, so that ``wait_until(lambda: listener.spin() or
        condition)`` spins while it waits."""
        self.executor.spin_once(timeout_sec=0.05)
        return False


def _state(t_ns, x, track):
    msg = BallState()
    set_time(msg.header.stamp, t_ns)
    msg.header.frame_id = 'table'
    msg.track_id = track
    # An incoming ball (towards -x) at 6 m/s, rising, with topspin: a valid state.
    (msg.position.x, msg.position.y, msg.position.z) = (x, 0.1, 0.3)
    (msg.velocity.x, msg.velocity.y, msg.velocity.z) = (-6.0, 0.0, 1.5)
    msg.spin.y = 100.0
    msg.covariance = np.diag([1e-6] * 3 + [1e-2] * 3 + [100.0] * 3).ravel().tolist()
    return msg


def _write_session(path, receive_base_ns, n=120):
    """A session bag of ``n`` states at 150 Hz stamped from the demo's time zero, received
    3 ms after their stamps on the time base ``receive_base_ns`` (= STAMP_BASE_NS: recorded
    on the recording's own clock). Returns the stamps, ns."""
    writer = BagWriter(str(path))
    conn = writer.add_topic('/ball/state', 'tt_msgs/msg/BallState')
    stamps = []
    for k in range(n):
        dt_ns = round(k * 1e9 / RATE_HZ)
        stamp = STAMP_BASE_NS + dt_ns
        msg = _state(stamp, 1.6 - 6.0 * (k % BALL_STATES) / RATE_HZ, track=k // BALL_STATES)
        writer.write(conn, receive_base_ns + dt_ns + 3_000_000, serialize_message(msg))
        stamps.append(stamp)
    writer.close()
    return stamps


@pytest.mark.parametrize('recorded_on', ['own time', 'wall clock'])
def test_a_session_bag_played_with_clock_gives_a_prediction_per_state(tmp_path, recorded_on):
    base = STAMP_BASE_NS if recorded_on == 'own time' else time.time_ns()
    stamps = _write_session(tmp_path / 'session', base)
    domain = unique_domain()
    # No /ball/state subscription here: --wait-for-subscribers then waits for prediction_node.
    listener = Listener(domain, states=False)
    try:
        with ProcessGroup(str(tmp_path)) as group:
            env = {'ROS_DOMAIN_ID': str(domain)}
            group.start('strike', ['ros2', 'run', 'tt_strike', 'strike_node', '--ros-args',
                                   '-p', 'use_sim_time:=true'], env=env)
            wait_until(lambda: listener.spin() or 'ready' in (tmp_path / 'strike.log')
                       .read_text(), TIMEOUT_S, 'strike_node ready')
            group.start('prediction', ['ros2', 'run', 'tt_prediction', 'prediction_node',
                                       '--ros-args', '-p', 'use_sim_time:=true',
                                       '-p', 'uncertainty:=false'], env=env)
            player = group.start('play', ['ros2', 'bag', 'play', str(tmp_path / 'session'),
                                          '--clock', '--wait-for-subscribers',
                                          '--rate', '0.25'], env=env)
            wait_until(lambda: listener.spin() or player.poll() is not None, TIMEOUT_S,
                       'the replay to end')
            assert player.returncode == 0
            # The states go best effort (sensor data): the node may match the player a moment
            # after the player matched it (--wait-for-subscribers sees the player's side
            # only), so the first states may be lost before the node's first (on a loaded
            # machine, 13 at a quarter speed: DDS discovery, not tt); from its first on, up to
            # MAX_LOST never reach the node, the last one among them at times. The node
            # answers in order: once a prediction of one of the last MAX_LOST + 1 states is
            # out (one of them reached it), it has seen all but at most those few. The
            # listener (a reliable reader of a depth-5 publisher, on a loaded machine) may
            # miss earlier predictions, not the last ones (nothing comes after them to push
            # them out): the node's own counts and stamps are the measure.
            last = set(stamps[-(MAX_LOST + 1):])
            wait_until(lambda: listener.spin() or any(
                stamp_ns(p.header.stamp) in last for p in listener.predictions), TIMEOUT_S,
                'a prediction of one of the last states')
            # strike_node, on the same clock, strikes the balls (its hit-time check compares
            # like with like, or is off for stamps on another time base).
            wait_until(lambda: listener.spin() or any(c.feasible for c in listener.commands),
                       TIMEOUT_S, 'a feasible strike command')
            assert group.stop('prediction') == 0
            assert group.stop('strike') == 0
    finally:
        listener.close()
    received, predicted, dropped, first, last = _summary(tmp_path)
    # From the first ball on (its first state at the latest), every state but a few reached
    # the node, up to one of the last ones.
    assert stamps.index(first) < BALL_STATES and stamps.index(last) >= len(stamps) - 1 - MAX_LOST
    assert received >= stamps.index(last) - stamps.index(first) + 1 - MAX_LOST
    assert (predicted, dropped) == (received, 0)        # none stale, none lost in the node
    assert {stamp_ns(p.header.stamp) for p in listener.predictions} <= set(stamps)
    log = (tmp_path / 'prediction.log').read_text()
    if recorded_on == 'wall clock':
        assert 'another time base' in log
    else:
        assert 'another time base' not in log


def test_a_session_bag_played_twice_is_judged_on_each_pass_clock(tmp_path):
    # Each `ros2 bag play` process its own pass: the second player made its /clock publisher
    # after waiting for the state's subscribers, and prediction_node matched it up to 2 s
    # after the first states (on a loaded machine), judging them against the first pass's
    # end (stale by the bag's length: 0.8 s here, over the 0.5 s limit). The player's side
    # is checked exactly in test_bag.py (test_play_with_clock_waits_for_a_clock_subscriber_too).
    stamps = _write_session(tmp_path / 'session', STAMP_BASE_NS)
    domain = unique_domain()
    listener = Listener(domain, states=False)
    try:
        with ProcessGroup(str(tmp_path)) as group:
            env = {'ROS_DOMAIN_ID': str(domain)}
            group.start('prediction', ['ros2', 'run', 'tt_prediction', 'prediction_node',
                                       '--ros-args', '-p', 'use_sim_time:=true',
                                       '-p', 'uncertainty:=false'], env=env)
            for n in range(2):
                player = group.start(f'play{n}', ['ros2', 'bag', 'play',
                                                  str(tmp_path / 'session'), '--clock',
                                                  '--wait-for-subscribers'], env=env)
                wait_until(lambda p=player: listener.spin() or p.poll() is not None,
                           TIMEOUT_S, f'pass {n} to end')
                assert player.returncode == 0
            assert group.stop('prediction') == 0
    finally:
        listener.close()
    received, predicted, dropped, first, last = _summary(tmp_path)
    assert received > len(stamps)                 # states of both passes reached the node
    assert (predicted, dropped) == (received, 0), 'states of a pass dropped (stale?)'


def _summary(tmp_path):
    """(states, predictions, dropped, first stamp, last stamp (ns)) of the summary
    prediction_node logs on exit; the test fails when its log has none."""
    log = (tmp_path / 'prediction.log').read_text()
    found = re.search(r'(\d+) states, (\d+) predictions, (\d+) dropped;.*; stamps '
                      r'(\d+)\.(\d{9}) to (\d+)\.(\d{9}) s', log)
    assert found, f'no summary line in prediction.log:\n{log}'
    v = [int(g) for g in found.groups()]
    return v[0], v[1], v[2], v[3] * 10**9 + v[4], v[5] * 10**9 + v[6]


def test_a_rig_of_video_files_gives_a_prediction_per_state_on_video_time(tmp_path):
    from tt_perception.camera import load_rig

    from tt_perception import synth

    rig_path = synth.make_rig(str(tmp_path / 'calib'))
    frames, truth = synth.render_balls(load_rig(rig_path), [synth.incoming_ball()], [0.0],
                                       duration=0.4, lead_in=0.1)
    video_rig = synth.write_scene(str(tmp_path / 'video'), rig_path, frames, truth,
                                  time_offset=0.0)   # synchronised: no offset to estimate
    domain = unique_domain()
    listener = Listener(domain)
    try:
        with ProcessGroup(str(tmp_path)) as group:
            env = {'ROS_DOMAIN_ID': str(domain)}
            group.start('prediction', ['ros2', 'run', 'tt_prediction', 'prediction_node',
                                       '--ros-args', '-p', 'use_sim_time:=true',
                                       '-p', 'uncertainty:=false'], env=env)
            wait_until(lambda: listener.spin() or listener.node.count_subscribers(
                '/ball/state') >= 2, TIMEOUT_S, 'prediction_node on /ball/state')
            group.start('perception', ['ros2', 'run', 'tt_perception', 'perception_node',
                                       '--ros-args', '-p', f'rig_file:={video_rig}',
                                       '-p', 'publish_clock:=true',
                                       '-p', 'wait_for_subscribers:=2',
                                       '-p', 'video_rate:=0'], env=env)
            log = tmp_path / 'perception.log'
            wait_until(lambda: listener.spin() or 'end of the video files' in log.read_text(),
                       TIMEOUT_S, 'the video files read and processed')
            end = re.search(r'end of the video files: (\d+) frames, (\d+) states',
                            log.read_text())
            n_states = int(end.group(2))
            assert n_states > 20
            wait_until(lambda: listener.spin() or len(listener.predictions) >= n_states,
                       TIMEOUT_S, f'{n_states} predictions')
            assert group.stop('perception') == 0
            assert group.stop('prediction') == 0
    finally:
        listener.close()
    # One prediction per state, stamped with the state's video time (from camera 0's first
    # frame, not the wall clock).
    predicted = sorted(stamp_ns(p.header.stamp) for p in listener.predictions)
    assert len(predicted) == n_states and predicted[-1] < 10 * 10**9
    assert listener.states and (
        {stamp_ns(s.header.stamp) for s in listener.states} <= set(predicted))
    assert 'stale' not in (tmp_path / 'prediction.log').read_text()
