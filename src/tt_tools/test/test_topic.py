"""ros2 topic echo / hz / delay / bw / list / info / pub and ros2 node list against a live
graph."""

import ast
import os
import signal
import time

from builtin_interfaces.msg import Time
from conftest import Graph, Ros2Process, error_lines, ros2
import pytest
from rclpy.duration import Duration
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from tt_ros.testing import unique_domain
from tt_tools.introspect import dict_to_message
from tt_tools.ros2 import build_parser
from tt_tools.rosutil import chosen_qos
import yaml

from tt_msgs.msg import BallState, StrikeTarget

pytestmark = pytest.mark.graph

STATE = {
    'header': {'stamp': {'sec': 1700000000, 'nanosec': 5}, 'frame_id': 'table'},
    'position': {'x': -1.0, 'y': 0.2, 'z': 0.3},
    'velocity': {'x': 5.0, 'y': 0.0, 'z': 1.5},
    'spin': {'x': 0.0, 'y': 120.0, 'z': 0.0},
    'covariance': [float(i) for i in range(81)],
    'track_id': 17,
}


def _echo_of_state(graph, procs, topic, *options):
    """``ros2 topic echo topic *options`` (which must end by itself, e.g. with ``--once``) while
    STATE is published on ``topic`` until it has; the ended process."""
    echo = procs('topic', 'echo', topic, *options)
    pub = graph.node.create_publisher(BallState, topic, QoSProfile(depth=10))
    msg = dict_to_message(STATE, BallState)

    def ended():
        if echo.proc.poll() is None:
            pub.publish(msg)    # until the subscription has matched and one got through
            return False
        return True

    graph.spin_until(ended, 60, f'echo {" ".join(options)} to end')
    assert echo.wait() == 0, echo.stderr
    return echo


def test_echo_once_prints_a_published_ball_state_as_yaml(graph, procs, topic):
    echo = _echo_of_state(graph, procs, topic, '--once')
    first = echo.stdout.split('---\n')[0]
    assert yaml.safe_load(first) == STATE
    assert echo.stdout.count('---\n') == 1  # --once


def test_echo_csv_prints_one_line_of_values_a_message(graph, procs, topic):
    echo = _echo_of_state(graph, procs, topic, '--csv', '--no-arr', '--times', '2')
    # STATE's values in BallState.msg's order, its covariance (float64[81]) named by --no-arr
    # as rosidl_runtime_py names it.
    row = '1700000000,5,table,-1.0,0.2,0.3,5.0,0.0,1.5,0.0,120.0,0.0,<array type: double[81]>,17'
    assert echo.stdout.splitlines() == [row, row]


def test_echo_filter_prints_and_counts_only_the_messages_it_passes(graph, procs, topic):
    # ros2cli's --filter: a Python expression of m, the message or, with --field, that field.
    echo = procs('topic', 'echo', topic, '--filter', 'm % 3 == 0 and m > 0', '--times', '2',
                 '--field', 'track_id')
    pub = graph.node.create_publisher(BallState, topic, QoSProfile(depth=10))
    sent = []

    def printed():
        if echo.proc.poll() is None:
            msg = BallState(track_id=len(sent))  # 0, 1, 2, ... until echo has printed two
            sent.append(msg.track_id)
            pub.publish(msg)
            return False
        return True

    graph.spin_until(printed, 60, 'echo --filter to print two messages')
    assert echo.wait() == 0, echo.stderr
    # Two ids, multiples of 3 above 0: the messages between them were not printed, nor
    # counted by --times (it would have ended after two messages whatever their ids).
    got = [int(v) for v in echo.stdout.split('---\n') if v.strip()]
    assert len(got) == 2 and 0 < got[0] < got[1] and got[0] % 3 == got[1] % 3 == 0, got
    assert set(got) <= set(sent)


