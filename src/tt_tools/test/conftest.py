"""Helpers for tt_tools tests: a ROS graph in the test process and ``ros2`` subprocesses."""

import os
import signal
import subprocess
import sys
import threading
import uuid

import pytest
from tt_tools.procs import ros_env

from tt_ros import testing

ROS2 = [sys.executable, '-m', 'tt_tools.ros2']


class Ros2Process:
    """A ``ros2 ...`` subprocess whose stdout and stderr are collected by reader threads."""

    def __init__(self, *args, env=None):
        self.proc = subprocess.Popen(
            [*ROS2, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            stdin=subprocess.DEVNULL,
            # PYTHONFAULTHANDLER: a SIGABRT (``dump_stack``) writes every thread's stack.
            env=ros_env({'TT_ROS2_NO_HANDOVER': '1', 'PYTHONFAULTHANDLER': '1', **(env or {})}),
            start_new_session=True)
        self._out, self._err = [], []
        self._threads = [threading.Thread(target=self._pump, args=(s, buf), daemon=True)
                         for s, buf in ((self.proc.stdout, self._out),
                                        (self.proc.stderr, self._err))]
        for t in self._threads:
            t.start()

    @staticmethod
    def _pump(stream, buf):
        for line in stream:
            buf.append(line)

    @property
    def stdout(self):
        return ''.join(self._out)

    @property
    def stderr(self):
        return ''.join(self._err)

    def signal(self, sig):
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, sig)

    def wait(self, timeout=30):
        """Exit code (threads drained) after the process ends; kills it on timeout."""
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.signal(signal.SIGKILL)
            self.proc.wait()
            raise
        for t in self._threads:
            t.join(5)
        return self.proc.returncode

    def dump_stack(self, timeout=5):
        """Where a process that does not end is: SIGABRT makes Python's faulthandler write
        every thread's stack to stderr (the process dies of it); that stderr's last lines."""
        self.signal(signal.SIGABRT)
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            pass
        for t in self._threads:
            t.join(1)
        return '\n'.join(self.stderr.splitlines()[-40:])

    def stop(self):
        if self.proc.poll() is None:
            self.signal(signal.SIGKILL)
            self.proc.wait()


def error_lines(stderr):
    """The lines of ``stderr`` written by tt, without the DDS library's own log lines (Fast DDS
    logs e.g. ``[RTPS_TRANSPORT_SHM Error]`` when another process holds a shared-memory port)."""
    return [line for line in stderr.splitlines()
            if line.strip() and '\x1b[' not in line and 'RTPS_' not in line]


def ros2(*args, timeout=60, env=None):
    """Run ``ros2 args`` to the end; (exit code, stdout, stderr)."""
    proc = Ros2Process(*args, env=env)
    rc = proc.wait(timeout)
    return rc, proc.stdout, proc.stderr


class Graph(testing.Graph):
    """A node in a fresh rclpy Context, spun by the test itself."""

    def __init__(self, domain_id=None):
        super().__init__(domain_id=domain_id)
        self.node = self.create_node('tt_tools_test')

    def node_running(self, proc):
        """True when the ros2 subprocess ``proc`` has its node in the graph."""
        suffix = f'_{proc.proc.pid}'
        return any(name.startswith('_ros2cli_') and name.endswith(suffix)
                   for name in self.node.get_node_names())


@pytest.fixture
def graph():
    g = Graph()
    yield g
    g.close()


@pytest.fixture
def procs():
    """Start ``ros2`` subprocesses with ``procs(*args)``; any left running are killed."""
    started = []

    def start(*args, env=None):
        started.append(Ros2Process(*args, env=env))
        return started[-1]

    yield start
    for p in started:
        p.stop()


@pytest.fixture
def topic():
    """A topic name no other test (or engineer) on this machine uses."""
    return f'/tt_tools_test_{os.getpid()}_{uuid.uuid4().hex[:8]}'
