"""tt_ros.shm: which Fast DDS shared-memory files a dead process left, and which domains
have ports."""

import fcntl
import os

from tt_ros.testing import unique_domain

from tt_ros import shm


def _touch(folder, name):
    path = folder / name
    path.write_bytes(b'')
    return path


def test_only_segments_whose_lock_no_process_holds_are_removed(tmp_path, monkeypatch):
    monkeypatch.setattr(shm, 'RECHECK_S', 0.0)
    live, dead = 'fastrtps_0123456789abcdef', 'fastrtps_fedcba9876543210'
    for name in (live, dead):
        _touch(tmp_path, name)
        _touch(tmp_path, name + '_el')
    # Ports are left alone, listened to or not; so is anything else.
    others = ['fastrtps_port26661', 'fastrtps_port26661_el', 'sem.fastrtps_port26661_mutex',
              'fastrtps_port7000', 'lttng-ust-wait-6', 'fastrtps_0123456789abcdef_x']
    for name in others:
        _touch(tmp_path, name)
    fd = os.open(tmp_path / f'{live}_el', os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)      # a live participant holds an flock on its lock file
    try:
        assert shm.remove_dead_segments(str(tmp_path)) == 2
        left = sorted(os.listdir(tmp_path))
    finally:
        os.close(fd)
    assert left == sorted(others + [live, f'{live}_el'])
    # Once its owner ends, the live one goes too.
    assert shm.remove_dead_segments(str(tmp_path)) == 2
    assert sorted(os.listdir(tmp_path)) == sorted(others)


def test_a_port_with_a_listeners_lock_belongs_to_the_domain_of_the_rtps_numbering(tmp_path):
    # RTPS: port = 7400 + 250 domain + offset (offsets 0..249); a listener's lock file is
    # the port's name + _el (exclusive: a unicast port) or _sl (shared: the multicast one).
    for port, lock in ((7400 + 250 * 42 + 11, '_el'), (7400 + 250 * 0, '_sl'),
                       (7400 + 250 * 230 + 249, '_el'), (7000, '_el')):
        _touch(tmp_path, f'fastrtps_port{port}')
        _touch(tmp_path, f'fastrtps_port{port}{lock}')
    # Ports whose listeners ended cleanly (no lock file), a mutex, a segment's lock: none.
    for name in (f'fastrtps_port{7400 + 250 * 99}', f'sem.fastrtps_port{7400 + 250 * 7}_mutex',
                 'fastrtps_0123456789abcdef_el', f'fastrtps_port{7400 + 250 * 8}_elx'):
        _touch(tmp_path, name)
    assert shm.domains_with_listeners(str(tmp_path)) == {0, 42, 230}
    assert shm.domains_with_listeners(str(tmp_path / 'missing')) == set()


def test_a_test_domain_avoids_domains_with_listeners(monkeypatch):
    monkeypatch.setattr('tt_ros.testing.domains_with_listeners', lambda: set(range(150, 230)))
    assert {unique_domain() for _ in range(20)} == {230}
    monkeypatch.setattr('tt_ros.testing.domains_with_listeners', lambda: set(range(1, 300)))
    assert all(150 <= unique_domain() <= 230 for _ in range(20))     # none free: any


def test_the_suite_runs_on_this_machine_alone():
    """Whoever runs the tests (make test, colcon test, pytest on one folder), tt_ros.pytest_env
    keeps ROS discovery on this machine and gives the suite a domain id."""
    import os
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert 0 <= int(os.environ['ROS_DOMAIN_ID']) <= 232
