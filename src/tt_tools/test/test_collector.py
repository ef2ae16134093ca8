"""tt_tools.collector.Collector, the demo's and the end-to-end tests' listener of the graph's
outputs: one ``spin_once`` runs every message already waiting, so a caller that polls a
condition (the demo's "outputs quiet") never falls behind the graph."""

import time

from rclpy.qos import QoSProfile, ReliabilityPolicy
from tt_tools.collector import Collector

from tt_msgs.msg import BallState
from tt_ros import testing

BURST = 200


def test_one_spin_takes_every_message_waiting(monkeypatch):
    """A burst of states is taken in a few spins. Stopping at the first spin that took
    nothing, as before, took two a call (rclpy's spin_once(0) takes nothing every other
    call): the demo's collector, behind by some 300 predictions when the videos ended, took
    7-19 s to catch up before the outputs went quiet, and this burst took 100 spins."""
    domain = testing.unique_domain()
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    states = '/ball/state'
    with Collector(name='tt_collector_test') as collector, \
            testing.Graph(domain_id=domain) as graph:
        node = graph.create_node('burst')
        qos = QoSProfile(depth=BURST, reliability=ReliabilityPolicy.RELIABLE)
        publisher = node.create_publisher(BallState, states, qos)

        def probed():           # matched both ways once a probe arrives
            publisher.publish(BallState())
            collector.spin_once()
            return len(collector.records[states]) > 0

        graph.spin_until(probed, 30.0, 'the collector to take a probe state')
        collector.spin_once()
        taken = len(collector.records[states])
        for _ in range(BURST):
            publisher.publish(BallState())
        spins = 0
        deadline = time.monotonic() + 30.0
        while len(collector.records[states]) < taken + BURST:
            assert time.monotonic() < deadline, (spins, len(collector.records[states]))
            collector.spin_once()
            spins += 1
        assert spins < BURST // 4, spins
