"""Prediction of an incoming ball: first bounce, hit point, landing; one state or a batch.

The robot stands at the x < 0 end of the table (MODEL.md); an incoming ball travels along -x,
should bounce once on the robot's half and then crosses the hitting plane x = hit_plane_x.
:func:`predict` flies the ball leg by leg with this module's compiled flight kernel
(:func:`flight_kernel`: eq. 8 to the first contact, the table and net as solid bodies; the
rebound of eqs. 1-6 at each contact with the top, :func:`predict_kernel`) and classifies where
it stops into a status:

    ok             one bounce on the robot's half, then the hitting plane is crossed
    net            the ball hits the net (over the table) before any bounce
    no_bounce      the hitting plane is crossed before any bounce
    miss           the ball falls past the table (floor) without touching it
    wrong_half     the first table contact is on the opponent's half (x > 0)
    double_bounce  a second bounce on the robot's half before the hitting plane
    no_hit         after the bounce the ball never reaches the plane (rolls, falls beside the
                   table, goes back over or into the net)
    table_edge     the ball meets an end or side face of the table top, an edge or its
                   underside (out of play)
    net_post       the ball meets the net beyond a side line or a post (out of play)
    timeout        nothing of the above within T_MAX seconds
    invalid        bad input (NaN or infinite, below the table, at rest, absurd speed or spin)

The optional path (``path_dt``) is sampled with :func:`tt_prediction.integrate.rollout`.

:func:`predict_landing` does the same for a ball leaving the racket (first table contact,
expected on the opponent's half, with the net checked: :func:`landing_kernel` on
:func:`landing_flight`). :func:`predict_batch` runs many states in one compiled call (numba
``prange``). The classification is compiled too, so the single and batch paths share one
implementation.
"""

import dataclasses
import math

from numba import njit, prange
import numpy as np

from .integrate import ROLL_SPEED, _locate, rk4_step, rollout
from .model import table_rebound_inplace
from .params import I_RADIUS, ModelParams
from .table import HALF_LENGTH, HALF_WIDTH, NET_HALF_WIDTH, NET_HEIGHT, TABLE_HEIGHT, zone_of

STATUSES = ('ok', 'net', 'no_bounce', 'miss', 'wrong_half', 'double_bounce', 'no_hit',
            'timeout', 'invalid', 'table_edge', 'net_post')
(OK, NET, NO_BOUNCE, MISS, WRONG_HALF, DOUBLE_BOUNCE, NO_HIT, TIMEOUT, INVALID, TABLE_EDGE,
 NET_POST) = range(11)

DEFAULT_HIT_PLANE_X = -1.5
"""Default hitting plane x = -1.50 m (DESIGN.md, tt-predict), 13 cm behind the end line."""
HIT_PLANE_X_RANGE = (-3.0, 0.0)
"""The hitting planes the tools and the prediction node accept: x on the robot's side, m."""
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
_N_OUT = 27
_O_N_PATH = 26      # rows of the post-bounce path written (predict_kernel's samples)
(_O_STATUS, _O_BOUNCE_OK, _O_BOUNCE_T, _O_BOUNCE_P, _O_BOUNCE_ZONE, _O_BOUNCE_HALF,
 _O_HIT_OK, _O_HIT_T, _O_HIT_P, _O_HIT_V, _O_HIT_W, _O_STOP_KIND, _O_STOP_T, _O_STOP_P,
 _O_NET_OK, _O_NET_Z) = (0, 1, 2, 3, 6, 7, 8, 9, 10, 13, 16, 19, 20, 21, 24, 25)

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
    ball centres at the requested sample times until the flight stops, or None;
    ``hit_path`` (k, 10) rows [t, p, v, w] after the bounce on the robot's half (predict with
    hit_path only); ``stop_t`` the time the outcome is met (the contact, crossing or stop
    that decided the status; for ``double_bounce`` the second bounce), s (NaN: invalid).
    """

    status: str
    bounce: Contact = None
    hit: Hit = None
    landing: Contact = None
    net_clearance: float = math.nan
    path: np.ndarray = None
    hit_path: np.ndarray = None
    stop_t: float = dataclasses.field(default=math.nan, compare=False)
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
    if not math.isfinite(math.fsum(map(abs, values))):
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
# The flight kernel: one flight leg to its first contact (every flight of tt's prediction and
# strike)

TOP_THICKNESS = 0.03
"""Depth of the table top's end and side faces, m (MODEL.md: z from -0.03 to 0)."""
CONTACT_KINDS = ('none', 'top', 'table_edge', 'net', 'net_post', 'floor', 'plane', 'timeout',
                 'off_table')
