"""A 1 kHz BallState flood for 60 s into prediction_node and strike_node (separate processes):
both stay alive, keep answering, and their memory stays flat.

Every millisecond this process publishes a BallState of a ball in flight (a fresh state of a
rally, track ids cycling) on /ball/state; prediction_node predicts each one and strike_node
solves for as many predictions as it can (its reliable depth-5 queue drops the rest: a late
stroke is worth nothing). The resident memory (VmRSS from /proc) of both nodes is sampled
every second. "Flat": the RSS of the last 20 s exceeds that of the 10 s after warm-up by at
most ``MAX_GROWTH_MB``; the trend (least-squares slope over the run after warm-up) is
reported too.
"""

import pathlib
import sys
import time

import numpy as np

DURATION_S = 60.0
RATE_HZ = 1000.0
WARMUP_S = 10.0
MAX_GROWTH_MB = 5.0


def run():
    from rclpy.qos import qos_profile_sensor_data
    from tt_tools.collector import Collector
    from tt_tools.procs import ProcessGroup, rss_mb, wait_until

    from tt_msgs.msg import BallState

    logs = pathlib.Path(__file__).resolve().parent / 'results' / 'flood_logs'
    logs.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(3)
    base = np.array([1.2, 0.1, 0.35, -5.5, 0.2, 1.0, 0.0, 80.0, 0.0])
    outputs = ('/ball/prediction', '/strike/command')
    with ProcessGroup(str(logs)) as group, \
            Collector(name='bench_flood', topics=outputs) as collector:
        node = collector.node
        procs = {
            'prediction': group.start('prediction', ['ros2', 'run', 'tt_prediction',
                                                     'prediction_node', '--ros-args', '-p',
                                                     'stale_after_s:=0.0']),
            'strike': group.start('strike', ['ros2', 'run', 'tt_strike', 'strike_node']),
        }
        pub = node.create_publisher(BallState, '/ball/state', qos_profile_sensor_data)
        wait_until(lambda: collector.spin_once() or (
            pub.get_subscription_count() >= 1
            and node.count_publishers('/strike/command') >= 1
            and node.count_subscribers('/ball/prediction') >= 2), 90.0, 'the two nodes')
        msg = BallState()
        msg.header.frame_id = 'table'
        msg.covariance = list(np.diag([1e-6] * 3 + [1e-3] * 3 + [25.0] * 3).ravel())
        samples = {name: [] for name in procs}
        sent = 0
        start = time.monotonic()
        next_sample = start
        while True:
            now = time.monotonic()
            if now - start >= DURATION_S:
                break
            due = start + sent / RATE_HZ
            if now < due:
                collector.spin_once(timeout=min(due - now, 0.001))
                continue
            s = base + rng.normal(0.0, [0.05, 0.05, 0.02, 0.2, 0.2, 0.2, 5.0, 5.0, 5.0])
            stamp = node.get_clock().now().to_msg()
            msg.header.stamp = stamp
            msg.track_id = (sent // 200) % 50
            msg.position.x, msg.position.y, msg.position.z = (float(v) for v in s[:3])
            msg.velocity.x, msg.velocity.y, msg.velocity.z = (float(v) for v in s[3:6])
            msg.spin.x, msg.spin.y, msg.spin.z = (float(v) for v in s[6:9])
            pub.publish(msg)
            sent += 1
            if now >= next_sample:
                for name, proc in procs.items():
                    samples[name].append((now - start, rss_mb(proc.pid)))
                next_sample += 1.0
        counts_during = {t: len(r) for t, r in collector.outputs().items()}
        alive = {name: proc.poll() is None for name, proc in procs.items()}
        # Still answering after the flood: one more state gets its prediction.
        before = len(collector.records['/ball/prediction'])
        wait_until(lambda: (pub.publish(msg) or True) and (collector.spin_once(0.05)
                   or len(collector.records['/ball/prediction']) > before), 10.0,
                   'a prediction after the flood')
        codes = {name: group.stop(name) for name in procs}
    result = {'sent': sent, 'achieved_rate_hz': sent / DURATION_S,
              'received': counts_during, 'alive_after': alive, 'exit_codes': codes}
    flat = True
    for name, series in samples.items():
        t, rss = np.array(series).T
        early = rss[(t >= WARMUP_S) & (t < WARMUP_S + 10.0)]
        late = rss[t >= DURATION_S - 20.0]
        growth = float(late.max() - early.max())
        slope = float(np.polyfit(t[t >= WARMUP_S], rss[t >= WARMUP_S], 1)[0])
        result[name] = {'rss_start_mb': float(rss[0]), 'rss_end_mb': float(rss[-1]),
                        'growth_mb': growth, 'slope_mb_per_min': 60.0 * slope}
        flat &= growth <= MAX_GROWTH_MB
    result['passed'] = bool(flat and all(alive.values())
                            and all(c in (0, -2, 130) for c in codes.values())
                            and result['achieved_rate_hz'] >= 0.9 * RATE_HZ)
    result['targets'] = {'rate_hz': RATE_HZ, 'duration_s': DURATION_S,
                         'max_growth_mb': MAX_GROWTH_MB}
    return result


if __name__ == '__main__':
    from run_all import bench_main
    sys.exit(bench_main(__file__, run))
