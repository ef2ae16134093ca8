"""The time a node's callback takes over its latest calls, for the one line of counts and
times that a node logs at exit (prediction_node, strike_node)."""

import time

import numpy as np


class CallbackTimes:
    """The durations of a callback's latest ``size`` calls (a ring buffer), s."""

    def __init__(self, size=4096):
        self._s = np.zeros(size)
        self.count = 0
        """Calls timed so far."""

    def call(self, callback, *args):
        """``callback(*args)``, its duration recorded when it returns."""
        start = time.perf_counter()
        result = callback(*args)
        self._s[self.count % len(self._s)] = time.perf_counter() - start
        self.count += 1
        return result

    def latest_ms(self):
        """The durations of the latest calls (at most ``size``, in no particular order), ms."""
        return self._s[:min(self.count, len(self._s))] * 1e3

    def percentiles_ms(self, qs=(50, 99)):
        """The ``qs`` percentiles of the latest calls' durations, ms (NaN before the first)."""
        times = self.latest_ms()
        if not len(times):
            return [float('nan')] * len(qs)
        return [float(v) for v in np.percentile(times, qs)]
