"""The hit point chosen along the predicted trajectory, inside the robot's reach.

Pure module (no rclpy). Table frame, SI units (MODEL.md). The incoming ball is predicted
(``tt_prediction.predict``, the table as a body) through its bounce on the robot's half and
on past the back of the workspace; its path after the bounce, every 10 ms
(``Prediction.hit_path``), gives the candidate hit points: those whose ball centre is within
one ball radius of the workspace (the racket centre is one radius behind the ball) and that
come at least ``min_time_before_hit`` after ``now``. Up to MAX_CANDIDATES of them, evenly
spread, are solved (:func:`tt_strike.solver.solve`, each Newton warm-started from the
previous candidate's outgoing velocity; a stroke into the table's edge is retried with a
higher arc, EDGE_RETRY_CLEARANCE); a solution counts only when the racket centre is
inside the workspace and the racket speed within its limit. The candidate with the best
in-zone probability wins: linearised (:func:`tt_strike.robust.linear_in_zone_probability`,
7 flights) under the given incoming covariance, or under the default noise (2 mm,
2 % of the speed, 10 % of the spin) without one; ties go to the slower racket.

A ball's hit point is chosen again on each of its predictions, 150-500 times a second. Its
candidates shift with every new prediction and with ``now`` (the rows too soon drop out),
and their scores are often level: the winner moved by up to 0.46 m and 0.18 s from one
prediction to the next (the demo's balls), and an arm following the commands would swing
back and forth. So the hit time chosen last for the ball (``keep_t``) is kept: the path's
state at that time (interpolated between its rows) is a candidate too, and it is left only
for a candidate whose score is more than SWITCH_MARGIN higher, or when it is no longer
within reach or feasible. Once it is closer than ``min_time_before_hit`` the arm is on its
way: the status is too_late, not a new hit point further on. A kept hit point that scores
1 - SWITCH_MARGIN or more cannot be beaten: the other candidates are not solved (most of a
ball's later predictions: one solve instead of up to five, a third of the time or less).

Statuses: ok; no_hit_point (no bounce on the robot's half: the prediction's status and
reason); unreachable (the path never comes within reach, or no solution puts the racket
centre inside the workspace); too_late (within reach only sooner than min_time_before_hit);
infeasible (no candidate has a stroke within the limits: the reason of the best one).
"""

import dataclasses
import math

import numpy as np
from tt_prediction.predict import Hit, hermite_position, predict

from .incoming import hit_point
from .robust import linear_in_zone_probability, noise_covariance
from .solver import StrikeSettings, StrikeSolution, resolve_target, scored_zone, solve

MAX_CANDIDATES = 4
"""Most hit points solved per ball (besides the kept one)."""
SWITCH_MARGIN = 0.05
"""In-zone probability by which another candidate must beat the kept hit time."""
EDGE_RETRY_CLEARANCE = (0.2, 0.4)
"""Net clearances added, m, to retry a stroke whose ball meets the table's edge."""


@dataclasses.dataclass
class StrikePlan:
    """Result of :func:`choose`: a status (see the module doc), the reason when not ok, the
    chosen hit (``tt_prediction.predict.Hit``), its solution, the prediction of the incoming
    ball, how many candidates were solved (the kept one included) and the chosen one's
    score (linearised in-zone probability, 0..1)."""

    status: str
    reason: str = ''
    hit: Hit = None
    solution: StrikeSolution = None
    prediction: object = None
    candidates: int = 0
    score: float = math.nan

    @property
    def feasible(self):
        return self.status == 'ok'


def _hit_from_row(row):
    return Hit(float(row[0]), row[1:4].copy(), row[4:7].copy(), row[7:10].copy())


def _row_at(rows, t):
    """The row [t, p, v, w] at time ``t`` between two of ``rows`` (10 ms apart), or None
    outside them: the position on the cubic through both rows' positions and velocities
    (``predict.hermite_position``: within microns of the flight), velocity and spin linear."""
    times = rows[:, 0]
    if rows.shape[0] == 0 or not times[0] <= t <= times[-1]:
        return None
    k = min(int(np.searchsorted(times, t, side='right')), rows.shape[0] - 1)
    a, b = rows[max(k - 1, 0)], rows[k]
    h = b[0] - a[0]
    s = (t - a[0]) / h if h > 0.0 else 0.0
    row = a + s * (b - a)
    row[0] = t
    row[1:4] = [hermite_position(a[1:10], b[1:10], h, s, i) for i in range(3)]
    return row


