"""A ROS graph inside a test process, for the tests of every tt package.

:class:`Graph` gives a test its own rclpy Context and executor, and spins them until a
condition holds: tests wait on what they check (a count, a message), never on a sleep. It
never imports pytest; each package's tests wrap it in their own fixtures.
"""

import os
import random
import time
import uuid

import rclpy
from rclpy.executors import SingleThreadedExecutor

from .shm import domains_with_listeners


def unique_prefix():
    """A topic prefix (``/t<pid>_<random>``) no other test on this machine uses."""
    return f'/t{os.getpid()}_{uuid.uuid4().hex[:6]}'


def remap_args(prefix, topics):
    """ROS arguments (``--ros-args -r /topic:=<prefix>/topic ...``) that move each of
    ``topics`` under ``prefix`` (e.g. :func:`unique_prefix`)."""
    args = ['--ros-args']
    for topic in topics:
        args += ['-r', f'{topic}:={prefix}{topic}']
    return args


def unique_domain(low=150, high=230):
    """A random ROS domain id in [low, high] for a test whose graph must be its own (a global
    topic such as /clock), among those with no Fast DDS shared-memory port listened to on
    this machine (:func:`tt_ros.shm.domains_with_listeners`): not another running test's, and
    none that a killed process left (a new participant on such a port can lose its first
    messages); any domain of the range when none is free."""
    rng = random.Random(uuid.uuid4().int)
    taken = domains_with_listeners()
    free = [d for d in range(low, high + 1) if d not in taken]
    return rng.choice(free) if free else rng.randint(low, high)


class Graph:
    """Nodes in one fresh rclpy Context, spun by the test itself.

    ``args`` and ``domain_id`` go to ``rclpy.init``. Nodes given to :meth:`add` are spun by
    :meth:`spin_until` and destroyed by :meth:`close`, which the end of a ``with`` block
    calls.
    """

    def __init__(self, args=None, domain_id=None):
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context, args=args, domain_id=domain_id)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes = []

    def add(self, node):
        """Spin ``node`` with the others; returns it."""
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def create_node(self, prefix='test'):
        """A plain node with a unique name (``<prefix>_<random>``), added to the graph."""
        return self.add(rclpy.create_node(f'{prefix}_{uuid.uuid4().hex[:8]}',
                                          context=self.context))

    def spin_until(self, condition, timeout, what):
        """Spin until ``condition()``; TimeoutError naming ``what`` after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise TimeoutError(f'timed out after {timeout} s waiting for {what}')
            self.executor.spin_once(timeout_sec=0.02)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        """Destroy the nodes and shut the context down (also at the end of a ``with``)."""
        self.executor.shutdown()
        for node in self.nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=self.context)
