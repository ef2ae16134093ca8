"""ros2 param / node info / topic type / interface show / pkg executables, the waits that say
what they wait for, a closed pipe, and list/info under load: each verb against live nodes."""

import os
import pathlib
import re
import signal
import subprocess
import sys
import threading
import time
import uuid

from conftest import ROS2, Graph, Ros2Process, error_lines, ros2
import pytest
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
import rclpy.parameter
from rclpy.qos import QoSProfile
from tt_ros.index import interface_file
from tt_tools.introspect import import_message_type
from tt_tools.param import parse_value
from tt_tools.procs import ros_env
import yaml

from tt_msgs.msg import BallPrediction, BallState

pytestmark = pytest.mark.graph


def run_all(graph, *commands, timeout=300, env=None):
    """Run ``ros2`` commands concurrently while the test's graph spins (its node answers
    service calls); [(exit code, stdout, stderr)] in the order given. ``env``: extra
    environment variables. ``timeout`` only guards against a command that never ends: 14 of
    them starting at once on this 2-core machine, at half its speed of 27 Nov (29 Nov 2026),
    took over 120 s once."""
    procs = [Ros2Process(*c, env=env) for c in commands]
    try:
        try:
            graph.spin_until(lambda: all(p.proc.poll() is not None for p in procs), timeout,
                             f'{len(procs)} ros2 commands to end')
        except TimeoutError as exc:   # say which did not end, and where each was
            stuck = [f'ros2 {" ".join(c)}:\n{p.dump_stack()}'
                     for c, p in zip(commands, procs, strict=True)
                     if p.proc.poll() is None]
            raise TimeoutError('\n'.join([str(exc), *stuck])) from None
        return [(p.wait(), p.stdout, p.stderr) for p in procs]
    finally:
        for p in procs:
            p.stop()


@pytest.fixture
def param_node(graph):
    """The test graph's node with declared parameters: ranges, a read-only one, dotted names,
    an array, and a set-callback that refuses a negative 'count'."""
    node = graph.node
    node.declare_parameter('gain', 0.5, ParameterDescriptor(
        description='a gain, 1', floating_point_range=[
            FloatingPointRange(from_value=0.0, to_value=1.0, step=0.0)]))
    node.declare_parameter('count', 3, ParameterDescriptor(
        description='a count', integer_range=[IntegerRange(from_value=-5, to_value=10, step=1)]))
    node.declare_parameter('mode', 'fast', ParameterDescriptor(read_only=True))
    node.declare_parameter('limits.low', -1.0)
    node.declare_parameter('limits.high', 2.0)
    node.declare_parameter('flags', [True, False])

    def check(params):
        for p in params:
            if p.name == 'count' and p.value < 0:
                return SetParametersResult(successful=False, reason='count must be >= 0')
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(check)
    return '/' + node.get_name()