(CONTACT_NONE, CONTACT_TOP, CONTACT_EDGE, CONTACT_NET, CONTACT_POST, CONTACT_FLOOR,
 CONTACT_PLANE, CONTACT_TIMEOUT, CONTACT_OFF) = range(9)

# Layout of the flight kernel's result row (FLIGHT_N,).
FLIGHT_N = 18
(FL_KIND, FL_T, FL_S, FL_NET_T, FL_NET_Y, FL_NET_Z, FL_CROSS_T, FL_CROSS_X, FL_CROSS_Y,
 FL_SAMPLES) = (0, 1, 2, 11, 12, 13, 14, 15, 16, 17)
_SUBSTEPS = 8        # sub-samples per step at which the gap to the solids is checked
_BISECT = 32         # bisection iterations locating a contact in a step (h / 2^32)


@njit(cache=True, nogil=True)
def solid_gap(x, y, z, r):
    """Gap between the ball (centre x, y, z, radius r; table frame, m) and the nearest solid:
    the table top (a slab z in [-TOP_THICKNESS, 0] over the 2.74 x 1.525 m footprint) or the
    net with its posts (the plane x = 0, |y| <= NET_HALF_WIDTH, z from -TOP_THICKNESS to
    NET_HEIGHT). MODEL.md, "Frames and the table".

    Returns ``(gap, kind)``: gap in m (<= 0: touching or inside), kind the CONTACT_* of that
    solid at its nearest point: top (the playing surface, from above), table_edge (an end or
    side face, an edge, the underside), net (the net over the table) or net_post (the net
    beyond a side line, or a post).
    """
    ax = abs(x)
    ay = abs(y)
    dx = ax - HALF_LENGTH if ax > HALF_LENGTH else 0.0
    dy = ay - HALF_WIDTH if ay > HALF_WIDTH else 0.0
    if z > 0.0:
        dz = z
    elif z < -TOP_THICKNESS:
        dz = -TOP_THICKNESS - z
    else:
        dz = 0.0
    gap = math.sqrt(dx * dx + dy * dy + dz * dz) - r
    kind = CONTACT_TOP if (dx == 0.0 and dy == 0.0 and z > 0.0) else CONTACT_EDGE
    ny = ay - NET_HALF_WIDTH if ay > NET_HALF_WIDTH else 0.0
    if z > NET_HEIGHT:
        nz = z - NET_HEIGHT
    elif z < -TOP_THICKNESS:
        nz = -TOP_THICKNESS - z
    else:
        nz = 0.0
    gap_net = math.sqrt(ax * ax + ny * ny + nz * nz) - r
    if gap_net < gap:
        gap = gap_net
        kind = CONTACT_NET if ay <= HALF_WIDTH else CONTACT_POST
    return gap, kind


@njit(cache=True, nogil=True)
def hermite_position(s, s1, h, u, i):
    """Coordinate i of the cubic Hermite position between states s and s1 (step h) at u: the
    cubic through both positions and velocities (u in [0, 1])."""
    u2 = u * u
    u3 = u2 * u
    return ((2.0 * u3 - 3.0 * u2 + 1.0) * s[i] + (u3 - 2.0 * u2 + u) * h * s[3 + i]
            + (3.0 * u2 - 2.0 * u3) * s1[i] + (u3 - u2) * h * s1[3 + i])


