"""tt_ros.connections.subscribe_input: the subscription of a node's input, remapped as any."""

import rclpy
from std_msgs.msg import String
from tt_ros.connections import subscribe_input
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
