"""Rate limits (pure: no rclpy): :func:`due`, by the messages' own stamps, so that a replayed
recording is thinned as the live one was, whatever the replay rate; :class:`ThrottledLog`, log
lines at most once a period per kind, decided before the logger is called."""

import time


def due(now_ns, last_ns, rate_hz):
    """Whether work limited to ``rate_hz`` (0: no limit) may run at stamp ``now_ns``, last run
    at ``last_ns`` (None: never); a stamp going back (a replayed bag restarting) counts as due.

    Parameters
    ----------
    now_ns, last_ns : int or None
        Stamps of this message and of the last one worked on, ns.
    rate_hz : float
        Highest rate, Hz; 0 or less: no limit.
    """
    return (rate_hz <= 0.0 or last_ns is None or now_ns < last_ns
            or now_ns - last_ns >= 1e9 / rate_hz)


class ThrottledLog:
    """A log function (e.g. a node logger's ``warning``) called at most once every ``period``
    s per ``key``, the first call of a key always: ``log(key, period, text)`` returns whether
    the line went out.

    rclpy's own ``throttle_duration_sec`` decides after its logger has looked up the caller's
    file and line (``inspect``, ``os.path.realpath``), about 1 ms a call on a 2-core machine
    whether the line goes out or not: a warning on 18 % of a 500 Hz stream's states took
    prediction_node's callback p99 from 0.38 to 1.6 ms (docs/prediction.md). Here a
    suppressed line costs a dict lookup.
    ``clock``: seconds, monotonic (default :func:`time.monotonic`; the wall clock, not a
    simulated one, paces what a person reads)."""

    def __init__(self, log, clock=time.monotonic):
        self._log = log
        self._clock = clock
        self._last = {}

    def __call__(self, key, period, text):
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < period:
            return False
        self._last[key] = now
        self._log(text)
        return True