def test_echo_message_info_flow_style_and_no_arr(graph, procs, topic):
    # -i: each message's info first (ros2cli's keys, sorted as its YAML prints them), then the
    # message: --flow-style on one line, --no-arr naming the covariance (float64[81]).
    echo = _echo_of_state(graph, procs, topic, '-i', '--flow-style', '--no-arr', '--once')
    info, message, rest = echo.stdout.split('---\n')
    info = yaml.safe_load(info)
    assert list(info) == ['publication_sequence_number', 'received_timestamp',
                          'reception_sequence_number', 'source_timestamp']
    # Stamped by the publisher's and the echo's clocks: both this machine's, now.
    assert abs(info['source_timestamp'] / 1e9 - time.time()) < 60
    assert 0 <= info['received_timestamp'] - info['source_timestamp'] < 30e9
    assert info['publication_sequence_number'] >= 1 and rest == ''
    assert message.count('\n') == 1 and message.startswith('{')
    assert yaml.safe_load(message) == {**STATE, 'covariance': '<array type: double[81]>'}


def test_echo_timeout_ends_without_a_message_and_raw_is_not_with_field(topic):
    # --timeout: no publisher ever comes; echo ends by itself (exit 0, as ros2cli's).
    rc, out, err = ros2('topic', 'echo', topic, 'tt_msgs/msg/BallState', '--timeout', '2')
    assert (rc, out) == (0, '') and 'Traceback' not in err
    rc, out, err = ros2('topic', 'echo', topic, '--raw', '--field', 'position')
    assert (rc, out) == (1, '') and error_lines(err) == [
        'ros2 topic: --raw prints the serialized message: not with --csv or --field']


def test_echo_raw_prints_the_serialized_message(graph, procs, topic):
    # The bytes as Python writes them, then the separator: the CDR of the published state,
    # as long as rclpy's serialization of it (their alignment padding is whatever memory
    # held, so the bytes are compared through the message they decode to).
    echo = _echo_of_state(graph, procs, topic, '--raw', '--once')
    printed, rest = echo.stdout.split('\n---\n')
    data = ast.literal_eval(printed)
    msg = dict_to_message(STATE, BallState)
    assert rest == '' and isinstance(data, bytes) and len(data) == len(serialize_message(msg))
    assert deserialize_message(data, BallState) == msg


def test_echo_filter_that_is_no_expression_or_fails_is_one_line(graph, procs, topic):
    rc, out, err = ros2('topic', 'echo', topic, '--filter', 'm.track_id >')
    assert (rc, out) == (1, '') and len(error_lines(err)) == 1
    assert err.startswith("ros2 topic: --filter 'm.track_id >' is not a Python expression: ")
    echo = procs('topic', 'echo', topic, '--filter', 'm.spin_rate > 1')
    pub = graph.node.create_publisher(BallState, topic, QoSProfile(depth=10))

    def ended():
        if echo.proc.poll() is None:
            pub.publish(BallState())
            return False
        return True

    graph.spin_until(ended, 60, 'echo --filter to fail on a message')
    assert echo.wait() == 1 and echo.stdout == ''
    assert error_lines(echo.stderr) == [
        "ros2 topic: --filter 'm.spin_rate > 1' failed on a BallState: AttributeError: "
        "'BallState' object has no attribute 'spin_rate'"]


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_the_verb_starts_ends_it_once_its_node_exists(monkeypatch, topic, sig):
    # A Ctrl-C that comes while ``ros2`` still imports is noted, not raised: echo then ends at
    # once with exit 0 instead of waiting for a publisher (it was lost now and then before).
    from tt_tools import ros2, stop

    monkeypatch.setenv('TT_ROS2_NO_HANDOVER', '1')
    monkeypatch.setattr(stop, 'requested', False)
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        stop.install()
        os.kill(os.getpid(), sig)
        assert stop.requested
        assert ros2.main(['topic', 'echo', topic]) == 0
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_echo_without_publisher_waits_and_exits_cleanly_on_signal(graph, procs, topic, sig):
    echo = procs('topic', 'echo', topic)
    graph.spin_until(lambda: graph.node_running(echo), 60, 'the echo node in the graph')
    assert echo.proc.poll() is None  # still waiting for a publisher
    echo.signal(sig)
    assert echo.wait() in (0, 130)
    assert 'Traceback' not in echo.stderr and echo.stdout == ''


