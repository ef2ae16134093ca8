"""Running a node as its own process (`ros2 run`): start-up, spin and a clean shutdown, in one
place for every tt node (ROS glue).

The executor is rclpy's ``SingleThreadedExecutor``. ``TT_EXECUTOR=events`` in the environment
selects rclpy's C++ events executor (``rclpy.experimental.EventsExecutor``, rclpy >= 7.1.4):
it takes a message from the middleware to its callback without rebuilding a Python wait set
on every wake-up, 0.5-1.2 ms off the p99 of a state-to-prediction hop at 500 Hz on a 2-core
machine, but in rclpy 7.1.6 it aborts the process at shutdown about one time in ten
("Destroying callback manager with callbacks remaining"), so it is not the default
(docs/prediction.md).
"""

import os

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

EXECUTOR_ENV = 'TT_EXECUTOR'
EXECUTORS = ('events', 'single')
SPIN_TIMEOUT_S = 0.5
"""Longest wait of one spin_once; a shutdown wakes the executor at once anyway."""


def make_executor(kind=None, context=None):
    """The executor ``kind`` ('events' or 'single'; None: $TT_EXECUTOR, else 'single').

    'events' falls back to 'single' with an rclpy older than the events executor. Raises
    ValueError for another name.
    """
    kind = kind or os.environ.get(EXECUTOR_ENV) or 'single'
    if kind not in EXECUTORS:
        raise ValueError(f'{EXECUTOR_ENV}={kind!r} is not one of: {", ".join(EXECUTORS)}')
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor(context=context)
        except ImportError:
            pass
    return SingleThreadedExecutor(context=context)


def spin_node(make_node, args=None, on_exit=None):
    """Run the node that ``make_node()`` returns until SIGINT or SIGTERM, then shut down
    cleanly: the node destroyed, the context shut down, exit status 0 and no traceback.

    The executor exists before the node, because a signal may come while the node starts
    (compiling its kernels, say); a failure after a signal has shut the context down is the
    shutdown, not an error. ``on_exit(node)`` runs before the node is destroyed.
    """
    rclpy.init(args=args)
    try:
        executor = make_executor()
    except ValueError as exc:
        rclpy.try_shutdown()
        raise SystemExit(str(exc)) from None
    node = None
    try:
        node = make_node()
        executor.add_node(node)
        if isinstance(executor, SingleThreadedExecutor):
            executor.spin()
        else:
            # spin_once in a loop, not spin(): the events executor's spin() of rclpy 7.1.6
            # runs no callback and ignores the shutdown (one core busy); spin_once does both.
            while rclpy.ok():
                executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok():
            raise
    finally:
        executor.shutdown()
        if node is not None:
            if on_exit is not None:
                on_exit(node)
            node.destroy_node()
        rclpy.try_shutdown()