def test_param_verbs_on_a_node_with_declared_parameters(graph, param_node):
    n = param_node
    (get, get_hidden, desc, dump, lst, lst_types, get_nope, get_no_node, set_count,
     set_neg, set_ro, set_range, set_int, desc_one_nope) = run_all(
        graph,
        ('param', 'get', n, 'gain'),
        ('param', 'get', n, 'flags', '--hide-type'),
        ('param', 'describe', n, 'gain', 'count', 'mode'),
        ('param', 'dump', n),
        ('param', 'list', n),
        ('param', 'list', n, '--param-type', '--param-prefixes', 'limits'),
        ('param', 'get', n, 'nope'),
        ('param', 'get', n + '_absent', 'gain'),
        ('param', 'set', n, 'count', '7'),
        ('param', 'set', n, 'count', '-1'),
        ('param', 'set', n, 'mode', 'slow'),
        ('param', 'set', n, 'gain', '2.0'),
        ('param', 'set', n, 'limits.low', '-2'),  # an integer for a double parameter
        ('param', 'describe', n, 'gain', 'nope'),
    )
    assert get == (0, 'Double value is: 0.5\n', get[2])
    assert get_hidden[:2] == (0, '[True, False]\n')
    assert desc[0] == 0, desc[2]
    assert desc[1].splitlines() == [
        'Parameter name: gain', '  Type: double', '  Description: a gain, 1',
        '  Constraints:', '    Min value: 0.0', '    Max value: 1.0',
        'Parameter name: count', '  Type: integer', '  Description: a count',
        '  Constraints:', '    Min value: -5', '    Max value: 10', '    Step: 1',
        'Parameter name: mode', '  Type: string', '  Constraints:', '    Read only: true']
    assert dump[0] == 0, dump[2]
    dumped = yaml.safe_load(dump[1])[n]['ros__parameters']
    assert dumped['gain'] == 0.5 and dumped['mode'] == 'fast'
    assert dumped['limits']['high'] == 2.0 and set(dumped['limits']) == {'low', 'high'}
    assert dumped['flags'] == [True, False] and dumped['use_sim_time'] is False
    names = [line.strip() for line in lst[1].splitlines()]
    assert {'gain', 'count', 'mode', 'limits.low', 'limits.high', 'flags',
            'use_sim_time'} <= set(names) and names == sorted(names)
    assert lst_types[1].splitlines() == ['  limits.high (type: double)',
                                         '  limits.low (type: double)']
    # Without a node: every node's names under '/node:'. Run alone: among a dozen ros2
    # processes starting at once on 2 cores, this node's participant can be discovered more
    # than SETTLE_MIN_S after the command starts (seen with Python 3.11, and with two test
    # suites side by side), past the settle of a daemon-less CLI (docs/tools.md): asked
    # again, as a user would, for up to a minute while it is missing.
    deadline = time.monotonic() + 60.0
    while True:
        (lst_all,) = run_all(graph, ('param', 'list'))
        assert lst_all[0] == 0, lst_all[2]
        every = lst_all[1].splitlines()
        if f'{n}:' in every or time.monotonic() > deadline:
            break
    assert f'{n}:' in every, lst_all
    assert every[every.index(f'{n}:') + 1:every.index(f'{n}:') + 4] == [
        '  count', '  flags', '  gain']
    assert get_nope[0] == 1 and error_lines(get_nope[2]) == [
        f"ros2 param: node '{n}' has no parameter 'nope'"]
    # One name not declared among several: that one is named, not all of them.
    assert desc_one_nope[0] == 1 and error_lines(desc_one_nope[2]) == [
        f"ros2 param: node '{n}' has no parameter 'nope'"]
    # A mistyped name is pointed at the node nearest it (a walk-through, 7 Dec 2026).
    assert get_no_node[0] == 1 and error_lines(get_no_node[2]) == [
        f"ros2 param: Node '{n}_absent' not found; did you mean '{n}'?"]
    # Accepted sets change the node's value; refused ones print the reason and exit 1.
    assert set_count[:2] == (0, 'Set parameter successful\n')
    assert set_int[:2] == (0, 'Set parameter successful\n')
    assert graph.node.get_parameter('limits.low').value == -2.0
    assert set_neg[0] == 1 and error_lines(set_neg[2]) == [
        'Setting parameter failed: count must be >= 0']
    assert graph.node.get_parameter('count').value == 7
    assert set_ro[0] == 1 and 'read-only' in set_ro[2]
    assert set_range[0] == 1 and error_lines(set_range[2])[0].startswith(
        'Setting parameter failed: ')
    assert graph.node.get_parameter('gain').value == 0.5
    assert graph.node.get_parameter('mode').value == 'fast'


def test_param_load_sets_what_a_parameters_file_gives_the_node(graph, param_node, tmp_path):
    n = param_node
    node = graph.node

    def load(sections, *options):
        path = tmp_path / f'{len(list(tmp_path.iterdir()))}.yaml'
        path.write_text(yaml.safe_dump(sections, sort_keys=False))
        (result,) = run_all(graph, ('param', 'load', n, str(path), *options))
        return result[0], result[1].splitlines(), error_lines(result[2]), str(path)

    # A '/**' section first, then the node's own (its 'count' in place of the shared one),
    # another node's section left out; 'mode' (read only) is already the node's value;
    # 'nope' is not declared: said on stderr, exit 1, the others set all the same.
    rc, out, err, _ = load({
        '/**': {'ros__parameters': {'gain': 0.25, 'count': 1}},
        n.lstrip('/'): {'ros__parameters': {'count': 4, 'limits': {'low': -3}, 'mode': 'fast',
                                            'nope': 1}},
        'another_node': {'ros__parameters': {'gain': 0.75}}})
    assert (rc, err) == (1, ['Set parameter nope failed: the node has no such parameter'])
    assert out == ['Set parameter gain successful', 'Set parameter count successful',
                   'Set parameter limits.low successful',
                   'Parameter mode left as it is: read only, and the node has this value']
    assert [node.get_parameter(p).value for p in ('gain', 'count', 'limits.low', 'mode')] == [
        0.25, 4, -3.0, 'fast']
    # --no-use-wildcard: only the section that names the node ('/**/name' names it).
    rc, out, err, _ = load({'/**': {'ros__parameters': {'gain': 0.5}},
                            f'/**{n}': {'ros__parameters': {'count': 2}}}, '--no-use-wildcard')
    assert (rc, out, err) == (0, ['Set parameter count successful'], [])
    assert (node.get_parameter('gain').value, node.get_parameter('count').value) == (0.25, 2)
    # What the node refuses is said with its reason, and changes nothing.
    rc, out, err, _ = load({n: {'ros__parameters': {'count': -1, 'mode': 'slow', 'gain': 2.0}}})
    assert rc == 1 and out == [] and len(err) == 3
    assert err[0] == 'Set parameter count failed: count must be >= 0'
    assert err[1].startswith('Set parameter mode failed: ') and 'read-only' in err[1]
    assert err[2].startswith('Set parameter gain failed: ')
    assert [node.get_parameter(p).value for p in ('count', 'mode', 'gain')] == [2, 'fast', 0.25]
    # A file with no section for the node, or none at all: one line, exit 1, nothing set.
    rc, out, err, path = load({'another_node': {'ros__parameters': {'gain': 0.75}}})
    assert (rc, out, err) == (1, [], [
        f"ros2 param: {path} has no section for the node '{n}' (its sections: /another_node)"])
    rc, out, err, path = load({'gain': 0.75})
    assert (rc, out) == (1, []) and err == [
        f'ros2 param: {path}: no section with ros__parameters (not a ROS 2 parameters file)']
    assert node.get_parameter('gain').value == 0.25
    # What dump prints, load sets again: the node's values after a change are back.
    (dump,) = run_all(graph, ('param', 'dump', n))
    node.set_parameters([rclpy.parameter.Parameter('gain', value=0.125),
                         rclpy.parameter.Parameter('flags', value=[False, False])])
    rc, out, err, _ = load(yaml.safe_load(dump[1]))
    assert (rc, err) == (0, []) and 'Set parameter gain successful' in out
    assert (node.get_parameter('gain').value, list(node.get_parameter('flags').value)) == (
        0.25, [True, False])


