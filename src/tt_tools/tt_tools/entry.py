"""The console scripts of tt_tools (light: the module each names is imported only once
:func:`tt_ros.entry.run` guards Ctrl-C). Both stop quietly (status 0) when interrupted while
they import, as each does once running: ``ros2`` as ros2cli does before a verb has started,
bringup as a clean stop of a graph that had not started."""

from tt_ros.entry import run


def ros2():
    return run('tt_tools.ros2:main', 'ros2', quiet=True)


def bringup():
    return run('tt_tools.bringup:main', 'bringup', quiet=True)
