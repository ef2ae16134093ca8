"""tt_ros.executor.run_node as a process: a signal stops the node cleanly (exit 0), and a
teardown that hangs is reported with every thread's stack and ended (exit 1) instead of
waiting for the parent's SIGKILL; a bad --params-file is one line and exit 2."""

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

# The node of the child process: a plain rclpy node; its on_exit may hang ({hang} s).
CHILD = textwrap.dedent("""
    import time
    import rclpy.node
    from tt_ros import executor
    executor.SHUTDOWN_LIMIT_S = {limit}
    def hang(node):
        node.get_logger().info('on_exit')
        time.sleep({hang})
    executor.run_node(lambda: rclpy.node.Node('executor_test_{pid}'), [],
                      on_exit=hang, name='executor_test')
""")


def _run_and_signal(limit, hang):
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    code = CHILD.format(limit=limit, hang=hang, pid=os.getpid())
    proc = subprocess.Popen([sys.executable, '-c', code], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        line = ''
        while 'ready' not in line:       # run_node logs READY once the node spins
            line = proc.stdout.readline()
            assert line or proc.poll() is None, 'the node exited before it was ready'
        start = time.monotonic()
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=60)
        return proc.returncode, rest, time.monotonic() - start
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_signal_stops_the_node_with_exit_0():
    code, out, _ = _run_and_signal(limit=30.0, hang=0.0)
    assert code == 0, out
    assert 'on_exit' in out and 'Traceback' not in out


def test_a_teardown_that_hangs_is_ended_at_the_limit_with_every_stack():
    limit = 1.0
    code, out, took = _run_and_signal(limit=limit, hang=60.0)
    assert code == 1, out
    # faulthandler's dump: the main thread's stack, down to the call that hung.
    assert 'Thread' in out and 'in hang' in out, out
    assert limit <= took < 30.0, (took, out)


# A node whose callback never returns (as one stuck in compiled code would not).
STUCK = textwrap.dedent("""
    import time
    import rclpy.node
    from tt_ros import executor
    def stuck_in_callback():
        print('stuck', flush=True)
        time.sleep(60)
    def make():
        node = rclpy.node.Node('executor_test_stuck_{pid}')
        node.create_timer(0.05, stuck_in_callback)
        return node
    executor.run_node(make, [], name='executor_test')
""")


def test_sigusr1_writes_the_stacks_of_a_stuck_node_and_the_node_goes_on():
    from tt_ros.executor import STACKS_SIGNAL

    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    proc = subprocess.Popen([sys.executable, '-c', STUCK.format(pid=os.getpid())], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        while not lines or lines[-1] != 'stuck':
            lines.append(proc.stdout.readline().rstrip('\n'))
            assert lines[-1] or proc.poll() is None, '\n'.join(lines)
        proc.send_signal(STACKS_SIGNAL)
        # faulthandler's dump names the function the main thread is stuck in; a
        # SIGUSR1 with the default action would end the process with nothing written.
        while 'in stuck_in_callback' not in lines[-1]:
            lines.append(proc.stdout.readline().rstrip('\n'))
            assert lines[-1] or proc.poll() is None, '\n'.join(lines)
        assert proc.poll() is None, '\n'.join(lines)
    finally:
        proc.kill()
        proc.wait()


# A node started as `ros2 run` starts it: the ROS arguments come from sys.argv (args=None).
ARGV_CHILD = textwrap.dedent("""
    import rclpy.node
    from tt_ros import executor
    executor.run_node(lambda: rclpy.node.Node('executor_test_{pid}'), name='executor_test')
""")


@pytest.mark.parametrize('content', [
    None,                              # no such file
    'a: [1, 2\n',                      # not YAML
    'hello\n',                         # YAML, but not a mapping of node names
])
def test_a_bad_params_file_is_one_line_and_exit_2(tmp_path, content):
    path = tmp_path / 'params.yaml'
    if content is not None:
        path.write_text(content)
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    proc = subprocess.run(
        [sys.executable, '-c', ARGV_CHILD.format(pid=os.getpid()),
         '--ros-args', '--params-file', str(path)],
        env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert 'Traceback' not in proc.stderr and proc.stdout == '', proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f'executor_test: cannot read --params-file {path}: '), lines


@pytest.mark.parametrize('domain_id', ['abc', '233'])
def test_a_domain_id_rcl_cannot_use_is_one_line_and_exit_2(domain_id):
    """rcl's RCLError traceback ('abc') and Fast DDS ending the process at the first node
    (233: no ports) are a line naming the variable before rclpy starts."""
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           'ROS_DOMAIN_ID': domain_id}
    proc = subprocess.run([sys.executable, '-c', ARGV_CHILD.format(pid=os.getpid())],
                          env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines() == [proc.stderr.strip()], proc.stderr
    assert proc.stderr.startswith('executor_test: ROS_DOMAIN_ID '), proc.stderr


def _handled_with_a_second_signal_inside(signals, at):
    """Run ``signals``' SIGTERM handler in a thread, with a second SIGTERM handled at its
    ``at``-th traced line (its own or those of what it calls). Returns the thread, joined
    for up to 5 s, and where the second one came ([] when the handler had fewer lines)."""
    where, lines = [], [0]

    def tracer(frame, event, arg):
        if event in ('call', 'line') and not where:
            lines[0] += 1
            if lines[0] == at:
                where.append(f'{frame.f_code.co_filename}:{frame.f_lineno}')
                signals._handle(signal.SIGTERM, None)          # the second SIGTERM
        return tracer

    def first():
        sys.settrace(tracer)
        try:
            signals._handle(signal.SIGTERM, None)
        finally:
            sys.settrace(None)

    worker = threading.Thread(target=first, daemon=True)
    worker.start()
    worker.join(timeout=5.0)
    return worker, where


@pytest.mark.parametrize('at', range(1, 12))
def test_a_signal_that_comes_while_its_handler_runs_leaves_the_node_told_to_stop(at):
    """A second SIGTERM at any line of the first one's handler (a node whose parent dies can
    get the kernel's PR_SET_PDEATHSIG more than once): Python runs the handlers nested, and
    both end with the node told to stop. With a threading.Event's set() in the handler, a
    second signal inside set() waited for ever on the Event's own lock."""
    from tt_ros.executor import _StopOnSignal

    signals = _StopOnSignal()
    worker, where = _handled_with_a_second_signal_inside(signals, at)
    assert not worker.is_alive(), f'the handler, entered again at {where}, never returned'
    assert signals.stopped


def test_a_slow_start_up_step_is_said_while_it_runs_and_a_quick_one_not():
    # perception_node compiling its kernels on its first start sat silent for a minute.
    from tt_ros.executor import said_if_slow
    said = threading.Event()

    class Logger:
        lines = []

        def info(self, text):
            self.lines.append(text)
            said.set()

    logger = Logger()
    with said_if_slow(logger, 'loading', after_s=0.0):
        assert said.wait(10.0)          # the block goes on until the line is said
    with said_if_slow(logger, 'quick', after_s=60.0):
        pass
    assert logger.lines == ['loading']
