"""Prediction of an incoming ball: first bounce, hit point, landing; one state or a batch.

The robot stands at the x < 0 end of the table (MODEL.md); an incoming ball travels along -x,
should bounce once on the robot's half and then crosses the hitting plane x = hit_plane_x.
:func:`predict` integrates flight and rebounds with the compiled event-driven integrator
(:func:`tt_prediction.integrate.rollout_kernel`) and classifies the events into a status:

    ok             one bounce on the robot's half, then the hitting plane is crossed
    net            the ball hits the net before any bounce
    no_bounce      the hitting plane is crossed before any bounce
    miss           the ball falls past the table (floor) without touching it
    wrong_half     the first table contact is on the opponent's half (x > 0)
    double_bounce  a second bounce on the robot's half before the hitting plane
    no_hit         after the bounce the ball never reaches the plane (rolls, falls beside the
                   table, goes back over or into the net)
    timeout        nothing of the above within T_MAX seconds
    invalid        bad input (NaN or infinite, below the table, at rest, absurd speed or spin)

:func:`predict_landing` does the same for a ball leaving the racket (first table contact,
expected on the opponent's half, with the net checked). :func:`predict_batch` runs many
states in one compiled call (numba ``prange``). The classification is compiled too, so the
single and batch paths share one implementation.
"""

import dataclasses
import math

from numba import njit, prange
import numpy as np

from .integrate import (
    EVENT_BOUNCE,
    EVENT_FLOOR,
    EVENT_NET,
    EVENT_PLANE,
    EVENT_ROLL,
    EVENT_TIMEOUT,
    STOP_AT_NET,
    STOP_AT_PLANE,
    rollout_kernel,
)
from .params import I_RADIUS, ModelParams
from .table import HALF_LENGTH, HALF_WIDTH, NET_HEIGHT, TABLE_HEIGHT, zone_of

STATUSES = ('ok', 'net', 'no_bounce', 'miss', 'wrong_half', 'double_bounce', 'no_hit',
            'timeout', 'invalid')
(OK, NET, NO_BOUNCE, MISS, WRONG_HALF, DOUBLE_BOUNCE, NO_HIT, TIMEOUT, INVALID) = range(9)

DEFAULT_HIT_PLANE_X = -1.5
"""Default hitting plane x = -1.50 m (DESIGN.md, tt-predict), 13 cm behind the end line."""
T_MAX = 3.0
"""Longest flight integrated, s (a slow lob from the far end takes about 1.5 s)."""
STEP = 0.01
"""RK4 step of the prediction, s. Twice the integrator's default: against scipy's DOP853 at
rtol 1e-9 the hit point stays within 1e-8 m (5 ms: 2e-9 m, 20 ms: 5e-8 m; the target is
1e-4 m), at 13 us instead of 22 us a flight."""
MAX_SPEED = 40.0
"""Faster than this is not a table-tennis ball (smashes reach about 30 m/s), m/s."""
MAX_SPIN = 1500.0
"""More spin than this is not a table-tennis ball (about 14,000 rpm; 150 rps is a lot), rad/s."""
MIN_SPEED = 1e-3
"""Slower than this the ball is taken to be at rest (no flight to predict), m/s."""
BELOW_TOLERANCE = 2e-3
"""A ball centre up to this far under the contact height z = r over the table is taken as
touching it (measurement noise); further down it is inside or under the table, m."""

# Layout of the compiled kernels' output row.
_N_OUT = 26
(_O_STATUS, _O_BOUNCE_OK, _O_BOUNCE_T, _O_BOUNCE_P, _O_BOUNCE_ZONE, _O_BOUNCE_HALF,
 _O_HIT_OK, _O_HIT_T, _O_HIT_P, _O_HIT_V, _O_HIT_W, _O_STOP_KIND, _O_STOP_T, _O_STOP_P,
 _O_NET_OK, _O_NET_Z) = (0, 1, 2, 3, 6, 7, 8, 9, 10, 13, 16, 19, 20, 21, 24, 25)
_MAX_EVENTS = 8

_zone_nb = njit(cache=True, nogil=True)(zone_of)
_NOMINAL = ModelParams()