@njit(cache=True, nogil=True)
def _crossing(s, s1, h, axis, level, down, P, work):
    """Time in (0, h] at which position coordinate ``axis`` crosses ``level`` in the step from
    s to s1 (only downwards if ``down``), the state there in work[1]; inf when it does not."""
    g0 = s[axis] - level
    g1 = s1[axis] - level
    if down:
        crosses = g0 >= 0.0 and g1 < 0.0
    else:
        crosses = (g0 > 0.0) != (g1 > 0.0) or (g1 == 0.0 and g0 != 0.0)
    if not crosses:
        return math.inf
    return _locate(s, h, g0, g1, axis, level, P, work[1], work[3], work[4], work[5], work[6],
                   work[2])


_EVENT_TOLERANCE = 1e-9   # m: a gap this small at a located crossing is a contact there


@njit(cache=True, nogil=True)
def _insert(at_u, at_g, at_k, n, u, g, kg):
    """Put (u, g, kg) among the first n candidates in time order; returns n + 1."""
    i = n
    while i > 0 and at_u[i - 1] > u:
        at_u[i], at_g[i], at_k[i] = at_u[i - 1], at_g[i - 1], at_k[i - 1]
        i -= 1
    at_u[i], at_g[i], at_k[i] = u, g, kg
    return n + 1


N_CANDIDATES = _SUBSTEPS + 11
"""Points of a step at which flight_kernel checks the gap (:func:`_contact_candidates`)."""


@njit(cache=True, nogil=True)
def _contact_candidates(s, s1, h, r, P, work, at_u, at_g, at_k):
    """The points of the step s -> s1 (length h) at which flight_kernel checks the gap to the
    solids, in time order: u (fraction of h) into at_u, the gap (m) and CONTACT_* kind of the
    nearest solid into at_g and at_k; returns their number (at most N_CANDIDATES).

    _SUBSTEPS points on the cubic Hermite path; the located crossings of the net's plane
    x = 0, the top's outline (x = +-HALF_LENGTH, y = +-HALF_WIDTH) and, downwards, the
    contact height z = r, where a gap within _EVENT_TOLERANCE counts as touching (the
    crossing is located to 1e-12 m); and the closest approach of the step's chord to the
    thin edges, the net's top (x = 0, z = NET_HEIGHT) and the top's end and side edges
    (z = 0): a ball crossing the net descending at 20 deg is nearest its top edge away from
    x = 0, and 0.5 mm into it for 10 mm of its path, between two sub-samples.
    """
    n = 0
    for j in range(1, _SUBSTEPS + 1):
        u = j / _SUBSTEPS
        if j == _SUBSTEPS:
            g, kg = solid_gap(s1[0], s1[1], s1[2], r)
        else:
            g, kg = solid_gap(hermite_position(s, s1, h, u, 0),
                              hermite_position(s, s1, h, u, 1),
                              hermite_position(s, s1, h, u, 2), r)
        at_u[n], at_g[n], at_k[n] = u, g, kg
        n += 1
    se = work[1]
    for e in range(6):
        if e == 0:
            axis, level, down = 2, r, True
        elif e == 1:
            axis, level, down = 0, 0.0, False
        elif e < 4:
            axis, level, down = 0, HALF_LENGTH if e == 2 else -HALF_LENGTH, False
        else:
            axis, level, down = 1, HALF_WIDTH if e == 4 else -HALF_WIDTH, False
        tau = _crossing(s, s1, h, axis, level, down, P, work)
        if tau > h:
            continue
        g, kg = solid_gap(se[0], se[1], se[2], r)
        n = _insert(at_u, at_g, at_k, n, tau / h, 0.0 if g <= _EVENT_TOLERANCE else g, kg)
    for e in range(5):
        # An edge line along y (across: axis 0) or along x (across: axis 1), at a and z_e.
        if e == 0:
            across, a, z_e = 0, 0.0, NET_HEIGHT
        elif e < 3:
            across, a, z_e = 0, HALF_LENGTH if e == 1 else -HALF_LENGTH, 0.0
        else:
            across, a, z_e = 1, HALF_WIDTH if e == 3 else -HALF_WIDTH, 0.0
        d_a, d_z = s1[across] - s[across], s1[2] - s[2]
        norm = d_a * d_a + d_z * d_z
        if norm == 0.0:
            continue
        u = -((s[across] - a) * d_a + (s[2] - z_e) * d_z) / norm
        if not 0.0 < u < 1.0:
            continue
        g, kg = solid_gap(hermite_position(s, s1, h, u, 0), hermite_position(s, s1, h, u, 1),
                          hermite_position(s, s1, h, u, 2), r)
        n = _insert(at_u, at_g, at_k, n, u, g, kg)
    return n


