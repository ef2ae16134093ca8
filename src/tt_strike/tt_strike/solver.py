"""Inverse racket solution: the racket normal and velocity that send the ball to a target.

Pure module (no rclpy). Table frame, SI units, spin in rad/s (MODEL.md).

The coupled problem racket -> rebound (eq. 7) -> flight (eq. 8) -> landing is solved on the
three components of the outgoing ball velocity ``v_out``:

1. For a trial ``v_out``, :func:`racket_for_outgoing` inverts eq. 7 in closed form for the
   racket normal ``n`` and speed ``s`` (racket velocity ``s n``, along the normal: the
   stated free-direction choice of the racket), and eq. 7 forward gives the outgoing spin.
2. The flight with drag and Magnus (``tt_prediction.ball.landing_flight``, the one flight
   kernel; its plane model while searching) gives where the ball comes down to the table's
   height and the height at which it crosses the net plane x = 0. The forward check of a
   solution flies it with the table as a body (``predict_landing``).
3. Newton's method (finite-difference Jacobian, damped) drives the three residuals
   (landing x, landing y, net clearance - ``net_clearance``) to zero, started from the
   drag-free ballistic solution through the same two points.

The free direction of the flight is the ball's clearance above the net top
(``StrikeSettings.net_clearance``): a higher clearance gives a slower, higher ball.
"""

import dataclasses
import math

from numba import njit
import numpy as np
from tt_prediction.ball import (
    CONTACT_OFF,
    CONTACT_TOP,
    FL_NET_T,
    FL_NET_Z,
    FL_S,
    FLIGHT_N,
    HALF_LENGTH,
    HALF_WIDTH,
    I_ER,
    I_GRAVITY,
    I_KP,
    I_MASS,
    I_RADIUS,
    NET_HEIGHT,
    landing_flight,
    packed_params,
    racket_rebound,
    racket_rebound_inplace,
    zone_centre,
    zone_margin,
    zone_of,
)
from tt_prediction.predict import predict_landing

from .robust import ENSEMBLE_SIZE, aim_in_zone, in_zone_probability, landing_ensemble

_NJIT = {'cache': True, 'nogil': True}

FLIGHT_T_MAX = 3.0
"""Longest flight from the racket to the table that the solver considers, s."""
FORWARD_TOLERANCE = 5e-3
"""A solution whose forward check lands further than this from the aim point is rejected, m."""


NET_CLEARANCE_RANGE = (0.02, 1.0)
"""Allowed ``net_clearance``, m: strike_node's parameter, tt-strike's option."""
MAX_RACKET_SPEED_RANGE = (0.1, 30.0)
"""Allowed racket speed limit, m/s: strike_node's parameter, tt-strike's option and a
workspace file's ``max_racket_speed`` (a smash's racket is below 30 m/s)."""


@dataclasses.dataclass
class StrikeSettings:
    """Choices and limits of the strike solver (the node's parameters of the same names)."""

    net_clearance: float = 0.20
    """Free direction: gap between the ball's underside and the net top at x = 0, m."""
    max_racket_speed: float = 8.0
    """Largest racket speed the arm can give at impact, m/s."""
    reach_z: tuple = (-0.30, 1.50)
    """Heights of the ball centre at the hit point the racket can reach, m (table frame)."""
    reach_y: float = 1.50
    """Largest |y| of the hit point the racket can reach, m."""
    max_normal_tilt_deg: float = 80.0
    """Largest angle between the racket normal and +x (towards the opponent), deg."""
    tolerance: float = 1e-4
    """Newton stops when the landing and net-height residuals are below this, m."""
    max_iterations: int = 30
    """Newton iteration limit."""
    aim_inside_zone: bool = False
    """Aim at the point of the target zone that maximises the in-zone probability (needs the
    incoming covariance) instead of its centre."""
    probability_samples: int = ENSEMBLE_SIZE
    """Size of the quasi-random ensemble for the in-zone probability (tt_strike.robust)."""