def test_hz_reports_the_rate_of_a_timer_publisher(graph, procs, topic):
    rate_hz = 20.0
    pub = graph.node.create_publisher(BallState, topic, qos_profile_sensor_data)
    sent = []

    def tick():
        pub.publish(BallState())
        sent.append(time.monotonic())

    graph.node.create_timer(1.0 / rate_hz, tick)
    hz = procs('topic', 'hz', topic, '--window', '40')
    graph.spin_until(lambda: hz.stdout.count('average rate') >= 3, 60, 'three hz reports')
    hz.signal(signal.SIGINT)
    assert hz.wait() == 0
    last = hz.stdout.strip().splitlines()[-2:]
    rate = float(last[0].split(':')[1])
    fields = last[1].split()
    assert fields[0] == 'min:' and fields[2] == 'max:' and fields[4:6] == ['std', 'dev:']
    shortest, longest = float(fields[1][:-1]), float(fields[3][:-1])
    window = int(fields[-1])
    # Content, not wall-clock rate (a loaded machine stretches the timer): the mean interval
    # 1/rate lies between the shortest and the longest interval, and the window counts
    # arrivals: at most the 40 asked for, and never more than the test published. (min and
    # max are printed to 1 ms: half of that is the rounding.)
    assert shortest - 0.0005 <= 1 / rate <= longest + 0.0005 and longest > 0
    assert float(fields[6][:-1]) >= 0
    assert 2 <= window <= min(40, len(sent))


def test_hz_filter_counts_only_the_messages_it_passes(graph, procs, topic):
    # 30 states sent at once, once hz has subscribed: ids 0, 3, ..., 27 pass (10 of them).
    pub = graph.node.create_publisher(BallState, topic, QoSProfile(depth=100))
    hz = procs('topic', 'hz', topic, '--filter', 'm.track_id % 3 == 0')
    graph.spin_until(lambda: pub.get_subscription_count() >= 1, 60, 'hz to subscribe')
    for i in range(30):
        pub.publish(BallState(track_id=i))
    assert pub.wait_for_all_acked(Duration(seconds=10))

    def windows():
        return [int(line.split()[-1]) for line in hz.stdout.splitlines() if 'window:' in line]

    # A report each second that brought messages: the last counts them all.
    graph.spin_until(lambda: windows() and windows()[-1] >= 10, 60, 'hz to count them all')
    hz.signal(signal.SIGINT)
    assert hz.wait() == 0, hz.stderr
    assert windows()[-1] == 10 and max(windows()) == 10, hz.stdout


def test_delay_reports_how_old_each_stamp_is_on_arrival(graph, procs, topic):
    # Every message is stamped 0.25 s before it is sent (the stamps on the same machine's
    # clock): no delay can be shorter than that, and the transport adds a little.
    back = 0.25
    pub = graph.node.create_publisher(BallState, topic, QoSProfile(depth=10))
    clock = graph.node.get_clock()

    def tick():
        msg = BallState()
        stamp = msg.header.stamp
        stamp.sec, stamp.nanosec = divmod(clock.now().nanoseconds - int(back * 1e9), 10**9)
        pub.publish(msg)

    graph.node.create_timer(0.05, tick)
    delay = procs('topic', 'delay', topic, '--window', '40')
    graph.spin_until(lambda: delay.stdout.count('average delay') >= 2, 60, 'two delay reports')
    delay.signal(signal.SIGINT)
    assert delay.wait() == 0, delay.stderr
    head, fields = (line.split() for line in delay.stdout.strip().splitlines()[-2:])
    assert head[:2] == ['average', 'delay:'] and fields[0] == 'min:' and fields[2] == 'max:'
    mean, shortest, longest = float(head[2]), float(fields[1][:-1]), float(fields[3][:-1])
    # Printed to 1 ms: half of that is the rounding. A delay in other units than seconds (or
    # of the wrong sign) would be far outside.
    assert back - 0.0005 <= shortest <= mean + 0.0005 <= longest + 0.001
    assert longest < back + 5.0
    assert 1 <= int(fields[-1]) <= 40