def test_verbs_on_the_running_prediction_node(graph, procs, topic):
    """The real prediction_node (name and topics remapped so that parallel runs do not meet):
    node info, topic type/info, param get/describe and an integer set on a double."""
    name = f'pred_{uuid.uuid4().hex[:8]}'
    state, prediction = f'{topic}/state', f'{topic}/prediction'
    node = procs('run', 'tt_prediction', 'prediction_node', '--ros-args',
                 '-r', f'__node:={name}', '-r', f'/ball/state:={state}',
                 '-r', f'/ball/prediction:={prediction}')
    graph.spin_until(
        lambda: (name in graph.node.get_node_names() and graph.node.count_publishers(prediction)
                 ) or node.proc.poll() is not None, 120, 'the prediction node in the graph')
    assert node.proc.poll() is None, node.stderr
    graph.node.create_subscription(BallPrediction, prediction, lambda m: None,
                                   QoSProfile(depth=1))
    info, ptype, tinfo, get, describe = run_all(
        graph,
        ('node', 'info', f'/{name}'),
        ('topic', 'type', prediction),
        ('topic', 'info', prediction),
        ('param', 'get', f'/{name}', 'stale_after_s'),
        ('param', 'describe', f'/{name}', 'stale_after_s'),
    )
    # After the get (run side by side, a set could land before it).
    (set_int,) = run_all(graph, ('param', 'set', f'/{name}', 'stale_after_s', '0'))
    lines = info[1].splitlines()
    assert info[0] == 0 and lines[0] == f'/{name}'
    sections = [line for line in lines if line.startswith('  ') and line.endswith(':')
                and not line.startswith('    ')]
    assert sections == ['  Subscribers:', '  Publishers:', '  Service Servers:',
                        '  Service Clients:', '  Action Servers:', '  Action Clients:']
    subscribers = lines[lines.index('  Subscribers:') + 1:lines.index('  Publishers:')]
    publishers = lines[lines.index('  Publishers:') + 1:lines.index('  Service Servers:')]
    assert f'    {state}: tt_msgs/msg/BallState' in subscribers
    assert f'    {prediction}: tt_msgs/msg/BallPrediction' in publishers
    assert f'    /{name}/get_parameters: rcl_interfaces/srv/GetParameters' in lines
    assert ptype == (0, 'tt_msgs/msg/BallPrediction\n', ptype[2])
    # Five new processes discovering the graph side by side on a loaded machine: a lost
    # discovery announcement is repaired only at a later DDS heartbeat (seconds), after the
    # verb may have settled. Asked again, as a user would, for up to a minute when an
    # endpoint is missing; the last try says how its discovery went (TT_SETTLE_DEBUG).
    expected = ['Type: tt_msgs/msg/BallPrediction', 'Publisher count: 1',
                'Subscription count: 1']
    tries, deadline = 1, time.monotonic() + 60.0
    while tinfo[1].splitlines() != expected and time.monotonic() < deadline:
        (tinfo,) = run_all(graph, ('topic', 'info', prediction),
                           env={'TT_SETTLE_DEBUG': '1'})
        tries += 1
    if not (tinfo[0] == 0 and tinfo[1].splitlines() == expected):
        # In full: an assertion's repr is cut by pytest, and this is what the next failure
        # must show (how the last try's discovery settled, whether the node still runs).
        pytest.fail(f'topic info after {tries} tries: exit {tinfo[0]}\n{tinfo[1]}'
                    f'its stderr:\n{tinfo[2]}\nprediction_node exit status: '
                    f'{node.proc.poll()}, its stderr ends:\n{node.stderr[-2000:]}',
                    pytrace=False)
    assert get == (0, 'Double value is: 0.5\n', get[2])  # the documented default
    assert describe[0] == 0 and '  Type: double' in describe[1].splitlines()
    assert set_int[:2] == (0, 'Set parameter successful\n'), set_int[2]
    node.signal(signal.SIGINT)
    assert node.wait(timeout=90) == 0 and 'Traceback' not in node.stderr