@dataclasses.dataclass
class StrikeSolution:
    """Result of :func:`solve` (arrays in the table frame)."""

    status: str
    """'ok', 'infeasible', 'invalid' (bad ball state) or 'bad_target'."""
    reason: str = ''
    """Why it is not feasible, one line ('' when ok)."""
    target_point: np.ndarray = None
    """Requested landing point (x, y), m."""
    target_zone: int = 0
    """Target zone 1..9 on the opponent's half (0 when a point was given)."""
    aim_point: np.ndarray = None
    """Point the solution aims at (= target_point unless aim_inside_zone), m."""
    normal: np.ndarray = None
    """Unit racket face normal, pointing where the ball leaves to."""
    racket_velocity: np.ndarray = None
    """Racket linear velocity at impact, m/s (along the normal)."""
    orientation_xyzw: np.ndarray = None
    """Racket orientation quaternion: z = normal, x = world up projected on the face."""
    racket_position: np.ndarray = None
    """Racket face centre at impact (one ball radius behind the ball), m."""
    ball_out_v: np.ndarray = None
    """Ball velocity just after the hit, m/s."""
    ball_out_w: np.ndarray = None
    """Ball spin just after the hit, rad/s."""
    landing: np.ndarray = None
    """First table contact of the forward check (x, y, z), m."""
    landing_zone: int = 0
    """Zone of the landing point (1..9 on the opponent's half, 0 elsewhere)."""
    forward_end: str = ''
    """How the forward check ended (``predict_landing``'s status: 'ok', 'table_edge', 'net',
    ...); '' when there was none."""
    flight_time: float = math.nan
    """Time from the hit to the landing, s."""
    net_clearance: float = math.nan
    """Gap between the ball's underside and the net top at x = 0 in the forward check, m."""
    margin: float = math.nan
    """Distance from the landing point to the nearest edge of the target zone, m."""
    residual: float = math.nan
    """Distance between the forward-check landing and the aim point, m."""
    iterations: int = 0
    """Newton iterations used."""
    in_zone_probability: float = math.nan
    """Probability of landing in the target zone under the incoming covariance (NaN if none)."""

    @property
    def feasible(self):
        return self.status == 'ok'


# --- eq. 7 inverted -----------------------------------------------------------------------

@njit(**_NJIT)
def _racket_for_outgoing(v_in, w_in, v_out, P, normal):
    """Racket normal (into ``normal``) and speed along it that turn v_in into v_out (eq. 7).

    With the racket velocity s n along the normal, eq. 7 splits into
        tangential:  P_n [v_out - (1 - K_v) v_in] = K_v r (w_in x n)
        normal:      v_out . n = (1 + e_r) s - e_r (v_in . n).
    Writing a = v_out - (1 - K_v) v_in and c = K_v r, the first reads a = alpha n + c (w x n)
    with alpha = a . n, so n = (alpha I + c [w]x)^-1 a, and |n| = 1 fixes alpha > 0:
        |a_par|^2 / alpha^2 + |a_perp|^2 / (alpha^2 + c^2 |w|^2) = 1    (a_par along w),
    a quadratic in alpha^2. Returns the racket speed s (m/s); NaN when a = 0.
    """
    m = P[I_MASS]
    r = P[I_RADIUS]
    k_v = P[I_KP] / m
    c = k_v * r
    ax = v_out[0] - (1.0 - k_v) * v_in[0]
    ay = v_out[1] - (1.0 - k_v) * v_in[1]
    az = v_out[2] - (1.0 - k_v) * v_in[2]
    a2 = ax * ax + ay * ay + az * az
    if a2 <= 0.0:
        return math.nan
    wx, wy, wz = w_in[0], w_in[1], w_in[2]
    w2 = wx * wx + wy * wy + wz * wz
    k = c * c * w2
    wa = wx * ax + wy * ay + wz * az
    a_par2 = wa * wa / w2 if w2 > 0.0 else 0.0
    b = k - a2
    root = math.sqrt(b * b + 4.0 * a_par2 * k)
    # alpha^2, the quadratic's positive root (written without cancellation when b > 0)
    q = 2.0 * a_par2 * k / (b + root) if b > 0.0 else 0.5 * (root - b)
    alpha = math.sqrt(q)
    den = q + k
    if alpha > 0.0:
        f = c * c / alpha * wa
    else:
        # a across w with |a| < c |w| (a ball on the centre line spinning about y only): the
        # rubber alone turns it, alpha = 0, and n leans sqrt(b / k) along w, either way (the
        # limit of c^2 wa / alpha as wa -> 0+; the two are mirror images).
        f = c * math.sqrt(b)
    normal[0] = (alpha * ax - c * (wy * az - wz * ay) + f * wx) / den
    normal[1] = (alpha * ay - c * (wz * ax - wx * az) + f * wy) / den
    normal[2] = (alpha * az - c * (wx * ay - wy * ax) + f * wz) / den
    nn = math.sqrt(normal[0] ** 2 + normal[1] ** 2 + normal[2] ** 2)
    for i in range(3):
        normal[i] /= nn                                      # removes round-off only
    e_r = P[I_ER]
    vn_in = v_in[0] * normal[0] + v_in[1] * normal[1] + v_in[2] * normal[2]
    vn_out = v_out[0] * normal[0] + v_out[1] * normal[1] + v_out[2] * normal[2]
    return (vn_out + e_r * vn_in) / (1.0 + e_r)             # eq. 7, normal row