@dataclasses.dataclass
class Contact:
    """A table contact: time t (s, absolute), ball centre p (3,) (m, z = r), area per the
    9-area criterion (zone 1..9, 0 off the table) and half (+1 opponent, -1 robot)."""

    t: float
    p: np.ndarray
    zone: int
    half: int

    def to_dict(self):
        return {'t': self.t, 'p': self.p.tolist(), 'zone': self.zone, 'half': self.half}


@dataclasses.dataclass
class Hit:
    """Crossing of the hitting plane: time t (s, absolute), ball centre p (m), velocity v (m/s)
    and spin w (rad/s), table frame."""

    t: float
    p: np.ndarray
    v: np.ndarray
    w: np.ndarray

    @property
    def state(self):
        """(9,) state (p, v, w) of the ball at the crossing, as a solver takes it."""
        return np.concatenate([self.p, self.v, self.w])

    def to_dict(self):
        return {'t': self.t, 'p': self.p.tolist(), 'v': self.v.tolist(), 'w': self.w.tolist()}


@dataclasses.dataclass
class Prediction:
    """Outcome of :func:`predict` or :func:`predict_landing`.

    ``status`` (one of STATUSES) and a human-readable ``reason``; ``bounce`` the first table
    contact (any half) or None; ``hit`` the hitting-plane crossing after one bounce on the
    robot's half (status ok) or None; ``landing`` the first table contact (for an incoming
    ball the bounce itself; for a ball leaving the racket its landing) or None;
    ``net_clearance`` the height of the ball's bottom above the net's top where it crosses
    x = 0 (m, NaN when it does not cross; :func:`predict_landing` only); ``path`` (k, 3)
    ball centres at the requested sample times until the flight stops, or None.
    """

    status: str
    bounce: Contact = None
    hit: Hit = None
    landing: Contact = None
    net_clearance: float = math.nan
    path: np.ndarray = None
    explanation: str = dataclasses.field(default='', repr=False)
    _why: tuple = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def reason(self):
        """Why this status, in words (formatted on first use: it costs more than the rest)."""
        if not self.explanation and self._why is not None:
            self.explanation = _reason(*self._why)
        return self.explanation

    @property
    def ok(self):
        return self.status == 'ok'

    def to_dict(self):
        """Plain JSON-ready dict (the tt-predict output line)."""
        out = {'status': self.status, 'reason': self.reason}
        for name in ('bounce', 'hit', 'landing'):
            value = getattr(self, name)
            out[name] = None if value is None else value.to_dict()
        return out


# ----------------------------------------------------------------------------------------------
# Input validation


def check_state(state, radius=0.020):
    """Reason why ``state`` (9,) = [p, v, w] is not a ball to predict, or '' when it is one."""
    try:
        values = state.tolist() if isinstance(state, np.ndarray) else [float(c) for c in state]
        x, y, z, vx, vy, vz, wx, wy, wz = values
    except (TypeError, ValueError):
        return f'state must be 9 numbers [p, v, w], got {state!r}'
    if not math.isfinite(math.fsum(abs(c) for c in values)):
        for i, name in enumerate(('position', 'velocity', 'spin')):
            if not all(math.isfinite(c) for c in values[3 * i:3 * i + 3]):
                return f'{name} is not finite: {values[3 * i:3 * i + 3]}'
    over_table = abs(x) <= HALF_LENGTH and abs(y) <= HALF_WIDTH
    if over_table and z < radius - BELOW_TOLERANCE:
        return f'ball centre z = {z:.4f} m is below the table surface (contact at z = {radius})'
    if z < radius - TABLE_HEIGHT:
        return f'ball centre z = {z:.4f} m is below the floor'
    speed = math.sqrt(vx * vx + vy * vy + vz * vz)
    if speed < MIN_SPEED:
        return f'ball is at rest (speed {speed:.2g} m/s): nothing to predict'
    if speed > MAX_SPEED:
        return f'speed {speed:.1f} m/s is above {MAX_SPEED} m/s: not a table-tennis ball'
    spin = math.sqrt(wx * wx + wy * wy + wz * wz)
    if spin > MAX_SPIN:
        return f'spin {spin:.0f} rad/s is above {MAX_SPIN} rad/s: not a table-tennis ball'
    return ''


