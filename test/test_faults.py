"""Faults across processes: a node killed in the middle of a stream and started again, and the
graph resumes (prediction_node and strike_node as `ros2 run` processes).

The test node replays a stream of incoming-ball states on /ball/state (a ball in flight, as
perception would publish it) and waits on conditions (messages arriving), never on sleeps.
"""

import os
import uuid

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import qos_profile_sensor_data
from rclpy.time import Time
from tt_prediction.ball import ModelParams, rollout
from tt_prediction.predict import predict
from tt_tools.procs import ProcessGroup, wait_until

from tt_msgs.msg import BallState, StrikeCommand

pytestmark = pytest.mark.graph


class StateStream:
    """Publishes BallStates of one flight (stamps from the node clock) and collects commands."""

    def __init__(self, prefix):
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(f'faults_{uuid.uuid4().hex[:6]}', context=self.context)
        self.pub = self.node.create_publisher(BallState, f'{prefix}/ball/state',
                                              qos_profile_sensor_data)
        self.commands = []
        self.node.create_subscription(StrikeCommand, f'{prefix}/strike/command',
                                      self.commands.append, 100)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.state = np.array([1.2, 0.1, 0.35, -5.5, 0.2, 1.0, 0.0, 80.0, 0.0])
        self.sent = 0
        self.stamps = set()

    def publish_and_spin(self):
        msg = BallState()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self.stamps.add(Time.from_msg(msg.header.stamp).nanoseconds)
        msg.header.frame_id = 'table'
        msg.track_id = self.sent // 50
        s = self.state
        msg.position.x, msg.position.y, msg.position.z = (float(v) for v in s[:3])
        msg.velocity.x, msg.velocity.y, msg.velocity.z = (float(v) for v in s[3:6])
        msg.spin.x, msg.spin.y, msg.spin.z = (float(v) for v in s[6:9])
        msg.covariance = list(np.diag([1e-6] * 3 + [1e-3] * 3 + [25.0] * 3).ravel())
        self.pub.publish(msg)
        self.sent += 1
        self.executor.spin_once(timeout_sec=0.01)
        return False

    def close(self):
        self.node.destroy_node()
        self.executor.shutdown()
        rclpy.try_shutdown(context=self.context)


def test_prediction_node_killed_and_restarted_the_strikes_resume(tmp_path):
    assert os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE') == 'LOCALHOST'
    prefix = f'/faults_{os.getpid()}_{uuid.uuid4().hex[:6]}'
    remap = ['--ros-args', '-r', f'/ball/state:={prefix}/ball/state',
             '-r', f'/ball/prediction:={prefix}/ball/prediction',
             '-r', f'/strike/command:={prefix}/strike/command']
    prediction = ['ros2', 'run', 'tt_prediction', 'prediction_node', *remap,
                  '-p', 'stale_after_s:=0.0', '-p', 'uncertainty:=false']
    stream = StateStream(prefix)
    expected = predict(stream.state)
    assert expected.status == 'ok'
    try:
        with ProcessGroup(str(tmp_path)) as group:
            # use_hit_plane: the strike at the prediction's hit point (the checks below).
            group.start('strike', ['ros2', 'run', 'tt_strike', 'strike_node', *remap,
                                   '-p', 'use_hit_plane:=true'])
            first = group.start('prediction', prediction)
            wait_until(lambda: stream.publish_and_spin() or len(stream.commands) >= 3, 120.0,
                       'strike commands through a fresh prediction_node')
            # The same ball every time (stamps aside): every command strikes the ball where
            # its flight (eq. 8 and the bounce, from the state sent) is at the hit time, after
            # the bounce on the robot's half.
            for c in stream.commands:
                assert (c.status, c.feasible, c.reason) == ('ok', True, '')
                stamp = Time.from_msg(c.header.stamp).nanoseconds
                assert stamp in stream.stamps
                t_hit = (Time.from_msg(c.hit_time).nanoseconds - stamp) * 1e-9
                assert expected.bounce.t < t_hit < 1.0
                _, at_hit = rollout(stream.state, ModelParams(), sample_times=[t_hit])
                hit = (c.hit_point.x, c.hit_point.y, c.hit_point.z)
                assert hit == pytest.approx(at_hit[0, :3], abs=1e-6)
            first.kill()            # SIGKILL: no chance to clean up
            first.wait(10.0)
            group.stop('prediction')  # already gone: closes its log and forgets it
            restart_ns = stream.node.get_clock().now().nanoseconds
            group.start('prediction', prediction)

            def fresh():
                return sum(Time.from_msg(c.header.stamp).nanoseconds > restart_ns
                           for c in stream.commands)
            wait_until(lambda: stream.publish_and_spin() or fresh() >= 3, 120.0,
                       'strike commands from states sent after prediction_node restarted')
            assert group.procs['strike'].poll() is None, 'strike_node died with its input'
            assert group.stop('prediction') in (0, -2, 130)
            assert group.stop('strike') in (0, -2, 130)
    finally:
        stream.close()
