"""Message <-> dict conversion, type strings and echo's YAML (no ROS graph needed)."""

import math

from geometry_msgs.msg import Pose, PoseArray
import pytest
from sensor_msgs.msg import CameraInfo, Image
from tt_tools.introspect import (
    dict_to_message,
    get_field,
    import_message_type,
    message_to_csv,
    message_to_dict,
    message_to_yaml,
    parse_yaml_values,
    type_string,
)
import yaml

from tt_msgs.msg import BallPrediction, BallState


def _ball_state_values():
    return {
        'header': {'stamp': {'sec': 1700000000, 'nanosec': 250_000_000}, 'frame_id': 'table'},
        'position': {'x': -1.2, 'y': 0.3, 'z': 0.25},
        'velocity': {'x': 4.5, 'y': -0.2, 'z': 1.0},
        'spin': {'x': 0.0, 'y': -150.0, 'z': 30.0},
        'covariance': [0.001 * (i + 1) for i in range(81)],
        'track_id': 42,
    }


def test_ball_state_round_trip_keeps_every_value_in_field_order():
    values = _ball_state_values()
    msg = dict_to_message(values, BallState)
    # The message holds what was given, read through its own attributes.
    assert msg.header.stamp.sec == 1700000000 and msg.header.stamp.nanosec == 250_000_000
    assert msg.spin.y == -150.0 and msg.track_id == 42
    assert msg.covariance[80] == pytest.approx(0.081)
    back = message_to_dict(msg)
    assert list(back) == list(BallState.get_fields_and_field_types())
    assert back == values


def test_csv_is_every_value_in_the_order_of_the_msg_file():
    # BallState.msg: header (stamp sec, nanosec; frame_id), position, velocity, spin (x, y, z
    # each), covariance[81], track_id: 3 + 9 + 81 + 1 = 94 values, written out here by hand.
    msg = dict_to_message(_ball_state_values(), BallState)
    head = ['1700000000', '250000000', 'table', '-1.2', '0.3', '0.25', '4.5', '-0.2', '1.0',
            '0.0', '-150.0', '30.0']
    covariance = [repr(0.001 * (i + 1)) for i in range(81)]
    assert message_to_csv(msg).split(',') == head + covariance + ['42']
    # --no-arr, --no-str (rosidl_runtime_py's words): one value naming each array, string.
    assert message_to_csv(msg, no_arr=True).split(',') == head + ['<array type: double[81]>',
                                                                  '42']
    assert message_to_csv(msg, no_arr=True, no_str=True).split(',') == (
        head[:2] + ['<string length: <5>>'] + head[3:] + ['<array type: double[81]>', '42'])
    assert message_to_csv(msg, field='spin') == '0.0,-150.0,30.0'
    assert message_to_csv(msg, field='position.z') == '0.25'


def test_prediction_round_trip_with_fixed_arrays_and_signed_fields():
    values = {'status': 'ok', 'bounce_half': -1, 'bounce_zone': 5,
              'bounce_time': {'sec': 3, 'nanosec': 7}, 'hit_valid': True,
              'zone_probabilities': [0.0, 0.1, 0.0, 0.0, 0.6, 0.3, 0.0, 0.0, 0.0, 0.0]}
    back = message_to_dict(dict_to_message(values, BallPrediction))
    for key, value in values.items():
        assert back[key] == value
    assert math.isclose(sum(back['zone_probabilities']), 1.0)
    assert back['hit_covariance'] == [0.0] * 9  # not given: default


def test_sensor_msgs_sequences_and_byte_data_round_trip():
    info = {'width': 640, 'height': 480, 'distortion_model': 'plumb_bob',
            'd': [0.1, -0.2, 0.0, 0.0, 0.01], 'k': [800.0, 0, 320, 0, 800, 240, 0, 0, 1]}
    msg = dict_to_message(info, CameraInfo)
    assert list(msg.d) == info['d'] and msg.k[2] == 320.0
    back = message_to_dict(msg)
    assert back['d'] == info['d'] and back['k'] == [float(v) for v in info['k']]
    pixels = list(range(0, 250, 10))
    image = dict_to_message({'encoding': 'mono8', 'width': 5, 'height': 5, 'step': 5,
                             'data': pixels}, Image)
    assert bytes(image.data) == bytes(pixels)
    assert message_to_dict(image)['data'] == pixels


def test_sequence_of_nested_messages():
    values = {'poses': [{'position': {'x': float(i)}} for i in range(3)]}
    msg = dict_to_message(values, PoseArray)
    assert [p.position.x for p in msg.poses] == [0.0, 1.0, 2.0]
    assert [p['position']['x'] for p in message_to_dict(msg)['poses']] == [0.0, 1.0, 2.0]


