"""Writing a verb's output to stdout when the reader may go away (``ros2 ... | head``)."""

import os
import sys


def silence_stdout():
    """Point stdout at /dev/null, so that the flush at interpreter exit cannot fail again
    (Python exits 120 when it cannot flush stdout)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


def write(text):
    """Write ``text`` to stdout and flush; False (and stdout silenced) when the pipe is closed."""
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
        return True
    except BrokenPipeError:
        silence_stdout()
        return False


def say(text):
    """One line for the user on stderr (what a verb is waiting for); never raises."""
    try:
        sys.stderr.write(text.rstrip('\n') + '\n')
        sys.stderr.flush()
    except (OSError, ValueError):
        pass
