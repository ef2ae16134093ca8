"""The console scripts of tt_perception (light: the module each names is imported only once
:func:`tt_ros.entry.run` guards Ctrl-C)."""

from tt_ros.entry import run


def perception_node():
    return run('tt_perception.node:main', 'perception_node', quiet=True)


def tt_perceive():
    return run('tt_perception.cli:main', 'tt-perceive')
