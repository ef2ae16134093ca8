"""Speed of the prediction (issue 3): single, batch, against the scipy reference, node latency.

- ``single_us``: median and p99 of one full :func:`predict` call (state -> bounce -> hitting
  plane, status and Python result objects included) over varied incoming balls; targets
  <= 50 and <= 200 us.
- ``reference``: the same balls by :func:`reference_predict` (solve_ivp DOP853, rtol 1e-9,
  terminal events) in the same run: speed-up of the medians (>= 30x), the largest
  hit-point disagreement (<= 0.1 mm) and the same status for every ball; a ball whose
  statuses differ where its flight passes within a radius of the net is left out and
  counted (``left_out_net_body``, at most a tenth): predict meets the net as a body (issue
  16), the reference as a line at x = 0.
- ``batch_10k_s``: 10,000 states in one :func:`predict_batch` call (<= 0.5 s).
- ``uncertainty_ms``: one :func:`predict_uncertainty` (19 sigma points), no target.
- ``cold_start_s``: import + first prediction in a fresh process with an empty numba cache
  (the compile time), and the same with the cache warm; no target.
- ``single_cpu_us``: the same calls timed by the thread's CPU clock, and
  ``load_average_1min``: on a shared machine the wall-clock p99 mostly measures the time the
  core was given to other processes; these two tell the cost from the contention.
- ``cli_20k``: tt-predict on 20,000 JSON lines (``cli.main`` in this process, so without the
  interpreter's start and imports: reading, parsing and checking the JSON, the batch kernel,
  formatting and writing the output), in us per state (<= 50), and its speed-up over the
  scipy reference's median per state measured in the same run (>= 30x); ``command_s``: the
  whole command (``tt-predict --input FILE`` in a new process) and ``startup_s``: the same
  command on one line, and ``cpu_us_per_state``: the process's CPU time (both kernel threads)
  per state, which leaves out the waits for a core on a shared machine; no target.
- ``node_latency_ms``: prediction_node in its own process on a core of its own (``taskset``),
  BallStates published at 500 Hz for 5 s from this process (pinned to the other core) and
  stamped with the time of publishing, latency = arrival of the BallPrediction - its stamp
  (= the state's stamp); p50 and p99. The node and the harness run on the nodes' default
  executor (rclpy's SingleThreadedExecutor; no TT_EXECUTOR). ``node_latency_floor_ms``: the
  same harness and pinning against ``echo_node.py``, which answers without predicting: what
  the platform (two Python processes, DDS, this machine) costs in this run. The target
  (issue 13) is on the difference: node p99 - echo p99 <= 0.3 ms. The two are measured in
  alternation, ROUNDS times each, and each p99 is that of its rounds' latencies pooled (the
  same share of every phase of the machine's load in both). ``node_latency_unpinned_ms``:
  prediction_node with both processes left to the scheduler, reported without a target
  (docs/prediction.md).
Runs in about two minutes. ``python bench/run_all.py --only prediction`` or this file directly.
"""

import io
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
import uuid

import numpy as np
from tt_prediction.ball import NET_HALF_WIDTH, NET_HEIGHT, ModelParams, rollout
from tt_prediction.predict import predict, predict_batch
from tt_prediction.reference import reference_predict
from tt_prediction.uncertainty import predict_uncertainty

from tt_prediction import cli

N_SINGLE = 3000
N_REFERENCE = 40
N_BATCH = 10_000
N_CLI = 20_000
NODE_RATE_HZ = 500.0
NODE_SECONDS = 5.0
ROUNDS = 3
"""Latency runs of prediction_node and of echo_node each, in alternation."""
EXECUTOR = 'single'
"""The executor in the latency runs: the nodes' default (docs/prediction.md)."""
STATE_COV = np.diag([1e-6] * 3 + [1e-2] * 3 + [100.0] * 3)
"""Covariance of the benchmark's states: 1 mm, 0.1 m/s, 10 rad/s."""
TARGETS = {'single_median_us': 50.0, 'single_p99_us': 200.0, 'speedup': 30.0,
           'max_hit_diff_mm': 0.1, 'batch_10k_s': 0.5, 'cli_us_per_state': 50.0,
           'cli_speedup': 30.0, 'node_p99_minus_echo_p99_ms': 0.3}


