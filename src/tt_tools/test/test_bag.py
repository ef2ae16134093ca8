"""ros2 bag record / info / play round trips, readers, signals and bad bags."""

import argparse
import os
import shutil
import signal

from conftest import Graph, Ros2Process, error_lines, ros2
from mcap.reader import make_reader
import pytest
from rclpy.duration import Duration
import rclpy.node
import rclpy.publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from rosbags.interfaces import QosReliability
from rosbags.rosbag2 import Reader
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo
from tt_ros.bagfile import BagError, BagWriter, TypeRegistry, open_bag
from tt_ros.testing import unique_domain, unique_prefix
from tt_tools.ros2 import build_parser
from tt_tools.rosutil import CliNode

from tt_msgs.msg import BallState
from tt_tools import bag as bag_verbs

pytestmark = pytest.mark.graph

N_STATES = 20
RATE_HZ = 20.0


def _state(i):
    msg = BallState()
    msg.header.stamp.sec, msg.header.frame_id = 1000 + i, 'table'
    msg.position.x, msg.spin.y, msg.track_id = -1.0 + 0.05 * i, 10.0 * i, i
    msg.covariance[i] = float(i)
    return msg


def _info(i):
    msg = CameraInfo()
    msg.width, msg.height, msg.distortion_model = 640 + i, 480, 'plumb_bob'
    msg.d = [0.01 * i, 0.0, 0.0, 0.0, 0.0]
    return msg


def _record(out, storage, prefix):
    """Record N_STATES BallStates (reliable) and CameraInfos (best effort) published at 20 Hz."""
    topics = {'state': f'{prefix}/state', 'info': f'{prefix}/info'}
    g = Graph()
    rec = Ros2Process('bag', 'record', '-o', str(out), '-s', storage, *topics.values())
    try:
        state_pub = g.node.create_publisher(BallState, topics['state'], QoSProfile(depth=50))
        info_pub = g.node.create_publisher(CameraInfo, topics['info'], qos_profile_sensor_data)
        g.spin_until(lambda: state_pub.get_subscription_count() >= 1
                     and info_pub.get_subscription_count() >= 1, 60, 'the recorder to subscribe')
        sent = {'state': [], 'info': []}

        def tick():
            i = len(sent['state'])
            if i < N_STATES:
                sent['state'].append(_state(i))
                sent['info'].append(_info(i))
                state_pub.publish(sent['state'][-1])
                info_pub.publish(sent['info'][-1])

        g.node.create_timer(1.0 / RATE_HZ, tick)
        g.spin_until(lambda: len(sent['state']) == N_STATES, 60, 'all messages published')
        assert state_pub.wait_for_all_acked(Duration(seconds=10))
        rec.signal(signal.SIGINT)
        assert rec.wait() == 0, rec.stderr
    finally:
        rec.stop()
        g.close()
    assert 'Traceback' not in rec.stderr
    return topics, sent


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp('bag') / 'session'
    topics, sent = _record(out, 'mcap', f'/tt_bag_test_{os.getpid()}')
    return out, topics, sent


def _bag_messages(path):
    """{topic: [(timestamp ns, raw bytes)]} read with rosbags."""
    out = {}
    with Reader(path) as reader:
        for conn, stamp, raw in reader.messages():
            out.setdefault(conn.topic, []).append((stamp, bytes(raw)))
    return out


def _is_subsequence(part, whole):
    it = iter(whole)
    return all(any(x == y for y in it) for x in part)


def test_info_counts_every_reliable_message(recorded):
    out, topics, sent = recorded
    rc, text, err = ros2('bag', 'info', str(out))
    assert rc == 0, err
    lines = dict(line.split(':', 1) for line in text.splitlines() if line[:1] != ' ')
    assert lines['Storage id'].strip() == 'mcap'
    n_info = len(_bag_messages(out)[topics['info']])
    assert int(lines['Messages']) == N_STATES + n_info
    assert (f'Topic: {topics["state"]} | Type: tt_msgs/msg/BallState | Count: {N_STATES} | '
            'Serialization Format: cdr') in text


