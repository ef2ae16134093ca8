"""Start ROS processes for the demo and the end-to-end tests, and stop them cleanly."""

import ctypes
import functools
import os
import shutil
import signal
import subprocess
import time

SHM_NEEDED = 1 << 30
"""Free bytes in /dev/shm below which the large-message Fast DDS profile is not used."""


def large_message_profile():
    """Path of tt's Fast DDS profile for images (config/fastdds_large_messages.xml), or None
    when /dev/shm is too small for its 32 MB segments (e.g. a container's default 64 MB)."""
    try:
        shm = shutil.disk_usage('/dev/shm')
        from ament_index_python.packages import get_package_share_directory
        path = os.path.join(get_package_share_directory('tt_tools'), 'config',
                            'fastdds_large_messages.xml')
    except (OSError, LookupError):
        return None
    return path if shm.free >= SHM_NEEDED and os.path.exists(path) else None


PR_SET_PDEATHSIG = 1
"""prctl(2) option: the signal a process gets when the thread that started it ends."""


def _prctl():
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):       # not Linux
        return None


_PRCTL = _prctl()   # looked up here: a preexec_fn should do as little as it can


def _end_with(parent_pid, sig):
    if _PRCTL is not None:
        _PRCTL(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
    if os.getppid() != parent_pid:          # the parent is gone already
        os.kill(os.getpid(), sig)


def ends_with_parent(sig=signal.SIGTERM):
    """A ``preexec_fn`` for :class:`subprocess.Popen`: the child gets ``sig`` when this process
    ends, however it ends (SIGKILL too), so that its nodes do not outlive it (Linux
    ``PR_SET_PDEATHSIG``; elsewhere it does nothing). Start the child from the thread that
    lives as long as the process: the signal comes when the starting thread ends."""
    return functools.partial(_end_with, os.getpid(), sig)


def ros_env(extra=None, large_messages=False, localhost=True):
    """The current environment with unbuffered Python output and, with ``localhost``,
    discovery kept on this machine (tests, demo); with ``large_messages`` also the Fast DDS
    profile for images (unless the caller's environment sets one)."""
    env = dict(os.environ)
    if localhost:
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if large_messages and not env.get('FASTRTPS_DEFAULT_PROFILES_FILE'):
        profile = large_message_profile()
        if profile:
            env['FASTRTPS_DEFAULT_PROFILES_FILE'] = profile
    env['PYTHONUNBUFFERED'] = '1'
    env.update(extra or {})
    return env


class ProcessGroup:
    """Processes started together and stopped together (SIGINT, then SIGTERM, then SIGKILL)."""

    def __init__(self, log_dir, large_messages=False):
        self.log_dir = log_dir
        self.large_messages = large_messages
        self.procs = {}

    def start(self, name, argv, env=None):
        """Start ``argv`` with stdout and stderr to ``log_dir/name.log``; it gets SIGTERM
        when this process ends, however it ends (:func:`ends_with_parent`: the demo ended by
        ``timeout`` or a closed terminal left its four nodes running for ever)."""
        log = open(os.path.join(self.log_dir, f'{name}.log'), 'w')
        proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, env=ros_env(env, self.large_messages),
                                start_new_session=True, preexec_fn=ends_with_parent())
        proc.log = log
        self.procs[name] = proc
        return proc

    def stop(self, name, timeout=10.0):
        """Stop one process: SIGINT, then SIGTERM, then SIGKILL; return its exit code."""
        proc = self.procs.pop(name)
        for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
            if proc.poll() is not None:
                break
            try:
                os.killpg(proc.pid, sig)
            except ProcessLookupError:
                break
            try:
                proc.wait(wait)
            except subprocess.TimeoutExpired:
                continue
        proc.log.close()
        return proc.returncode

    def stop_all(self):
        for name in list(self.procs)[::-1]:
            self.stop(name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop_all()


def rss_mb(pid):
    """Resident memory (VmRSS) of process ``pid``, MB; 0 when it is gone."""
    try:
        with open(f'/proc/{pid}/status') as f:
            for line in f:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def wait_until(condition, timeout, what, poll=0.05):
    """Poll ``condition()`` until true; raise TimeoutError naming ``what`` after ``timeout``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(poll)
    raise TimeoutError(f'timed out after {timeout:.0f} s waiting for {what}')
