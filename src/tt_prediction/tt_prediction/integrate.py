"""Event-driven integration of the ball's flight and table rebounds (compiled, numba).

The flight ODE (eq. 8) is stepped with classic RK4 at a fixed step (default 5 ms, far below
the flight's time scales: its truncation error is below 1e-7 m over a rally; the benchmark
checks it against scipy's DOP853 at rtol 1e-9). Events are located exactly, not at the
nearest step: a sign change of the event function inside a step starts a Newton iteration
on the step length, each evaluation a fresh RK4 sub-step from the start of the step, so the
event state is as accurate as the integrator itself.

Events (``EVENT_*``): table contact inside the table's outline (the rebound of eqs. 1-6 is
applied and integration goes on), the net (the centre crosses x = 0 less than one radius above
the net's top), the hitting plane x = plane_x (either direction), the floor, a ball that starts
rolling on the table, and the time limit.
"""

import math

from numba import njit
import numpy as np

from .model import flight_derivative, table_rebound_inplace
from .params import I_RADIUS
from .table import HALF_LENGTH, HALF_WIDTH, NET_HALF_WIDTH, NET_HEIGHT, TABLE_HEIGHT

EVENT_BOUNCE = 1
EVENT_NET = 2
EVENT_PLANE = 3
EVENT_FLOOR = 4
EVENT_ROLL = 5
EVENT_TIMEOUT = 6
EVENT_NAMES = {EVENT_BOUNCE: 'bounce', EVENT_NET: 'net', EVENT_PLANE: 'plane',
               EVENT_FLOOR: 'floor', EVENT_ROLL: 'roll', EVENT_TIMEOUT: 'timeout'}

STOP_AT_PLANE = 1
"""Stop at the first crossing of the hitting plane (otherwise it is only recorded)."""
STOP_AT_NET = 2
"""Stop when the ball hits the net (otherwise the net is ignored)."""

DEFAULT_STEP = 5e-3
"""RK4 step, s."""
ROLL_SPEED = 0.05
"""Below this normal speed after a bounce the ball is taken to roll, m/s."""

_NJIT = {'cache': True, 'nogil': True}


