"""The incoming ball at the hitting plane, for the strike command line and evaluation.

Pure module (no rclpy). Uses ``tt_prediction.predict``: the ball must bounce once on the
robot's half and then cross the hitting plane x = hit_plane_x. A serve first bounces on the
server's (opponent's) half: with ``serve=True`` that first bounce is flown through and the
prediction restarts from just after it.
"""

import math

from tt_prediction.ball import rollout
from tt_prediction.predict import DEFAULT_HIT_PLANE_X, T_MAX, predict


def hit_point(state, params, t0=0.0, hit_plane_x=DEFAULT_HIT_PLANE_X, serve=False,
              hit_path=False):
    """Prediction of the ball at ``state`` (9,) at time ``t0`` (s) to the hitting plane.

    Returns the ``tt_prediction.predict.Prediction`` (status 'ok' with ``.hit``, else the
    status and ``.reason`` of why there is no hit point). ``serve``: a first bounce on the
    opponent's half (x > 0) is part of the ball's path, not an error. ``hit_path``: also the
    path after the bounce on the robot's half (``Prediction.hit_path``, the candidates of
    :mod:`tt_strike.hitpoint`).
    """
    pred = predict(state, params, t0=t0, hit_plane_x=hit_plane_x, hit_path=hit_path)
    if serve and pred.status == 'wrong_half' and pred.bounce is not None:
        events, _ = rollout(state, params, t0=t0, t_max=t0 + T_MAX, stop_at_net=True,
                            max_bounces=1)
        last = events[-1]
        if last.kind == 'bounce' and last.state[0] > 0.0 and math.isfinite(last.t):
            pred = predict(last.after, params, t0=last.t, hit_plane_x=hit_plane_x,
                           hit_path=hit_path)
    return pred