@pytest.mark.parametrize('text', ['99999999999999999999999', '-9223372036854775809',
                                  '[1, 99999999999999999999999]'])
def test_an_integer_beyond_64_bits_is_a_one_line_error_not_a_traceback(text):
    # rclpy takes it into the message and fails to serialise it (OverflowError, then a
    # SystemError from the C extension): refused when the value is read.
    with pytest.raises(ValueError, match='an integer outside the 64-bit range'):
        parse_value(text, ParameterType.PARAMETER_DOUBLE)
    assert parse_value(str(2 ** 63 - 1)).integer_value == 2 ** 63 - 1


def test_a_list_of_integers_and_doubles_mixed_is_a_double_array_where_one_is_declared():
    # '[0.5, 0]' is a string to rcl (YAML's list has no one type): a node's double array
    # refused it as 'not a list of 2 numbers' (a walk-through, 6 Dec 2026).
    value = parse_value('[0.5, 0]', ParameterType.PARAMETER_DOUBLE_ARRAY)
    assert value.type == ParameterType.PARAMETER_DOUBLE_ARRAY
    assert list(value.double_array_value) == [0.5, 0.0]
    assert parse_value('[0.5, 0]').type == ParameterType.PARAMETER_STRING    # as ros2cli
    from tt_tools.param import file_value
    assert list(file_value('p', [0.5, 0], ParameterType.PARAMETER_DOUBLE_ARRAY)
                .double_array_value) == [0.5, 0.0]
    for text in ('[0.5, true]', 'a, b'):
        assert parse_value(text, ParameterType.PARAMETER_DOUBLE_ARRAY).type == (
            ParameterType.PARAMETER_STRING)


def test_node_info_and_topic_type_of_an_absent_node_or_topic(topic):
    rc, out, err = ros2('node', 'info', '/tt_no_such_node_' + uuid.uuid4().hex[:6],
                        '--spin-time', '0.5')
    assert rc == 1 and out == '' and error_lines(err)[0].startswith(
        "ros2 node: Unable to find node '/tt_no_such_node_")
    rc, out, err = ros2('topic', 'type', topic, '--spin-time', '0.5')
    assert rc == 1 and error_lines(err) == [f"ros2 topic: Unknown topic '{topic}'"]


def _installed_msg(type_str):
    with open(interface_file(*type_str.split('/'))) as f:
        return f.read().splitlines()


def test_interface_show_prints_the_msg_file_with_nested_definitions():
    rc, out, err = ros2('interface', 'show', 'tt_msgs/msg/BallState')
    assert rc == 0, err
    lines = out.splitlines()
    top = [line for line in lines if not line.startswith('\t')]
    assert top == [line.rstrip() for line in _installed_msg('tt_msgs/msg/BallState')]
    header = lines.index(next(x for x in lines if x.startswith('std_msgs/Header header')))
    assert lines[header + 1:header + 5] == [
        '\tbuiltin_interfaces/Time stamp', '\t\tint32 sec', '\t\tuint32 nanosec',
        '\tstring frame_id']
    # Without comments: one line per field, in the order of the generated class.
    rc, out, _ = ros2('interface', 'show', 'tt_msgs/msg/BallState', '--no-comments')
    fields = [line.split()[1] for line in out.splitlines() if not line.startswith('\t')]
    assert fields == list(BallState.get_fields_and_field_types())
    assert '#' not in out