@njit(**_NJIT)
def rk4_step(s, h, P, out, k1, k2, k3, k4, tmp):
    """One classic RK4 step of the flight ODE (eq. 8) of size ``h`` from ``s`` into ``out``.

    Parameters
    ----------
    s : ndarray (9,)
        State [p (m), v (m/s), w (rad/s)], table frame, at the start of the step.
    h : float
        Step length, s.
    P : ndarray
        Packed model parameters (:meth:`tt_prediction.params.ModelParams.packed`).
    out : ndarray (9,)
        Receives the state after ``h`` s of free flight (may not alias ``s``).
    k1, k2, k3, k4, tmp : ndarray (9,)
        Scratch arrays (the RK4 stages), overwritten.

    Returns
    -------
    None
        The result is written into ``out``; no table contact is handled (see
        :func:`rollout_kernel` for the events).
    """
    flight_derivative(s, P, k1)
    for i in range(9):
        tmp[i] = s[i] + 0.5 * h * k1[i]
    flight_derivative(tmp, P, k2)
    for i in range(9):
        tmp[i] = s[i] + 0.5 * h * k2[i]
    flight_derivative(tmp, P, k3)
    for i in range(9):
        tmp[i] = s[i] + h * k3[i]
    flight_derivative(tmp, P, k4)
    for i in range(9):
        out[i] = s[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@njit(**_NJIT)
def rk4_advance(s, h, P):
    """One RK4 step of eq. 8 of size ``h`` from ``s``, into a new array.

    :func:`rk4_step` with its scratch arrays allocated here, for callers that take one step
    at a time (a filter's prediction); loops keep theirs and call :func:`rk4_step`.

    Parameters
    ----------
    s, h, P : ndarray (9,), float, ndarray
        State [p (m), v (m/s), w (rad/s)] at the start, step length (s) and packed
        parameters, as for :func:`rk4_step`.

    Returns
    -------
    ndarray (9,)
        The state after ``h`` s of free flight (no table contact).
    """
    out = np.empty(9)
    work = np.empty((5, 9))
    rk4_step(s, h, P, out, work[0], work[1], work[2], work[3], work[4])
    return out


@njit(**_NJIT)
def _locate(s, h, g0, g1, axis, level, P, out, k1, k2, k3, k4, tmp):
    """Step length tau in (0, h] at which s[axis] (position) crosses level, state into out.

    Newton on tau, started from linear interpolation and safeguarded by bisection; each
    evaluation is an RK4 sub-step from s, the derivative is the velocity along axis.
    """
    lo, hi = 0.0, h
    tau = h * g0 / (g0 - g1)
    for _ in range(40):
        rk4_step(s, tau, P, out, k1, k2, k3, k4, tmp)
        g = out[axis] - level
        if abs(g) < 1e-12:
            break
        if (g > 0.0) == (g0 > 0.0):
            lo = tau
        else:
            hi = tau
        v = out[axis + 3]
        nxt = tau - g / v if v != 0.0 else -1.0
        if not (lo < nxt < hi):
            nxt = 0.5 * (lo + hi)
        if abs(nxt - tau) < 1e-13:
            tau = nxt
            rk4_step(s, tau, P, out, k1, k2, k3, k4, tmp)
            break
        tau = nxt
    return tau


@njit(**_NJIT)
def rollout_kernel(s0, t0, P, t_max, dt, plane_x, stop_mask, max_bounces, sample_t, samples,
                   ev_kind, ev_t, ev_s):
    """Integrate from (t0, s0) until a stopping event (compiled); returns the number of events.

    The flight (eq. 8) is stepped with :func:`rk4_step`; at a table contact inside the
    outline the rebound (eqs. 1-6, :func:`tt_prediction.model.table_rebound_inplace`) is
    applied and integration goes on.

    Parameters
    ----------
    s0 : ndarray (9,)
        Initial state [p (m), v (m/s), w (rad/s)], table frame.
    t0 : float
        Time of s0, s.
    P : ndarray
        Packed model parameters (:meth:`tt_prediction.params.ModelParams.packed`).
    t_max : float
        Absolute time limit, s.
    dt : float
        RK4 step, s.
    plane_x : float
        x of the hitting plane, m (NaN for none).
    stop_mask : int
        STOP_AT_PLANE | STOP_AT_NET bits.
    max_bounces : int
        Stop after this many table bounces.
    sample_t : ndarray (k,)
        Sorted absolute times (s) at which to write the state into ``samples``.
    samples : ndarray (k, 9)
        Receives the states at ``sample_t`` (rows not reached stay as they are).
    ev_kind, ev_t, ev_s : ndarray (e,), (e,), (e, 9)
        Receive each event's EVENT_* code, time (s) and state (before any rebound); at most
        e are kept, the last one is the stop.

    Returns
    -------
    int
        Number of events written.
    """
    r = P[I_RADIUS]
    s = s0.copy()
    s1 = np.empty(9)
    se = np.empty(9)
    k1 = np.empty(9)
    k2 = np.empty(9)
    k3 = np.empty(9)
    k4 = np.empty(9)
    tmp = np.empty(9)
    t = t0
    n_ev = 0
    max_ev = ev_kind.shape[0]
    n_bounce = 0
    j = 0
    n_samples = sample_t.shape[0]
    while j < n_samples and sample_t[j] < t0:
        j += 1
    below = s[2] < r and not (abs(s[0]) <= HALF_LENGTH and abs(s[1]) <= HALF_WIDTH)
    floor_z = r - TABLE_HEIGHT
    has_plane = not math.isnan(plane_x)
    while True:
        # (<=: an event located at a step's end may put t an ulp past the sample it ends at)
        if j < n_samples and sample_t[j] <= t:
            for i in range(9):
                samples[j, i] = s[i]
            j += 1
            continue
        h = dt
        to_sample = False
        if j < n_samples and sample_t[j] - t < h:
            h = sample_t[j] - t
            to_sample = True
        if t_max - t < h:
            h = t_max - t
            to_sample = False
        if h <= 0.0:
            kind = EVENT_TIMEOUT
            if n_ev < max_ev:
                ev_kind[n_ev] = kind
                ev_t[n_ev] = t
                ev_s[n_ev, :] = s
                n_ev += 1
            return n_ev
        rk4_step(s, h, P, s1, k1, k2, k3, k4, tmp)
        # Earliest event inside this step.
        best_tau = h + 1.0
        kind = 0
        if below:
            g0, g1 = s[2] - floor_z, s1[2] - floor_z
            if g0 >= 0.0 and g1 < 0.0:
                tau = _locate(s, h, g0, g1, 2, floor_z, P, se, k1, k2, k3, k4, tmp)
                best_tau, kind = tau, EVENT_FLOOR
        else:
            g0, g1 = s[2] - r, s1[2] - r
            if g0 >= 0.0 and g1 < 0.0:
                tau = _locate(s, h, g0, g1, 2, r, P, se, k1, k2, k3, k4, tmp)
                if abs(se[0]) <= HALF_LENGTH and abs(se[1]) <= HALF_WIDTH:
                    best_tau, kind = tau, EVENT_BOUNCE
                else:
                    below = True    # passes the table's edge: falls on to the floor
                    g0, g1 = s[2] - floor_z, s1[2] - floor_z
                    if g0 >= 0.0 and g1 < 0.0:
                        tau = _locate(s, h, g0, g1, 2, floor_z, P, se, k1, k2, k3, k4, tmp)
                        best_tau, kind = tau, EVENT_FLOOR
        if stop_mask & STOP_AT_NET:
            if (s[0] > 0.0) != (s1[0] > 0.0):
                tau = _locate(s, h, s[0], s1[0], 0, 0.0, P, tmp, k1, k2, k3, k4, se)
                rk4_step(s, tau, P, tmp, k1, k2, k3, k4, se)
                if (tau < best_tau and abs(tmp[1]) <= NET_HALF_WIDTH
                        and tmp[2] < NET_HEIGHT + r and tmp[2] > -r):
                    best_tau, kind = tau, EVENT_NET
        if has_plane:
            g0, g1 = s[0] - plane_x, s1[0] - plane_x
            if (g0 > 0.0) != (g1 > 0.0) or (g1 == 0.0 and g0 != 0.0):
                tau = _locate(s, h, g0, g1, 0, plane_x, P, tmp, k1, k2, k3, k4, se)
                if tau < best_tau:
                    best_tau, kind = tau, EVENT_PLANE
        if kind == 0:
            for i in range(9):
                s[i] = s1[i]
            # at a sample, its time exactly: t + (sample - t) can land an ulp past it
            t = sample_t[j] if to_sample else t + h
            continue
        # An event at t + best_tau: the state there, recorded before any rebound.
        rk4_step(s, best_tau, P, se, k1, k2, k3, k4, tmp)
        t += best_tau
        for i in range(9):
            s[i] = se[i]
        if kind == EVENT_BOUNCE:
            s[2] = r
        elif kind == EVENT_PLANE:
            s[0] = plane_x
        stop = kind == EVENT_FLOOR or kind == EVENT_NET
        if kind == EVENT_PLANE:
            stop = (stop_mask & STOP_AT_PLANE) != 0
        if kind == EVENT_BOUNCE:
            n_bounce += 1
            table_rebound_inplace(s, P)
            if s[5] < ROLL_SPEED:
                kind = EVENT_ROLL
                stop = True
            elif n_bounce >= max_bounces:
                stop = True
        if n_ev < max_ev:
            ev_kind[n_ev] = kind
            ev_t[n_ev] = t
            ev_s[n_ev, :] = se
            if kind == EVENT_BOUNCE or kind == EVENT_ROLL:
                ev_s[n_ev, 2] = r
            n_ev += 1
        if stop:
            return n_ev


class Event:
    """One event of a rollout.

    Attributes
    ----------
    kind : str
        'bounce', 'net', 'plane', 'floor', 'roll' or 'timeout'.
    t : float
        Time of the event, s (absolute).
    state : ndarray (9,)
        [p (m), v (m/s), w (rad/s)] at the event; for a bounce just before contact.
    after : ndarray (9,) or None
        For a bounce (or roll), the state just after the rebound (eqs. 1-6).
    """

    __slots__ = ('kind', 't', 'state', 'after')

    def __init__(self, kind, t, state, after=None):
        self.kind, self.t, self.state, self.after = kind, t, state, after

    def __repr__(self):
        return f'Event({self.kind!r}, t={self.t:.4f}, p={np.round(self.state[:3], 4)})'


def rollout(state, params, t0=0.0, t_max=3.0, plane_x=math.nan, stop_at_plane=True,
            stop_at_net=True, max_bounces=2, sample_times=None, dt=DEFAULT_STEP,
            max_events=8):
    """Integrate a ball from ``state`` at time ``t0`` until it stops.

    Parameters
    ----------
    state : array_like (9,)
        [p (m), v (m/s), w (rad/s)], table frame.
    params : ModelParams or ndarray
        The model, or its packed array.
    t0, t_max : float
        Start time and absolute time limit, s.
    plane_x : float
        x of the hitting plane, m (NaN: none).
    stop_at_plane, stop_at_net : bool
        Stop at the hitting plane's first crossing; at the net.
    max_bounces : int
        Stop after this many table bounces.
    sample_times : array_like (k,), optional
        Sorted absolute times (s) at which to return the state.
    dt : float
        RK4 step, s.
    max_events : int
        Most events kept.

    Returns
    -------
    events : list of Event
        In time order; the last one is why it stopped.
    samples : ndarray (k, 9) or None
        The states at ``sample_times`` (NaN after the stop); None without sample times.
    """
    P = params if isinstance(params, np.ndarray) else params.packed()
    s0 = np.ascontiguousarray(state, dtype=np.float64)
    sample_t = (np.empty(0) if sample_times is None
                else np.ascontiguousarray(sample_times, dtype=np.float64))
    samples = np.full((sample_t.shape[0], 9), np.nan)
    ev_kind = np.zeros(max_events, dtype=np.int64)
    ev_t = np.zeros(max_events)
    ev_s = np.zeros((max_events, 9))
    mask = (STOP_AT_PLANE if stop_at_plane else 0) | (STOP_AT_NET if stop_at_net else 0)
    n = rollout_kernel(s0, float(t0), P, float(t_max), float(dt), float(plane_x), mask,
                       int(max_bounces), sample_t, samples, ev_kind, ev_t, ev_s)
    events = []
    for i in range(n):
        kind = EVENT_NAMES[int(ev_kind[i])]
        after = None
        if kind in ('bounce', 'roll'):
            after = ev_s[i].copy()
            table_rebound_inplace(after, P)
        events.append(Event(kind, float(ev_t[i]), ev_s[i].copy(), after))
    return events, (samples if sample_times is not None else None)
