"""Console-script entry points that start quietly when interrupted.

A tt executable spends its first second importing rclpy, numpy, scipy and numba before its
own Ctrl-C handling exists (:func:`tt_ros.executor.run_node` for a node, the command's
``<tool>: interrupted`` for a CLI). A Ctrl-C in that second would print a KeyboardInterrupt
traceback from deep inside an import. Each package's ``entry`` module (which imports nothing
heavy) points its console scripts here instead: a command then ends with one line and status
130, as the shell reports a SIGINT, and a node stops cleanly (status 0, as
:func:`tt_ros.executor.run_node` ends on SIGINT: bringup's Ctrl-C during start-up is a clean
stop). This module must stay free of heavy imports.
"""

import importlib
import sys

INTERRUPTED_EXIT = 130
"""Exit status of a process ended by Ctrl-C (128 + SIGINT), as a shell reports it."""


def run(target, name, node=False):
    """Import ``target`` (``'package.module:function'``), call the function and return its
    result (the exit status). A KeyboardInterrupt before the function has taken over Ctrl-C
    (during the imports, say) returns 0 for a ``node`` (it stopped before it started) and
    otherwise prints ``<name>: interrupted`` on stderr and returns :data:`INTERRUPTED_EXIT`."""
    module, _, function = target.partition(':')
    try:
        return getattr(importlib.import_module(module), function)()
    except KeyboardInterrupt:
        if node:
            return 0
        print(f'{name}: interrupted', file=sys.stderr, flush=True)
        return INTERRUPTED_EXIT
