"""The demo's verdict names each ball that lacked a state, a prediction or a strike command."""

from tt_tools.demo_report import BallResult, balls_missed


def test_balls_missed_names_what_each_ball_lacked():
    full = BallResult(index=1, truth=None, states=[object()], prediction={}, command={})
    no_strike = BallResult(index=2, truth=None, states=[object()], prediction={})
    unseen = BallResult(index=3, truth=None)
    assert balls_missed([full]) == []
    assert balls_missed([full, no_strike, unseen]) == [
        'ball 2: no strike command', 'ball 3: no state, no prediction, no strike command']