@njit(cache=True, nogil=True)
def flight_kernel(s0, t0, P, t_end, plane_x, body, samples, res):
    """Fly a ball from (t0, s0) to its first contact; the one flight leg of tt (compiled).

    Eq. 8 with classic RK4 (tt_prediction.integrate.rk4_step) at this module's fixed step
    STEP, events located inside the step. ``body`` True: the table is a solid body
    (MODEL.md): the flight stops at the first contact with the top (CONTACT_TOP, only from
    above over the footprint), an end or side face or edge (CONTACT_EDGE), the net over the
    table (CONTACT_NET), the net beyond a side line or a post (CONTACT_POST) or the floor.
    ``body`` False (the plane model, used while searching, where the landing must vary
    smoothly): it stops where the centre first comes down through the contact height z = r,
    on the footprint (CONTACT_TOP) or beside it (CONTACT_OFF), or at the floor; the net and
    faces are ignored. Either way it also stops where the centre crosses x = plane_x
    (CONTACT_PLANE; NaN: no plane) and at t_end.

    Inputs: s0 (9,) p (m), v (m/s), w (rad/s); t0, t_end absolute (s); P packed parameters;
    samples (k, 10) receives [t, state] after each step while rows remain. Output res
    (FLIGHT_N,): FL_KIND, FL_T, FL_S..+9 the state at the stop (before any rebound; z = r
    exactly on a top contact), FL_NET_T/Y/Z where the centre first crosses x = 0 (NaN if it
    does not before the stop), FL_CROSS_T/X/Y where it first comes down through z = r (NaN if
    not), FL_SAMPLES the rows of samples written. Returns the kind.
    """
    r = P[I_RADIUS]
    dt = STEP
    s = s0.copy()
    work = np.empty((7, 9))       # one allocation: step end, event state, RK4 stages
    s1, se, tmp = work[0], work[1], work[2]
    k1, k2, k3, k4 = work[3], work[4], work[5], work[6]
    at_u = np.empty(N_CANDIDATES)    # the points of a step where the gap is checked
    at_g = np.empty(N_CANDIDATES)
    at_k = np.empty(N_CANDIDATES)
    for i in range(FLIGHT_N):
        res[i] = math.nan
    res[FL_SAMPLES] = 0.0
    n_samples = 0
    floor_z = r - TABLE_HEIGHT
    has_plane = not math.isnan(plane_x)
    t = t0
    kind = CONTACT_NONE
    tau = 0.0
    g_prev, kind_prev = solid_gap(s[0], s[1], s[2], r)
    if body and g_prev <= 1e-12:
        # Starting in contact: a ball on the top coming down bounces now, one leaving it
        # (just after a rebound) flies on; any other solid is met now.
        if kind_prev != CONTACT_TOP or s[5] < 0.0:
            kind = kind_prev
    while kind == CONTACT_NONE:
        h = dt
        if t_end - t < h:
            h = t_end - t
        if h <= 0.0:
            kind = CONTACT_TIMEOUT
            tau = 0.0
            break
        rk4_step(s, h, P, s1, k1, k2, k3, k4, tmp)
        best = math.inf
        if body:
            lo_z = min(s[2], s1[2]) - 0.01
            near = (lo_z < NET_HEIGHT + r
                    and min(s[0], s1[0]) < HALF_LENGTH + r + 0.01
                    and max(s[0], s1[0]) > -HALF_LENGTH - r - 0.01
                    and min(s[1], s1[1]) < NET_HALF_WIDTH + r + 0.01
                    and max(s[1], s1[1]) > -NET_HALF_WIDTH - r - 0.01
                    and max(s[2], s1[2]) > -TOP_THICKNESS - r - 0.01)
            # Above the surface well inside the outline and away from the net, the only solid
            # within reach is the top from above: its contact is the centre coming down
            # through z = r.
            margin = r + 0.005
            inner = (max(abs(s[0]), abs(s1[0])) <= HALF_LENGTH - margin
                     and max(abs(s[1]), abs(s1[1])) <= HALF_WIDTH - margin
                     and min(abs(s[0]), abs(s1[0])) > margin and (s[0] > 0.0) == (s1[0] > 0.0)
                     and min(s[2], s1[2]) > 0.0)
            if near and inner:
                best = _crossing(s, s1, h, 2, r, True, P, work)
                if best <= h:
                    kind = CONTACT_TOP
            elif near:
                # The gap at the step's points where it can be least (_contact_candidates).
                n_at = _contact_candidates(s, s1, h, r, P, work, at_u, at_g, at_k)
                u_prev = 0.0
                for j in range(n_at):
                    u = at_u[j]
                    if at_g[j] <= 0.0 and (g_prev > 0.0 or u > 1.0 / _SUBSTEPS):
                        lo, hi = u_prev * h, u * h
                        for _ in range(_BISECT):
                            mid = 0.5 * (lo + hi)
                            rk4_step(s, mid, P, se, k1, k2, k3, k4, tmp)
                            gm, km = solid_gap(se[0], se[1], se[2], r)
                            if gm <= 0.0:
                                hi = mid
                            else:
                                lo = mid
                        rk4_step(s, hi, P, se, k1, k2, k3, k4, tmp)
                        gm, km = solid_gap(se[0], se[1], se[2], r)
                        best = hi
                        kind = km if gm <= 0.0 else int(at_k[j])
                        break
                    u_prev = u
            if s1[2] < floor_z:
                tf = _crossing(s, s1, h, 2, floor_z, True, P, work)
                if tf < best:
                    best, kind = tf, CONTACT_FLOOR
        elif s1[2] < r:           # (the cheap tests first: most steps cross nothing)
            best = _crossing(s, s1, h, 2, r, True, P, work)
            if best <= h:
                on = abs(se[0]) <= HALF_LENGTH and abs(se[1]) <= HALF_WIDTH
                kind = CONTACT_TOP if on else CONTACT_OFF
            elif s1[2] < floor_z:
                best = _crossing(s, s1, h, 2, floor_z, True, P, work)
                if best <= h:
                    kind = CONTACT_FLOOR
        # The hitting plane crossed towards the robot (-x) only: a ball struck back from
        # behind it (its track going on) was taken to reach it, moving away, as its hit.
        if has_plane and s[0] > plane_x >= s1[0]:
            tp = _crossing(s, s1, h, 0, plane_x, False, P, work)
            if tp < best:
                best, kind = tp, CONTACT_PLANE
        if (s[0] > 0.0) != (s1[0] > 0.0) and math.isnan(res[FL_NET_T]):
            tn = _crossing(s, s1, h, 0, 0.0, False, P, work)
            if tn <= h and tn <= best:
                res[FL_NET_T] = t + tn
                res[FL_NET_Y] = se[1]
                res[FL_NET_Z] = se[2]
        if s1[2] < r <= s[2] and math.isnan(res[FL_CROSS_T]):
            tc = _crossing(s, s1, h, 2, r, True, P, work)
            if tc <= h and tc <= best:
                res[FL_CROSS_T] = t + tc
                res[FL_CROSS_X] = se[0]
                res[FL_CROSS_Y] = se[1]
        if kind != CONTACT_NONE:
            tau = best
            break
        for i in range(9):
            s[i] = s1[i]
        t += h
        g_prev, _ = solid_gap(s[0], s[1], s[2], r)
        if n_samples < samples.shape[0]:
            samples[n_samples, 0] = t
            for i in range(9):
                samples[n_samples, 1 + i] = s[i]
            n_samples += 1
    if tau > 0.0:
        rk4_step(s, tau, P, se, k1, k2, k3, k4, tmp)
        for i in range(9):
            s[i] = se[i]
        t += tau
    if kind == CONTACT_TOP:
        s[2] = r
    elif kind == CONTACT_PLANE:
        s[0] = plane_x
    res[FL_KIND] = kind
    res[FL_T] = t
    for i in range(9):
        res[FL_S + i] = s[i]
    res[FL_SAMPLES] = n_samples
    return kind


