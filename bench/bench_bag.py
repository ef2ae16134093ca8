"""Bag recording speed: the rosbags writer alone, and ``ros2 bag record`` under a 1 kHz flood.

``writer_ballstate_per_s`` / ``writer_image_mb_per_s``: BagWriter.write of serialised
BallStates (752 B) and 640x480 mono8 Images (307 kB) into MCAP, in this process.
``flood_*``: a BallState publisher at 1 kHz on average (reliable) for FLOOD_S seconds, recorded
by a ``ros2 bag record`` subprocess; the share of published messages in the bag, and the
recorder's resident memory after 1 s and at the end (flat memory: growth under 20 MB).
"""

import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import time

import rclpy
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Image
from tt_ros.bagfile import BagWriter, open_bag
from tt_tools.procs import ros_env, rss_mb

from tt_msgs.msg import BallState

FLOOD_HZ = 1000.0
FLOOD_S = 5.0
TOPIC = f'/bench_bag_{os.getpid()}/state'


def _writer_rate(tmp, msgtype, data, n):
    writer = BagWriter(str(tmp / msgtype.split('/')[-1]), 'mcap')
    conn = writer.add_topic('/x', msgtype)
    start = time.perf_counter()
    for i in range(n):
        writer.write(conn, 10**18 + i * 1000, data)
    writer.close()
    return n / (time.perf_counter() - start)


def _flood(tmp):
    out = tmp / 'flood'
    rec = subprocess.Popen([sys.executable, '-m', 'tt_tools.ros2', 'bag', 'record', '-o',
                            str(out), TOPIC], env=ros_env({'TT_ROS2_NO_HANDOVER': '1'}),
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('bench_bag_flood', context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    pub = node.create_publisher(BallState, TOPIC, QoSProfile(depth=1000))
    try:
        deadline = time.monotonic() + 60
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        msg = BallState()
        sent = [0]
        start = time.monotonic()

        def tick():
            # Catch up when the timer fires late, so the average rate is FLOOD_HZ.
            while sent[0] < (time.monotonic() - start) * FLOOD_HZ:
                msg.track_id = sent[0]
                pub.publish(msg)
                sent[0] += 1

        node.create_timer(1.0 / FLOOD_HZ, tick)
        rss = {}
        while time.monotonic() - start < FLOOD_S:
            executor.spin_once(timeout_sec=0.01)
            if 'early' not in rss and time.monotonic() - start > 1.0:
                rss['early'] = rss_mb(rec.pid)
        rss['late'] = rss_mb(rec.pid)
        pub.wait_for_all_acked(Duration(seconds=10))
        rec.send_signal(signal.SIGINT)
        rec.wait(60)
    finally:
        if rec.poll() is None:
            rec.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    reader = open_bag(str(out))
    recorded = reader.message_count
    reader.close()
    return sent[0], recorded, rss


def run():
    with tempfile.TemporaryDirectory() as d:
        tmp = pathlib.Path(d)
        ball = serialize_message(BallState())
        image = Image(height=480, width=640, encoding='mono8', step=640)
        image.data = bytes(640 * 480)
        image_bytes = serialize_message(image)
        ball_rate = _writer_rate(tmp, 'tt_msgs/msg/BallState', ball, 20000)
        image_rate = _writer_rate(tmp, 'sensor_msgs/msg/Image', image_bytes, 200)
        sent, recorded, rss = _flood(tmp)
    growth = rss['late'] - rss['early']
    result = {
        'writer_ballstate_per_s': round(ball_rate),
        'writer_image_mb_per_s': round(image_rate * len(image_bytes) / 1e6, 1),
        'flood_published': sent,
        'flood_rate_hz': round(sent / FLOOD_S, 1),
        'flood_recorded': recorded,
        'flood_recorded_share': round(recorded / sent, 4) if sent else 0.0,
        'recorder_rss_mb_after_1s': round(rss['early'], 1),
        'recorder_rss_mb_at_end': round(rss['late'], 1),
        'targets': {'flood_recorded_share': '>= 0.99 (reliable QoS)',
                    'recorder_rss_growth_mb': '< 20', 'writer_ballstate_per_s': '>= 1000'},
    }
    result['passed'] = (result['flood_recorded_share'] >= 0.99 and growth < 20
                        and ball_rate >= 1000)
    return result


if __name__ == '__main__':
    from run_all import bench_main
    sys.exit(bench_main(__file__, run))