def test_interface_list_and_package_name_what_the_index_installs():
    # `ros2 interface list` (a ROS user's first look at a stack's messages) was not there.
    # Every listed type imports (its generated class exists); tt_msgs' are the .msg files
    # installed in its share folder.
    rc, out, err = ros2('interface', 'list')
    assert rc == 0, err
    lines = out.splitlines()
    assert [x for x in lines if not x.startswith('    ')] == ['Messages:', 'Services:',
                                                              'Actions:']
    msgs = lines[1:lines.index('Services:')]
    srvs = lines[lines.index('Services:') + 1:lines.index('Actions:')]
    assert '    tt_msgs/msg/BallState' in msgs and '    rcl_interfaces/srv/GetParameters' in srvs
    assert all(x.split('/')[1] == 'msg' for x in msgs)
    assert all(x.split('/')[1] == 'srv' for x in srvs)
    for name in ('    rcl_interfaces/msg/ParameterValue', '    tt_msgs/msg/StrikeCommand'):
        assert import_message_type(name.strip()).get_fields_and_field_types()
    rc, out, _ = ros2('interface', 'list', '-m')
    assert out.splitlines() == lines[:lines.index('Services:')]
    share = os.path.dirname(interface_file('tt_msgs', 'msg', 'BallState'))
    installed = sorted(f'tt_msgs/msg/{f[:-4]}' for f in os.listdir(share) if f.endswith('.msg'))
    rc, out, err = ros2('interface', 'package', 'tt_msgs')
    assert rc == 0 and out.splitlines() == installed, err
    rc, out, err = ros2('interface', 'package', 'no_such_pkg')
    assert rc == 1 and out == '' and error_lines(err) == [
        "ros2 interface: Unknown package 'no_such_pkg'"]


def test_interface_show_of_a_service_and_bad_names():
    rc, out, err = ros2('interface', 'show', 'rcl_interfaces/srv/GetParameters', '--no-comments')
    assert rc == 0, err
    top = [line for line in out.splitlines() if not line.startswith('\t')]
    assert top == ['string[] names', '---', 'ParameterValue[] values']
    value_fields = list(import_message_type('rcl_interfaces/msg/ParameterValue')
                        .get_fields_and_field_types())
    nested = [line.split()[1] for line in out.splitlines() if line.startswith('\t')]
    assert nested == value_fields
    rc, out, err = ros2('interface', 'show', 'tt_msgs/msg/NoSuch')
    assert rc == 1 and out == '' and len(error_lines(err)) == 1
    assert "Could not find the interface 'tt_msgs/msg/NoSuch'" in err
    rc, _, err = ros2('interface', 'show', 'BallState')
    assert rc == 1 and len(error_lines(err)) == 1 and 'invalid interface name' in err


def test_interface_proto_prints_a_default_message_to_fill_in():
    # A ROS user's way to a `topic pub` argument: every field of the .msg at its default
    # (float64 0.0, bool false), in quotes unless --no-quotes; a service's request.
    rc, out, err = ros2('interface', 'proto', 'geometry_msgs/msg/Point')
    assert (rc, out) == (0, '"x: 0.0\ny: 0.0\nz: 0.0\n"\n'), err
    rc, out, err = ros2('interface', 'proto', 'std_srvs/srv/SetBool', '--no-quotes')
    assert (rc, out) == (0, 'data: false\n'), err
    rc, out, err = ros2('interface', 'proto', 'tt_msgs/msg/BallState', '--no-quotes')
    assert rc == 0, err
    values = yaml.safe_load(out)
    assert list(values) == list(BallState.get_fields_and_field_types())
    assert values['covariance'] == [0.0] * 81              # float64[81], not cut at 128 chars
    assert values['header'] == {'stamp': {'sec': 0, 'nanosec': 0}, 'frame_id': ''}
    for bad, says in (('tt_msgs/msg/NoSuch', "unknown message type 'tt_msgs/msg/NoSuch'"),
                      ('std_srvs/srv/NoSuch', "unknown service type 'std_srvs/srv/NoSuch'"),
                      ('BallState', "bad message type 'BallState'")):
        rc, out, err = ros2('interface', 'proto', bad)
        assert rc == 1 and out == '' and len(error_lines(err)) == 1 and says in err, err


