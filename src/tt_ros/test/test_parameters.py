"""Validation of node parameters (pure part of tt_ros.parameters): kinds, ranges, messages."""

import array

import pytest
from tt_ros.parameters import Param, ParameterError, coerce

STALE = Param('stale_after_s', 0.5, 'drop old states', 's', 0.0, 60.0)
ZONE = Param('target_zone', 5, 'target zone', lo=0, hi=9)
POINT = Param('target_point', [0.7, 0.0], 'target point', 'm', length=2)
COLOUR = Param('ball_colour', 'any', 'colour', choices=('white', 'orange', 'any'))
FLAG = Param('uncertainty', True, 'propagate')


def test_kinds_come_from_the_defaults():
    assert [p.kind for p in (STALE, ZONE, POINT, COLOUR, FLAG)] == [
        'float', 'int', 'floats', 'str', 'bool']


@pytest.mark.parametrize('spec, value, expected', [
    (STALE, 0, 0.0),              # -p stale_after_s:=0 arrives as an integer
    (STALE, 60, 60.0),            # the range is inclusive
    (ZONE, 9, 9),
    (ZONE, 3.0, 3),               # an integral float for an integer
    (POINT, [1, 0], [1.0, 0.0]),
    (POINT, array.array('d', [0.5, -0.2]), [0.5, -0.2]),
    (COLOUR, 'white', 'white'),
    (FLAG, False, False),
])
def test_accepted_values_take_the_parameters_kind(spec, value, expected):
    out = coerce(spec, value)
    assert out == expected and type(out) is type(expected)


@pytest.mark.parametrize('spec, value, line', [
    (STALE, -0.1, 'stale_after_s: -0.1 is not a number in [0, 60] s'),
    (STALE, 'abc', "stale_after_s: 'abc' is not a number in [0, 60] s"),
    (STALE, True, 'stale_after_s: true is not a number in [0, 60] s'),
    (STALE, float('nan'), 'stale_after_s: nan is not a number in [0, 60] s'),
    (ZONE, 12, 'target_zone: 12 is not an integer in [0, 9]'),
    (ZONE, 2.5, 'target_zone: 2.5 is not an integer in [0, 9]'),
    (POINT, [1.0], 'target_point: [1.0] is not a list of 2 numbers (m)'),
    (COLOUR, 'red', "ball_colour: 'red' is not one of white, orange, any"),
    (FLAG, 1, 'uncertainty: 1 is not true or false'),
])
def test_refused_values_give_one_line_naming_the_parameter_and_its_range(spec, value, line):
    with pytest.raises(ParameterError) as err:
        coerce(spec, value)
    assert str(err.value) == line


def test_the_descriptor_carries_the_range_and_the_words():
    d = STALE.descriptor()
    assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == (
        0.0, 60.0)
    assert d.description == 'drop old states (a number in [0, 60] s)'
    z = ZONE.descriptor()
    assert (z.integer_range[0].from_value, z.integer_range[0].to_value) == (0, 9)
    assert not z.floating_point_range


def test_time_base():
    from tt_ros.timebase import TIME_BASE_MISMATCH_S, same_time_base

    now = 1_795_000_000.0                      # the wall clock, 2026
    assert same_time_base(now - 0.3, now)
    assert same_time_base(now - TIME_BASE_MISMATCH_S, now)
    assert not same_time_base(1_700_000_000.0, now)     # a 2023 recording against today
    assert not same_time_base(0.4, now)                 # video time against the wall clock
    assert not same_time_base(0.4, 0.0)                 # use_sim_time before any /clock