@njit(cache=True, nogil=True)
def landing_flight(s0, t0, P, body, res):
    """First contact of a ball leaving the racket: :func:`flight_kernel` without a plane, for
    T_MAX; the one landing flight of tt (:func:`landing_kernel`, the strike solver, the
    in-zone ensemble)."""
    return flight_kernel(s0, t0, P, t0 + T_MAX, math.nan, body, np.empty((0, 10)), res)


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


_STOP_ROLL = 9     # stop kind (beside the CONTACT_* kinds): the ball rolls after a bounce


@njit(cache=True, nogil=True)
def _stop(out, status, kind, t, s):
    out[_O_STATUS] = status
    out[_O_STOP_KIND] = kind
    out[_O_STOP_T] = t
    for j in range(3):
        out[_O_STOP_P + j] = s[j]


@njit(cache=True, nogil=True)
def predict_kernel(s0, t0, P, plane_x, bounced, samples, out):
    """Predict one incoming ball into ``out`` (_N_OUT,); see the module docstring.

    s0 (9,) state at absolute time t0 (s); P packed parameters; plane_x hitting plane (m);
    bounced: the ball has already bounced once on the robot's half (so the plane crossing
    without a further bounce is a hit). Flight legs of :func:`flight_kernel` with the table
    as a body, the rebound of eqs. 1-6 at each top contact. samples (k, 10) receives the
    path [t, state] of the leg after the bounce on the robot's half every STEP (the hit
    candidates), out[_O_N_PATH] its rows.
    """
    for i in range(_N_OUT):
        out[i] = 0.0
    out[_O_NET_Z] = math.nan
    res = np.empty(FLIGHT_N)
    no_samples = np.empty((0, 10))
    s = s0.copy()
    t = t0
    t_end = t0 + T_MAX
    robot_bounces = 1 if bounced else 0
    contacts = 0
    while True:
        after = robot_bounces == 1
        kind = flight_kernel(s, t, P, t_end, plane_x, True, samples if after else no_samples,
                             res)
        if after:
            out[_O_N_PATH] = res[FL_SAMPLES]
        t = res[FL_T]
        for i in range(9):
            s[i] = res[FL_S + i]
        if kind == CONTACT_TOP:
            if contacts == 0 and not bounced:
                _record_contact(out, t, s)
            contacts += 1
            if s[0] > 0.0:
                # First contact on the opponent's half, or back over the net after the bounce.
                _stop(out, NO_HIT if robot_bounces > 0 else WRONG_HALF, kind, t, s)
                return
            robot_bounces += 1
            if robot_bounces >= 2:
                _stop(out, DOUBLE_BOUNCE, kind, t, s)
                return
            table_rebound_inplace(s, P)                          # eqs. 1-6
            if s[5] < ROLL_SPEED:
                _stop(out, NO_HIT, _STOP_ROLL, t, s)
                return
        elif kind == CONTACT_PLANE:
            if robot_bounces == 1:
                out[_O_HIT_OK] = 1.0
                out[_O_HIT_T] = t
                for j in range(3):
                    out[_O_HIT_P + j] = s[j]
                    out[_O_HIT_V + j] = s[3 + j]
                    out[_O_HIT_W + j] = s[6 + j]
                out[_O_HIT_P] = plane_x     # located to 1e-12 m: the plane by definition
                _stop(out, OK, kind, t, s)
            else:
                _stop(out, NO_BOUNCE, kind, t, s)
            return
        elif kind == CONTACT_NET:
            _stop(out, NO_HIT if robot_bounces > 0 else NET, kind, t, s)
            return
        elif kind == CONTACT_POST:
            _stop(out, NET_POST, kind, t, s)
            return
        elif kind == CONTACT_EDGE:
            _stop(out, TABLE_EDGE, kind, t, s)
            return
        elif kind == CONTACT_FLOOR:
            _stop(out, NO_HIT if robot_bounces > 0 else MISS, kind, t, s)
            return
        else:
            _stop(out, TIMEOUT, kind, t, s)
            return


