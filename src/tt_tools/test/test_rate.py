"""ros2 topic hz statistics from arrival times."""

import pytest
from tt_tools.rate import format_stats, rate_stats


def test_steady_rate():
    stats = rate_stats([0.1 * i for i in range(11)])
    assert stats['rate'] == pytest.approx(10.0)
    assert stats['std_dev'] == pytest.approx(0.0, abs=1e-12)
    assert stats['window'] == 11


def test_alternating_intervals():
    # Intervals 0.1, 0.3, 0.1, 0.3: mean 0.2 s -> 5 Hz, population std dev 0.1 s.
    stats = rate_stats([0.0, 0.1, 0.4, 0.5, 0.8])
    assert stats['rate'] == pytest.approx(5.0)
    assert (stats['min'], stats['max']) == (pytest.approx(0.1), pytest.approx(0.3))
    assert stats['std_dev'] == pytest.approx(0.1)
    assert format_stats(stats) == ('average rate: 5.000\n\tmin: 0.100s max: 0.300s '
                                   'std dev: 0.10000s window: 5')


def test_too_few_arrivals():
    assert rate_stats([]) is None and rate_stats([1.0]) is None