def choose(state, params, workspace, t0=0.0, target_zone=None, target_point=None,
           settings=None, now=None, covariance=None, serve=False, bounced=False, keep_t=None):
    """Choose the hit point along the trajectory and solve the stroke there.

    ``state`` (9,) the incoming ball at time ``t0`` (s); ``workspace`` a
    :class:`tt_strike.workspace.Workspace`; target as for :func:`tt_strike.solver.solve`;
    ``now`` (s, same clock; default t0) the time of the decision, for min_time_before_hit;
    ``covariance`` (9x9) of the ball at the hit point, optional (also used for the chosen
    solution's in-zone probability); ``serve``: the first bounce on the opponent's half is
    part of the path; ``bounced``: the ball has already bounced on the robot's half (the
    state is after it, e.g. a BallPrediction's hit point); ``keep_t`` (s) the hit time chosen
    for this ball before, kept unless a candidate beats it by SWITCH_MARGIN (module doc).
    Returns a :class:`StrikePlan`.
    """
    settings = settings or StrikeSettings()
    settings = dataclasses.replace(settings, reach_z=(-math.inf, math.inf), reach_y=math.inf,
                                   max_racket_speed=workspace.max_racket_speed)
    now = t0 if now is None else now
    try:
        resolve_target(target_zone, target_point)
    except ValueError as err:
        return StrikePlan('bad_target', str(err))
    r = params.radius
    x_lo, _ = workspace.x_range()
    plane = x_lo - 2.0 * r - 0.01          # behind the reach: the whole path through it
    if bounced:
        pred = predict(state, params, t0=t0, hit_plane_x=plane, bounced=True, hit_path=True)
    else:
        pred = hit_point(state, params, t0=t0, hit_plane_x=plane, serve=serve, hit_path=True)
    rows = pred.hit_path if pred.hit_path is not None else np.empty((0, 10))
    if pred.hit is not None:
        rows = np.vstack([rows, np.concatenate([[pred.hit.t], pred.hit.state])])
    if pred.status not in ('ok', 'invalid') and rows.shape[0] == 0 and not bounced:
        return StrikePlan('no_hit_point', f'{pred.status}: {pred.reason}', prediction=pred)
    if pred.status == 'invalid':
        return StrikePlan('no_hit_point', f'invalid: {pred.reason}', prediction=pred)
    reach = rows[workspace.contains(rows[:, 1:4], margin=r)] if rows.shape[0] else rows
    if reach.shape[0] == 0:
        why = '' if pred.status == 'ok' else f' (the ball stops: {pred.status})'
        return StrikePlan('unreachable', f'the ball never comes within reach of the racket '
                          f'centre ({workspace.describe()}){why}', prediction=pred)
    soon = reach[:, 0] - now >= workspace.min_time_before_hit
    if not np.any(soon):
        return StrikePlan('too_late', f'within reach only until {reach[-1, 0] - now:.3f} s '
                          f'from now, below min_time_before_hit '
                          f'{workspace.min_time_before_hit:.3f} s', prediction=pred)
    if keep_t is not None and keep_t - now < workspace.min_time_before_hit:
        return StrikePlan('too_late', f'the hit chosen for this ball comes in {keep_t - now:.3f}'
                          f' s, below min_time_before_hit {workspace.min_time_before_hit:.3f} '
                          's: kept', prediction=pred)
    reach = reach[soon]
    kept = _row_at(rows, keep_t) if keep_t is not None else None
    if kept is not None and not workspace.contains(kept[1:4], margin=r):
        kept = None
    if reach.shape[0] > MAX_CANDIDATES:
        pick = np.unique(np.round(np.linspace(0, reach.shape[0] - 1, MAX_CANDIDATES)))
        reach = reach[pick.astype(int)]
    if kept is not None:
        reach = np.vstack([kept, reach])
    best, best_key, first_reason, outside = None, None, '', 0
    kept_best = None
    guess = None
    for i, row in enumerate(reach):
        s_hit = row[1:10]
        sol = solve(s_hit, params, target_zone=target_zone, target_point=target_point,
                    settings=settings, guess=guess)
        for extra in EDGE_RETRY_CLEARANCE:
            if sol.feasible or sol.forward_end != 'table_edge':
                break
            # Into the table's end face or edge (a ball struck below the surface): a higher
            # arc over the net rises more steeply and may clear the edge.
            higher = dataclasses.replace(settings, net_clearance=settings.net_clearance + extra)
            sol = solve(s_hit, params, target_zone=target_zone, target_point=target_point,
                        settings=higher)
        if not sol.feasible:
            first_reason = first_reason or sol.reason
            continue
        guess = sol.ball_out_v
        if not workspace.contains(sol.racket_position):
            outside += 1
            continue
        cov = covariance if covariance is not None else noise_covariance(s_hit)
        zone = scored_zone(sol)
        score = linear_in_zone_probability(s_hit, cov, sol.normal, sol.racket_velocity,
                                           params, sol.landing, zone)
        key = (round(score, 3), -float(np.linalg.norm(sol.racket_velocity)))
        if best_key is None or key > best_key:
            best, best_key = (row, sol, score), key
        if kept is not None and i == 0:
            kept_best = (row, sol, score)
            if score >= 1.0 - SWITCH_MARGIN:
                break            # no score (at most 1) beats it by SWITCH_MARGIN: kept
    if kept_best is not None and best[2] <= kept_best[2] + SWITCH_MARGIN:
        best = kept_best
    n = i + 1
    if best is None:
        if outside:
            return StrikePlan('unreachable', f'no stroke puts the racket centre inside the '
                              f'workspace ({workspace.describe()})', prediction=pred,
                              candidates=n)
        return StrikePlan('infeasible', first_reason, prediction=pred, candidates=n)
    row, sol, score = best
    if covariance is not None:
        # The chosen hit point's full solution: ensemble probability, aim_inside_zone.
        full = solve(row[1:10], params, target_zone=target_zone, target_point=target_point,
                     settings=settings, covariance=covariance, guess=sol.ball_out_v)
        if full.feasible and workspace.contains(full.racket_position):
            sol = full
    return StrikePlan('ok', '', hit=_hit_from_row(row), solution=sol, prediction=pred,
                      candidates=n, score=score)