def test_topic_and_service_find_list_the_names_of_a_type(graph, topic):
    from std_msgs.msg import Char
    from std_srvs.srv import Empty

    qos = QoSProfile(depth=1)
    for name in (f'{topic}/grip', f'{topic}/_grip'):   # the second is hidden: '_' begins a part
        graph.node.create_publisher(Char, name, qos)
        graph.node.create_service(Empty, name + '_reset', lambda request, response: response)
    graph.node.create_publisher(BallState, f'{topic}/state', qos)
    found, short, hidden, count, states, srv, srv_hidden, srv_count, bad, lst = run_all(
        graph,
        ('topic', 'find', 'std_msgs/msg/Char'),
        ('topic', 'find', 'std_msgs/Char', '--no-daemon'),     # as ros2cli's scripts give it
        ('topic', 'find', 'std_msgs/msg/Char', '--include-hidden-topics'),
        ('topic', 'find', 'std_msgs/msg/Char', '-c', '--include-hidden-topics'),
        ('topic', 'find', 'tt_msgs/msg/BallState'),
        ('service', 'find', 'std_srvs/srv/Empty'),
        ('service', 'find', 'std_srvs/Empty', '--include-hidden-services'),
        ('service', 'find', 'std_srvs/srv/Empty', '-c'),
        ('topic', 'find', 'Char'),
        ('topic', 'list'))
    assert found == short == (0, f'{topic}/grip\n', ''), found
    assert hidden[:2] == (0, f'{topic}/_grip\n{topic}/grip\n') and count[:2] == (0, '2\n')
    assert states[:2] == (0, f'{topic}/state\n')
    assert srv[:2] == (0, f'{topic}/grip_reset\n') and srv_count[:2] == (0, '1\n')
    assert srv_hidden[:2] == (0, f'{topic}/_grip_reset\n{topic}/grip_reset\n')
    assert bad[:2] == (1, '') and error_lines(bad[2]) == [
        "ros2 topic: bad message type 'Char': expected 'package/msg/Type'"]
    # `topic list` leaves hidden topics out too, as ros2cli's does.
    assert lst[0] == 0 and f'{topic}/grip' in lst[1].split() and '_grip' not in lst[1]


def test_pkg_executables():
    rc, out, err = ros2('pkg', 'executables', 'tt_prediction')
    assert rc == 0, err
    # The console scripts tt_prediction's setup.py declares.
    assert {'tt_prediction prediction_node', 'tt_prediction tt-predict',
            'tt_prediction tt-identify'} <= set(out.splitlines())
    assert all(line.startswith('tt_prediction ') for line in out.splitlines())
    rc, out, _ = ros2('pkg', 'executables')
    assert rc == 0 and {'tt_tools ros2', 'tt_strike strike_node'} <= set(out.splitlines())
    rc, out, err = ros2('pkg', 'executables', 'no_such_pkg')
    assert rc == 1 and error_lines(err) == ["ros2 pkg: Package 'no_such_pkg' not found"]


def test_pkg_prefix_finds_the_shipped_configs():
    # The shipped configs' own comments name $(ros2 pkg prefix tt_tools)/share/...: the verb
    # was missing ('invalid choice').
    rc, out, err = ros2('pkg', 'prefix', 'tt_tools')
    assert rc == 0, err
    config = pathlib.Path(out.strip(), 'share', 'tt_tools', 'config')
    assert (config / 'robot.yaml').is_file() and (config / 'replay.yaml').is_file()
    rc, share, _ = ros2('pkg', 'prefix', '--share', 'tt_tools')
    assert rc == 0 and share.strip() == str(config.parent)
    rc, out, err = ros2('pkg', 'prefix', 'no_such_pkg')
    assert rc == 1 and error_lines(err) == ["ros2 pkg: Package 'no_such_pkg' not found"]


def test_service_list_type_and_call_against_a_service_the_test_serves(graph, topic):
    from std_srvs.srv import SetBool

    name = f'{topic}/enable'
    got = []

    def serve(request, response):
        got.append(request.data)
        response.success, response.message = True, f'set to {request.data}'
        return response

    graph.node.create_service(SetBool, name, serve)
    lst, typ, call, other_type, bad_field, typ_now = run_all(
        graph,
        ('service', 'list', '-t'),
        ('service', 'type', name),
        ('service', 'call', name, 'std_srvs/srv/SetBool', '{data: true}'),
        ('service', 'call', name, 'std_srvs/srv/Trigger'),
        ('service', 'call', name, 'std_srvs/srv/SetBool', '{dat: true}'),
        ('service', 'type', name))
    # The graph's types count clients too (a Trigger client of the name, here): list shows
    # them, as ros2cli does; type shows what the server serves.
    assert lst[0] == 0 and f'{name} [std_srvs/srv/SetBool]' in [
        line.replace(', std_srvs/srv/Trigger', '') for line in lst[1].splitlines()]
    assert typ[:2] == typ_now[:2] == (0, 'std_srvs/srv/SetBool\n')
    # ros2cli's output: the request and the response as Python prints them.
    assert call[:2] == (0, 'requester: making request: std_srvs.srv.SetBool_Request(data=True)'
                           '\n\nresponse:\nstd_srvs.srv.SetBool_Response(success=True, '
                           "message='set to True')\n\n"), call[2]
    assert got == [True]                 # sent once: a service need not be idempotent
    assert other_type[:2] == (1, '') and error_lines(other_type[2]) == [
        f'ros2 service: {name} is served as std_srvs/srv/SetBool, not std_srvs/srv/Trigger']
    assert bad_field[:2] == (1, '') and error_lines(bad_field[2]) == [
        "ros2 service: std_srvs/srv/SetBool_Request has no field 'dat'"]