def _valid_mask(states, radius):
    """Vectorised :func:`check_state` (True where valid) for an (N, 9) array."""
    finite = np.all(np.isfinite(states), axis=1)
    s = np.where(finite[:, None], states, 0.0)
    over = (np.abs(s[:, 0]) <= HALF_LENGTH) & (np.abs(s[:, 1]) <= HALF_WIDTH)
    below = (over & (s[:, 2] < radius - BELOW_TOLERANCE)) | (s[:, 2] < radius - TABLE_HEIGHT)
    speed = np.linalg.norm(s[:, 3:6], axis=1)
    spin = np.linalg.norm(s[:, 6:9], axis=1)
    return finite & ~below & (speed >= MIN_SPEED) & (speed <= MAX_SPEED) & (spin <= MAX_SPIN)


# ----------------------------------------------------------------------------------------------
# Compiled kernels


@njit(cache=True, nogil=True)
def _record_contact(out, t, s):
    zone, half = _zone_nb(s[0], s[1])
    out[_O_BOUNCE_OK] = 1.0
    out[_O_BOUNCE_T] = t
    for i in range(3):
        out[_O_BOUNCE_P + i] = s[i]
    out[_O_BOUNCE_ZONE] = zone
    out[_O_BOUNCE_HALF] = half


@njit(cache=True, nogil=True)
def predict_kernel(s0, t0, P, plane_x, bounced, sample_t, samples, out):
    """Predict one incoming ball into ``out`` (_N_OUT,); see the module docstring.

    s0 (9,) state at absolute time t0 (s); P packed parameters; plane_x hitting plane (m);
    bounced: the ball has already bounced once on the robot's half (so the plane crossing
    without a further bounce is a hit); sample_t, samples as for rollout_kernel.
    """
    for i in range(_N_OUT):
        out[i] = 0.0
    out[_O_NET_Z] = math.nan
    ev_kind = np.zeros(_MAX_EVENTS, dtype=np.int64)
    ev_t = np.zeros(_MAX_EVENTS)
    ev_s = np.zeros((_MAX_EVENTS, 9))
    max_bounces = 1 if bounced else 2
    n = rollout_kernel(s0, t0, P, t0 + T_MAX, STEP, plane_x,
                       STOP_AT_PLANE | STOP_AT_NET, max_bounces, sample_t, samples,
                       ev_kind, ev_t, ev_s)
    robot_bounces = 1 if bounced else 0
    contacts = 0
    status = TIMEOUT
    last = 0
    for i in range(n):
        last = i
        kind = ev_kind[i]
        if kind == EVENT_BOUNCE or kind == EVENT_ROLL:
            if contacts == 0 and not bounced:
                _record_contact(out, ev_t[i], ev_s[i])
            contacts += 1
            if ev_s[i, 0] > 0.0:
                # First contact on the opponent's half, or back over the net after the bounce.
                status = NO_HIT if robot_bounces > 0 else WRONG_HALF
                break
            robot_bounces += 1
            if robot_bounces >= 2:
                status = DOUBLE_BOUNCE
                break
            if kind == EVENT_ROLL:
                status = NO_HIT
                break
        elif kind == EVENT_PLANE:
            if robot_bounces == 1:
                status = OK
                out[_O_HIT_OK] = 1.0
                out[_O_HIT_T] = ev_t[i]
                for j in range(3):
                    out[_O_HIT_P + j] = ev_s[i, j]
                    out[_O_HIT_V + j] = ev_s[i, 3 + j]
                    out[_O_HIT_W + j] = ev_s[i, 6 + j]
                out[_O_HIT_P] = plane_x     # located to 1e-12 m: the plane by definition
            else:
                status = NO_BOUNCE
            break
        elif kind == EVENT_NET:
            status = NO_HIT if robot_bounces > 0 else NET
            break
        elif kind == EVENT_FLOOR:
            status = NO_HIT if robot_bounces > 0 else MISS
            break
        elif kind == EVENT_TIMEOUT:
            status = TIMEOUT
            break
    out[_O_STATUS] = status
    if n > 0:
        out[_O_STOP_KIND] = ev_kind[last]
        out[_O_STOP_T] = ev_t[last]
        for j in range(3):
            out[_O_STOP_P + j] = ev_s[last, j]


