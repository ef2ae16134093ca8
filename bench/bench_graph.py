"""Latency of the whole graph: camera image to strike command, across three processes.

perception_node, prediction_node and strike_node run as separate ``ros2 run`` processes (with
tt's Fast DDS profile for images). This process publishes the demo recording's images
(two 640x480 cameras, 150 fps scene time) at ``RATE`` times real time and notes the wall time
at which each image went out; a StrikeCommand carries the stamp of the BallState it derives
from, which is the exposure stamp of an image, so its latency is its arrival time minus the
publication time of that image. Reported: p50, p99, max (ms), how many commands, and whether
every ball of the recording got commands. There is no target in the issues for the chain;
prediction_node's own latency target is in bench_prediction.
"""

import os
import pathlib
import sys
import time

import numpy as np

RATE = 0.25
"""Replay rate: images at 0.25 x 2 x 150 = 75 per second through perception."""


def run():
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosbags.rosbag2 import Reader
    from tt_tools.collector import Collector, stamp_s
    from tt_tools.procs import ProcessGroup, ros_env, wait_until
    from tt_tools.recording import STAMP_BASE_S, ensure_recording, replay_publishers

    from tt_msgs.msg import StrikeCommand

    os.environ.update(ros_env(large_messages=True))     # this process publishes the images
    cache = pathlib.Path(__file__).resolve().parent / 'results' / 'graph_recording'
    rec = ensure_recording(cache, balls=3, seed=5)
    published = {}
    arrivals = []
    logs = cache.parent / 'graph_logs'
    logs.mkdir(parents=True, exist_ok=True)
    with ProcessGroup(str(logs), large_messages=True) as group, \
            Collector(rec.image_topics, name='bench_graph') as collector:
        node = collector.node
        node.create_subscription(
            StrikeCommand, '/strike/command',
            lambda msg: arrivals.append((stamp_s(msg.header.stamp), time.time())),
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        group.start('perception', ['ros2', 'run', 'tt_perception', 'perception_node',
                                   '--ros-args', '-p', f'rig_file:={rec.path / "rig.yaml"}'])
        group.start('prediction', ['ros2', 'run', 'tt_prediction', 'prediction_node',
                                   '--ros-args', '-p', 'stale_after_s:=0.0'])
        group.start('strike', ['ros2', 'run', 'tt_strike', 'strike_node'])
        pubs = replay_publishers(node, rec.image_topics)
        wait_until(lambda: collector.spin_once() or (
            all(p.get_subscription_count() > 0 for p in pubs.values())
            and node.count_publishers('/strike/command') > 0
            and node.count_subscribers('/ball/prediction') >= 2), 90.0, 'the three nodes')
        with Reader(rec.path / 'bag') as reader:
            messages = [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]
        first = messages[0][1]
        start = time.monotonic()
        for topic, t_ns, data in messages:
            due = start + (t_ns - first) / 1e9 / RATE
            while time.monotonic() < due:
                collector.spin_once(timeout=max(0.0, min(0.002, due - time.monotonic())))
            pubs[topic].publish(data)
            if topic in rec.image_topics:
                published[round(t_ns / 1e3)] = time.time()
        wait_until(lambda: collector.spin_once() or collector.quiet_for(2.0), 30.0,
                   'the last commands')
        records, arrival_times = collector.outputs(), dict(collector.arrival)
        counts = {topic: len(r) for topic, r in records.items()}
    stamps_us = np.array(sorted(published))

    def latencies_ms(pairs):
        """Arrival minus publication of the image with the same stamp, ms."""
        out = []
        for stamp, arrival in pairs:
            us = stamp * 1e6
            i = np.clip(np.searchsorted(stamps_us, us), 1, len(stamps_us) - 1)
            j = i if abs(stamps_us[i] - us) < abs(stamps_us[i - 1] - us) else i - 1
            if abs(stamps_us[j] - us) <= 5.0:
                out.append(1e3 * (arrival - published[int(stamps_us[j])]))
        return np.array(out)

    stages = {topic: latencies_ms(zip([r['t'] for r in records[topic]],
                                      arrival_times[topic], strict=True))
              for topic in ('/ball/state', '/ball/prediction')}
    lat_ms = latencies_ms(arrivals)
    balls_with_commands = sum(
        any(tr.ball.launch_time <= s - STAMP_BASE_S <= tr.hit_time for s, _ in arrivals)
        for tr in rec.truths)
    result = {
        'rate': RATE, 'images': len(published), 'messages': counts,
        'commands': len(arrivals),
        'matched': int(lat_ms.size), 'balls': len(rec.truths),
        'balls_with_commands': int(balls_with_commands),
    }
    if lat_ms.size:
        result.update({'latency_p50_ms': float(np.percentile(lat_ms, 50)),
                       'latency_p99_ms': float(np.percentile(lat_ms, 99)),
                       'latency_max_ms': float(lat_ms.max())})
    for topic, lat in stages.items():
        if lat.size:
            result[f'image_to_{topic.rsplit("/", 1)[1]}_ms'] = {
                'p50': float(np.percentile(lat, 50)), 'p99': float(np.percentile(lat, 99))}
    result['passed'] = bool(lat_ms.size > 0 and balls_with_commands == len(rec.truths))
    return result


if __name__ == '__main__':
    from run_all import bench_main
    sys.exit(bench_main(__file__, run))