def test_param_set_without_a_value_is_a_usage_error():
    # Exit 1 where every other usage error exits 2 (docs/tools.md; a walk-through).
    rc, out, err = ros2('param', 'set', '/nobody', 'stale_after_s')
    assert rc == 2 and out == '' and error_lines(err) == [
        'ros2 param: parameters must be given as name value pairs: got 1 argument(s)']


def test_service_call_timeout_bounds_the_wait_for_a_service_never_served(topic):
    # --timeout bounded the wait for the response only: a call to a service nobody serves
    # waited for ever (a walk-through, 7 Dec 2026).
    rc, out, err = ros2('service', 'call', f'{topic}/nobody', 'std_srvs/srv/SetBool',
                        '{data: true}', '--timeout', '2')
    assert rc == 1 and out == ''
    assert error_lines(err)[-1] == (f'ros2 service: no service {topic}/nobody within 2 s '
                                    '(--timeout): nothing sent'), err


@pytest.mark.parametrize('verb', ['action', 'launch'])
def test_a_ros2cli_verb_tt_does_not_have_is_named_so(verb):
    # argparse said "invalid choice" after `ros2 node info` had listed services (a ROS
    # user's walk-through).
    rc, out, err = ros2(verb, 'list')
    assert rc == 2 and out == ''
    said = error_lines(err)
    assert len(said) == 1 and said[0].startswith(
        f"ros2: '{verb}' is a verb of ros2cli that tt's ros2 command does not have")
    assert 'docs/tools.md' in said[0]
    # What starts the graph here, for a user who reached for a launch file.
    assert ('ros2 run tt_tools bringup' in said[0]) == (verb == 'launch')


def test_daemon_verbs_say_there_is_none_and_let_a_script_go_on():
    """Scripts written for ros2cli stop its daemon before a test; tt's ros2 has none."""
    for subverb, said in (('stop', 'The daemon is not running\n'),
                          ('status', 'The daemon is not running\n'),
                          ('start', "tt's ros2 has no daemon to start: each command discovers "
                                    'the graph itself\n')):
        assert ros2('daemon', subverb)[:2] == (0, said)


def test_a_domain_id_rcl_cannot_use_is_one_line_naming_it():
    """rcl's traceback for a ROS_DOMAIN_ID that is no number; Fast DDS ending the command
    with its own log lines for one without ports (233)."""
    for value, why in (('abc', "ROS_DOMAIN_ID 'abc' is not a domain id"),
                       ('233', 'ROS_DOMAIN_ID 233 is out of range')):
        rc, out, err = ros2('topic', 'list', env={'ROS_DOMAIN_ID': value})
        assert rc == 1 and out == '', err
        assert err.splitlines() == [err.strip()] and err.startswith(f'ros2 topic: {why}'), err


def test_echo_and_hz_say_what_they_wait_for(graph, procs, topic):
    """Issue 17: `echo` on a misspelled topic waited forever without a word."""
    pub = graph.node.create_publisher(BallState, topic, QoSProfile(depth=10))
    misspelled = topic + 'x'
    echo = procs('topic', 'echo', misspelled)
    hz = procs('topic', 'hz', misspelled)
    graph.spin_until(lambda: 'waiting' in echo.stderr and 'waiting' in hz.stderr, 90,
                     'the waiting lines')
    for proc in (echo, hz):
        said = error_lines(proc.stderr)
        assert len(said) == 1 and said[0].startswith(
            f'waiting for a publisher on {misspelled} (none yet; known topics: ')
        # The suggestion needs discovery to have found the test's own publisher by then,
        # which a loaded machine may not have done: when there is one, it is the right topic.
        assert 'did you mean' not in said[0] or said[0].endswith(f"did you mean '{topic}'?")
        assert proc.proc.poll() is None  # still waiting
        proc.signal(signal.SIGINT)
        assert proc.wait() == 0 and proc.stdout == ''
    assert pub.get_subscription_count() == 0


def test_pub_once_says_it_waits_for_a_subscription_then_publishes(graph, procs, topic):
    pub = procs('topic', 'pub', topic, 'tt_msgs/msg/BallState', '{track_id: 4}', '--once')
    graph.spin_until(lambda: 'waiting' in pub.stderr, 90, 'the waiting line')
    assert error_lines(pub.stderr) == [
        f'waiting for 1 matching subscription(s) on {topic} (0 now), until there is one; '
        '-w 0 publishes without waiting']
    got = []
    graph.node.create_subscription(BallState, topic, got.append, QoSProfile(depth=10))
    graph.spin_until(lambda: got, 60, 'the message published after the wait')
    assert got[0].track_id == 4
    assert pub.wait() == 0


