"""tt_ros.connections.subscribe_input: the subscription of a node's input, remapped as any;
LostMessages, what it lost before its callback."""

import rclpy
from std_msgs.msg import String
from tt_ros.connections import UNKNOWN_SEQUENCE, LostMessages, subscribe_input
from tt_ros.testing import Graph


def test_an_input_is_remapped_once_as_a_plain_subscription_is():
    # The topic was resolved (remaps applied) and then given to create_subscription, which
    # applied them again: with -r ball/state:=ball/raw -r /ball/raw:=/ball/other the input
    # listened on /ball/other while a plain subscription of the same name was on /ball/raw.
    with Graph() as graph:
        node = graph.add(rclpy.create_node(
            'remap_test', context=graph.context,
            cli_args=['--ros-args', '-r', 'ball/state:=ball/raw', '-r',
                      '/ball/raw:=/ball/other']))
        plain = node.create_subscription(String, 'ball/state', lambda m: None, 10)
        tt_input = subscribe_input(node, String, 'ball/state', lambda m: None, 10)
        assert plain.topic_name == '/ball/raw'
        assert tt_input.topic_name == plain.topic_name


def test_lost_messages_are_the_gaps_in_one_publishers_sequence_numbers():
    publishers = [1]
    lost = LostMessages()
    lost.publishers = lambda: publishers[0]
    for sequence in (7, 8, 12, 13):         # the first one taken: nothing known before it
        lost.taken(sequence)
    assert lost.count == 3                  # 9, 10 and 11
    lost.taken(1)                           # the publisher started again
    lost.taken(3)
    assert lost.count == 4
    publishers[0] = 2                       # two publishers' numbers interleave
    for sequence in (40, 4, 41, 5):
        lost.taken(sequence)
    assert lost.count == 4
    publishers[0] = 1
    for sequence in (UNKNOWN_SEQUENCE, UNKNOWN_SEQUENCE):   # a middleware that numbers none
        lost.taken(sequence)
    lost.taken(9)
    assert lost.count == 4 + 3              # 6, 7 and 8 after the 5 last numbered


def test_an_input_counts_the_messages_its_queue_lost():
    # A reliable queue of 2: of 1 taken, then 10 published before the next spin, the last 2
    # are taken and 8 counted lost.
    with Graph() as graph:
        node = graph.add(rclpy.create_node('lost_test', context=graph.context))
        got, lost = [], LostMessages()
        sub = subscribe_input(node, String, 'lost_test', lambda m: got.append(m.data), 2,
                              lost=lost)
        pub = node.create_publisher(String, sub.topic_name, 2)
        graph.spin_until(lambda: pub.get_subscription_count() == 1, 10.0, 'discovery')
        pub.publish(String(data='0'))
        graph.spin_until(lambda: got == ['0'], 10.0, 'the first message')
        for k in range(1, 11):
            pub.publish(String(data=str(k)))
        graph.spin_until(lambda: len(got) == 3, 10.0, 'the last two')
        assert got == ['0', '9', '10'] and lost.count == 8
