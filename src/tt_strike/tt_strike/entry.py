"""The console scripts of tt_strike (light: the module each names is imported only once
:func:`tt_ros.entry.run` guards Ctrl-C)."""

from tt_ros.entry import run


def strike_node():
    return run('tt_strike.node:main', 'strike_node', quiet=True)


def tt_strike():
    return run('tt_strike.cli:main', 'tt-strike')