@njit(cache=True, nogil=True)
def landing_kernel(s0, t0, P, out):
    """First table contact of a ball leaving the racket into ``out`` (_N_OUT,).

    Two legs: up to the net plane x = 0 (stopping on the net, recording the clearance), then
    on to the first contact. ok when that contact is on the opponent's half (x > 0).
    """
    for i in range(_N_OUT):
        out[i] = 0.0
    out[_O_NET_Z] = math.nan
    r = P[I_RADIUS]
    ev_kind = np.zeros(_MAX_EVENTS, dtype=np.int64)
    ev_t = np.zeros(_MAX_EVENTS)
    ev_s = np.zeros((_MAX_EVENTS, 9))
    no_t = np.empty(0)
    no_s = np.empty((0, 9))
    t_end = t0 + T_MAX
    n = rollout_kernel(s0, t0, P, t_end, STEP, 0.0, STOP_AT_PLANE | STOP_AT_NET, 1,
                       no_t, no_s, ev_kind, ev_t, ev_s)
    kind = ev_kind[n - 1]
    t = ev_t[n - 1]
    if kind == EVENT_PLANE:
        out[_O_NET_OK] = 1.0
        out[_O_NET_Z] = ev_s[n - 1, 2] - r - NET_HEIGHT
        s1 = ev_s[n - 1].copy()
        n = rollout_kernel(s1, t, P, t_end, STEP, math.nan, STOP_AT_NET, 1,
                           no_t, no_s, ev_kind, ev_t, ev_s)
        kind = ev_kind[n - 1]
        t = ev_t[n - 1]
    if kind == EVENT_BOUNCE or kind == EVENT_ROLL:
        _record_contact(out, t, ev_s[n - 1])
        status = OK if ev_s[n - 1, 0] > 0.0 else WRONG_HALF
    elif kind == EVENT_NET:
        status = NET
    elif kind == EVENT_FLOOR:
        status = MISS
    else:
        status = TIMEOUT
    out[_O_STATUS] = status
    out[_O_STOP_KIND] = kind
    out[_O_STOP_T] = t
    for j in range(3):
        out[_O_STOP_P + j] = ev_s[n - 1, j]


@njit(cache=True, nogil=True)
def _batch_row(states, t0, valid, P, plane_x, bounced, outgoing, out, i):
    if not valid[i]:
        out[i, _O_STATUS] = INVALID
        out[i, _O_NET_Z] = math.nan
    elif outgoing:
        landing_kernel(states[i], t0[i], P, out[i])
    else:
        predict_kernel(states[i], t0[i], P, plane_x, bounced, np.empty(0), np.empty((0, 9)),
                       out[i])


# Two functions, not one compiled twice: numba's cache tells them apart by name only.
@njit(cache=True, nogil=True)
def _batch_serial(states, t0, valid, P, plane_x, bounced, outgoing, out):
    for i in range(states.shape[0]):
        _batch_row(states, t0, valid, P, plane_x, bounced, outgoing, out, i)


@njit(cache=True, nogil=True, parallel=True)
def _batch_parallel(states, t0, valid, P, plane_x, bounced, outgoing, out):
    for i in prange(states.shape[0]):
        _batch_row(states, t0, valid, P, plane_x, bounced, outgoing, out, i)


PARALLEL_MIN = 256
"""Batches at least this large run on all cores (prange); smaller ones on the caller's."""


# ----------------------------------------------------------------------------------------------
# Python API


_PACKED_CACHE = [None, None, None]     # params object, its field values, packed array
_NO_T = np.empty(0)                    # no sample times
_NO_S = np.empty((0, 9))


def _packed(params):
    """Packed array of ``params`` (ModelParams, packed array or None = nominal), cached for
    the last ModelParams object as long as its field values do not change."""
    if isinstance(params, np.ndarray):
        return params
    if params is None:
        params = _NOMINAL
    values = tuple(params.__dict__.values())
    if _PACKED_CACHE[0] is not params or _PACKED_CACHE[1] != values:
        _PACKED_CACHE[:] = [params, values, params.packed()]
    return _PACKED_CACHE[2]


