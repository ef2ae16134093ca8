"""Fast DDS's shared-memory files in /dev/shm: what a process killed by a signal leaves behind.

Each Fast DDS participant (one per ROS 2 process) maps a data segment (``fastrtps_<16 hex>``,
0.5 MB by default, 32 MB with tt's large-message profile) and listens on ports
(``fastrtps_port<N>``, N the RTPS port: 7400 + 250 x domain + offset), each with an ``_el``
lock file that the owner holds (``flock``) while it lives, and a port's ``sem.*_mutex``. A
participant deleted cleanly removes its own; a process killed by a signal (SIGKILL, or a
watchdog's ``_exit``) leaves them:

- segments take /dev/shm's memory for good (32 MB each with the large-message profile);
- a later participant of the same domain that opens a left-over port may lose its first
  messages (discovery included) until Fast DDS finds the port's listener dead.

:func:`remove_dead_segments` removes the data segments that no live process holds (as
``fastdds shm clean`` does; written here from the locking rule above, so that bringup can do
it whenever one of its nodes dies). Ports are left alone: live processes that wrote to a dead
node's port keep it open, and the node restarted with the same participant id reopens it
(Fast DDS resets a port whose listener died); removing it would part them.
:func:`domains_with_listeners` says which domains have a port with a listener's lock file
(held by a running participant, or left by a killed one), so that a test can take a domain
that has none. A port file without one is harmless: its listeners ended cleanly and a new
participant that opens it finds no listener to wait for (Fast DDS leaves these behind
after every run; counting them, the test domains filled up within days).
No ROS import: bringup uses it without rclpy.
"""

import fcntl
import os
import re
import time

SHM_DIR = '/dev/shm'
"""Where Fast DDS keeps its shared-memory files on Linux."""
PORT_BASE, DOMAIN_GAIN = 7400, 250
"""RTPS port numbering: domain d's ports are PORT_BASE + DOMAIN_GAIN d + [0, DOMAIN_GAIN)."""

RECHECK_S = 0.1
"""A lock found free is checked again after this time before anything is removed: a starting
participant creates its lock file a moment before it locks it, s."""

_SEGMENT_LOCK = re.compile(r'^fastrtps_[0-9a-z]{16}_el$')
_PORT_LOCK = re.compile(r'^fastrtps_port(\d{1,5})_[es]l$')


def _held(path):
    """Whether a live process holds the lock file ``path`` (an exclusive ``flock`` fails);
    False when it is gone."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)        # closing drops the lock we may have taken
    return False


def _remove(paths):
    removed = 0
    for path in paths:
        try:
            os.remove(path)
            removed += 1
        except OSError:
            pass
    return removed


def remove_dead_segments(shm_dir=SHM_DIR):
    """Remove the Fast DDS data segments (with their lock files) whose lock no live process
    holds (their owner ended without deleting its participant); returns the number of files
    removed. Safe while other participants run: a held lock is never touched, a reader that
    still maps a dead writer's segment keeps its mapping, and ports are left alone."""
    try:
        names = os.listdir(shm_dir)
    except OSError:
        return 0
    locks = [name for name in names if _SEGMENT_LOCK.match(name)]
    free = [name for name in locks if not _held(os.path.join(shm_dir, name))]
    if not free:
        return 0
    time.sleep(RECHECK_S)
    dead = []
    for name in free:
        path = os.path.join(shm_dir, name)
        if _held(path):
            continue
        dead += [path, path[:-3]]
    return _remove(dead)


def port_domain(port):
    """The ROS domain id an RTPS port number belongs to (None below the first domain)."""
    return None if port < PORT_BASE else (port - PORT_BASE) // DOMAIN_GAIN


def domains_with_listeners(shm_dir=SHM_DIR):
    """The domain ids that have a Fast DDS shared-memory port with a listener's lock file
    (``_el`` exclusive, ``_sl`` shared) in ``shm_dir``: held by a running participant, or
    left by a killed one."""
    try:
        names = os.listdir(shm_dir)
    except OSError:
        return set()
    ports = (_PORT_LOCK.match(name) for name in names)
    return {port_domain(int(m.group(1))) for m in ports if m} - {None}