def test_pub_once_with_a_bounded_wait_and_no_subscription_fails(topic):
    rc, out, err = ros2('topic', 'pub', topic, 'tt_msgs/msg/BallState', '{}', '--once',
                        '--max-wait-time-secs', '0.5')
    assert rc == 1 and out == ''
    assert error_lines(err)[-1] == (
        f'ros2 topic: no 1 matching subscription(s) on {topic} after 0.5 s: nothing published')


def test_echo_into_a_closed_pipe_exits_0(procs, topic):
    """Issue 17: `ros2 topic echo /ball/state | head -2` exited 120 with a BrokenPipeError."""
    procs('topic', 'pub', topic, 'tt_msgs/msg/BallState', '{}', '-r', '50')
    echo = subprocess.Popen([*ROS2, 'topic', 'echo', topic], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                            env=ros_env({'TT_ROS2_NO_HANDOVER': '1'}), start_new_session=True)
    head = []

    def read_two_lines_and_close():  # what `head -2` does
        head.extend([echo.stdout.readline(), echo.stdout.readline()])
        echo.stdout.close()

    reader = threading.Thread(target=read_two_lines_and_close, daemon=True)
    reader.start()
    try:
        rc = echo.wait(timeout=120)
    finally:
        if echo.poll() is None:
            os.killpg(echo.pid, signal.SIGKILL)
    stderr = echo.stderr.read().decode()
    assert head == [b'header:\n', b'  stamp:\n']
    assert rc == 0, stderr
    assert 'Traceback' not in stderr and 'BrokenPipe' not in stderr


@pytest.fixture
def burners():
    """Two busy processes (this machine has 2 cores) for the duration of a test (the 'under
    load' of issue 17)."""
    started = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
               for _ in range(min(os.cpu_count() or 2, 2))]
    yield
    for p in started:
        p.kill()
        p.wait()


def test_list_and_info_see_every_live_entity_under_load(graph, topic, burners):
    """Issue 17: `node list` and `topic info` missed live entities in 2 of 6 and 3 of 4 runs.
    Three participants (one publisher, two subscriptions), then three `node list` and three
    `topic info` at once on a machine kept busy: each must see all of them."""
    others = [Graph() for _ in range(2)]
    try:
        graph.node.create_publisher(BallState, topic, QoSProfile(depth=1))
        for g in others:
            g.node.create_subscription(BallState, topic, lambda m: None, QoSProfile(depth=1))
        names = {graph.node.get_name(), *(g.node.get_name() for g in others)}
        graph.spin_until(lambda: names <= set(graph.node.get_node_names())
                         and graph.node.count_subscribers(topic) == 2, 60, 'the three nodes')
        results = run_all(graph, *[('node', 'list')] * 3, *[('topic', 'info', topic)] * 3)
    finally:
        for g in others:
            g.close()
    for rc, out, err in results[:3]:
        assert rc == 0, err
        assert {'/' + n for n in names} <= set(out.splitlines())
    for rc, out, err in results[3:]:
        assert rc == 0, err
        assert out.splitlines() == ['Type: tt_msgs/msg/BallState', 'Publisher count: 1',
                                    'Subscription count: 2']


def test_pkg_xml_prints_the_installed_manifest_and_a_tags_values():
    # colcon installs the source's package.xml as it is; -t prints each element's text.
    source = pathlib.Path(__file__).parents[3] / 'src' / 'tt_prediction' / 'package.xml'
    text = source.read_text()
    rc, out, err = ros2('pkg', 'xml', 'tt_prediction')
    assert (rc, out) == (0, text), err
    rc, out, err = ros2('pkg', 'xml', 'tt_prediction', '-t', 'exec_depend')
    assert rc == 0 and out.splitlines() == re.findall(r'<exec_depend>\s*([^<\s]+)\s*<', text)
    rc, out, _ = ros2('pkg', 'xml', 'tt_prediction', '--tag', 'export/build_type')
    assert (rc, out) == (0, 'ament_python\n')
    for argv, said in [
            (['no_such_pkg'], "Package 'no_such_pkg' not found"),
            (['tt_prediction', '-t', 'maintainers'], "no tag 'maintainers'"),
            (['tt_prediction', '-t', 'a['], "--tag 'a[' is not an element path")]:
        rc, out, err = ros2('pkg', 'xml', *argv)
        assert (rc, out) == (1, '') and len(error_lines(err)) == 1 and said in err, err