def _touching(states, valid, radius):
    """States (N, 9) with a centre less than BELOW_TOLERANCE under the contact height over the
    table lifted to z = r (touching it), so that the integrator sees the contact; a copy only
    when one is lifted."""
    low = (valid & (states[:, 2] < radius) & (np.abs(states[:, 0]) <= HALF_LENGTH)
           & (np.abs(states[:, 1]) <= HALF_WIDTH))
    if np.any(low):
        states = states.copy()
        states[low, 2] = radius
    return states


def _lifted(state9, radius):
    """A float64 copy of one (valid) state, lifted like :func:`_touching`."""
    s0 = np.array(state9, dtype=np.float64)
    if s0[2] < radius and abs(s0[0]) <= HALF_LENGTH and abs(s0[1]) <= HALF_WIDTH:
        s0[2] = radius
    return s0


def _contact(row):
    if not row[_O_BOUNCE_OK]:
        return None
    return Contact(float(row[_O_BOUNCE_T]), row[_O_BOUNCE_P:_O_BOUNCE_P + 3].copy(),
                   int(row[_O_BOUNCE_ZONE]), int(row[_O_BOUNCE_HALF]))


def _hit(row):
    if not row[_O_HIT_OK]:
        return None
    return Hit(float(row[_O_HIT_T]), row[_O_HIT_P:_O_HIT_P + 3].copy(),
               row[_O_HIT_V:_O_HIT_V + 3].copy(), row[_O_HIT_W:_O_HIT_W + 3].copy())


def _fmt(p):
    return '(' + ', '.join(f'{c:.3f}' for c in p) + ')'


def _reason(status, row, bounce, plane_x, outgoing):
    stop_p = _fmt(row[_O_STOP_P:_O_STOP_P + 3])
    stop_t = row[_O_STOP_T]
    if status == OK:
        if outgoing:
            return f"lands in zone {bounce.zone} of the opponent's half at t = {bounce.t:.3f} s"
        where = 'after the bounce' if bounce is None else (
            f"after a bounce in zone {bounce.zone} of the robot's half")
        return f'crosses x = {plane_x:.3f} at t = {row[_O_HIT_T]:.3f} s {where}'
    if status == NET:
        return f'hits the net at {stop_p}, t = {stop_t:.3f} s'
    if status == NO_BOUNCE:
        return (f'crosses the hitting plane x = {plane_x:.3f} without a bounce'
                f' at t = {stop_t:.3f} s')
    if status == MISS:
        return f'falls past the table to the floor at {stop_p}'
    if status == WRONG_HALF:
        side = 'robot' if outgoing else 'opponent'
        return f"first table contact at {_fmt(bounce.p)} is on the {side}'s half"
    if status == DOUBLE_BOUNCE:
        return f"bounces a second time on the robot's half at {stop_p} before the plane"
    if status == NO_HIT:
        kind = int(row[_O_STOP_KIND])
        what = {EVENT_ROLL: 'rolls on the table', EVENT_FLOOR: 'falls beside the table',
                EVENT_NET: 'goes back into the net',
                EVENT_BOUNCE: "goes back to the opponent's half"}.get(kind, 'stops')
        return f'after the bounce the ball {what} at {stop_p} before the plane'
    if status == TIMEOUT:
        return f'no outcome within {T_MAX:.1f} s of flight'
    return 'invalid input'


def _to_prediction(row, plane_x, outgoing=False, path=None):
    status = int(row[_O_STATUS])
    contact = _contact(row)
    return Prediction(status=STATUSES[status], bounce=None if outgoing else contact,
                      hit=_hit(row), landing=contact, net_clearance=float(row[_O_NET_Z]),
                      path=path, _why=(status, row, contact, plane_x, outgoing))


