"""pytest plugin of the tt packages' tests: the environment they run in, whoever runs them.

``make test`` (scripts/run_pytest.sh) and ``colcon test`` (each package's setup.cfg) load it
with ``-p tt_ros.pytest_env``:

- ROS discovery on this machine only (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``);
- a ROS domain of the suite's own (1-100) unless ``ROS_DOMAIN_ID`` is set: two suites on one
  machine (a flake check, a developer's shell) never see each other's nodes and topics, and
  none takes a domain whose Fast DDS shared-memory port a killed process left
  (:func:`tt_ros.testing.unique_domain`);
- matplotlib without a display (``MPLBACKEND=Agg`` unless set);
- the test markers ``graph`` and ``slow``;
- at the end, the shared-memory segments that the graph tests' killed nodes left removed
  (:func:`tt_ros.shm.remove_dead_segments`).
"""

import os


def pytest_configure(config):
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if not os.environ.get('ROS_DOMAIN_ID'):
        from tt_ros.testing import unique_domain
        os.environ['ROS_DOMAIN_ID'] = str(unique_domain(1, 100))
    os.environ.setdefault('MPLBACKEND', 'Agg')
    config.addinivalue_line('markers', 'graph: tests that start ROS nodes (rclpy executors, '
                            'launch-free)')
    config.addinivalue_line('markers', 'slow: tests that take more than a few seconds')


def pytest_unconfigure(config):
    from tt_ros.shm import remove_dead_segments
    remove_dead_segments()
