"""The whole graph on a recording, launch-free: perception -> prediction -> strike in one
executor, fed frame by frame from a rosbag2 bag of two synthetic cameras, checked against the
truth the recording was rendered from.

Flow control without sleeps: each image is published and the executor spun until the
perception node has taken it (its ``frames_received`` counter); at the end the executor is
spun until every published state has its prediction and every prediction its command.
"""

import os
import time
import uuid

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader
from tt_perception.node import PerceptionNode
from tt_perception.sources import camera_info_topic
from tt_prediction.ball import zone_margin
from tt_prediction.node import PredictionNode
from tt_strike.node import StrikeNode
from tt_tools.collector import TOPICS
from tt_tools.recording import STAMP_BASE_S, ensure_recording, replay_publishers

from tt_tools import demo_report

pytestmark = pytest.mark.graph

TARGET_ZONE = 5
HIT_PLANE_X = -1.5


@pytest.fixture(scope='module', params=[('clean', 'white'), ('hall', 'orange')],
                ids=['clean', 'hall_orange'])
def recording(request, tmp_path_factory):
    """The recording of two balls: synth's clean imaging, and a hall's (overhead light,
    shading and highlight, contact shadow, vignetting, shot noise, JPEG q30, 2 ms blur) with
    an orange ball."""
    imaging, colour = request.param
    return ensure_recording(tmp_path_factory.mktemp('rec') / 'recording', balls=2,
                            hit_plane_x=HIT_PLANE_X, seed=11, imaging=imaging, colour=colour)


def _spin_until(executor, condition, timeout, what):
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f'timed out waiting for {what}')
        executor.spin_once(timeout_sec=0.01)


def _replay(recording):
    """Run the three nodes on the recording; return the outputs as collector records."""
    assert os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE') == 'LOCALHOST'
    prefix = f'/e2e_{os.getpid()}_{uuid.uuid4().hex[:6]}'
    remap = ['--ros-args']
    for topic in ('/ball/state', '/ball/prediction', '/ball/predicted_path', '/tt/markers',
                  '/strike/command', '/strike/target'):
        remap += ['-r', f'{topic}:={prefix}{topic}']
    for image_topic in recording.image_topics:
        for topic in (image_topic, camera_info_topic(image_topic)):
            remap += ['-r', f'{topic}:={prefix}{topic}']
    context = rclpy.context.Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    nodes = []
    try:
        perception = PerceptionNode(context=context, cli_args=remap, parameter_overrides=[
            rclpy.parameter.Parameter('rig_file', value=str(recording.path / 'rig.yaml')),
            rclpy.parameter.Parameter('ball_colour', value=recording.colour)])
        prediction = PredictionNode(context=context, cli_args=remap, parameter_overrides=[
            rclpy.parameter.Parameter('hit_plane_x', value=HIT_PLANE_X),
            rclpy.parameter.Parameter('stale_after_s', value=0.0)])
        strike = StrikeNode(context=context, cli_args=remap, parameter_overrides=[
            rclpy.parameter.Parameter('target_zone', value=TARGET_ZONE),
            # The recording's stamps are not on the node clock; the true ball is struck at
            # the prediction's hitting plane (demo_report).
            rclpy.parameter.Parameter('check_hit_time', value=False),
            rclpy.parameter.Parameter('use_hit_plane', value=True)])
        feeder = rclpy.create_node(f'feeder_{uuid.uuid4().hex[:6]}', context=context)
        nodes = [perception, prediction, strike, feeder]
        for node in nodes:
            executor.add_node(node)
        outputs = {topic: [] for topic in TOPICS}
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
        for topic, (msg_type, convert) in TOPICS.items():
            feeder.create_subscription(
                msg_type, prefix + topic,
                lambda msg, records=outputs[topic], convert=convert: records.append(
                    convert(msg)), qos)
        publishers = replay_publishers(feeder, recording.image_topics, prefix)
        _spin_until(executor, lambda: all(p.get_subscription_count() > 0
                                          for p in publishers.values()), 10.0, 'discovery')
        with Reader(recording.path / 'bag') as reader:
            for connection, _, data in reader.messages():
                publisher = publishers[connection.topic]
                taken = perception.frames_received
                publisher.publish(bytes(data))
                if connection.topic in recording.image_topics:
                    _spin_until(executor, lambda n=taken: perception.frames_received > n, 10.0,
                                f'perception to take a frame of {connection.topic}')
        _spin_until(executor, lambda: len(outputs['/ball/prediction'])
                    >= perception.states_published, 30.0, 'a prediction for every state')
        _spin_until(executor, lambda: strike.n_received
                    >= len(outputs['/ball/prediction']), 30.0, 'strike to take every prediction')
        _spin_until(executor, lambda: len(outputs['/strike/command'])
                    >= strike.n_commands, 30.0, 'every strike command')
        return demo_report.shift_times(outputs, STAMP_BASE_S)
    finally:
        for node in nodes:
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)


@pytest.fixture(scope='module')
def results(recording):
    outputs = _replay(recording)
    return demo_report.evaluate(recording.truths, outputs, recording.params), outputs