def incoming(rng, n):
    """Served balls from behind the opponent's end line, most of them reaching the robot."""
    return np.column_stack([
        rng.uniform(1.4, 1.8, n), rng.uniform(-0.5, 0.5, n), rng.uniform(0.2, 0.4, n),
        rng.uniform(-8.0, -4.0, n), rng.uniform(-1.0, 1.0, n), rng.uniform(0.8, 2.0, n),
        rng.uniform(-300, 300, (n, 3))])


def time_single(states, params, clock=time.perf_counter_ns):
    """Time of each predict call, us (wall clock; or the thread's CPU time with
    clock=time.thread_time_ns, which leaves out the time other processes had the core)."""
    times = np.empty(len(states))
    for i, s in enumerate(states):
        start = clock()
        predict(s, params)
        times[i] = clock() - start
    return times * 1e-3


def near_the_net(state, params, margin=5e-3):
    """Whether the flight (until the robot's side's plane, no net stop) comes within a ball
    radius (+ ``margin``, m) of the net's top edge or of its face below it: there predict
    meets the net as a body and the reference (the net as a line at x = 0) does not."""
    r = params.radius
    _, samples = rollout(state, params, stop_at_net=False, max_bounces=2,
                         sample_times=np.arange(0.0, 1.5, 5e-4))
    p = samples[np.isfinite(samples[:, 0]), :3]
    near = (np.abs(p[:, 0]) < r + margin) & (np.abs(p[:, 1]) <= NET_HALF_WIDTH + r) & (
        p[:, 2] < NET_HEIGHT + r + margin)
    return bool(near.any())


def time_reference(states, params):
    """Reference timings, hit-point differences, and (status agreements, states compared,
    states left out as touching the net's body)."""
    times, diffs, agree, compared = [], [], 0, 0
    for s in states:
        start = time.perf_counter_ns()
        ref = reference_predict(s, params)
        times.append((time.perf_counter_ns() - start) * 1e-3)
        fast = predict(s, params)
        if fast.status != ref.status and near_the_net(s, params):
            continue        # the net as a body (predict) against a line (the reference)
        compared += 1
        agree += fast.status == ref.status
        if ref.hit is not None and fast.hit is not None:
            diffs.append(float(np.abs(fast.hit.p - ref.hit.p).max()) * 1e3)
    return np.array(times), diffs, (agree, compared, len(states) - compared)


def json_lines(states, t0=0.0, dt=0.002):
    """tt-predict's input: one JSON object per state, at times t0, t0 + dt, ..."""
    return ''.join(json.dumps({'t': t0 + i * dt, 'p': s[:3].tolist(), 'v': s[3:6].tolist(),
                               'w': s[6:].tolist()}) + '\n' for i, s in enumerate(states))


