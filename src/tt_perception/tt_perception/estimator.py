"""The ball's extended Kalman filter, s = [p, v, w] (9,), as perception runs it.

It is :mod:`tt_prediction.ball_filter`: the same filter (eq. 8 flight with its Jacobian, the
table rebound of eqs. 1-6 with its Jacobian, gating) that ``tt-predict --tracks`` replays
measured tracks through, here fed triangulated positions with their covariance. This module
keeps perception's names.
"""

from tt_prediction.ball_filter import BallFilter, FilterConfig

__all__ = ['BallFilter', 'FilterConfig']
