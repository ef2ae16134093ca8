"""``ros2 doctor``: what keeps messages from flowing, found in a graph of the test's own.

The truths: DDS's matching rules (a best-effort publisher cannot serve a reliable
subscription; endpoints of different types never match), what the test's nodes publish
and subscribe, and rcl's reading of the discovery variables."""

from conftest import Graph, Ros2Process, error_lines, ros2
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from tt_tools.doctor import network_findings

from tt_msgs.msg import BallState
from tt_ros import testing

BEST_EFFORT = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


@pytest.mark.graph
def test_doctor_names_the_topics_whose_messages_cannot_flow(topic):
    domain = testing.unique_domain()         # the findings of this graph alone
    env = {'ROS_DOMAIN_ID': str(domain)}
    with Graph(domain_id=domain) as g, testing.Graph(domain_id=domain) as other_graph:
        a, b = g.node, other_graph.create_node('other')
        a.create_publisher(BallState, f'{topic}/state', BEST_EFFORT)
        b.create_subscription(BallState, f'{topic}/state', lambda m: None, RELIABLE)
        a.create_publisher(String, f'{topic}/mixed', RELIABLE)
        b.create_subscription(BallState, f'{topic}/mixed', lambda m: None, RELIABLE)
        a.create_publisher(BallState, f'{topic}/fine', RELIABLE)
        b.create_subscription(BallState, f'{topic}/fine', lambda m: None, BEST_EFFORT)
        a.create_publisher(BallState, f'{topic}/alone', RELIABLE)
        a_name, b_name = '/' + a.get_name(), '/' + b.get_name()
        (rc, out, err), (rc_iw, out_iw, err_iw) = _run_while_spinning(
            g, env, ('doctor',), ('doctor', '--include-warnings', '--report-failed'))
    said = error_lines(err)
    assert said == [
        f'ros2 doctor: WARNING: network: ROS_DOMAIN_ID {domain}: its ports can collide with '
        'ports Linux hands out (0-101 keep clear of them)',
        f'ros2 doctor: WARNING: topic: publisher without subscription on {topic}/alone '
        f'({a_name})',
        f'ros2 doctor: ERROR: type: {topic}/mixed has endpoints of 2 types, between which no '
        f'message passes (std_msgs/msg/String: {a_name} publisher; tt_msgs/msg/BallState: '
        f'{b_name} subscription)',
        f'ros2 doctor: ERROR: qos: {topic}/state: publisher of {a_name} and subscription of '
        f'{b_name}: Best effort publisher and reliable subscription'], err
    assert rc == 1 and out == '2/4 checks failed\nFailed modules: type qos\n', out
    # Warnings fail their checks too; the sections of the failed ones are printed.
    assert rc_iw == 1 and error_lines(err_iw) == said
    assert out_iw.endswith('4/4 checks failed\nFailed modules: network topic type qos\n')
    assert 'PLATFORM INFORMATION' not in out_iw
    report = out_iw.split('QOS COMPATIBILITY LIST\n')[1]
    # The reliable publisher serves the best-effort subscription; not the other way round.
    assert (f'topic [type]         : {topic}/fine [tt_msgs/msg/BallState]\n'
            f'publisher node       : {a_name}\nsubscriber node      : {b_name}\n'
            'compatibility status : OK\n') in report
    assert ('compatibility status : ERROR: Best effort publisher and reliable subscription'
            in report)
    assert f'{topic}/mixed' not in report     # no pair of one type there
    assert f'topic            : {topic}/alone\npublisher count  : 1\nsubscriber count : 0\n' \
        in out_iw.split('TOPIC LIST\n')[1]


def _run_while_spinning(graph, env, *commands):
    """The ``ros2`` ``commands``, run at once to the end while ``graph`` spins; [(exit code,
    stdout, stderr)] in their order."""
    procs = [Ros2Process(*c, env=env) for c in commands]
    try:
        graph.spin_until(lambda: all(p.proc.poll() is not None for p in procs), 120,
                         'ros2 doctor')
        return [(p.wait(), p.stdout, p.stderr) for p in procs]
    finally:
        for p in procs:
            p.stop()


def test_doctor_without_a_domain_checks_nothing_else():
    rc, out, err = ros2('doctor', env={'ROS_DOMAIN_ID': '233'})
    assert rc == 1 and out == '1/4 checks failed\nFailed modules: network\n', out
    assert error_lines(err) == [
        'ros2 doctor: ERROR: network: ROS_DOMAIN_ID 233 is out of range: Fast DDS has ports '
        "for 0-232 only (101 at most keeps them clear of Linux's ephemeral ports)"]


@pytest.mark.parametrize('environ, said', [
    ({}, []),
    ({'ROS_DOMAIN_ID': '42', 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}, []),
    ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'localhost'}, ["'localhost' is none of"]),
    ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'OFF'}, ['OFF and ROS_STATIC_PEERS empty']),
    ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'OFF', 'ROS_STATIC_PEERS': '10.0.0.2'}, []),
    ({'ROS_LOCALHOST_ONLY': '1'}, ['ROS_LOCALHOST_ONLY is deprecated']),
    ({'ROS_DOMAIN_ID': '102'}, ['ROS_DOMAIN_ID 102: its ports']),
])
def test_network_findings_follow_rcls_reading_of_the_variables(environ, said):
    found = network_findings(environ)
    assert [f.level for f in found] == ['warning'] * len(said)
    assert all(s in f.text for s, f in zip(said, found, strict=True)), found