def predict(state9, params=None, t0=0.0, hit_plane_x=DEFAULT_HIT_PLANE_X, bounced=False,
            path_dt=None):
    """Predict the flight of an incoming ball from ``state9`` = [p, v, w] at time ``t0``.

    ``state9`` in the table frame (m, m/s, rad/s), ``t0`` absolute time (s, all output times
    are absolute in the same clock), ``params`` a ModelParams (or packed array; None = nominal),
    ``hit_plane_x`` the hitting plane (m, robot's side). ``bounced``: the ball has already
    bounced on the robot's half (tracking after the bounce), so crossing the plane without
    another bounce is a hit. ``path_dt`` (s): also return ``path``, the ball centres every
    ``path_dt`` from t0 until the flight stops (rebounds included).
    Never raises for bad states: returns status 'invalid' with the reason.
    """
    P = _packed(params)
    reason = check_state(state9, P[I_RADIUS])
    if reason:
        return Prediction(status='invalid', explanation=reason)
    if not math.isfinite(hit_plane_x):
        return Prediction(status='invalid',
                          explanation=f'hit_plane_x is not finite: {hit_plane_x}')
    s0 = _lifted(state9, P[I_RADIUS])
    if path_dt:
        sample_t = float(t0) + np.arange(0.0, T_MAX, float(path_dt))
        samples = np.full((sample_t.shape[0], 9), np.nan)
    else:
        sample_t, samples = _NO_T, _NO_S
    out = np.empty(_N_OUT)
    predict_kernel(s0, float(t0), P, float(hit_plane_x), bool(bounced), sample_t, samples, out)
    path = None
    if path_dt:
        reached = np.isfinite(samples[:, 0])
        path = samples[reached, :3]
    return _to_prediction(out, hit_plane_x, path=path)


def predict_landing(state9, params=None, t0=0.0):
    """First table contact of a ball leaving the racket, from ``state9`` at time ``t0``.

    Status ok when it lands on the opponent's half (``landing`` its contact, zone and half),
    net when it hits the net, wrong_half when it lands on the robot's half, miss when it
    misses the table, invalid for bad input. ``net_clearance`` is the height of the ball's
    bottom above the net's top where it crosses x = 0 (m).
    """
    P = _packed(params)
    reason = check_state(state9, P[I_RADIUS])
    if reason:
        return Prediction(status='invalid', explanation=reason)
    s0 = _lifted(state9, P[I_RADIUS])
    out = np.empty(_N_OUT)
    landing_kernel(s0, float(t0), P, out)
    return _to_prediction(out, math.nan, outgoing=True)


@dataclasses.dataclass
class BatchPrediction:
    """Arrays (first axis N) of :func:`predict_batch`.

    status (N,) int codes into STATUSES; bounce_t (N,) s (NaN without contact), bounce_p
    (N, 3) m, bounce_zone (N,) 0..9, bounce_half (N,) -1/0/+1; hit_t (N,) s (NaN without a hit),
    hit_p, hit_v, hit_w (N, 3); net_clearance (N,) m (outgoing only).
    """

    status: np.ndarray
    bounce_t: np.ndarray
    bounce_p: np.ndarray
    bounce_zone: np.ndarray
    bounce_half: np.ndarray
    hit_t: np.ndarray
    hit_p: np.ndarray
    hit_v: np.ndarray
    hit_w: np.ndarray
    net_clearance: np.ndarray

    def status_names(self):
        return [STATUSES[s] for s in self.status]


def _batch_rows(states, P, t0, hit_plane_x, bounced, outgoing, parallel, validate):
    """The compiled kernels' output rows (N, _N_OUT) for N states (see predict_batch)."""
    states = np.ascontiguousarray(states, dtype=np.float64)
    if states.ndim != 2 or states.shape[1] != 9:
        raise ValueError(f'states must be an (N, 9) array, got shape {states.shape}')
    n = states.shape[0]
    times = np.ascontiguousarray(np.broadcast_to(np.asarray(t0, dtype=np.float64), (n,)))
    if not outgoing and not math.isfinite(hit_plane_x):
        raise ValueError(f'hit_plane_x is not finite: {hit_plane_x}')
    if isinstance(validate, np.ndarray):
        valid = validate                # the caller's own mask (True where valid)
    elif validate:
        valid = _valid_mask(states, P[I_RADIUS])
    else:
        valid = np.all(np.isfinite(states), axis=1)
    states = _touching(states, valid, P[I_RADIUS])
    out = np.zeros((n, _N_OUT))
    use_parallel = n >= PARALLEL_MIN if parallel is None else parallel
    kernel = _batch_parallel if use_parallel else _batch_serial
    kernel(states, times, valid, P, float(hit_plane_x), bool(bounced), bool(outgoing), out)
    return out


