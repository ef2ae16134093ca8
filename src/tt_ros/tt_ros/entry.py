"""Console-script entry points that start quietly when interrupted.

A tt executable spends its first second importing rclpy, numpy, scipy and numba before its
own Ctrl-C handling exists (:func:`tt_ros.executor.run_node` for a node, the command's
``<tool>: interrupted`` for a CLI). A Ctrl-C in that second would print a KeyboardInterrupt
traceback from deep inside an import. Each package's ``entry`` module (which imports nothing
heavy) points its console scripts here instead: a command then ends with one line and status
130, as the shell reports a SIGINT, and a node stops cleanly (status 0, as
:func:`tt_ros.executor.run_node` ends on SIGINT: bringup's Ctrl-C during start-up is a clean
stop). Output that cannot be written ends as :func:`finish_output` says. This module must
stay free of heavy imports.
"""

import errno
import importlib
import os
import signal
import sys

INTERRUPTED_EXIT = 130
"""Exit status of a process ended by Ctrl-C (128 + SIGINT), as a shell reports it."""


WRITE_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO)
"""Errors of a write to stdout that are the output's place's, not the program's."""


def finish_output(body, name):
    """``body()``'s exit status once stdout is flushed. A reader that went away (``| head``)
    ends it quietly with 0; a full disk or another failed write of stdout (``> /dev/full``)
    with ``<name>: cannot write the output: <reason>`` on stderr and 1. Neither gives a
    traceback, nor Python's "Exception ignored" and status 120 at exit."""
    status = None
    try:
        try:
            status = body()
        except SystemExit as exc:         # argparse's --help and usage errors, say
            status = exc.code
        sys.stdout.flush()
        return status
    except BrokenPipeError:
        _stdout_to_devnull()
        return status or 0
    except OSError as exc:
        if exc.filename is not None or exc.errno not in WRITE_ERRORS:
            raise
        _stdout_to_devnull()
        if status:                        # a failure the body reported already
            return status
        print(f'{name}: cannot write the output: {exc.strerror}', file=sys.stderr, flush=True)
        return 1


def _stdout_to_devnull():
    """What stdout still buffers goes nowhere at exit (the flush would fail again)."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _interrupted(exc):
    """Whether ``exc`` came of a Ctrl-C: a KeyboardInterrupt, or an ImportError raised from
    one (a pybind11 module, rclpy's say, whose initialisation the signal cut: "ImportError:
    initialization failed", with a traceback, from a node interrupted 0.8 s into its start
    in a walk-through, 6 Dec 2026)."""
    while exc is not None:
        if isinstance(exc, KeyboardInterrupt):
            return True
        if not isinstance(exc, ImportError):
            return False
        exc = exc.__cause__ or exc.__context__
    return False


def run(target, name, quiet=False):
    """Import ``target`` (``'package.module:function'``), call the function and return its
    result (the exit status), through :func:`finish_output`. A KeyboardInterrupt before the
    function has taken over Ctrl-C (during the imports, say) returns 0 without a word when
    ``quiet`` (a node: it stopped before it started), else prints ``<name>: interrupted`` on
    stderr and returns :data:`INTERRUPTED_EXIT`. SIGTERM is taken as SIGINT from the start:
    bringup and service managers stop nodes with it (run_node does once it runs), and
    ``timeout`` or a batch system a command, whose staged output was left behind half
    written when SIGTERM ended the process at once (a walk-through, 7 Dec 2026)."""
    module, _, function = target.partition(':')
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        return finish_output(getattr(importlib.import_module(module), function), name)
    except (KeyboardInterrupt, ImportError) as exc:
        if not _interrupted(exc):
            raise
        if quiet:
            return 0
        print(f'{name}: interrupted', file=sys.stderr, flush=True)
        return INTERRUPTED_EXIT
