"""Message rate statistics for ``ros2 topic hz`` (pure, no rclpy)."""

import numpy as np


def rate_stats(arrival_times):
    """Statistics of the intervals between message arrivals, as ``ros2 topic hz`` prints them.

    ``arrival_times``: increasing arrival times, s (any clock). Returns None with fewer than two
    arrivals, else a dict: ``rate`` (1 / mean interval, Hz), ``min``, ``max``, ``std_dev``
    (population standard deviation of the intervals, s) and ``window`` (number of arrivals).
    """
    t = np.asarray(arrival_times, dtype=float)
    if t.size < 2:
        return None
    dt = np.diff(t)
    mean = float(dt.mean())
    return {
        'rate': 1.0 / mean if mean > 0 else float('inf'),
        'min': float(dt.min()),
        'max': float(dt.max()),
        'std_dev': float(dt.std()),
        'window': int(t.size),
    }


def format_stats(stats):
    """The two lines ``ros2 topic hz`` prints for ``rate_stats`` output."""
    return ('average rate: {rate:.3f}\n\tmin: {min:.3f}s max: {max:.3f}s std dev: {std_dev:.5f}s '
            'window: {window}'.format(**stats))