def test_every_ball_is_tracked_to_within_a_few_millimetres(results):
    balls, _ = results
    for ball in balls:
        assert len(ball.states) >= 30, f'ball {ball.index}: only {len(ball.states)} states'
        # Perception's own target is 2 mm RMS; through the ROS glue it must stay within 5 mm.
        assert ball.position_rms_mm <= 5.0, f'ball {ball.index}: {ball.position_rms_mm:.1f} mm'
        assert ball.velocity_err <= 0.1, f'ball {ball.index}: {ball.velocity_err:.3f} m/s'


def test_prediction_finds_the_true_hit_point(results):
    balls, _ = results
    for ball in balls:
        pred = ball.prediction
        assert pred is not None and pred['status'] == 'ok', f'ball {ball.index}: {pred}'
        # 150 ms before the hit the state is known to ~1 mm and ~0.02 m/s: the hit point
        # follows within a few centimetres.
        assert ball.hit_err_mm <= 30.0, f'ball {ball.index}: {ball.hit_err_mm:.1f} mm'
        assert abs(ball.hit_time_err_ms) <= 10.0


def test_predictions_before_the_bounce_name_the_true_bounce_zone(results):
    balls, outputs = results
    for ball in balls:
        truth = ball.truth
        early = [p for p in outputs['/ball/prediction']
                 if truth.ball.launch_time <= p['t'] <= truth.bounce_time - 0.1
                 and p['bounce_valid']]
        assert early, f'ball {ball.index}: no prediction of the bounce'
        last = early[-1]
        assert last['bounce_half'] == -1
        err = np.linalg.norm(last['bounce_p'][:2] - truth.bounce_point[:2])
        assert err <= 0.03, f'ball {ball.index}: bounce point off by {err * 1e3:.0f} mm'
        x, y = truth.bounce_point[:2]
        if zone_margin(x, y, truth.bounce_zone, -1) > err:
            assert last['bounce_zone'] == truth.bounce_zone


def test_strike_sends_the_true_ball_into_the_target_zone(results):
    balls, _ = results
    for ball in balls:
        cmd = ball.command
        assert cmd is not None and cmd['feasible'], f'ball {ball.index}: {cmd}'
        assert cmd['target_zone'] == TARGET_ZONE
        assert cmd['landing_zone'] == TARGET_ZONE
        # The command was computed from the perceived ball; the true ball, struck with the
        # commanded racket, must still land in the target zone on the opponent's half.
        assert ball.true_landing_zone == TARGET_ZONE, (
            f'ball {ball.index}: lands at {ball.true_landing} (zone {ball.true_landing_zone})')


def test_two_robots_in_namespaces_of_their_own_do_not_cross_talk():
    # Topic names are relative to the node's namespace: prediction_node and strike_node
    # started with `-r __ns:=/robot1` use /robot1/ball/state ... /robot1/strike/command. With
    # the absolute names they had, a second robot's nodes (/robot2) took robot 1's ball and
    # both strike nodes commanded both arms.
    from rclpy.parameter import Parameter

    from tt_msgs.msg import BallState, StrikeCommand

    robots = [f'/robot{k}_{os.getpid()}_{uuid.uuid4().hex[:6]}' for k in (1, 2)]
    context = rclpy.context.Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    nodes = []
    try:
        chains = {}
        for robot in robots:
            args = ['--ros-args', '-r', f'__ns:={robot}']
            prediction = PredictionNode(context=context, cli_args=args, parameter_overrides=[
                Parameter('stale_after_s', value=0.0)])
            strike = StrikeNode(context=context, cli_args=args, parameter_overrides=[
                Parameter('check_hit_time', value=False)])
            chains[robot] = (prediction, strike)
            nodes += [prediction, strike]
        feeder = rclpy.create_node(f'feeder_{uuid.uuid4().hex[:6]}', context=context)
        nodes.append(feeder)
        for node in nodes:
            executor.add_node(node)
        commands = {robot: [] for robot in robots}
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        for robot in robots:
            feeder.create_subscription(StrikeCommand, f'{robot}/strike/command',
                                       commands[robot].append, reliable)
        prediction, strike = chains[robots[0]]
        assert prediction.sub.topic_name == f'{robots[0]}/ball/state'
        assert strike.pub.topic_name == f'{robots[0]}/strike/command'
        pub = feeder.create_publisher(BallState, f'{robots[0]}/ball/state', QoSProfile(
            depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        _spin_until(executor, lambda: pub.get_subscription_count() == 1
                    and feeder.count_publishers(f'{robots[0]}/strike/command') == 1, 10.0,
                    "robot 1's chain")
        msg = BallState()
        msg.header.frame_id = 'table'
        msg.position.x, msg.position.y, msg.position.z = 1.2, 0.1, 0.35
        msg.velocity.x, msg.velocity.y, msg.velocity.z = -5.5, 0.2, 1.0
        msg.spin.y = 80.0
        msg.track_id = 1

        def struck():                   # best effort, as perception's: again until answered
            if not commands[robots[0]]:
                msg.header.stamp = prediction.get_clock().now().to_msg()
                pub.publish(msg)
            return bool(commands[robots[0]])

        _spin_until(executor, struck, 20.0, "robot 1's strike command")
        assert commands[robots[0]][0].feasible
        # Robot 2's nodes got nothing of it.
        other_prediction, other_strike = chains[robots[1]]
        assert other_prediction.n_predicted == 0 and other_strike.n_received == 0
        assert commands[robots[1]] == []
    finally:
        for node in nodes:
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)