def test_qos_profile_presets_and_their_overrides(graph, procs, topic):
    # ros2cli's --qos-profile: rclpy's preset (sensor_data: best effort) in place of the QoS
    # matching the publishers (reliable here), a --qos-* option in place of its part.
    graph.node.create_publisher(BallState, topic, QoSProfile(depth=10))   # reliable
    echos = [procs('topic', 'echo', topic, '--qos-profile', 'sensor_data'),
             procs('topic', 'echo', topic, '--qos-profile', 'sensor_data',
                   '--qos-reliability', 'reliable')]
    pubs = [procs('topic', 'pub', topic + '/out', 'tt_msgs/msg/BallState', '-r', '1',
                  *extra) for extra in ((), ('--qos-profile', 'sensor_data'))]

    def endpoints(infos):
        return sorted(ReliabilityPolicy(i.qos_profile.reliability).name for i in infos
                      if i.node_name.startswith('_ros2cli_'))

    def seen():
        return (len(endpoints(graph.node.get_subscriptions_info_by_topic(topic))) == 2
                and len(endpoints(graph.node.get_publishers_info_by_topic(topic + '/out'))) == 2)

    graph.spin_until(seen, 60, "the commands' subscriptions and publishers")
    both = ['BEST_EFFORT', 'RELIABLE']
    assert endpoints(graph.node.get_subscriptions_info_by_topic(topic)) == both
    assert endpoints(graph.node.get_publishers_info_by_topic(topic + '/out')) == both
    for proc in echos + pubs:
        proc.signal(signal.SIGINT)
        assert proc.wait() == 0, proc.stderr


@pytest.mark.parametrize('argv, history, depth', [
    (['echo', '/x', '--qos-history', 'keep_all'], HistoryPolicy.KEEP_ALL, None),
    (['echo', '/x', '--qos-profile', 'sensor_data', '--qos-history', 'keep_last'],
     HistoryPolicy.KEEP_LAST, 5),
    (['pub', '/x', 'tt_msgs/msg/BallState', '{}', '--qos-depth', '3', '--qos-history',
      'keep_last'], HistoryPolicy.KEEP_LAST, 3),
    (['pub', '/x', 'tt_msgs/msg/BallState', '{}'], HistoryPolicy.KEEP_LAST, 10),
])
def test_qos_history_is_an_option_as_in_ros2cli(argv, history, depth):
    # ros2cli's echo and pub take --qos-history; tt's refused it ('unrecognized arguments',
    # exit 2; a ROS user's walk-through, 6 Dec 2026).
    qos = chosen_qos(build_parser().parse_args(['topic', *argv]))
    assert qos.history == history and (depth is None or qos.depth == depth)


