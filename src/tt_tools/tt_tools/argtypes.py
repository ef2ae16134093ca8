"""argparse types of the ros2 verbs' numeric options: a value outside what the option means
(a rate of 0, a negative timeout) is a usage error naming it (exit 2), not a command that
hangs, prints nothing or takes it silently."""

import argparse
import math


def _number(kind, lowest, inclusive):
    what = ('an integer' if kind is int else 'a number') + (
        f' >= {lowest:g}' if inclusive else f' > {lowest:g}')

    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value) or value < lowest or (value == lowest and not inclusive):
            raise argparse.ArgumentTypeError(f'{text} is not {what}')
        return value
    parse.__name__ = what
    return parse


positive_float = _number(float, 0.0, inclusive=False)
"""A finite number > 0 (a rate, a timeout)."""
non_negative_float = _number(float, 0.0, inclusive=True)
"""A finite number >= 0 (a delay, an offset)."""
positive_int = _number(int, 1, inclusive=True)
"""An integer >= 1 (a window, a count)."""
non_negative_int = _number(int, 0, inclusive=True)
"""An integer >= 0 (a count where 0 means no limit)."""


class UsageError(ValueError):
    """A command line argparse cannot check (``param set``'s name value pairs): one line,
    exit 2, as argparse's own usage errors."""
