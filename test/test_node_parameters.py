"""Parameters of the live nodes (`ros2 run` processes): an integer where a float is expected is
taken as that float; a wrong-typed or out-of-range value is refused with one line naming the
parameter and its range, the node keeping the old value; at start-up the node exits 2 with
that line and no traceback (issue 17 item 3).

Each node runs in a namespace of its own; the test waits on services and futures, never on
sleeps.
"""

import os
import signal
import subprocess
import uuid

import pytest
from rcl_interfaces.msg import ParameterType
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from tt_ros.testing import Graph, unique_domain
from tt_tools.procs import ProcessGroup, ros_env
import yaml

pytestmark = pytest.mark.graph

TIMEOUT_S = 120.0


def _tt_lines(stderr):
    """stderr lines written by tt (not Fast DDS's own log lines)."""
    return [line for line in stderr.splitlines() if line.strip() and 'RTPS_' not in line]


class ParamClient(Graph):
    """A parameter client of one live node, waiting on futures."""

    def __init__(self, node_path):
        super().__init__()
        self.node = self.create_node('ptest')
        self.client = AsyncParameterClient(self.node, node_path)
        assert self.client.wait_for_services(timeout_sec=TIMEOUT_S), f'{node_path} not up'

    def _wait(self, future):
        self.executor.spin_until_future_complete(future, timeout_sec=TIMEOUT_S)
        assert future.done()
        return future.result()

    def get(self, name):
        value = self._wait(self.client.get_parameters([name])).values[0]
        return value

    def set(self, name, value):
        return self._wait(self.client.set_parameters([Parameter(name, value=value)])).results[0]


def _node(group, package, executable, ns, *params):
    args = ['ros2', 'run', package, executable, '--ros-args', '-r', f'__ns:={ns}']
    for p in params:
        args += ['-p', p]
    return group.start(executable, args)


def test_prediction_node_integers_for_floats_and_refused_values_keep_the_old(tmp_path):
    assert os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE') == 'LOCALHOST'
    ns = f'/ptest_{os.getpid()}_{uuid.uuid4().hex[:6]}'
    with ProcessGroup(str(tmp_path)) as group:
        proc = _node(group, 'tt_prediction', 'prediction_node', ns, 'stale_after_s:=0',
                     'max_rate_hz:=100', 'uncertainty:=false')
        client = ParamClient(f'{ns}/prediction_node')
        try:
            value = client.get('stale_after_s')
            assert (value.type, value.double_value) == (ParameterType.PARAMETER_DOUBLE, 0.0)
            assert client.get('max_rate_hz').double_value == 100.0
            # An integer at run time, as `ros2 param set ... stale_after_s 2` sends it.
            assert client.set('stale_after_s', 2).successful
            value = client.get('stale_after_s')
            assert (value.type, value.double_value) == (ParameterType.PARAMETER_DOUBLE, 2.0)
            # Out of the declared range [0, 60] s, and a string: refused, 2.0 kept.
            for bad in (100.0, 'abc', True):
                result = client.set('stale_after_s', bad)
                assert not result.successful
                assert '\n' not in result.reason
                assert 'stale_after_s' in result.reason
                assert '0' in result.reason and '60' in result.reason
                assert client.get('stale_after_s').double_value == 2.0
            # Read-only: refused with the parameter's name.
            result = client.set('model_file', 'other.yaml')
            assert not result.successful and 'model_file' in result.reason
        finally:
            client.close()
        assert proc.poll() is None, 'prediction_node died on a parameter set'
        assert group.stop('prediction_node') == 0


def test_strike_node_refuses_a_bad_zone_and_crossed_reach_at_run_time(tmp_path):
    ns = f'/ptest_{os.getpid()}_{uuid.uuid4().hex[:6]}'
    with ProcessGroup(str(tmp_path)) as group:
        proc = _node(group, 'tt_strike', 'strike_node', ns, 'max_racket_speed:=10',
                     'in_zone_probability:=false')
        client = ParamClient(f'{ns}/strike_node')
        try:
            value = client.get('max_racket_speed')
            assert (value.type, value.double_value) == (ParameterType.PARAMETER_DOUBLE, 10.0)
            result = client.set('target_zone', 12)
            assert not result.successful
            # rclpy's own range check words it: 'Parameter target_zone out of range. Min: 0,
            # Max: 9, value: 12'.
            assert 'target_zone' in result.reason and '9' in result.reason
            assert '\n' not in result.reason
            assert client.get('target_zone').integer_value == 5
            assert client.set('target_zone', 3).successful
            assert client.get('target_zone').integer_value == 3
            # reach_z_max default 1.5 m: a minimum above it is refused.
            result = client.set('reach_z_min', 1.8)
            assert not result.successful and 'reach_z_min' in result.reason
            assert client.get('reach_z_min').double_value == pytest.approx(-0.30)
            # A point on the robot's half is not a target.
            assert client.set('target_zone', 0).successful
            result = client.set('target_point', [-0.7, 0.0])
            assert not result.successful and 'target_point' in result.reason
            assert list(client.get('target_point').double_array_value) == [0.7, 0.0]
            # An integer list where floats are expected.
            assert client.set('target_point', [1, 0]).successful
            assert list(client.get('target_point').double_array_value) == [1.0, 0.0]
        finally:
            client.close()
        assert proc.poll() is None
        assert group.stop('strike_node') == 0