def racket_for_outgoing(v_in, w_in, v_out, params):
    """Racket normal (3,) and velocity (3,) that turn (v_in, w_in) into v_out (eq. 7 inverted).

    Velocities in m/s, spin in rad/s, table frame. The racket moves along its normal. Returns
    ``(normal, racket_velocity)``; NaNs when v_out cannot be produced.
    """
    P = packed_params(params)
    normal = np.empty(3)
    s = _racket_for_outgoing(np.asarray(v_in, float), np.asarray(w_in, float),
                             np.asarray(v_out, float), P, normal)
    return normal, s * normal


# --- one shot: v_out -> racket -> rebound -> flight ---------------------------------------

SHOT_OK = 0
SHOT_NO_RACKET = 1      # v_out not reachable by any racket (a = 0)
SHOT_BEHIND = 2         # the racket would not meet the ball (relative normal speed >= 0)
SHOT_NO_NET = 3         # lands before crossing the net plane x = 0
SHOT_NO_LANDING = 4     # no table-height crossing within FLIGHT_T_MAX


@njit(**_NJIT)
def _shoot(s_hit, v_out, P, out):
    """Fly the ball sent with v_out from the hit state s_hit (9,).

    Writes into ``out`` (7,): landing x, y (where the centre first comes down through z = r,
    on the table or beside it) and the centre's height z where it crosses x = 0 (m, when
    SHOT_OK), normal (3), racket speed (m/s). Returns a SHOT_* code.
    """
    normal = np.empty(3)
    speed = _racket_for_outgoing(s_hit[3:6], s_hit[6:9], v_out, P, normal)
    if math.isnan(speed):
        return SHOT_NO_RACKET
    rv = speed * normal
    s = s_hit.copy()
    racket_rebound_inplace(s, P, normal, rv)
    vn_rel = ((s_hit[3] - rv[0]) * normal[0] + (s_hit[4] - rv[1]) * normal[1]
              + (s_hit[5] - rv[2]) * normal[2])
    for i in range(3):
        out[3 + i] = normal[i]
    out[6] = speed
    if vn_rel >= 0.0:
        return SHOT_BEHIND
    # The plane model (body False): the landing varies smoothly with v_out, also through the
    # net and past the table's edges, as Newton needs; the forward check has the body.
    res = np.empty(FLIGHT_N)
    kind = landing_flight(s, 0.0, P, False, res)
    if kind != CONTACT_TOP and kind != CONTACT_OFF:
        return SHOT_NO_LANDING
    if math.isnan(res[FL_NET_T]):
        return SHOT_NO_NET
    out[0] = res[FL_S]
    out[1] = res[FL_S + 1]
    out[2] = res[FL_NET_Z]
    return SHOT_OK


# --- Newton on v_out ----------------------------------------------------------------------

def ballistic_guess(p_hit, target, z_net, gravity):
    """Drag-free outgoing velocity from p_hit (3,) over (0, ., z_net) to (target, r) (m/s).

    With u = 1/v_x, d1 = -x0 (to the net), D = x_t - x0 (to the target), the two heights give
    g u^2 d1 D (D - d1) / 2 = D (z_net - z0) - d1 (z_t - z0); v_z from the landing height.
    Returns None when no such parabola exists (target not beyond the net).
    """
    x0, y0, z0 = p_hit
    d1, dd = -x0, target[0] - x0
    z_t = target[2]
    if not (d1 > 0.0 and dd > d1):
        return None
    rhs = dd * (z_net - z0) - d1 * (z_t - z0)
    if rhs <= 0.0:
        return None
    u = math.sqrt(2.0 * rhs / (gravity * d1 * dd * (dd - d1)))
    vx = 1.0 / u
    t_land = dd * u
    vz = (z_t - z0 + 0.5 * gravity * t_land * t_land) / t_land
    vy = (target[1] - y0) / t_land
    return np.array([vx, vy, vz])


