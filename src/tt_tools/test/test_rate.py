"""ros2 topic hz, delay and bw statistics from arrival times, stamps and sizes."""

import pytest
from tt_tools.rate import (
    bandwidth_stats,
    delay_stats,
    format_bandwidth,
    format_delay,
    format_stats,
    rate_stats,
)


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


def test_delay_statistics_of_known_delays():
    # Delays 0.010, 0.030, 0.020 s: mean 0.020, population std dev sqrt(2/3) * 0.010.
    stats = delay_stats([0.010, 0.030, 0.020])
    assert stats['delay'] == pytest.approx(0.020)
    assert (stats['min'], stats['max']) == (pytest.approx(0.010), pytest.approx(0.030))
    assert stats['std_dev'] == pytest.approx(0.010 * (2.0 / 3.0) ** 0.5)
    assert format_delay(stats) == ('average delay: 0.020\n\tmin: 0.010s max: 0.030s '
                                   'std dev: 0.00816s window: 3')
    assert delay_stats([]) is None


def test_bandwidth_of_known_arrivals():
    # 1000 + 3000 + 2000 bytes arriving from t = 10 s, reported at t = 12 s: 3000 B/s.
    arrivals = [(10.0, 1000), (10.5, 3000), (11.0, 2000)]
    stats = bandwidth_stats(arrivals, 12.0)
    assert stats['rate'] == pytest.approx(3000.0)
    assert (stats['mean'], stats['min'], stats['max'], stats['window']) == (2000, 1000, 3000, 3)
    assert format_bandwidth(stats) == ('3.00 KB/s from 3 messages\n'
                                       '\tMessage size mean: 2.00 KB min: 1.00 KB max: 3.00 KB')
    assert format_bandwidth(bandwidth_stats([(0.0, 744)], 2.0)) == (
        '372 B/s from 1 messages\n\tMessage size mean: 744 B min: 744 B max: 744 B')
    assert bandwidth_stats([], 1.0) is None and bandwidth_stats([(1.0, 8)], 1.0) is None