def predict_many(states, params=None, t0=0.0, hit_plane_x=DEFAULT_HIT_PLANE_X, parallel=None,
                 checked=False):
    """:func:`predict` for N incoming balls through the batch kernel: a list of N Predictions,
    each the same, to the last bit, as ``predict(states[i], params, t0[i], hit_plane_x)``
    (same compiled kernel, same inputs), at the batch's cost (tt-predict on many lines).

    ``states`` (N, 9) [p, v, w] in the table frame (m, m/s, rad/s); ``t0`` a scalar or (N,)
    absolute times (s); ``hit_plane_x`` (m). A row that is not a ball to predict gets status
    'invalid' with :func:`check_state`'s reason. ``checked``: the caller has already found
    every row valid with :func:`check_state` (tt-predict does, line by line), so it is not
    checked again.
    """
    P = _packed(params)
    states = np.asarray(states, dtype=np.float64)
    if not math.isfinite(hit_plane_x):
        return [Prediction(status='invalid',
                           explanation=f'hit_plane_x is not finite: {hit_plane_x}')
                for _ in range(len(states))]
    # check_state row by row, as predict does (the vectorised mask may differ in the last bit
    # at a limit such as MAX_SPEED).
    reasons = [''] * len(states) if checked else [check_state(s, P[I_RADIUS]) for s in states]
    valid = np.array([not r for r in reasons], dtype=bool)
    rows = _batch_rows(states, P, t0, hit_plane_x, False, False, parallel, valid)
    return [_to_prediction(row, hit_plane_x) if ok
            else Prediction(status='invalid', explanation=reason)
            for row, ok, reason in zip(rows, valid, reasons, strict=True)]


def predict_batch(states, params=None, t0=0.0, hit_plane_x=DEFAULT_HIT_PLANE_X,
                  bounced=False, outgoing=False, parallel=None, validate=True):
    """:func:`predict` (or :func:`predict_landing` with ``outgoing``) for N states at once.

    ``states`` (N, 9), ``t0`` a scalar or (N,) times (s). Invalid rows get status 'invalid'
    (use :func:`check_state` for the reason); with ``validate`` False only non-finite rows are
    (for callers that build the states themselves, e.g. sigma points). ``parallel``: None =
    on all cores from PARALLEL_MIN states on. Returns a :class:`BatchPrediction`.
    """
    out = _batch_rows(states, _packed(params), t0, hit_plane_x, bounced, outgoing, parallel,
                      validate)
    n = out.shape[0]
    has_b = out[:, _O_BOUNCE_OK] > 0.0
    has_h = out[:, _O_HIT_OK] > 0.0
    nan3 = np.full((n, 3), np.nan)
    return BatchPrediction(
        status=out[:, _O_STATUS].astype(np.int64),
        bounce_t=np.where(has_b, out[:, _O_BOUNCE_T], np.nan),
        bounce_p=np.where(has_b[:, None], out[:, _O_BOUNCE_P:_O_BOUNCE_P + 3], nan3),
        bounce_zone=out[:, _O_BOUNCE_ZONE].astype(np.int64),
        bounce_half=out[:, _O_BOUNCE_HALF].astype(np.int64),
        hit_t=np.where(has_h, out[:, _O_HIT_T], np.nan),
        hit_p=np.where(has_h[:, None], out[:, _O_HIT_P:_O_HIT_P + 3], nan3),
        hit_v=np.where(has_h[:, None], out[:, _O_HIT_V:_O_HIT_V + 3], nan3),
        hit_w=np.where(has_h[:, None], out[:, _O_HIT_W:_O_HIT_W + 3], nan3),
        net_clearance=out[:, _O_NET_Z].copy(),
    )
