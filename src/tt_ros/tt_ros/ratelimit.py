"""Rate limits by the messages' own stamps (pure: no rclpy), so that a replayed recording
is thinned as the live one was, whatever the replay rate."""


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
