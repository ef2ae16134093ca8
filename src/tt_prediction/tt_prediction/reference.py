"""Reference prediction: the model of MODEL.md integrated by scipy's solve_ivp (DOP853).

The straightforward implementation the compiled predictor is checked and timed against:
eq. 8 and eqs. 1-6 written out again in numpy (not the compiled kernels), DOP853 at
rtol 1e-9 / atol 1e-12, and terminal events (table plane, floor, net plane, hitting plane)
that solve_ivp locates by root finding on its dense output. Nominal model only (the effects
of identification are not written out here): :func:`reference_predict` refuses a model with
an effect switched on.
"""

import math

import numpy as np
from scipy.integrate import solve_ivp

from .ball import (
    HALF_LENGTH,
    HALF_WIDTH,
    NET_HALF_WIDTH,
    NET_HEIGHT,
    ROLL_SPEED,
    TABLE_HEIGHT,
    ModelParams,
    zone_of,
)
from .predict import DEFAULT_HIT_PLANE_X, T_MAX, Contact, Hit, Prediction

RTOL = 1e-9
ATOL = 1e-12


def flight_rhs(params):
    """d/dt [p, v, w] of eq. 8 (constant spin) for solve_ivp."""
    m, r, rho = params.mass, params.radius, params.air_density
    k_drag = 0.5 * params.c_d * rho * params.area / m
    k_lift = 4.0 / 3.0 * params.c_m * math.pi * rho * r ** 3 / m
    g = np.array([0.0, 0.0, -params.gravity])

    def rhs(_t, s):
        v, w = s[3:6], s[6:9]
        a = g - k_drag * np.linalg.norm(v) * v + k_lift * np.cross(w, v)
        return np.concatenate([v, a, np.zeros(3)])
    return rhs


def table_rebound(v, w, params):
    """Eqs. 1-6 in matrix form: (v', w') = (A_v v + B_v w, A_w v + B_w w)."""
    r, e_t, mu = params.radius, params.e_t, params.mu
    v_t = np.array([v[0] - r * w[1], v[1] + r * w[0]])
    speed_t = np.linalg.norm(v_t)
    alpha = 0.4
    if speed_t > 1e-12:
        s = mu * (1.0 + e_t) * abs(v[2]) / speed_t
        if 1.0 - 2.5 * s > 0.0:
            alpha = s
    a_v = np.diag([1.0 - alpha, 1.0 - alpha, -e_t])
    b_v = np.array([[0.0, alpha * r, 0.0], [-alpha * r, 0.0, 0.0], [0.0, 0.0, 0.0]])
    a_w = np.array([[0.0, -1.5 * alpha / r, 0.0], [1.5 * alpha / r, 0.0, 0.0], [0.0, 0.0, 0.0]])
    b_w = np.diag([1.0 - 1.5 * alpha, 1.0 - 1.5 * alpha, 1.0])
    return a_v @ v + b_v @ w, a_w @ v + b_w @ w


def _event(fun, direction=0.0):
    fun.terminal = True
    fun.direction = direction
    return fun


def reference_events(state9, params=None, t0=0.0, plane_x=math.nan, max_bounces=2):
    """Events [(kind, t, state)] of the flight from state9 at t0, as the integrator names them.

    Stops at the net, the floor, the hitting plane, a rolling ball, the max_bounces-th bounce
    or T_MAX. The state of a bounce is the one just before contact.
    """
    params = ModelParams() if params is None else params        # None: nominal, as predict
    if params.active_effects():
        raise ValueError('the reference implements the nominal model only (no effects)')
    r = params.radius
    rhs = flight_rhs(params)
    s = np.array(state9, dtype=float)
    t = float(t0)
    t_end = t + T_MAX
    events = []
    bounces = 0
    while True:
        over = abs(s[0]) <= HALF_LENGTH and abs(s[1]) <= HALF_WIDTH
        below = s[2] < r and not over
        funcs = []
        if below:
            funcs.append(('floor', _event(lambda _t, y: y[2] - (r - TABLE_HEIGHT), -1.0)))
        else:
            funcs.append(('table', _event(lambda _t, y: y[2] - r, -1.0)))
        if s[0] != 0.0:
            funcs.append(('net', _event(lambda _t, y: y[0])))
        if math.isfinite(plane_x) and s[0] > plane_x:      # crossed towards the robot only
            funcs.append(('plane', _event(lambda _t, y: y[0] - plane_x, -1.0)))
        sol = solve_ivp(rhs, (t, t_end), s, method='DOP853', rtol=RTOL, atol=ATOL,
                        events=[f for _, f in funcs])
        hits = [(te[0], ye[0], name) for (name, _), te, ye in
                zip(funcs, sol.t_events, sol.y_events, strict=True) if len(te)]
        if not hits:
            events.append(('timeout', sol.t[-1], sol.y[:, -1]))
            return events
        t, s, name = min(hits, key=lambda h: h[0])
        s = s.copy()
        if name == 'floor':
            events.append(('floor', t, s))
            return events
        if name == 'plane':
            s[0] = plane_x
            events.append(('plane', t, s))
            return events
        if name == 'net':
            s[0] = 0.0
            if abs(s[1]) <= NET_HALF_WIDTH and -r < s[2] < NET_HEIGHT + r:
                events.append(('net', t, s))
                return events
            continue
        # The table plane z = r: a bounce inside the outline, else on towards the floor.
        if not (abs(s[0]) <= HALF_LENGTH and abs(s[1]) <= HALF_WIDTH):
            s[2] = r - 1e-12
            continue
        s[2] = r
        v, w = table_rebound(s[3:6], s[6:9], params)
        after = np.concatenate([s[:3], v, w])
        bounces += 1
        if v[2] < ROLL_SPEED:
            events.append(('roll', t, s))
            return events
        events.append(('bounce', t, s))
        if bounces >= max_bounces:
            return events
        s = after


def reference_predict(state9, params=None, t0=0.0, hit_plane_x=DEFAULT_HIT_PLANE_X):
    """:func:`tt_prediction.predict.predict` for a valid state, by the reference integrator.

    Classifies the events in plain Python: ok, net, no_bounce, miss, wrong_half,
    double_bounce, no_hit or timeout.
    """
    events = reference_events(state9, params, t0, hit_plane_x, max_bounces=2)
    bounce = None
    robot = 0
    for kind, t, s in events:
        if kind in ('bounce', 'roll'):
            zone, _ = zone_of(s[0], s[1])
            half = 1 if s[0] > 0.0 else -1
            if bounce is None:
                bounce = Contact(t, s[:3].copy(), zone, half)
            if half > 0:
                return Prediction('no_hit' if robot else 'wrong_half', bounce=bounce,
                                  landing=bounce)
            robot += 1
            if robot == 2:
                return Prediction('double_bounce', bounce=bounce, landing=bounce)
            if kind == 'roll':
                return Prediction('no_hit', bounce=bounce, landing=bounce)
        elif kind == 'plane':
            if robot == 1:
                hit = Hit(t, s[:3].copy(), s[3:6].copy(), s[6:9].copy())
                return Prediction('ok', bounce=bounce, hit=hit, landing=bounce)
            return Prediction('no_bounce')
        elif kind == 'net':
            return Prediction('no_hit' if robot else 'net', bounce=bounce, landing=bounce)
        elif kind == 'floor':
            return Prediction('no_hit' if robot else 'miss', bounce=bounce, landing=bounce)
    return Prediction('timeout', bounce=bounce, landing=bounce)
