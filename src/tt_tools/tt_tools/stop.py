"""A stop request (SIGINT or SIGTERM) noted, not raised, from the start of a ``ros2`` verb.

``install()`` runs first thing in ``ros2``: a signal that comes while the verb is still
importing rclpy is kept in ``requested`` (a KeyboardInterrupt raised in the middle of an
import could be lost, and the verb then waited forever); the verb's node
(``rosutil.CliNode``) starts stopped when it is set. Standard library only, so that
installing it costs nothing.
"""

import signal

requested = False


def request(signum=None, frame=None):
    """Note a stop request (the signal handler)."""
    global requested
    requested = True


def install():
    """Make SIGINT and SIGTERM note a stop request instead of raising or ending the process."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, request)