@pytest.mark.parametrize('package, executable, param, words', [
    ('tt_prediction', 'prediction_node', 'hit_plane_x:=-1500.0',
     ['hit_plane_x', '-1500', '[-3, 0] m']),
    ('tt_prediction', 'prediction_node', 'stale_after_s:=fast', ['stale_after_s', '[0, 60] s']),
    ('tt_strike', 'strike_node', 'target_zone:=12', ['target_zone', '12', '[0, 9]']),
    ('tt_strike', 'strike_node', 'reach_z_min:=2.0', ['reach_z_min', 'reach_z_max']),
    ('tt_perception', 'perception_node', 'ball_colour:=red', ['ball_colour', 'orange']),
])
def test_a_bad_value_at_start_up_exits_2_with_one_line(package, executable, param, words):
    ns = f'/ptest_{os.getpid()}_{uuid.uuid4().hex[:6]}'
    proc = subprocess.run(['ros2', 'run', package, executable, '--ros-args', '-r',
                           f'__ns:={ns}', '-p', param], capture_output=True, text=True,
                          env=ros_env(), timeout=TIMEOUT_S, stdin=subprocess.DEVNULL)
    lines = _tt_lines(proc.stderr)
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f'{executable}: ')
    for word in words:
        assert word in lines[0]
    assert 'Traceback' not in proc.stderr + proc.stdout


