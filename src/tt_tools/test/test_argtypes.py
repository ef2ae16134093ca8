"""The ros2 verbs' numeric options refuse values outside what they mean, naming them."""

import argparse

import pytest
from tt_tools.argtypes import non_negative_float, non_negative_int, positive_float, positive_int


@pytest.mark.parametrize('parse, text, value', [
    (positive_float, '0.5', 0.5), (non_negative_float, '0', 0.0), (positive_int, '1', 1),
    (non_negative_int, '0', 0),
])
def test_values_within_the_meaning_are_taken(parse, text, value):
    out = parse(text)
    assert out == value and type(out) is type(value)


@pytest.mark.parametrize('parse, text, words', [
    (positive_float, '0', '0 is not a number > 0'),          # a rate of 0 never publishes
    (positive_float, '-1', '-1 is not a number > 0'),        # a negative timeout
    (positive_float, 'nan', 'nan is not a number > 0'),
    (positive_float, 'inf', 'inf is not a number > 0'),
    (non_negative_float, '-0.5', '-0.5 is not a number >= 0'),
    (positive_int, '0', '0 is not an integer >= 1'),          # a window of no message
    (non_negative_int, '-1', '-1 is not an integer >= 0'),
    (non_negative_int, '1.5', '1.5 is not an integer >= 0'),
    (positive_float, 'fast', 'fast is not a number > 0'),
])
def test_values_outside_are_refused_naming_them(parse, text, words):
    with pytest.raises(argparse.ArgumentTypeError) as err:
        parse(text)
    assert str(err.value) == words
