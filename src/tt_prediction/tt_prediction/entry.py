"""The console scripts of tt_prediction (light: the module each names is imported only once
:func:`tt_ros.entry.run` guards Ctrl-C)."""

from tt_ros.entry import run


def prediction_node():
    return run('tt_prediction.node:main', 'prediction_node', quiet=True)


def tt_predict():
    return run('tt_prediction.cli:main', 'tt-predict')


def tt_identify():
    return run('tt_prediction.identify.cli:main', 'tt-identify')