def _newton(s_hit, aim, z_net_goal, P, settings, guess=None):
    """Outgoing velocity that lands at aim (x, y) with the net height z_net_goal.

    ``guess``: an outgoing velocity to start from (warm start, e.g. the solution at a nearby
    hit point); the drag-free guess when None or when it does not land.
    Returns (out, iterations, reason): out the _shoot row of the solution (None if there is
    none, with the reason)."""
    r = P[I_RADIUS]
    goal = np.array([aim[0], aim[1], z_net_goal])
    out = np.zeros(7)
    if guess is not None and _shoot(s_hit, guess, P, out) == SHOT_OK:
        return _newton_from(s_hit, np.array(guess, dtype=float), out, goal, P, settings)
    v = ballistic_guess(s_hit[:3], (aim[0], aim[1], r), z_net_goal, P[I_GRAVITY])
    if v is None:
        return None, 0, 'target is not beyond the net from the hit point'
    # The drag-free guess falls short under drag (and may land right at the net, where the
    # residuals bend sharply): start from the first of a few faster shots along the same
    # line that clears the net top, or else the first that lands at all.
    start, code = None, SHOT_NO_LANDING
    for scale in (1.0, 1.2, 1.5, 2.0):
        code = _shoot(s_hit, v * scale, P, out)
        if code == SHOT_OK and out[2] > NET_HEIGHT + r:
            v = v * scale
            break
        if code == SHOT_OK and start is None:
            start = scale
    else:
        if start is None:
            return None, 0, _SHOT_REASON[code]
        v = v * start
        _shoot(s_hit, v, P, out)
    return _newton_from(s_hit, v, out, goal, P, settings)


def _newton_from(s_hit, v, out, goal, P, settings):
    """Newton on v_out from v (its _shoot row in out) to the goal (x, y, z_net)."""
    f = out[:3] - goal
    jac = np.empty((3, 3))
    out_h = np.zeros(7)
    for it in range(1, settings.max_iterations + 1):
        if np.max(np.abs(f)) < settings.tolerance:
            return out, it - 1, ''
        for j in range(3):
            h = 1e-5 * max(1.0, abs(v[j]))
            vh = v.copy()
            vh[j] += h
            if _shoot(s_hit, vh, P, out_h) != SHOT_OK:
                vh[j] -= 2.0 * h
                h = -h
                if _shoot(s_hit, vh, P, out_h) != SHOT_OK:
                    return None, it, 'no landing near the solution'
            jac[:, j] = (out_h[:3] - out[:3]) / h
        try:
            step = np.linalg.solve(jac, -f)
        except np.linalg.LinAlgError:
            return None, it, 'singular sensitivity (cannot steer)'
        norm = np.max(np.abs(f))
        lam = 1.0
        for _ in range(12):                   # damping: accept a step that reduces |f|
            v_try = v + lam * step
            if _shoot(s_hit, v_try, P, out_h) == SHOT_OK:
                f_try = out_h[:3] - goal
                if np.max(np.abs(f_try)) < norm:
                    break
            lam *= 0.5
        else:
            return None, it, 'Newton stalled: target not reachable'
        v, f = v_try, f_try
        out[:] = out_h
    if np.max(np.abs(f)) < settings.tolerance:
        return out, settings.max_iterations, ''
    return None, settings.max_iterations, 'Newton did not converge'


_SHOT_REASON = {
    SHOT_NO_RACKET: 'no racket orientation produces the outgoing velocity',
    SHOT_BEHIND: 'the racket would not meet the ball',
    SHOT_NO_NET: 'the ball lands before the net',
    SHOT_NO_LANDING: 'the ball does not come down within 3 s',
}


# --- geometry helpers ---------------------------------------------------------------------

def racket_orientation(normal):
    """Quaternion (x, y, z, w) of the racket frame: z = normal, x = world +z projected on the
    face (world +x when the face is horizontal), y = z cross x."""
    nx, ny, nz = (float(c) for c in normal)
    n = math.sqrt(nx * nx + ny * ny + nz * nz)
    nx, ny, nz = nx / n, ny / n, nz / n
    xx, xy, xz = -nz * nx, -nz * ny, 1.0 - nz * nz         # up - z (up . z)
    if math.sqrt(xx * xx + xy * xy + xz * xz) < 1e-6:
        xx, xy, xz = 1.0 - nx * nx, -nx * ny, -nx * nz     # +x - z (x . z)
    k = math.sqrt(xx * xx + xy * xy + xz * xz)
    xx, xy, xz = xx / k, xy / k, xz / k
    yx, yy, yz = ny * xz - nz * xy, nz * xx - nx * xz, nx * xy - ny * xx   # z cross x
    return matrix_to_quaternion(np.array([[xx, yx, nx], [xy, yy, ny], [xz, yz, nz]]))