def test_delay_and_pub_read_the_time_of_clock_with_use_sim_time(procs, topic):
    # A bag played with --clock: the time is /clock's (1000 s on, 50 ms a tick), far from this
    # machine's (1.8e9 s) and from the 0 a sim-time node has before its first /clock.
    back, step = 250_000_000, 50_000_000
    published = []
    domain = unique_domain()        # /clock is shared: a domain of this test's own
    env = {'ROS_DOMAIN_ID': str(domain)}
    with Graph(domain_id=domain) as g:
        clock_pub = g.node.create_publisher(Clock, '/clock', QoSProfile(depth=10))
        state_pub = g.node.create_publisher(BallState, topic, QoSProfile(depth=10))

        def tick():
            now = 1000 * 10**9 + len(published) * step
            published.append(now)
            clock_pub.publish(Clock(clock=Time(sec=now // 10**9, nanosec=now % 10**9)))
            msg = BallState()
            msg.header.stamp = Time(sec=(now - back) // 10**9, nanosec=(now - back) % 10**9)
            state_pub.publish(msg)

        stamps = []
        g.node.create_subscription(BallState, topic + '/stamped', stamps.append,
                                   QoSProfile(depth=10))
        g.node.create_timer(0.05, tick)
        delay = procs('topic', 'delay', topic, '--use-sim-time', env=env)
        pub = procs('topic', 'pub', topic + '/stamped', 'tt_msgs/msg/BallState',
                    '{header: {stamp: now}}', '--once', '--use-sim-time', env=env)
        g.spin_until(lambda: delay.stdout.count('average delay') >= 2 and stamps, 60,
                     'two delay reports and a stamped message')
        delay.signal(signal.SIGINT)
        assert delay.wait() == 0 and pub.wait() == 0, delay.stderr + pub.stderr
    # The time a sim-time node reads is the last /clock it received: one of those sent.
    stamp = stamps[0].header.stamp
    assert stamp.sec * 10**9 + stamp.nanosec in published
    # Each state is 0.25 s older than the /clock sent with it; the one the command had last
    # read may be a tick older (-0.05 s) or, with the state late, a few ticks newer.
    head, fields = (line.split() for line in delay.stdout.strip().splitlines()[-2:])
    shortest, longest = float(fields[1][:-1]), float(fields[3][:-1])
    assert (back - step) * 1e-9 - 0.0005 <= shortest <= float(head[2]) <= longest < 1.0


def test_delay_of_a_message_without_a_header_is_one_line_and_exit_1(graph, topic):
    graph.node.create_publisher(StrikeTarget, topic, QoSProfile(depth=10))
    proc = Ros2Process('topic', 'delay', topic)
    graph.spin_until(lambda: proc.proc.poll() is not None, 60, 'ros2 topic delay to end')
    assert proc.wait() == 1 and proc.stdout == ''
    assert error_lines(proc.stderr) == [
        f'ros2 topic: {topic}: tt_msgs/msg/StrikeTarget has no header, so no stamp to '
        'measure a delay from']


def test_bw_reports_the_serialized_size_of_the_messages(graph, procs, topic):
    msg = dict_to_message(STATE, BallState)
    size = len(serialize_message(msg))      # CDR, as the subscription receives it
    assert size < 1000                      # printed in bytes
    pub = graph.node.create_publisher(BallState, topic, QoSProfile(depth=10))
    sent = []

    def tick():
        pub.publish(msg)
        sent.append(1)

    graph.node.create_timer(0.05, tick)
    bw = procs('topic', 'bw', topic, '--window', '30')
    graph.spin_until(lambda: bw.stdout.count('Message size') >= 2, 60, 'two bw reports')
    bw.signal(signal.SIGINT)
    assert bw.wait() == 0, bw.stderr
    rate_line, size_line = bw.stdout.strip().splitlines()[-2:]
    assert size_line.strip() == f'Message size mean: {size} B min: {size} B max: {size} B'
    value, unit, _, count, _ = rate_line.split()
    assert float(value) > 0 and unit in ('B/s', 'KB/s', 'MB/s')
    assert 1 <= int(count) <= min(30, len(sent))


def test_list_and_info_show_type_and_offered_qos(graph, topic):
    graph.node.create_publisher(BallState, topic, qos_profile_sensor_data)
    def run(*args):
        proc = Ros2Process(*args, '--spin-time', '5')
        graph.spin_until(lambda: proc.proc.poll() is not None, 60, f'ros2 {args[0]} {args[1]}')
        assert proc.wait() == 0, proc.stderr
        return proc.stdout

    assert f'{topic} [tt_msgs/msg/BallState]' in run('topic', 'list', '-t').splitlines()
    info = run('topic', 'info', topic, '-v')
    assert info.startswith('Type: tt_msgs/msg/BallState\n')
    assert 'Publisher count: 1' in info and 'Subscription count: 0' in info
    assert '  Reliability: BEST_EFFORT' in info
    assert f'/{graph.node.get_name()}' in run('node', 'list').splitlines()


def test_node_list_warns_of_nodes_that_share_a_name(graph):
    # Two strike_nodes started by mistake were listed once and without a word, while both
    # commanded the arm.
    import rclpy

    twin = rclpy.create_node(graph.node.get_name(), context=graph.context)
    try:
        proc = Ros2Process('node', 'list', '--spin-time', '5')
        graph.spin_until(lambda: proc.proc.poll() is not None, 60, 'ros2 node list')
        assert proc.wait() == 0, proc.stderr
        assert proc.stdout.splitlines().count(f'/{graph.node.get_name()}') == 1
        assert [line for line in error_lines(proc.stderr) if 'WARNING' in line] == [
            f'WARNING: nodes in the graph share an exact name: /{graph.node.get_name()} (2); '
            'their topics, services and parameters are not told apart']
        # A parameter verb reached one of them without a word (a walk-through).
        proc = Ros2Process('param', 'list', f'/{graph.node.get_name()}')
        graph.spin_until(lambda: proc.proc.poll() is not None, 60, 'ros2 param list')
        assert proc.wait() == 0, proc.stderr
        assert [line for line in error_lines(proc.stderr) if 'WARNING' in line] == [
            f'WARNING: 2 nodes in the graph are named /{graph.node.get_name()}; this reaches '
            'one of them, not told which']
    finally:
        twin.destroy_node()


@pytest.mark.parametrize('verb, given', [('echo', 'tt_msgs/msg/BallPrediction'),
                                          ('hz', 'tt_msgs/BallPrediction')])
def test_echo_or_hz_of_another_type_than_published_is_one_line_and_exit_1(graph, topic, verb,
                                                                        given):
    # A subscription of the type given would never match: said instead of waiting silently.
    graph.node.create_publisher(BallState, topic, QoSProfile(depth=10))
    proc = Ros2Process('topic', verb, topic, given)
    graph.spin_until(lambda: proc.proc.poll() is not None, 60, f'ros2 topic {verb} to end')
    assert proc.wait() == 1 and proc.stdout == ''
    assert error_lines(proc.stderr) == [
        f'ros2 topic: {topic} is published as tt_msgs/msg/BallState, not {given}']


def test_info_on_an_unknown_topic_is_one_line_and_exit_1(topic):
    rc, out, err = ros2('topic', 'info', topic, '--spin-time', '0.5')
    assert rc == 1 and out == ''
    assert error_lines(err) == [f"ros2 topic: Unknown topic '{topic}'"]


def test_pub_once_delivers_the_yaml_values(graph, procs, topic):
    got = []
    graph.node.create_subscription(BallState, topic, got.append, QoSProfile(depth=10))
    pub = procs('topic', 'pub', topic, 'tt_msgs/msg/BallState',
                '{position: {x: 1.5, z: 0.2}, track_id: 9, header: {frame_id: table}}', '--once')
    graph.spin_until(lambda: got, 60, 'the published message')
    assert pub.wait() == 0, pub.stderr
    assert (got[0].position.x, got[0].position.z, got[0].track_id) == (1.5, 0.2, 9)
    assert got[0].header.frame_id == 'table'


def test_pub_names_its_node_and_prints_every_nth_message(graph, procs, topic):
    # -n: the publisher's node as the graph shows it; -p 5: 'publishing #5', '#10', ... only.
    name = f'tt_pub_test_{os.getpid()}'
    got = []
    graph.node.create_subscription(BallState, topic, got.append, QoSProfile(depth=100))
    pub = procs('topic', 'pub', topic, 'tt_msgs/msg/BallState', '{track_id: 3}', '-r', '20',
                '-p', '5', '-n', name)
    graph.spin_until(lambda: len(got) >= 12, 60, 'a dozen published states')
    assert [p.node_name for p in graph.node.get_publishers_info_by_topic(topic)] == [name]
    pub.signal(signal.SIGINT)
    assert pub.wait() == 0, pub.stderr
    printed = [line for line in pub.stdout.splitlines() if line.startswith('publishing #')]
    numbers = [int(line.split('#')[1].split(':')[0]) for line in printed]
    assert len(numbers) >= 2 and numbers == list(range(5, 5 * len(numbers) + 1, 5)), numbers
    rc, out, err = ros2('topic', 'pub', topic, 'tt_msgs/msg/BallState', '-n', 'bad name')
    assert (rc, out) == (1, '') and len(error_lines(err)) == 1
    assert err.startswith('ros2 topic: Invalid node name: node name must not contain '), err


def test_pub_of_another_type_than_subscribed_is_one_line_and_exit_1(graph, topic):
    # Waiting for a subscription that can never match is said as echo says it.
    graph.node.create_subscription(BallState, topic, lambda m: None, QoSProfile(depth=10))
    proc = Ros2Process('topic', 'pub', topic, 'std_msgs/msg/String', '{data: hi}', '--once')
    graph.spin_until(lambda: proc.proc.poll() is not None, 60, 'ros2 topic pub to end')
    assert proc.wait() == 1 and proc.stdout == ''
    assert error_lines(proc.stderr) == [
        f'ros2 topic: {topic} is subscribed as tt_msgs/msg/BallState, not std_msgs/msg/String']


def test_pub_bad_values_fail_before_publishing(topic):
    rc, out, err = ros2('topic', 'pub', topic, 'tt_msgs/msg/BallState', '{track_id: 1.5}')
    assert rc == 1 and out == ''
    assert error_lines(err) == ["ros2 topic: field 'track_id': 1.5 is not a valid uint32"]
    rc, out, err = ros2('topic', 'pub', topic, 'tt_msgs/msg/NoSuch', '{}')
    assert rc == 1 and error_lines(err) == [
        "ros2 topic: unknown message type 'tt_msgs/msg/NoSuch'"]


def test_run_prediction_node_and_echo_its_prediction(graph, procs, topic):
    """Issue 2: `ros2 run tt_prediction prediction_node` starts, and `ros2 topic echo
    /ball/prediction --once` prints a message when a BallState is published (topics remapped
    so that parallel runs do not meet)."""
    state_topic, prediction_topic = f'{topic}/state', f'{topic}/prediction'
    node = procs('run', 'tt_prediction', 'prediction_node', '--ros-args',
                 '-r', f'/ball/state:={state_topic}',
                 '-r', f'/ball/prediction:={prediction_topic}')
    echo = procs('topic', 'echo', prediction_topic, '--once')
    pub = graph.node.create_publisher(BallState, state_topic, QoSProfile(depth=10))
    # From the opponent's side towards the robot, no spin, no sideways speed.
    values = {'header': {'frame_id': 'table'}, 'position': {'x': 1.4, 'y': 0.1, 'z': 0.3},
              'velocity': {'x': -6.0, 'y': 0.0, 'z': 1.2}}

    def printed():
        if '---' in echo.stdout or echo.proc.poll() is not None or node.proc.poll() is not None:
            return True
        msg = dict_to_message(values, BallState)
        msg.header.stamp = graph.node.get_clock().now().to_msg()
        pub.publish(msg)
        return False

    graph.spin_until(printed, 90, 'the echoed prediction')
    assert echo.wait() == 0, echo.stderr + node.stderr
    prediction = yaml.safe_load(echo.stdout.split('---\n')[0])
    assert prediction['header']['frame_id'] == 'table'
    # Without drag the ball would reach z = r (0.02 m) after t = 0.391 s, at x = -0.94 m;
    # drag only shortens that: the bounce is on the robot's half between there and the net,
    # on the line y = 0.1 (no sideways force), and the ball goes on to the hitting plane.
    assert prediction['status'] == 'ok'
    assert prediction['bounce_valid'] and prediction['bounce_half'] == -1
    assert -0.944 < prediction['bounce_point']['x'] < 0.0
    assert prediction['bounce_point']['y'] == pytest.approx(0.1, abs=1e-6)
    assert prediction['hit_valid']
    assert prediction['hit_point']['x'] == pytest.approx(prediction['hit_plane_x'])
    node.signal(signal.SIGINT)
    assert node.wait(timeout=90) == 0 and 'Traceback' not in node.stderr