@njit(cache=True, nogil=True)
def landing_kernel(s0, t0, P, out):
    """First contact of a ball leaving the racket into ``out`` (_N_OUT,): :func:`landing_flight`
    with the table as a body. ok when it is the top of the opponent's half (x > 0)."""
    for i in range(_N_OUT):
        out[i] = 0.0
    out[_O_NET_Z] = math.nan
    res = np.empty(FLIGHT_N)
    kind = landing_flight(s0, t0, P, True, res)
    if not math.isnan(res[FL_NET_T]):
        out[_O_NET_OK] = 1.0
        out[_O_NET_Z] = res[FL_NET_Z] - P[I_RADIUS] - NET_HEIGHT
    s = res[FL_S:FL_S + 9]
    t = res[FL_T]
    if kind == CONTACT_TOP:
        _record_contact(out, t, s)
        status = OK if s[0] > 0.0 else WRONG_HALF
    elif kind == CONTACT_NET:
        status = NET
    elif kind == CONTACT_POST:
        status = NET_POST
    elif kind == CONTACT_EDGE:
        status = TABLE_EDGE
    elif kind == CONTACT_FLOOR:
        status = MISS
    else:
        status = TIMEOUT
    _stop(out, status, kind, t, s)


@njit(cache=True, nogil=True)
def _batch_row(states, t0, valid, P, plane_x, bounced, outgoing, out, i):
    if not valid[i]:
        out[i, _O_STATUS] = INVALID
        out[i, _O_NET_Z] = math.nan
    elif outgoing:
        landing_kernel(states[i], t0[i], P, out[i])
    else:
        predict_kernel(states[i], t0[i], P, plane_x, bounced, np.empty((0, 10)), out[i])


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


