"""Work whose result can come later, run off the callback (pure: no rclpy)."""

import collections
import threading


class LatestWorker:
    """Runs ``work(request)`` in a thread of its own for the latest request submitted, so
    that a subscription's callback never waits for work whose result can come later
    (prediction_node's covariance propagation and path message, strike_node's in-zone
    probability). A request submitted while the thread is busy replaces the one of the same
    key still waiting, if any: only the newest is worth the time. Those of other keys (two
    balls' tracks) wait their turn, the oldest first. ``on_error(exc)``, if given, is told of
    an exception the work raised, and the thread goes on with the next request (without it
    the thread ends there, and no later request is worked on)."""

    def __init__(self, name, work, on_error=None):
        self._work = work
        self._on_error = on_error
        self._requests = collections.OrderedDict()     # key -> its latest request
        self._stop = False
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, request, key=None):
        """Queues ``request`` in place of the one of ``key`` still waiting, if any."""
        with self._lock:
            self._requests.pop(key, None)
            self._requests[key] = request
        self._wake.set()

    def _run(self):
        while True:
            self._wake.wait()
            if self._stop:
                return
            with self._lock:
                if not self._requests:
                    self._wake.clear()
                    continue
                _, request = self._requests.popitem(last=False)
                if not self._requests:
                    self._wake.clear()
            try:
                self._work(request)
            except Exception as exc:            # noqa: BLE001 (told, then the next one)
                if self._on_error is None:
                    raise
                self._on_error(exc)

    def stop(self):
        """Ends the thread once its current work is done."""
        self._stop = True
        self._wake.set()
        self._thread.join(timeout=5.0)
