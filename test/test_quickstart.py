"""The README's quick start, run as written (its code block parsed from README.md), ends with
a /strike/command on screen (issue 17 item 7).

It runs in a ROS domain of its own; the block itself synchronises on conditions (bringup
starts the nodes in order, pub waits for its subscriber, echo for its message), never on
sleeps.
"""

import os
import pathlib
import re
import signal
import subprocess
import textwrap

import pytest
from tt_ros.testing import unique_domain
from tt_tools.procs import ros_env

pytestmark = pytest.mark.graph

TOP = pathlib.Path(__file__).resolve().parents[1]


def quick_start_block(readme):
    """The first indented code block under the '## Quick start' heading, dedented."""
    section = readme.split('\n## Quick start\n', 1)[1].split('\n## ', 1)[0]
    lines, block = section.splitlines(), []
    for line in lines:
        if line.startswith('    ') or (block and not line.strip()):
            block.append(line)
        elif block:
            break
    return textwrap.dedent('\n'.join(block)).strip() + '\n'


def test_the_block_is_found_and_ends_with_the_strike_command():
    block = quick_start_block((TOP / 'README.md').read_text())
    assert block.startswith('set +u; . ./env.sh')
    assert 'ros2 topic echo /strike/command --once' in block


def test_the_readme_quick_start_shows_a_strike_command():
    block = quick_start_block((TOP / 'README.md').read_text())
    env = ros_env({'ROS_DOMAIN_ID': str(unique_domain())})
    proc = subprocess.Popen(['bash', '-c', block], cwd=TOP, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            stdin=subprocess.DEVNULL, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0, out
    # The echoed StrikeCommand: a feasible stroke to the robot's default target, zone 5.
    command = out[out.index('status: ok'):]
    assert re.search(r'^feasible: true$', command, re.M), out
    assert re.search(r'^landing_zone: 5$', command, re.M), out
    assert re.search(r'^target_zone: 5$', command, re.M), out
    assert 'bringup: stopped' in out and 'Traceback' not in out