def packed_params(params):
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
        what = {_STOP_ROLL: 'rolls on the table', CONTACT_FLOOR: 'falls beside the table',
                CONTACT_NET: 'goes back into the net',
                CONTACT_TOP: "goes back to the opponent's half"}.get(kind, 'stops')
        return f'after the bounce the ball {what} at {stop_p} before the plane'
    if status == TABLE_EDGE:
        return (f"meets the table's end or side face (or an edge) at {stop_p}, "
                f't = {stop_t:.3f} s: out of play')
    if status == NET_POST:
        return (f'meets the net beyond the side line (or its post) at {stop_p}, '
                f't = {stop_t:.3f} s: out of play')
    if status == TIMEOUT:
        return f'no outcome within {T_MAX:.1f} s of flight'
    return 'invalid input'


def _to_prediction(row, plane_x, outgoing=False, path=None):
    status = int(row[_O_STATUS])
    contact = _contact(row)
    return Prediction(status=STATUSES[status], bounce=None if outgoing else contact,
                      hit=_hit(row), landing=contact, net_clearance=float(row[_O_NET_Z]),
                      path=path, stop_t=float(row[_O_STOP_T]),
                      _why=(status, row, contact, plane_x, outgoing))


_NO_SAMPLES = np.empty((0, 10))
"""The kernel's ``samples`` when no hit path is asked for (no row is written to it)."""


