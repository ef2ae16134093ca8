"""Message statistics for ``ros2 topic hz``, ``delay`` and ``bw`` (pure, no rclpy)."""

import numpy as np


def _spread(values):
    """mean, min, max and population standard deviation of ``values`` (a non-empty array)."""
    return (float(values.mean()), float(values.min()), float(values.max()),
            float(values.std()))


def rate_stats(arrival_times):
    """Statistics of the intervals between message arrivals, as ``ros2 topic hz`` prints them.

    ``arrival_times``: increasing arrival times, s (any clock). Returns None with fewer than two
    arrivals, else a dict: ``rate`` (1 / mean interval, Hz), ``min``, ``max``, ``std_dev``
    (population standard deviation of the intervals, s) and ``window`` (number of arrivals).
    """
    t = np.asarray(arrival_times, dtype=float)
    if t.size < 2:
        return None
    mean, shortest, longest, std_dev = _spread(np.diff(t))
    return {
        'rate': 1.0 / mean if mean > 0 else float('inf'),
        'min': shortest,
        'max': longest,
        'std_dev': std_dev,
        'window': int(t.size),
    }


def format_stats(stats):
    """The two lines ``ros2 topic hz`` prints for ``rate_stats`` output."""
    return ('average rate: {rate:.3f}\n\tmin: {min:.3f}s max: {max:.3f}s std dev: {std_dev:.5f}s '
            'window: {window}'.format(**stats))


def delay_stats(delays):
    """Statistics of the delays of messages, as ``ros2 topic delay`` prints them: each one's
    arrival time minus its header's stamp, s. None without any, else a dict: ``delay`` (their
    mean), ``min``, ``max``, ``std_dev`` (population standard deviation, s) and ``window``
    (number of messages)."""
    d = np.asarray(delays, dtype=float)
    if d.size == 0:
        return None
    mean, shortest, longest, std_dev = _spread(d)
    return {'delay': mean, 'min': shortest, 'max': longest, 'std_dev': std_dev,
            'window': int(d.size)}


def format_delay(stats):
    """The two lines ``ros2 topic delay`` prints for ``delay_stats`` output."""
    return ('average delay: {delay:.3f}\n\tmin: {min:.3f}s max: {max:.3f}s '
            'std dev: {std_dev:.5f}s window: {window}'.format(**stats))


def bandwidth_stats(arrivals, now):
    """Bandwidth of a topic, as ``ros2 topic bw`` prints it. ``arrivals``: (arrival time, s;
    serialized size, bytes) of the messages in the window, in time order; ``now``: the time
    of the report (same clock). None without any message or time, else a dict: ``rate``
    (the window's bytes over the time from its first arrival to ``now``, B/s), ``mean``,
    ``min`` and ``max`` (message sizes, B) and ``window`` (number of messages)."""
    if not len(arrivals):
        return None
    a = np.asarray(arrivals, dtype=float).reshape(-1, 2)
    span = now - a[0, 0]
    if not span > 0:
        return None
    sizes = a[:, 1]
    return {'rate': float(sizes.sum()) / span, 'mean': float(sizes.mean()),
            'min': float(sizes.min()), 'max': float(sizes.max()), 'window': int(sizes.size)}


def _bytes(n):
    """``n`` bytes with a decimal unit: '512 B', '1.23 KB', '4.56 MB'."""
    for unit, size in (('GB', 1e9), ('MB', 1e6), ('KB', 1e3)):
        if n >= size:
            return f'{n / size:.2f} {unit}'
    return f'{n:.0f} B'


def format_bandwidth(stats):
    """The two lines ``ros2 topic bw`` prints for ``bandwidth_stats`` output."""
    return (f'{_bytes(stats["rate"])}/s from {stats["window"]} messages\n\tMessage size mean: '
            f'{_bytes(stats["mean"])} min: {_bytes(stats["min"])} max: {_bytes(stats["max"])}')
