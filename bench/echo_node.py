"""The floor of the node-latency benchmark: a node that answers each BallState with an empty
BallPrediction (the state's header and track only), on the same topics, QoS and executor as
prediction_node. Its latency is what the platform (two Python processes, DDS, this machine)
costs before any prediction is made."""

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from tt_ros.executor import run_node

from tt_msgs.msg import BallPrediction, BallState


class EchoNode(Node):

    def __init__(self):
        super().__init__('prediction_echo')
        self.out = BallPrediction()
        self.pub = self.create_publisher(
            BallPrediction, '/ball/prediction',
            QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE))
        self.create_subscription(BallState, '/ball/state', self.on_state,
                                 qos_profile_sensor_data)

    def on_state(self, msg):
        self.out.header = msg.header
        self.out.track_id = msg.track_id
        self.pub.publish(self.out)


if __name__ == '__main__':
    run_node(EchoNode)