def matrix_to_quaternion(rot):
    """Unit quaternion (x, y, z, w), w >= 0, of the rotation matrix rot (3, 3)."""
    m = rot
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[3] >= 0.0 else -q


def resolve_target(target_zone=None, target_point=None):
    """Target as ``(zone, point (x, y))``; raises ValueError naming what is wrong.

    A zone 1..9 means its centre on the opponent's half; a point must lie inside that half,
    off its edges (a ball whose centre comes down on an edge does not bounce on the table).
    """
    if target_zone is not None and target_point is not None:
        raise ValueError('give target_zone or target_point, not both')
    if target_zone is not None:
        if isinstance(target_zone, bool) or not isinstance(target_zone, (int, np.integer)) \
                or not 1 <= target_zone <= 9:
            raise ValueError(f'target_zone must be an integer 1..9, got {target_zone!r}')
        return int(target_zone), zone_centre(int(target_zone), 1)
    if target_point is None:
        raise ValueError('no target: give target_zone (1..9) or target_point [x, y]')
    point = np.asarray(target_point, dtype=float).reshape(-1)
    if point.shape[0] not in (2, 3) or not np.all(np.isfinite(point)):
        raise ValueError(f'target_point must be 2 finite numbers [x, y], got {target_point!r}')
    x, y = point[0], point[1]
    if not (0.0 < x < HALF_LENGTH and abs(y) < HALF_WIDTH):
        raise ValueError(f"target_point ({x:.3f}, {y:.3f}) m is not inside the opponent's "
                         f'half (0 < x < {HALF_LENGTH} m, |y| < {HALF_WIDTH} m)')
    return 0, point[:2].copy()


# --- the solver ---------------------------------------------------------------------------

def solve(hit_state, params, target_zone=None, target_point=None, settings=None,
          covariance=None, guess=None):
    """Racket normal and velocity that send the ball at ``hit_state`` to the target.

    hit_state: (9,) ball p (m), v (m/s), w (rad/s) at the hit point, table frame.
    params: tt_prediction ModelParams. Target: ``target_zone`` 1..9 on the opponent's half
    (its centre) or ``target_point`` (x, y) m. ``covariance``: optional 9x9 covariance of
    hit_state, for the in-zone probability (and ``aim_inside_zone``). ``guess``: outgoing
    ball velocity (m/s) to start Newton from (warm start from a nearby hit point). Returns a
    :class:`StrikeSolution`; the landing fields come from the forward check
    (``racket_rebound`` + ``predict_landing``, net included), ``residual`` its distance to
    the aim point.
    """
    settings = settings or StrikeSettings()
    P = packed_params(params)
    try:
        zone, point = resolve_target(target_zone, target_point)
    except ValueError as err:
        return StrikeSolution('bad_target', str(err))
    sol = StrikeSolution('infeasible', target_point=point, target_zone=zone, aim_point=point)
    s_hit = np.asarray(hit_state, dtype=float).reshape(-1)
    if s_hit.shape != (9,) or not np.all(np.isfinite(s_hit)):
        sol.status, sol.reason = 'invalid', 'hit state must be 9 finite numbers (p, v, w)'
        return sol
    z_lo, z_hi = settings.reach_z
    if not z_lo <= s_hit[2] <= z_hi:
        sol.reason = f'hit point z {s_hit[2]:.3f} m outside reach [{z_lo:.2f}, {z_hi:.2f}] m'
        return sol
    if abs(s_hit[1]) > settings.reach_y:
        sol.reason = f'hit point |y| {abs(s_hit[1]):.3f} m beyond reach {settings.reach_y:.2f} m'
        return sol
    if covariance is not None:
        covariance = np.asarray(covariance, dtype=float)
        if covariance.shape != (9, 9) or not np.all(np.isfinite(covariance)):
            sol.status, sol.reason = 'invalid', 'covariance must be 9x9 finite numbers'
            return sol
    r = P[I_RADIUS]
    z_net_goal = NET_HEIGHT + r + settings.net_clearance
    out, sol.iterations, reason = _newton(s_hit, point, z_net_goal, P, settings, guess)
    if out is None:
        sol.reason = f'cannot reach the target: {reason}'
        return sol
    _fill(sol, s_hit, out[3:6].copy(), out[6], params, settings)
    if covariance is None or sol.status != 'ok':
        return sol
    zone_p = scored_zone(sol)
    points = landing_ensemble(s_hit, covariance, sol.normal, sol.racket_velocity, P,
                              settings.probability_samples)
    sol.in_zone_probability = in_zone_probability(points, zone_p)
    if settings.aim_inside_zone:
        aim = aim_in_zone(s_hit, sol.normal, sol.racket_velocity, P, points, point, zone_p)
        out2, its2, _ = _newton(s_hit, aim, z_net_goal, P, settings)
        if out2 is not None:
            other = dataclasses.replace(sol, aim_point=aim, iterations=sol.iterations + its2)
            _fill(other, s_hit, out2[3:6].copy(), out2[6], params, settings)
            if other.status == 'ok':
                other.in_zone_probability = in_zone_probability(landing_ensemble(
                    s_hit, covariance, other.normal, other.racket_velocity, P,
                    settings.probability_samples), zone_p)
                if other.in_zone_probability > sol.in_zone_probability:   # else keep centre
                    sol = other
    return sol