@pytest.mark.parametrize('package, executable, module', [
    ('tt_prediction', 'prediction_node', 'tt_prediction.node'),
    ('tt_strike', 'strike_node', 'tt_strike.node'),
    ('tt_perception', 'perception_node', 'tt_perception.node'),
])
def test_help_lists_every_parameter_with_its_range_and_starts_nothing(package, executable,
                                                                      module):
    # What a ROS user types first: `ros2 run <package> <node> --help`. It prints how to set
    # the parameters and each declared one with what it accepts (as ros2 param describe
    # does), and exits 0 without starting the node.
    import importlib
    parameters = importlib.import_module(module).PARAMETERS
    proc = subprocess.run(['ros2', 'run', package, executable, '--help'], capture_output=True,
                          text=True, env=ros_env(), timeout=TIMEOUT_S,
                          stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr
    assert _tt_lines(proc.stderr) == []
    out = proc.stdout.splitlines()
    assert out[0].startswith(f'usage: ros2 run {package} {executable} [--ros-args')
    for p in parameters:
        lines = [line for line in out if line.startswith(f'  {p.name} = ')]
        assert len(lines) == 1, p.name
        line = lines[0]
        assert p.expected() in line, p.name
        # The default as -p NAME:=VALUE and a parameters file take it, spelt as ros2 param
        # dump writes it (true, not Python's True).
        shown = line[len(f'  {p.name} = '):].split(f': {p.expected()}')[0]
        assert yaml.safe_load(shown) == p.default, (p.name, shown)
        if isinstance(p.default, bool):
            assert shown == ('true' if p.default else 'false'), (p.name, shown)


def test_help_after_ros_args_is_the_same_help():
    # `ros2 run tt_strike strike_node --ros-args --help` said 'unknown ROS arguments'
    # (a ROS user's walk-through): rcl has no --help, the node's is meant.
    runs = [subprocess.run(['ros2', 'run', 'tt_strike', 'strike_node'] + args,
                           capture_output=True, text=True, env=ros_env(), timeout=TIMEOUT_S,
                           stdin=subprocess.DEVNULL)
            for args in (['--help'], ['--ros-args', '-p', 'target_zone:=3', '--help'],
                         ['--ros-args', '--log-level', '-h'])]
    assert [r.returncode for r in runs] == [0, 0, 2], runs[1].stderr
    assert runs[1].stdout == runs[0].stdout and 'target_zone = 5' in runs[0].stdout
    # A ROS flag's value is not a request for help: rcl's to refuse, in one line.
    assert runs[2].stdout == '' and len(runs[2].stderr.strip().splitlines()) == 1


def test_a_parameter_given_without_ros_args_is_named_in_a_warning():
    # rclpy ignores `-p name:=value` before --ros-args; the node says so instead of starting
    # silently on the default. It still starts: a bad value given after --ros-args stops it
    # as above, with only that line.
    ns = f'/ptest_{os.getpid()}_{uuid.uuid4().hex[:6]}'
    proc = subprocess.run(['ros2', 'run', 'tt_strike', 'strike_node', '-p', 'target_zone:=3',
                           '--ros-args', '-r', f'__ns:={ns}', '-p', 'target_zone:=12'],
                          capture_output=True, text=True, env=ros_env(), timeout=TIMEOUT_S,
                          stdin=subprocess.DEVNULL)
    lines = _tt_lines(proc.stderr)
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 2, proc.stderr
    assert lines[0].startswith('strike_node: warning: -p target_zone:=3 before --ros-args')
    assert '--ros-args' in lines[0]
    assert lines[1].startswith('strike_node: ') and 'target_zone' in lines[1]


def test_a_misspelt_parameter_is_named_in_a_warning():
    # rclpy keeps an override of a name the node never declares without a word; the node
    # names it. A bad value of a real one then stops it, so the test needs no running node.
    ns = f'/ptest_{os.getpid()}_{uuid.uuid4().hex[:6]}'
    proc = subprocess.run(['ros2', 'run', 'tt_prediction', 'prediction_node', '--ros-args',
                           '-r', f'__ns:={ns}', '-p', 'stale_aftr_s:=1.0', '-p',
                           'use_sim_time:=false', '-p',  # rclpy's own, as param dump writes
                           'start_type_description_service:=true', '-p',
                           'stale_after_s:=fast'],
                          capture_output=True, text=True, env=ros_env(), timeout=TIMEOUT_S,
                          stdin=subprocess.DEVNULL)
    lines = _tt_lines(proc.stderr)
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 2, proc.stderr
    assert lines[0].endswith("parameter 'stale_aftr_s' given but prediction_node has no such "
                             'parameter: ignored (--help lists them)')
    assert '[WARN]' in lines[0]
    assert lines[1].startswith('prediction_node: ') and 'stale_after_s' in lines[1]


def test_another_nodes_parameter_in_a_shared_section_is_not_taken_for_a_misspelt_one(
        tmp_path):
    # One /** section for the whole graph holds every node's parameters: prediction_node
    # named strike_node's target_zone (and each node every other's) as misspelt, burying a
    # real misspelling. Those of a section naming the node, and -p, are still named.
    path = tmp_path / 'graph.yaml'
    path.write_text('/**:\n  ros__parameters:\n    target_zone: 8\n    hit_plane_x: -1.2\n'
                    '/**/prediction_node:\n  ros__parameters:\n    stale_aftr_s: 1.0\n')
    ns = f'/ptest_{os.getpid()}_{uuid.uuid4().hex[:6]}'
    proc = subprocess.run(['ros2', 'run', 'tt_prediction', 'prediction_node', '--ros-args',
                           '-r', f'__ns:={ns}', '--params-file', str(path), '-p',
                           'max_racket_speed:=5.0', '-p', 'stale_after_s:=fast'],
                          capture_output=True, text=True, env=ros_env(), timeout=TIMEOUT_S,
                          stdin=subprocess.DEVNULL)
    lines = _tt_lines(proc.stderr)
    assert proc.returncode == 2, proc.stderr
    warned = sorted(line.split("parameter '")[1].split("'")[0] for line in lines
                    if 'has no such parameter' in line)
    assert warned == ['max_racket_speed', 'stale_aftr_s'], proc.stderr


@pytest.mark.parametrize('section, namespaced, unused', [
    ('other_node', False, True),            # a file written for another node
    ('prediction_node', True, True),        # a plain name is the root namespace's node only
    ('/**/prediction_node', True, False),   # rcl's wildcards: any namespace
    ('/**', True, False),
    ('/*/prediction_node', True, False),
])
def test_a_params_file_with_no_section_for_the_node_is_named_in_a_warning(tmp_path, section,
                                                                          namespaced, unused):
    # rcl sets nothing from a parameters file none of whose sections names the node, without
    # a word: the node started on its defaults. It says so, and runs.
    path = tmp_path / 'params.yaml'
    path.write_text(f'{section}:\n  ros__parameters:\n    stale_after_s: 0.25\n')
    ns = f'/ptest_{os.getpid()}_{uuid.uuid4().hex[:6]}' if namespaced else '/'
    proc = subprocess.Popen(['ros2', 'run', 'tt_prediction', 'prediction_node', '--ros-args',
                             '-r', f'__ns:={ns}', '--params-file', str(path)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=ros_env({'ROS_DOMAIN_ID': str(unique_domain())}),
                            stdin=subprocess.DEVNULL)
    try:
        lines = []
        for line in proc.stderr:            # until the node says it is ready (or ends)
            lines.append(line.rstrip())
            if line.rstrip().endswith(']: ready'):
                break
        proc.send_signal(signal.SIGINT)
        proc.wait(TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, '\n'.join(lines)
    warned = [ln for ln in lines if 'has no section for' in ln]
    if unused:
        assert len(warned) == 1 and '[WARN]' in warned[0], '\n'.join(lines)
        assert f'--params-file {path} (its sections: /{section})' in warned[0]
        assert '/prediction_node: nothing set from it' in warned[0]
    else:
        assert warned == [], '\n'.join(lines)