def test_rosbags_and_mcap_read_the_same_messages_that_were_published(recorded):
    out, topics, sent = recorded
    bag = _bag_messages(out)
    # Reliable topic: every message, in order, as sent (CDR padding bytes are arbitrary, so
    # the comparison is on the decoded messages).
    assert [deserialize_message(raw, BallState) for _, raw in bag[topics['state']]] == (
        sent['state'])
    # Best-effort topic: what arrived is a subset of what was sent, in order.
    infos = [deserialize_message(raw, CameraInfo) for _, raw in bag[topics['info']]]
    assert infos and _is_subsequence(infos, sent['info'])
    with Reader(out) as reader:
        qos = {c.topic: c.ext.offered_qos_profiles[0].reliability for c in reader.connections}
        # The type hash seen in the graph (rclpy) is the hash of the stored definition.
        registry = TypeRegistry()
        for conn in reader.connections:
            assert conn.digest.startswith('RIHS01_')
            assert conn.digest == registry.definition(conn.msgtype)[1]
    assert qos == {topics['state']: QosReliability.RELIABLE,
                   topics['info']: QosReliability.BEST_EFFORT}
    # rosbags decodes with the definitions stored in the bag only (no tt_msgs needed).
    with AnyReader([out]) as reader:
        decoded = [reader.deserialize(raw, conn.msgtype)
                   for conn, _, raw in reader.messages()
                   if conn.topic == topics['state']]
    assert [m.track_id for m in decoded] == list(range(N_STATES))
    assert [m.position.x for m in decoded] == [m.position.x for m in sent['state']]
    # The mcap reader sees the same messages with a ros2msg schema (what Foxglove decodes).
    (mcap_file,) = out.glob('*.mcap')
    seen = {}
    with open(mcap_file, 'rb') as f:
        for schema, channel, message in make_reader(f).iter_messages():
            seen.setdefault(channel.topic, []).append((message.log_time, message.data))
            if channel.topic == topics['state']:
                assert (schema.name, schema.encoding) == ('tt_msgs/msg/BallState', 'ros2msg')
                assert b'geometry_msgs/Point position' in schema.data
                assert b'MSG: geometry_msgs/Point' in schema.data
    assert seen == {k: [(t, raw) for t, raw in v] for k, v in bag.items()}