def _fill(sol, s_hit, normal, speed, params, settings):
    """Racket fields, forward check (racket_rebound + predict_landing) and limits of sol."""
    r = params.radius
    sol.normal = normal
    sol.racket_velocity = speed * normal
    sol.orientation_xyzw = racket_orientation(normal)
    sol.racket_position = s_hit[:3] - r * normal
    fwd = forward(s_hit, normal, sol.racket_velocity, params)
    sol.ball_out_v, sol.ball_out_w = fwd['v_out'], fwd['w_out']
    sol.net_clearance = fwd['net_clearance']
    sol.landing = fwd['landing']
    sol.flight_time = fwd['flight_time']
    sol.forward_end = fwd['end']
    if fwd['end'] != 'ok':
        sol.status, sol.reason = 'infeasible', f'forward check: {fwd["end"]}'
        return
    x, y = sol.landing[0], sol.landing[1]
    zone, half = zone_of(x, y)
    sol.landing_zone = zone if half == 1 else 0
    sol.residual = float(np.hypot(x - sol.aim_point[0], y - sol.aim_point[1]))
    sol.margin = zone_margin(x, y, scored_zone(sol), 1)
    if sol.residual > FORWARD_TOLERANCE:
        sol.status = 'infeasible'
        sol.reason = f'forward check lands {sol.residual * 1e3:.1f} mm from the aim point'
        return
    sol.status, sol.reason = 'ok', ''
    _check_limits(sol, settings)


def scored_zone(sol):
    """The zone a solution is scored against: the target zone, or the one holding the point."""
    return sol.target_zone or zone_of(sol.target_point[0], sol.target_point[1])[0]


def _check_limits(sol, settings):
    """Turn a converged solution that the robot cannot execute into 'infeasible'."""
    speed = float(np.linalg.norm(sol.racket_velocity))
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, sol.normal[0]))))
    if speed > settings.max_racket_speed:
        sol.status = 'infeasible'
        sol.reason = (f'racket speed {speed:.1f} m/s above limit '
                      f'{settings.max_racket_speed:.1f} m/s')
    elif tilt > settings.max_normal_tilt_deg:
        sol.status = 'infeasible'
        sol.reason = (f'racket normal {tilt:.0f} deg from +x, above limit '
                      f'{settings.max_normal_tilt_deg:.0f} deg')
    elif not sol.net_clearance > 0.0:
        sol.status, sol.reason = 'infeasible', 'the ball hits the net'


def forward(hit_state, normal, racket_velocity, params):
    """Forward model of a stroke: eq. 7 (``racket_rebound``), then the flight with the net to
    the first table contact (``tt_prediction.predict.predict_landing``).

    ``params``: a ModelParams. Returns a dict: v_out, w_out (after the hit), landing (x, y, z)
    of the first table contact or None, flight_time (s), net_clearance (gap under the ball at
    x = 0, m; NaN if it never crosses) and end (predict_landing's status). Like
    ``racket_rebound`` it does not check that the racket meets the ball.
    """
    s = np.asarray(hit_state, dtype=float).copy()
    v_out, w_out = racket_rebound(s[3:6], s[6:9], normal, racket_velocity, params)
    s[3:6], s[6:9] = v_out, w_out
    pred = predict_landing(s, params)
    landing = None if pred.landing is None else np.asarray(pred.landing.p, dtype=float)
    return {'v_out': v_out, 'w_out': w_out, 'landing': landing,
            'flight_time': math.nan if landing is None else pred.landing.t,
            'net_clearance': pred.net_clearance, 'end': pred.status}