def test_yaml_is_what_echo_prints_and_parses_back():
    values = _ball_state_values()
    text = message_to_yaml(dict_to_message(values, BallState), truncate_length=None)
    assert text.startswith('header:\n  stamp:\n    sec: 1700000000\n')
    assert '\nposition:\n  x: -1.2\n' in text
    assert yaml.safe_load(text) == values


def test_echo_truncates_long_arrays_and_selects_fields():
    msg = dict_to_message(_ball_state_values(), BallState)
    cut = yaml.safe_load(message_to_yaml(msg, truncate_length=4))
    assert cut['covariance'] == [0.001, 0.002, 0.003, 0.004, '...']
    assert yaml.safe_load(message_to_yaml(msg, field='spin.y')) == -150.0
    assert yaml.safe_load(message_to_yaml(msg, field='header.frame_id')) == 'table'
    assert yaml.safe_load(message_to_yaml(msg, truncate_length=2, field='covariance')) == [
        0.001, 0.002, '...']
    assert yaml.safe_load(message_to_yaml(msg, field='position')) == {'x': -1.2, 'y': 0.3,
                                                                      'z': 0.25}
    with pytest.raises(KeyError, match='spin.q'):
        get_field(msg, 'spin.q')


def test_time_field_now_uses_the_given_clock():
    from builtin_interfaces.msg import Time

    msg = dict_to_message({'header': {'stamp': 'now'}}, BallState,
                          now=lambda: Time(sec=12, nanosec=34))
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 34)


def test_type_strings():
    assert import_message_type('tt_msgs/msg/BallState') is BallState
    assert import_message_type('sensor_msgs/Image') is Image
    assert type_string(BallState()) == 'tt_msgs/msg/BallState'
    for bad, words in (('nope_msgs/msg/X', 'unknown message package'),
                       ('tt_msgs/msg/Nope', 'unknown message type'),
                       ('BallState', 'expected')):
        with pytest.raises(ValueError, match=words):
            import_message_type(bad)


@pytest.mark.parametrize('values, words', [
    ({'track_id': 1.5}, "'track_id'"),
    ({'track_id': -1}, "'track_id'"),
    ({'position': {'w': 1.0}}, "'position.w'"),
    ({'covariance': [0.0] * 3}, 'expected 81 values'),
    ({'header': {'frame_id': 3}}, "'header.frame_id'"),
    ({'position': 2.0}, 'expected a mapping'),
    ({'position': {'x': '1.5'}}, "'position.x'"),
    ({'position': {'x': 'e5'}}, "'position.x'"),
    ({'track_id': '1e3'}, "'track_id'"),
])
def test_bad_values_name_the_field(values, words):
    with pytest.raises(ValueError, match=words):
        dict_to_message(values, BallState)


def test_exponent_notation_without_a_dot_is_a_float():
    # PyYAML (YAML 1.1) reads 1e-6 as a string; the user means the number.
    values = parse_yaml_values('{position: {x: 1e-6, y: -2E+1, z: .5e1}, covariance: [' +
                               ', '.join(['1e-4'] * 81) + ']}')
    msg = dict_to_message(values, BallState)
    assert (msg.position.x, msg.position.y, msg.position.z) == (1e-6, -20.0, 5.0)
    assert list(msg.covariance) == [1e-4] * 81


def test_command_line_yaml():
    assert parse_yaml_values('{position: {x: 1.0}, track_id: 2}') == {
        'position': {'x': 1.0}, 'track_id': 2}
    assert parse_yaml_values('') == {}
    with pytest.raises(ValueError, match='invalid YAML'):
        parse_yaml_values('{x: [1, 2')
    with pytest.raises(ValueError, match='mapping'):
        parse_yaml_values('[1, 2]')


def test_no_arr_and_no_str_name_each_array_and_string_and_flow_style_is_one_line():
    # ros2 topic echo --no-arr --no-str: BallState's covariance is float64[81] (a fixed array),
    # geometry_msgs/PoseArray's poses an unbounded sequence of Pose, a frame_id a string.
    msg = dict_to_message(_ball_state_values(), BallState)
    plain = yaml.safe_load(message_to_yaml(msg, no_arr=True, no_str=True))
    assert plain['covariance'] == '<array type: double[81]>'
    assert plain['header']['frame_id'] == '<string length: <5>>'
    assert plain['spin'] == _ball_state_values()['spin']
    poses = PoseArray()
    poses.poses = [Pose(), Pose(), Pose()]
    assert yaml.safe_load(message_to_yaml(poses, no_arr=True))['poses'] == \
        '<sequence type: geometry_msgs/msg/Pose, length: 3>'
    flow = message_to_yaml(msg, truncate_length=None, flow_style=True)
    assert flow.count('\n') == 1 and flow.startswith('{header: {stamp: {sec: 1700000000')
    assert yaml.safe_load(flow) == _ball_state_values()