def predict_row(state9, P, t0, hit_plane_x, bounced, out, samples=_NO_SAMPLES):
    """What :func:`predict` computes, without the Prediction built from it: the compiled
    predictor's row (:func:`predict_kernel`, layout ``_O_*``) of ``state9`` (9,) [p, v, w]
    (m, m/s, rad/s) at ``t0`` (s) into ``out`` (_N_OUT,), the hit path into ``samples``.
    ``P`` packed parameters, ``hit_plane_x`` m, ``bounced`` as in :func:`predict`.
    Returns '' when ``out`` was filled, else why the prediction is 'invalid' (``out`` left
    as it was)."""
    reason = check_state(state9, P[I_RADIUS])
    if not reason and not math.isfinite(hit_plane_x):
        reason = f'hit_plane_x is not finite: {hit_plane_x}'
    if not reason:
        predict_kernel(_lifted(state9, P[I_RADIUS]), float(t0), P, float(hit_plane_x),
                       bool(bounced), samples, out)
    return reason


def predict(state9, params=None, t0=0.0, hit_plane_x=DEFAULT_HIT_PLANE_X, bounced=False,
            path_dt=None, hit_path=False):
    """Predict the flight of an incoming ball from ``state9`` = [p, v, w] at time ``t0``.

    ``state9`` in the table frame (m, m/s, rad/s), ``t0`` absolute time (s, all output times
    are absolute in the same clock), ``params`` a ModelParams (or packed array; None = nominal),
    ``hit_plane_x`` the hitting plane (m, robot's side). ``bounced``: the ball has already
    bounced on the robot's half (tracking after the bounce), so crossing the plane without
    another bounce is a hit. ``path_dt`` (s): also return ``path``, the ball centres every
    ``path_dt`` from t0 until the flight stops (rebounds included). ``hit_path``: also return
    ``hit_path``, (k, 10) rows [t, p, v, w] every STEP along the flight after the bounce on
    the robot's half up to its stop (the candidate hit points; empty without that bounce).
    Never raises for bad states: returns status 'invalid' with the reason.
    """
    P = packed_params(params)
    out = np.empty(_N_OUT)
    hit_rows = np.empty((int(T_MAX / STEP) + 2, 10)) if hit_path else _NO_SAMPLES
    reason = predict_row(state9, P, t0, hit_plane_x, bounced, out, hit_rows)
    if reason:
        return Prediction(status='invalid', explanation=reason)
    path = None
    if path_dt:
        s0 = _lifted(state9, P[I_RADIUS])
        # The path from the integrator's rollout (rebounds included), up to the stop.
        sample_t = float(t0) + np.arange(0.0, T_MAX, float(path_dt))
        sample_t = sample_t[sample_t <= out[_O_STOP_T]]
        _, path_rows = rollout(s0, P, t0=float(t0), t_max=float(t0) + T_MAX,
                               stop_at_plane=False, stop_at_net=False, max_bounces=3,
                               sample_times=sample_t, dt=STEP)
        path = path_rows[np.isfinite(path_rows[:, 0]), :3]
    pred = _to_prediction(out, hit_plane_x, path=path)
    if hit_path:
        pred.hit_path = hit_rows[:int(out[_O_N_PATH])].copy()
    return pred


def predict_landing(state9, params=None, t0=0.0):
    """First table contact of a ball leaving the racket, from ``state9`` at time ``t0``.

    Status ok when it lands on the opponent's half (``landing`` its contact, zone and half),
    net when it hits the net, wrong_half when it lands on the robot's half, miss when it
    misses the table, table_edge or net_post when it meets the table's face or edge or the
    net beyond a side line or a post, timeout, invalid for bad input. ``net_clearance`` is
    the height of the ball's bottom above the net's top where it crosses x = 0 (m).
    """
    P = packed_params(params)
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
    P = packed_params(params)
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
    out = _batch_rows(states, packed_params(params), t0, hit_plane_x, bounced, outgoing, parallel,
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