def time_cli(states):
    """(us per state of tt-predict's main in this process, wall clock and the process's CPU
    time (all threads), the whole command's s, its s on one line) for ``states`` written as
    JSON lines; the output is checked to have a line each."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, 'in.jsonl')
        with open(path, 'w') as f:
            f.write(json_lines(states))
        one = os.path.join(tmp, 'one.jsonl')
        with open(one, 'w') as f:
            f.write(json_lines(states[:1]))
        times, cpu = [], []
        stdout = sys.stdout
        for _ in range(4):                  # the first run also loads the compiled kernels
            sys.stdout = sink = io.StringIO()
            try:
                start, start_cpu = time.perf_counter(), time.process_time()
                rc = cli.main(['--input', path])
                times.append(time.perf_counter() - start)
                cpu.append(time.process_time() - start_cpu)
            finally:
                sys.stdout = stdout
            if rc != 0 or sink.getvalue().count('\n') != len(states):
                raise RuntimeError(f'tt-predict failed (exit {rc})')
        command = []
        for p in (path, one):
            start = time.perf_counter()
            subprocess.run([sys.executable, '-m', 'tt_prediction.cli', '--input', p],
                           stdout=subprocess.DEVNULL, check=True, timeout=600)
            command.append(time.perf_counter() - start)
    n = len(states)
    return (float(np.median(times[1:])) / n * 1e6, float(np.median(cpu[1:])) / n * 1e6,
            command[0], command[1])


COLD = ('import time; t = time.perf_counter(); from tt_prediction.predict import predict; '
        'p = predict([1.6, 0.1, 0.3, -6, 0, 1.5, 0, 100, 0]); assert p.status == "ok"; '
        'print(time.perf_counter() - t)')


def cold_start():
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, 'NUMBA_CACHE_DIR': cache}
        times = []
        for _ in range(2):           # empty cache (compiles), then the cache it wrote
            out = subprocess.run([sys.executable, '-c', COLD], env=env, capture_output=True,
                                 text=True, timeout=300, check=True)
            times.append(float(out.stdout.strip()))
    return times


ECHO_NODE = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'echo_node.py')


def node_latency(params=(), cpus=None, node=('-m', 'tt_prediction.node')):
    """(p50, p99, received, sent, node's callback summary, all latencies) of the latency in ms.

    ``params``: node parameters as 'name:=value'. ``cpus``: None, the scheduler places both
    processes; else (node core, harness core): the node runs under ``taskset -c`` on the
    first, this process's publishing and receiving threads are pinned to the second.
    ``node``: the node's command after the interpreter (``(ECHO_NODE,)``: the floor).
    """
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from tt_ros.executor import EXECUTOR_ENV, make_executor

    from tt_msgs.msg import BallPrediction, BallState

    prefix = f'/bench_{os.getpid()}_{uuid.uuid4().hex[:6]}'
    remap = []
    for topic in ('/ball/state', '/ball/prediction', '/ball/predicted_path', '/tt/markers'):
        remap += ['-r', f'{topic}:={prefix}{topic}']
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    env.pop(EXECUTOR_ENV, None)                 # the nodes' default executor
    taskset = [] if cpus is None else ['taskset', '-c', str(cpus[0])]
    log = tempfile.TemporaryFile('w+')
    proc = subprocess.Popen([*taskset, sys.executable, *node,
                             '--ros-args', *remap, *(a for p in params for a in ('-p', p))],
                            env=env, stdout=log, stderr=subprocess.STDOUT)
    affinity = os.sched_getaffinity(0)
    if cpus is not None:
        os.sched_setaffinity(0, {cpus[1]})      # this thread and the threads it starts
    context = rclpy.context.Context()
    rclpy.init(context=context, args=[])
    node = rclpy.create_node(f'bench_{uuid.uuid4().hex[:6]}', context=context)
    latencies = []
    clock = node.get_clock()

    def on_prediction(msg):
        now = clock.now().nanoseconds
        latencies.append((now - (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec))
                         * 1e-6)

    node.create_subscription(BallPrediction, f'{prefix}/ball/prediction', on_prediction, 50)
    pub = node.create_publisher(BallState, f'{prefix}/ball/state', qos_profile_sensor_data)
    # The receiving side as lean as the node's: the same executor (docs/prediction.md).
    executor = make_executor(EXECUTOR, context=context)
    executor.add_node(node)

    def receive():
        try:
            while context.ok():
                executor.spin_once(timeout_sec=0.2)
        except Exception:           # the context shut down under it
            if context.ok():
                raise

    thread = threading.Thread(target=receive, daemon=True)
    thread.start()
    # The publishing loop and the receiving thread share this process's GIL: with Python's
    # default 5 ms switch interval the receiver could wait for the publisher to let go, and
    # the harness, not the node, would set the tail. The node sets the same interval.
    switch_interval = sys.getswitchinterval()
    sys.setswitchinterval(2e-4)
    try:
        deadline = time.monotonic() + 120
        while pub.get_subscription_count() == 0 or node.count_publishers(
                f'{prefix}/ball/prediction') == 0:
            if time.monotonic() > deadline or proc.poll() is not None:
                raise RuntimeError('prediction_node did not come up')
            time.sleep(0.05)
        msg = BallState()
        msg.header.frame_id = 'table'
        msg.covariance = STATE_COV.ravel().tolist()
        rng = np.random.default_rng(3)
        states = incoming(rng, int(NODE_RATE_HZ * NODE_SECONDS))
        # Warm-up second, not counted.
        period = 1.0 / NODE_RATE_HZ
        sent = 0
        for phase in ('warm', 'measure'):
            latencies.clear()
            n = int(NODE_RATE_HZ) if phase == 'warm' else len(states)
            next_t = time.perf_counter()
            for i in range(n):
                s = states[i % len(states)]
                (msg.position.x, msg.position.y, msg.position.z, msg.velocity.x, msg.velocity.y,
                 msg.velocity.z, msg.spin.x, msg.spin.y, msg.spin.z) = s.tolist()
                msg.track_id = i // 100
                msg.header.stamp = clock.now().to_msg()
                pub.publish(msg)
                next_t += period
                delay = next_t - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)      # pacing the publisher, not synchronisation
            sent = n
            time.sleep(0.2)                # let the last answers arrive
        lat = np.array(latencies)
        result = [float(np.median(lat)), float(np.percentile(lat, 99)), len(lat), sent, lat]
    finally:
        sys.setswitchinterval(switch_interval)
        rclpy.try_shutdown(context=context)
        thread.join(timeout=5.0)
        executor.shutdown()
        node.destroy_node()
        os.sched_setaffinity(0, affinity)
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.seek(0)
        summary = [line for line in log.read().splitlines() if 'callback median' in line]
        log.close()
    # The node's own summary at shutdown: the time its callback took (no scheduling waits).
    return (*result[:4], summary[-1].split(']: ')[-1] if summary else 'not logged', result[4])


def node_cores():
    """(node core, harness core) for the pinned latency run, or None with fewer than 2."""
    cores = sorted(os.sched_getaffinity(0))
    return (cores[-1], cores[0]) if len(cores) >= 2 else None


def run():
    params = ModelParams()
    rng = np.random.default_rng(11)
    states = incoming(rng, N_SINGLE)
    predict(states[0], params)                          # compiled outside the timing
    predict_batch(states[:300], params)
    load = os.getloadavg()[0]
    single = time_single(states, params)
    single_cpu = time_single(states, params, time.thread_time_ns)
    ref_times, diffs, (agree, compared, net_body) = time_reference(states[:N_REFERENCE],
                                                                    params)
    fast_ref = time_single(states[:N_REFERENCE], params)
    batch_states = incoming(rng, N_BATCH)
    start = time.perf_counter()
    batch = predict_batch(batch_states, params)
    batch_s = time.perf_counter() - start
    predict_uncertainty(states[0], STATE_COV, params)
    start = time.perf_counter()
    for s in states[:50]:
        predict_uncertainty(s, STATE_COV, params)
    unc_ms = (time.perf_counter() - start) / 50 * 1e3
    cold, warm = cold_start()
    cli_us, cli_cpu_us, command_s, startup_s = time_cli(incoming(rng, N_CLI))
    cli_speedup = float(np.median(ref_times)) / cli_us
    cores = node_cores()
    runs, floors = [], []
    for _ in range(ROUNDS):
        runs.append(node_latency(cpus=cores))
        floors.append(node_latency(cpus=cores, node=(ECHO_NODE,)))
    # The rounds pooled: the same share of each load phase in both.
    node_lat = np.concatenate([r[5] for r in runs])
    floor_lat = np.concatenate([r[5] for r in floors])
    p50, p99 = float(np.median(node_lat)), float(np.percentile(node_lat, 99))
    floor_p50, floor_p99 = float(np.median(floor_lat)), float(np.percentile(floor_lat, 99))
    received, sent = sum(r[2] for r in runs), sum(r[3] for r in runs)
    floor_received, floor_sent = sum(r[2] for r in floors), sum(r[3] for r in floors)
    free = node_latency()
    result = {
        'single_us': {'median': round(float(np.median(single)), 1),
                      'p99': round(float(np.percentile(single, 99)), 1),
                      'n': N_SINGLE},
        'single_cpu_us': {'median': round(float(np.median(single_cpu)), 1),
                          'p99': round(float(np.percentile(single_cpu, 99)), 1)},
        'load_average_1min': {'start': round(load, 2), 'end': round(os.getloadavg()[0], 2),
                              'cores': os.cpu_count()},
        'status_counts': {name: int(c) for name, c in zip(
            *np.unique(batch.status_names(), return_counts=True), strict=True)},
        'reference': {'median_us': round(float(np.median(ref_times)), 1),
                      'fast_median_us_same_states': round(float(np.median(fast_ref)), 1),
                      'speedup': round(float(np.median(ref_times) / np.median(fast_ref)), 1),
                      'max_hit_diff_mm': float(f'{max(diffs):.3g}'),
                      'n': N_REFERENCE, 'n_hits': len(diffs), 'status_agree': agree,
                      'status_compared': compared, 'left_out_net_body': net_body},
        'batch_10k_s': round(batch_s, 3),
        'cli_20k': {'us_per_state': round(cli_us, 1), 'cpu_us_per_state': round(cli_cpu_us, 1),
                    'n': N_CLI,
                    'reference_median_us': round(float(np.median(ref_times)), 1),
                    'speedup': round(cli_speedup, 1), 'command_s': round(command_s, 2),
                    'startup_s': round(startup_s, 2)},
        'uncertainty_ms': round(unc_ms, 2),
        'cold_start_s': {'empty_numba_cache': round(cold, 2), 'warm_cache': round(warm, 2)},
        'node_latency_ms': {'p50': round(p50, 3), 'p99': round(p99, 3), 'rate_hz': NODE_RATE_HZ,
                            'executor': EXECUTOR, 'rounds': ROUNDS,
                            'p99_per_round': [round(r[1], 3) for r in runs],
                            'received': received, 'sent': sent,
                            'node_callback': [r[4] for r in runs],
                            'cores': {'node': cores[0], 'harness': cores[1]} if cores else None},
        'node_latency_floor_ms': {'p50': round(floor_p50, 3), 'p99': round(floor_p99, 3),
                                  'p99_per_round': [round(r[1], 3) for r in floors],
                                  'received': floor_received, 'sent': floor_sent},
        'node_p99_minus_echo_p99_ms': round(p99 - floor_p99, 3),
        'node_latency_unpinned_ms': {'p50': round(free[0], 3), 'p99': round(free[1], 3),
                                     'received': free[2], 'sent': free[3],
                                     'node_callback': free[4]},
        'targets': {k: (f'>= {v}' if 'speedup' in k else f'<= {v}') for k, v in TARGETS.items()},
    }
    result['passed'] = bool(
        result['single_us']['median'] <= TARGETS['single_median_us']
        and result['single_us']['p99'] <= TARGETS['single_p99_us']
        and result['reference']['speedup'] >= TARGETS['speedup']
        and result['reference']['max_hit_diff_mm'] <= TARGETS['max_hit_diff_mm']
        and agree == compared and net_body <= N_REFERENCE // 10
        and batch_s <= TARGETS['batch_10k_s']
        and cli_us <= TARGETS['cli_us_per_state'] and cli_speedup >= TARGETS['cli_speedup']
        and p99 - floor_p99 <= TARGETS['node_p99_minus_echo_p99_ms']
        and received >= 0.95 * sent and floor_received >= 0.95 * floor_sent)
    return result


if __name__ == '__main__':
    from run_all import bench_main
    sys.exit(bench_main(__file__, run))
