"""tt_tools.rosutil.CliNode as a process (its teardown, leave_graph, is the Collector's too):
a teardown that hangs (Fast DDS can deadlock in it) is reported with every thread's stack and
ended with exit 1 instead of waiting for ever, and a teardown that does not hang leaves the
command to go on for as long as it needs."""

import os
import subprocess
import sys
import textwrap
import time

# A verb's node whose destroy_node may hang ({hang} s); the limit is {limit} s. After the node
# is closed the command goes on for {after} s (writing a long output, say), then says 'done'.
CHILD = textwrap.dedent("""
    import time
    from tt_tools import rosutil
    rosutil.SHUTDOWN_LIMIT_S = {limit}
    def hang():
        time.sleep({hang})
    with rosutil.CliNode('cli_node_test') as cli:
        cli.node.destroy_node = hang
    time.sleep({after})
    print('done', flush=True)
""")


def _run(limit, hang, after):
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    start = time.monotonic()
    proc = subprocess.run(
        [sys.executable, '-c', CHILD.format(limit=limit, hang=hang, after=after)], env=env,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=120)
    return proc.returncode, proc.stdout, time.monotonic() - start


def test_a_teardown_that_hangs_is_ended_at_the_limit_with_every_stack():
    code, out, took = _run(limit=1.0, hang=60.0, after=0.0)
    assert code == 1, out
    # faulthandler's dump names the call the main thread was stuck in.
    assert 'Thread' in out and 'in hang' in out, out
    assert 'done' not in out, out
    assert took < 30.0, (took, out)


def test_the_limit_ends_with_the_teardown_not_with_the_command():
    code, out, _ = _run(limit=1.0, hang=0.0, after=2.0)
    assert code == 0, out
    assert out.strip().splitlines()[-1] == 'done', out
    assert 'Thread' not in out, out