def test_play_replays_content_and_timing_scaled_by_rate(recorded, graph, procs):
    out, topics, sent = recorded
    got = []
    graph.node.create_subscription(
        BallState, topics['state'],
        lambda m: got.append((graph.node.get_clock().now().nanoseconds, m)),
        QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    graph.node.create_subscription(CameraInfo, topics['info'], lambda m: None,
                                   qos_profile_sensor_data)  # every topic has a subscriber
    play = procs('bag', 'play', str(out), '--rate', '2', '--wait-for-subscribers')
    graph.spin_until(lambda: len(got) == N_STATES, 60, 'the replayed states')
    assert play.wait() == 0, play.stderr
    assert [m for _, m in got] == sent['state']


def test_play_delivers_every_message_to_a_best_effort_subscriber(recorded, graph, procs):
    # A reliable recording (states from ros2 topic pub) into prediction_node's best-effort
    # subscription: the first state went out before the node had matched the player, or the
    # last one was lost as the player ended, in 3 of 6 plays (a ROS user's walk-through).
    out, topics, sent = recorded
    got = []
    graph.node.create_subscription(BallState, topics['state'], got.append,
                                   qos_profile_sensor_data)
    play = procs('bag', 'play', str(out), '--topics', topics['state'], '--rate', '4',
                 '--wait-for-subscribers')
    graph.spin_until(lambda: play.proc.poll() is not None, 60, 'the player to end')
    assert play.wait() == 0, play.stderr
    graph.spin_until(lambda: len(got) == N_STATES, 10, 'every replayed state')
    assert got == sent['state']


def test_play_waits_for_a_link_further_down_the_chain(recorded, graph, procs):
    # A session replayed into prediction and strike: the player waited for prediction's
    # subscription of /ball/state only, and the first ball's predictions went out before
    # strike had found prediction (a ROS user's walk-through: ball 1 never struck).
    out, topics, sent = recorded
    link = f'{unique_prefix()}/prediction'
    got = []
    graph.node.create_subscription(BallState, topics['state'], got.append,
                                   QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    graph.node.create_subscription(CameraInfo, topics['info'], lambda m: None,
                                   qos_profile_sensor_data)
    play = procs('bag', 'play', str(out), '--wait-for-subscribers', '--wait-for-topic', link)
    graph.spin_until(lambda: f'not yet: {link})' in play.stderr, 60, 'the player to wait')
    assert not got and play.proc.poll() is None
    graph.node.create_publisher(BallState, link, 10)         # the link's two ends
    graph.node.create_subscription(BallState, link, lambda m: None, 10)
    graph.spin_until(lambda: len(got) == N_STATES, 60, 'the replayed states')
    assert play.wait() == 0, play.stderr
    assert got == sent['state']


class _FakeTime:
    """The player's clock in :func:`test_play_paces_messages_and_clock_by_bag_time_over_rate`:
    it moves only when the player waits, by exactly the time waited, and runs the player's
    timers (the /clock publisher) at their periods of this time."""

    def __init__(self):
        self.now = 100.0
        self.timers = []        # [period s, next due s, callback]

    def monotonic(self):
        return self.now

    def advance(self, dt):
        end = self.now + dt
        while True:
            due = [t for t in self.timers if t[1] <= end]
            if not due:
                break
            timer = min(due, key=lambda t: t[1])
            self.now = timer[1]
            timer[1] += timer[0]
            timer[2]()
        self.now = end


def _play_on_fake_time(monkeypatch, argv, stop=None, late=0.0):
    """Run ``bag play`` in this process on a fake clock (:class:`_FakeTime`); returns the
    start time and [(time, topic, message)] of everything published. ``stop(published)``:
    the player is stopped (as by a signal) once it is true. ``late``: every wait lasts that
    much longer than asked, s (a busy machine)."""
    fake = _FakeTime()
    published = []

    def spin_until(self, condition=lambda: False, timeout=None, step=0.1):
        if timeout is not None and timeout > 0:
            fake.advance(timeout + late)
        if stop is not None and stop(published):
            self.stopped = True
        return bool(condition())

    def create_timer(self, period, callback, *args, **kwargs):
        fake.timers.append([period, fake.now + period, callback])

    monkeypatch.setattr(bag_verbs, 'time', fake)
    monkeypatch.setattr(CliNode, 'spin_until', spin_until)
    monkeypatch.setattr(rclpy.node.Node, 'create_timer', create_timer)
    monkeypatch.setattr(rclpy.publisher.Publisher, 'publish',
                        lambda self, msg: published.append((fake.now, self.topic_name, msg)))
    parser = argparse.ArgumentParser()
    bag_verbs.add_arguments(parser.add_subparsers())
    start = fake.now
    assert bag_verbs.bag_play(parser.parse_args(['play', *argv])) == 0
    return start, published


def _clock_ns(msg):
    return msg.clock.sec * 10**9 + msg.clock.nanosec


@pytest.mark.parametrize('rate, clock_hz', [(2.0, 50.0), (0.5, 10.0)])
def test_play_paces_messages_and_clock_by_bag_time_over_rate(recorded, monkeypatch, rate,
                                                              clock_hz):
    # The player in this process on a fake clock: message k goes out (stamp_k - first) / rate
    # after the start, and /clock carries first + elapsed * rate, on the player's timer at
    # clock_hz: checked exactly, with no wall-clock time in the test.
    out, topics, _ = recorded
    start, published = _play_on_fake_time(
        monkeypatch, [str(out), '--rate', str(rate), '--clock', str(clock_hz)])
    bag = _bag_messages(out)
    first = min(t for msgs in bag.values() for t, _ in msgs)
    expected = sorted((t, topic, raw) for topic, msgs in bag.items() for t, raw in msgs)
    played = [(t, topic, msg) for t, topic, msg in published if topic in bag]
    assert [(topic, msg) for _, topic, msg in played] == [(topic, raw) for _, topic, raw in
                                                          expected]
    for (t_pub, _, _), (stamp, _, _) in zip(played, expected, strict=True):
        assert t_pub - start == pytest.approx((stamp - first) / 1e9 / rate, abs=1e-9)
    clocks = [(t, _clock_ns(msg)) for t, topic, msg in published if topic == '/clock']
    # The bag's start at once, before the first message (a node on /clock would otherwise
    # take it before it has a time), then one /clock per period of clock_hz until the last
    # message, each with the bag time.
    assert next(topic for _, topic, _ in published if topic == '/clock' or topic in bag) == \
        '/clock'
    span = (expected[-1][0] - first) / 1e9 / rate
    assert len(clocks) == 1 + int(span * clock_hz + 1e-9)
    for k, (t, ns) in enumerate(clocks):
        assert t - start == pytest.approx(k / clock_hz, abs=1e-9)
        assert ns - first == pytest.approx(k / clock_hz * rate * 1e9, abs=2)


@pytest.mark.parametrize('matched_after', [3, 0, None])
def test_play_says_what_went_out_before_a_subscriber_matched(recorded, monkeypatch, capfd,
                                                            matched_after):
    # A plain play into nodes already running: discovery matched prediction_node 3.5 s into
    # a 5 s bag, and what went out before reached no one, without a word (a walk-through,
    # 7 Dec 2026). Here each topic's subscriber matches after its first 3 messages; or is
    # there from the start (0); or never comes (None: nobody listens, nothing lost).
    checks = {}

    def subscription_count(self):
        checks[self.topic_name] = checks.get(self.topic_name, 0) + 1
        if matched_after is None:
            return 0
        return int(checks[self.topic_name] > matched_after)
    monkeypatch.setattr(rclpy.publisher.Publisher, 'get_subscription_count',
                        subscription_count)
    out, _, _ = recorded
    _play_on_fake_time(monkeypatch, [str(out)])
    warned = [line for line in capfd.readouterr().err.splitlines() if 'matched' in line]
    expected = sorted(f'[WARN] 3 of {len(msgs)} messages on {topic} went out before its '
                      'subscriber matched, to no one: --wait-for-subscribers waits for the '
                      'subscribers first' for topic, msgs in _bag_messages(out).items()
                      if len(msgs) >= 3) if matched_after == 3 else []
    assert sorted(warned) == expected and (expected or matched_after != 3)


def test_play_clock_stops_at_the_bags_end_when_the_player_wakes_late(recorded, monkeypatch):
    # Every wait 15 ms longer than asked, as on a busy machine: /clock's timer then runs
    # while the last message is overdue. The bag time it publishes stays within the bag (it
    # ran 15 ms past the end in a full test run, which a node on /clock takes for time that
    # passed).
    out, _, _ = recorded
    _, published = _play_on_fake_time(monkeypatch, [str(out), '--clock', '100'], late=0.015)
    with Reader(out) as reader:
        start, end = reader.start_time, reader.end_time
    clocks = [_clock_ns(m) for _, topic, m in published if topic == '/clock']
    assert clocks == sorted(clocks) and len(clocks) > 2
    assert start == clocks[0] and clocks[-1] <= end


def test_play_loop_puts_the_clock_back_before_each_pass(recorded, monkeypatch):
    # --loop --clock: /clock jumps back to the bag's start before a pass's first message.
    # It kept the end of the pass before until its timer's next tick, and a node on /clock
    # dropped the pass's first states as stale by the bag's length.
    out, _, _ = recorded
    bag = _bag_messages(out)
    n = sum(len(msgs) for msgs in bag.values())
    first = min(t for msgs in bag.values() for t, _ in msgs)
    _, published = _play_on_fake_time(
        monkeypatch, [str(out), '--loop', '--clock', '10'],
        stop=lambda published: sum(topic in bag for _, topic, _ in published) > n + 2)
    topics = [topic for _, topic, _ in published]
    second_pass = [k for k, topic in enumerate(topics) if topic in bag][n]
    clocks_before = [_clock_ns(m) for _, topic, m in published[:second_pass]
                     if topic == '/clock']
    assert clocks_before[-1] == first and max(clocks_before) > first


def test_play_selected_topics_from_an_offset(recorded, graph, procs):
    out, topics, sent = recorded
    bag = _bag_messages(out)
    start = min(t for msgs in bag.values() for t, _ in msgs)
    stamps = [t for t, _ in bag[topics['state']]]
    offset_ns = stamps[N_STATES // 2] - start - 1000
    expected = [sent['state'][i] for i, t in enumerate(stamps) if t >= start + offset_ns]
    assert 0 < len(expected) < N_STATES
    got = []
    graph.node.create_subscription(BallState, topics['state'], got.append,
                                   QoSProfile(depth=100))
    play = procs('bag', 'play', str(out), '--topics', topics['state'], '--start-offset',
                 f'{offset_ns / 1e9:.9f}', '--wait-for-subscribers')
    graph.spin_until(lambda: len(got) == len(expected), 60, 'the replayed states')
    # The player offers only the selected topic.
    assert graph.node.get_publishers_info_by_topic(topics['info']) == []
    assert play.wait() == 0, play.stderr
    assert got == expected


def test_play_publishes_the_bag_time_on_clock(recorded, procs):
    out, topics, sent = recorded
    domain = 50 + os.getpid() % 50  # /clock is shared: keep this test in its own domain
    with Graph(domain_id=domain) as g:
        clocks, got = [], []
        g.node.create_subscription(
            Clock, '/clock', lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec),
            QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT))
        g.node.create_subscription(BallState, topics['state'], got.append, QoSProfile(depth=100))
        g.node.create_subscription(CameraInfo, topics['info'], lambda m: None,
                                   qos_profile_sensor_data)
        play = procs('bag', 'play', str(out), '--clock', '100', '--wait-for-subscribers',
                     env={'ROS_DOMAIN_ID': str(domain)})
        g.spin_until(lambda: len(got) == N_STATES and play.proc.poll() is not None, 60,
                     'the replay to end')
    assert play.wait() == 0, play.stderr
    bag = _bag_messages(out)
    start = min(t for msgs in bag.values() for t, _ in msgs)
    end = max(t for msgs in bag.values() for t, _ in msgs)
    # How many arrive depends on how long the replay takes: their pace is checked on a fake
    # clock (test_play_paces_messages_and_clock_by_bag_time_over_rate); here the bag time,
    # in order, within the bag's span (plus the last period of the 100 Hz clock).
    assert clocks
    assert clocks == sorted(clocks)
    assert start <= clocks[0] and clocks[-1] <= end + 10_000_000


def test_play_with_clock_waits_only_for_nodes_on_sim_time(recorded, procs):
    # --clock --wait-for-subscribers waits for every /clock subscription the graph shows (a
    # node on sim time matched the player's /clock up to 2 s after its first states, made
    # after the wait: stale states, strokes too late); with none (consumers not on sim time,
    # as here) it plays once the replayed topics have theirs, not forever.
    out, topics, _ = recorded
    domain = unique_domain()        # /clock is shared: a domain of this test's own
    with Graph(domain_id=domain) as g:
        got = []
        g.node.create_subscription(BallState, topics['state'], got.append, QoSProfile(depth=100))
        g.node.create_subscription(CameraInfo, topics['info'], lambda m: None,
                                   qos_profile_sensor_data)
        play = procs('bag', 'play', str(out), '--clock', '--wait-for-subscribers',
                     env={'ROS_DOMAIN_ID': str(domain)})
        g.spin_until(lambda: len(got) == N_STATES and play.proc.poll() is not None, 60,
                     'the replay to end')
    assert play.wait() == 0, play.stderr
    assert '/clock' not in play.stderr


def test_sqlite3_storage_round_trip(tmp_path):
    out = tmp_path / 'db'
    topics, sent = _record(out, 'sqlite3', f'/tt_bag_sqlite_{os.getpid()}')
    assert list(out.glob('*.db3'))
    bag = _bag_messages(out)
    assert [deserialize_message(raw, BallState) for _, raw in bag[topics['state']]] == (
        sent['state'])
    rc, text, _ = ros2('bag', 'info', str(out))
    assert rc == 0 and 'Storage id:        sqlite3' in text


def test_sigterm_while_recording_leaves_a_complete_bag(graph, procs, tmp_path, topic):
    out = tmp_path / 'cut_short'
    rec = procs('bag', 'record', '-o', str(out), topic)
    pub = graph.node.create_publisher(BallState, topic, QoSProfile(depth=100))
    graph.spin_until(lambda: pub.get_subscription_count() >= 1, 60, 'the recorder')
    sent = []

    def tick():
        sent.append(_state(len(sent) % 81))
        pub.publish(sent[-1])

    graph.node.create_timer(0.01, tick)
    graph.spin_until(lambda: len(sent) >= 30, 60, '30 messages published')
    assert pub.wait_for_all_acked(Duration(seconds=10))
    acked = len(sent)
    rec.signal(signal.SIGTERM)  # the publisher keeps going while the recorder stops
    graph.spin_until(lambda: rec.proc.poll() is not None, 60, 'the recorder to exit')
    assert rec.wait() == 0 and 'Traceback' not in rec.stderr
    reader = open_bag(str(out))  # raises if metadata and storage disagree
    try:
        got = [deserialize_message(raw, BallState) for _, _, raw in reader.messages()]
    finally:
        reader.close()
    assert acked <= len(got) <= len(sent)
    assert got == sent[:len(got)]


def _small_bag(path, storage):
    writer = BagWriter(str(path), storage)
    conn = writer.add_topic('/ball/state', 'tt_msgs/msg/BallState')
    for i in range(300):
        writer.write(conn, 10**18 + i * 10**7, serialize_message(_state(i % 81)))
    writer.close()
    return path


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_truncated_bag_is_a_one_line_error(tmp_path, storage):
    bag = _small_bag(tmp_path / 'whole', storage)
    assert open_bag(str(bag)).message_count == 300
    cut = tmp_path / 'cut'
    shutil.copytree(bag, cut)
    (storage_file,) = [p for p in cut.iterdir() if p.name != 'metadata.yaml']
    os.truncate(storage_file, storage_file.stat().st_size * 6 // 10)
    for verb in ('info', 'play'):
        rc, out, err = ros2('bag', verb, str(cut))
        assert rc == 1 and out == ''
        assert err.count('\n') == 1 and 'truncated or corrupt' in err, err


def test_play_from_past_the_end_is_one_line_and_plays_nothing(tmp_path):
    bag = _small_bag(tmp_path / 'bag', 'mcap')           # 300 messages 10 ms apart: 2.99 s
    rc, out, err = ros2('bag', 'play', str(bag), '--start-offset', '3.5')
    assert (rc, out) == (1, '')
    assert err == ('ros2 bag: --start-offset 3.5 s is past the end of the bag (2.99 s long): '
                   'nothing to play\n')


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_play_of_a_bag_without_messages_is_one_line(tmp_path, storage):
    # As record leaves it when nothing was published: a topic, no message.
    writer = BagWriter(str(tmp_path / 'empty'), storage)
    writer.add_topic('/ball/state', 'tt_msgs/msg/BallState')
    writer.close()
    rc, out, err = ros2('bag', 'play', str(tmp_path / 'empty'))
    assert (rc, out) == (1, '')
    assert err == f"ros2 bag: bag '{tmp_path / 'empty'}' holds no message: nothing to play\n"


@pytest.mark.parametrize('rate', ['0', 'nan', '-1'])
def test_play_clock_rate_that_is_not_a_rate_is_a_usage_error(tmp_path, rate):
    bag = _small_bag(tmp_path / 'bag', 'mcap')
    rc, out, err = ros2('bag', 'play', str(bag), '--clock', rate)
    assert (rc, out) == (2, '') and f'{rate} is not a number > 0' in err


def test_record_to_a_place_that_takes_no_bag_is_one_line(tmp_path):
    note = tmp_path / 'note.txt'
    note.write_text('keep')
    rc, out, err = ros2('bag', 'record', '-o', str(note / 'bag'), '/ball/state')
    assert (rc, out) == (1, '')
    assert err == f"ros2 bag: output '{note / 'bag'}': cannot write: Not a directory\n"
    assert note.read_text() == 'keep'


def test_record_of_an_invalid_topic_name_makes_no_bag(tmp_path):
    # The bag was made first (metadata.yaml and an empty .mcap left), so that the same -o
    # given again, with the name mended, was refused: 'already exists'.
    out = tmp_path / 'recz'
    rc, stdout, err = ros2('bag', 'record', '-o', str(out), 'ball state')
    assert (rc, stdout) == (1, '') and not out.exists()
    assert err == ("ros2 bag: topic name '/ball state' is invalid: a name must not contain "
                   "characters other than alphanumerics, '_', or '/'\n")


def test_foreign_paths_are_one_line_errors(tmp_path):
    random_file = tmp_path / 'noise.mcap'
    random_file.write_bytes(os.urandom(4096))
    empty_dir = tmp_path / 'empty'
    empty_dir.mkdir()
    fake = shutil.copytree(_small_bag(tmp_path / 'good', 'mcap'), tmp_path / 'fake')
    (storage_file,) = fake.glob('*.mcap')
    storage_file.write_bytes(os.urandom(4096))
    # A recording killed (SIGKILL) before it wrote its metadata.yaml.
    killed = shutil.copytree(_small_bag(tmp_path / 'whole', 'mcap'), tmp_path / 'killed')
    (killed / 'metadata.yaml').unlink()
    cases = [(random_file, 'not a rosbag2 bag'), (empty_dir, 'no metadata.yaml'),
             (tmp_path / 'missing', 'does not exist'), (fake, 'truncated or corrupt'),
             (killed, r'incomplete: whole\.mcap without metadata\.yaml \(a recording that '
                      r'did not end: killed\?\)')]
    for path, words in cases:
        with pytest.raises(BagError, match=words):
            open_bag(str(path))
    rc, out, err = ros2('bag', 'info', str(random_file))
    assert rc == 1 and err.count('\n') == 1 and 'not a rosbag2 bag' in err


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_info_and_play_take_a_bags_storage_file_for_its_folder(tmp_path, monkeypatch, storage):
    # As rosbag2 does; the storage file was refused as 'not a rosbag2 bag'.
    bag = _small_bag(tmp_path / 'bag', storage)
    (storage_file,) = [p for p in bag.iterdir() if p.name != 'metadata.yaml']
    of_folder, of_file = ros2('bag', 'info', str(bag)), ros2('bag', 'info', str(storage_file))
    assert of_folder[0] == 0 and of_file == of_folder
    _, published = _play_on_fake_time(monkeypatch, [str(storage_file)])
    assert len([p for p in published if p[1] == '/ball/state']) == 300


def test_play_names_a_chosen_topic_the_bag_does_not_have(tmp_path, monkeypatch, capfd):
    bag = _small_bag(tmp_path / 'bag', 'mcap')
    _, published = _play_on_fake_time(monkeypatch, [str(bag), '--topics', '/ball/state',
                                                    '/ball/stat'])
    assert len([p for p in published if p[1] == '/ball/state']) == 300
    assert capfd.readouterr().err.splitlines() == [
        '[WARN] --topics: /ball/stat not in the bag (it has /ball/state)']


def test_record_names_a_topic_that_never_appeared(graph, procs, tmp_path, topic):
    # It recorded nothing of it without a word: a misspelt name among others.
    out = tmp_path / 'typo'
    rec = procs('bag', 'record', '-o', str(out), topic, topic + 'x')
    pub = graph.node.create_publisher(BallState, topic, QoSProfile(depth=10))
    graph.spin_until(lambda: pub.get_subscription_count() >= 1, 60, 'the recorder to subscribe')
    pub.publish(_state(1))
    assert pub.wait_for_all_acked(Duration(seconds=10))
    rec.signal(signal.SIGINT)
    assert rec.wait() == 0, rec.stderr
    assert (f"[WARN] '{topic}x' not recorded: no publisher of it appeared; did you mean "
            f"'{topic}'?") in rec.stderr.splitlines()
    assert len(_bag_messages(out)[topic]) == 1


def test_record_all_topics_picks_up_a_new_publisher(graph, procs, tmp_path, topic):
    out = tmp_path / 'all'
    rec = procs('bag', 'record', '-a', '-o', str(out))
    graph.spin_until(lambda: graph.node_running(rec), 60, 'the recorder node')
    pub = graph.node.create_publisher(BallState, topic, QoSProfile(depth=10))  # after it started
    graph.spin_until(lambda: pub.get_subscription_count() >= 1, 60, 'the recorder to subscribe')
    sent = [_state(i) for i in range(5)]
    for msg in sent:
        pub.publish(msg)
    assert pub.wait_for_all_acked(Duration(seconds=10))
    rec.signal(signal.SIGINT)
    assert rec.wait() == 0, rec.stderr
    got = [deserialize_message(raw, BallState) for _, raw in _bag_messages(out)[topic]]
    assert got == sent


@pytest.mark.parametrize('argv, chosen', [
    (['-a'], {'/ball/state', '/ball/prediction', '/cam0/image_raw', '/rosout'}),
    (['-e', '^/ball/'], {'/ball/state', '/ball/prediction'}),
    (['-e', 'image'], {'/cam0/image_raw'}),                      # anywhere in the name
    (['-a', '-x', 'image|rosout'], {'/ball/state', '/ball/prediction'}),
    (['-e', '/ball/', '--exclude-topics', '/ball/prediction'], {'/ball/state'}),
    # A topic given by name is recorded whatever the exclusions say (rosbag2's).
    (['/rosout', '-e', '/ball/', '-x', 'state|rosout'], {'/ball/prediction', '/rosout'}),
])
def test_record_chooses_topics_by_name_regex_and_exclusions(argv, chosen):
    graph_topics = ['/ball/state', '/ball/prediction', '/cam0/image_raw', '/rosout']
    args = build_parser().parse_args(['bag', 'record', *argv])
    _, test = bag_verbs.topic_chooser(args)
    assert {t for t in graph_topics if test(t)} == chosen


def test_record_regex_records_the_matching_topics_only(graph, procs, tmp_path, topic):
    out = tmp_path / 'regex'
    rec = procs('bag', 'record', '-o', str(out), '-e', f'^{topic}/ball/', '-x', 'skip$',
                f'{topic}/other')
    pubs = {name: graph.node.create_publisher(BallState, f'{topic}/{name}',
                                              QoSProfile(depth=10))
            for name in ('ball/a', 'ball/skip', 'other', 'elsewhere')}
    graph.spin_until(lambda: pubs['ball/a'].get_subscription_count() >= 1
                     and pubs['other'].get_subscription_count() >= 1, 60,
                     'the recorder to subscribe')
    for i, pub in enumerate(pubs.values()):
        pub.publish(_state(i))
    assert pubs['ball/a'].wait_for_all_acked(Duration(seconds=10))
    assert pubs['other'].wait_for_all_acked(Duration(seconds=10))
    rec.signal(signal.SIGINT)
    assert rec.wait() == 0, rec.stderr
    assert set(_bag_messages(out)) == {f'{topic}/ball/a', f'{topic}/other'}
    assert pubs['ball/skip'].get_subscription_count() == 0
    assert pubs['elsewhere'].get_subscription_count() == 0


def test_record_with_a_bad_regex_is_one_line_and_makes_no_bag(tmp_path):
    out = tmp_path / 'bad'
    rc, stdout, err = ros2('bag', 'record', '-o', str(out), '-e', '/ball/(')
    assert (rc, stdout) == (1, '') and not out.exists()
    assert err.startswith("ros2 bag: -e '/ball/(' is not a regular expression: ")
    assert err.count('\n') == 1


def test_play_remap_plays_a_topic_on_another_name(recorded, graph, procs):
    out, topics, sent = recorded
    renamed = topics['state'] + '_replayed'
    got = []
    graph.node.create_subscription(BallState, renamed, got.append, QoSProfile(depth=100))
    play = procs('bag', 'play', str(out), '--topics', topics['state'], '--remap',
                 f'{topics["state"]}:={renamed}', '--wait-for-subscribers')
    graph.spin_until(lambda: len(got) == N_STATES, 60, 'the remapped states')
    assert play.wait() == 0, play.stderr
    assert got == sent['state']
    assert graph.node.get_publishers_info_by_topic(topics['state']) == []
    rc, stdout, err = ros2('bag', 'play', str(out), '--remap', '/not/in/bag:=/x')
    assert (rc, stdout) == (1, '') and error_lines(err) == [
        'ros2 bag: --remap /not/in/bag: not among the topics played']
    rc, stdout, err = ros2('bag', 'play', str(out), '--remap', topics['state'])
    assert rc == 1 and error_lines(err) == [
        f"ros2 bag: --remap '{topics['state']}': not OLD_TOPIC:=NEW_TOPIC"]


def test_play_loop_repeats_until_interrupted(recorded, graph, procs):
    out, topics, sent = recorded
    got = []
    graph.node.create_subscription(BallState, topics['state'], got.append, QoSProfile(depth=100))
    play = procs('bag', 'play', str(out), '--topics', topics['state'], '--rate', '4', '--loop',
                 '--wait-for-subscribers')
    graph.spin_until(lambda: len(got) >= 2 * N_STATES + 1, 60, 'a third pass of the bag')
    play.signal(signal.SIGINT)
    assert play.wait() == 0 and 'Traceback' not in play.stderr
    assert got[:2 * N_STATES] == sent['state'] * 2


@pytest.mark.parametrize('argv, chosen', [
    ([], {'/ball/state', '/ball/prediction', '/cam0/image_raw', '/rosout'}),
    (['--topics', '/ball/state', 'rosout'], {'/ball/state', '/rosout'}),
    (['-e', '^/ball/'], {'/ball/state', '/ball/prediction'}),
    (['-e', 'image', '--topics', '/rosout'], {'/cam0/image_raw', '/rosout'}),
    (['-x', 'image|rosout'], {'/ball/state', '/ball/prediction'}),
    (['--exclude-topics', '/ball/prediction', '/rosout'], {'/ball/state', '/cam0/image_raw'}),
    # Unlike record's, play's exclusions apply to topics named too (rosbag2's play).
    (['--topics', '/ball/state', '/rosout', '-x', 'state'], {'/rosout'}),
])
def test_play_chooses_topics_by_name_regex_and_exclusions(argv, chosen):
    bag_topics = ['/ball/state', '/ball/prediction', '/cam0/image_raw', '/rosout']
    test = bag_verbs.play_chooser(build_parser().parse_args(['bag', 'play', 'b', *argv]))
    assert {t for t in bag_topics if test(t)} == chosen


def test_play_leaves_out_the_excluded_topics(recorded, monkeypatch):
    out, topics, _ = recorded
    _, published = _play_on_fake_time(monkeypatch, [str(out), '-x', 'info$'])
    assert [topic for _, topic, _ in published if topic in topics.values()] == \
        [topics['state']] * N_STATES


@pytest.mark.parametrize('argv, first_s, last_s', [
    (['--playback-duration', '0.5'], 0.0, 0.5),                 # both ends included
    (['--start-offset', '1', '--playback-duration', '0.5'], 1.0, 1.5),
    (['--start-offset', '1', '--playback-duration', '100'], 1.0, 2.99),
    (['--playback-until-nsec', str(10**18 + 2 * 10**9)], 0.0, 2.0),
    (['--playback-until-sec', '1000000002.0055'], 0.0, 2.0055),
    # Whichever ends first.
    (['--playback-duration', '0.3', '--playback-until-nsec', str(10**18 + 2 * 10**9)], 0.0, 0.3),
    (['--start-offset', '1', '--playback-duration', '2', '--playback-until-sec',
      '1000000002.5'], 1.0, 2.5),
])
def test_play_plays_the_messages_recorded_within_its_window(tmp_path, monkeypatch, argv,
                                                             first_s, last_s):
    # 300 messages 10 ms apart from 10**18 ns; a window [first, last] s after the bag's start
    # (rosbag2's --playback-duration from the start offset, --playback-until-* a bag time).
    bag = _small_bag(tmp_path / 'bag', 'mcap')
    stamps = [t for t, _ in _bag_messages(bag)['/ball/state']]
    expected = [raw for t, raw in _bag_messages(bag)['/ball/state']
                if round(first_s * 1e9) <= t - stamps[0] <= round(last_s * 1e9)]
    assert 0 < len(expected) < len(stamps)
    start, published = _play_on_fake_time(monkeypatch, [str(bag), *argv])
    played = [(t, msg) for t, topic, msg in published if topic == '/ball/state']
    assert [msg for _, msg in played] == expected
    assert played[0][0] == start            # the window's first message at once


def test_play_window_and_choice_that_leave_nothing_are_one_line(tmp_path):
    bag = _small_bag(tmp_path / 'bag', 'mcap')           # /ball/state, 10**18 ns to 2.99 s on
    for argv, error in [
            (['--playback-until-nsec', str(10**18 - 1)],
             '--playback-until-nsec: 999999999.999999999 s is before the play starts '
             '(1000000000.000000000 s): nothing to play'),
            (['--start-offset', '1', '--playback-until-sec', '1000000000.5'],
             '--playback-until-sec: 1000000000.500000000 s is before the play starts '
             '(1000000001.000000000 s): nothing to play'),
            (['--exclude-topics', 'state', '/ball/state'],
             '--exclude-topics: no topic of the bag chosen (it has /ball/state)'),
            (['--topics', '/ball/pred', '-e', 'image'],
             '--topics, -e: no topic of the bag chosen (it has /ball/state)')]:
        rc, out, err = ros2('bag', 'play', str(bag), *argv)
        assert (rc, out) == (1, '') and error_lines(err) == [f'ros2 bag: {error}'], argv
    rc, out, err = ros2('bag', 'play', str(bag), '-x', '[')
    assert (rc, out) == (1, '') and err.startswith("ros2 bag: --exclude-regex '[' is not a ")
    rc, out, err = ros2('bag', 'play', str(bag), '--playback-until-sec', '1e9',
                        '--playback-until-nsec', '1')
    assert (rc, out) == (2, '') and 'not allowed with argument' in err


def test_play_clock_follows_a_remap_of_clock(recorded, monkeypatch):
    # A robot's graph in a namespace on its own clock (bringup --namespace /robot1): the
    # player's /clock remapped with the topics, as rosbag2 remaps it (refused before, 'not
    # among the topics played'; a walk-through, 6 Dec 2026).
    out, topics, _ = recorded
    _, published = _play_on_fake_time(
        monkeypatch, [str(out), '--clock', '50', '--remap', '/clock:=/robot1/clock'])
    played = {topic for _, topic, _ in published}
    assert '/robot1/clock' in played and '/clock' not in played
