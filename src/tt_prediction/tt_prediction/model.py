"""The ball model's equations (MODEL.md), as small compiled functions on plain arrays.

State vector ``s`` (9,): position p (m), velocity v (m/s), spin w (rad/s), table frame.
Parameters: the packed array of :meth:`tt_prediction.params.ModelParams.packed`.
The functions are numba-compiled (``cache=True``) so that the integrator can call them in its
inner loop; they are also plain callables from Python.
"""

import math

from numba import njit
import numpy as np

from .params import (
    DRAG_SPEED_REF,
    EDGE_LENGTH_REF,
    I_AREA,
    I_CD,
    I_CD_SLOPE,
    I_CD_SPIN_SLOPE,
    I_CM,
    I_CM_SLOPE,
    I_ER,
    I_ET,
    I_ET_EDGE,
    I_ET_SLOPE,
    I_ET_SPIN_SLOPE,
    I_ET_TANGENTIAL,
    I_GRAVITY,
    I_GRAVITY_X,
    I_GRAVITY_Y,
    I_KP,
    I_MASS,
    I_MU,
    I_MU_SLIP_SLOPE,
    I_MU_SLOPE,
    I_RADIUS,
    I_RHO,
    I_SPIN_DECAY,
    I_WIND_X,
    I_WIND_Y,
    I_WIND_Z,
    IMPACT_SPEED_REF,
    LIFT_SPIN_RATIO_REF,
    SLIP_SPEED_REF,
)
from .table import HALF_LENGTH, HALF_WIDTH

_NJIT = {'cache': True, 'fastmath': False, 'nogil': True}


@njit(**_NJIT)
def _aero(s, P):
    """The air terms of eq. 8 at state ``s``: air-relative velocity u = v - wind (m/s), its
    magnitude, C_D and C_M with their effects, K_D = rho A / (2 m) (1/m) and
    K_M = 4/3 pi rho r^3 / m (m): the drag acceleration is -K_D C_D |u| u, the Magnus one
    K_M C_M (w x u)."""
    m = P[I_MASS]
    r = P[I_RADIUS]
    rho = P[I_RHO]
    ux = s[3] - P[I_WIND_X]
    uy = s[4] - P[I_WIND_Y]
    uz = s[5] - P[I_WIND_Z]
    speed = math.sqrt(ux * ux + uy * uy + uz * uz)
    c_d = P[I_CD] + P[I_CD_SLOPE] * (speed - DRAG_SPEED_REF)
    c_m = P[I_CM]
    if (P[I_CM_SLOPE] != 0.0 or P[I_CD_SPIN_SLOPE] != 0.0) and speed > 0.0:
        spin = math.sqrt(s[6] * s[6] + s[7] * s[7] + s[8] * s[8])
        ratio = r * spin / speed - LIFT_SPIN_RATIO_REF
        c_m += P[I_CM_SLOPE] * ratio
        c_d += P[I_CD_SPIN_SLOPE] * ratio
    k_d = 0.5 * rho * P[I_AREA] / m
    k_m = 4.0 / 3.0 * math.pi * rho * r * r * r / m
    return ux, uy, uz, speed, c_d, c_m, k_d, k_m


@njit(**_NJIT)
def flight_derivative(s, P, out):
    """Time derivative of the state in free flight (eq. 8 with its effects), into ``out``.

    Eq. 8: m a = m g - 1/2 C_D rho A |u| u + 4/3 C_M pi rho r^3 (w x u), with u = v - wind
    the air-relative velocity (u = v in the paper's still air), C_D and C_M with their
    speed and spin-ratio effects, g = (gravity_x, gravity_y, -gravity) (along -z in the
    paper: a level table) and dw/dt = -spin_decay w (0 in the paper: constant spin).

    Parameters
    ----------
    s : ndarray (9,)
        State [p (m), v (m/s), w (rad/s)], table frame.
    P : ndarray
        Packed model parameters (:meth:`tt_prediction.params.ModelParams.packed`).
    out : ndarray (9,)
        Receives ds/dt = [v (m/s), a (m/s^2), dw/dt (rad/s^2)].

    Returns
    -------
    None
    """
    ux, uy, uz, speed, c_d, c_m, k_d, k_m = _aero(s, P)
    wx, wy, wz = s[6], s[7], s[8]
    drag = k_d * c_d * speed                            # eq. 8, drag term / (m |u|)
    lift = k_m * c_m                                    # eq. 8, Magnus term / m
    out[0] = s[3]
    out[1] = s[4]
    out[2] = s[5]
    # Eq. 8; g = (gravity_x, gravity_y, -gravity): a table not level (0 in the paper).
    out[3] = P[I_GRAVITY_X] - drag * ux + lift * (wy * uz - wz * uy)
    out[4] = P[I_GRAVITY_Y] - drag * uy + lift * (wz * ux - wx * uz)
    out[5] = -P[I_GRAVITY] - drag * uz + lift * (wx * uy - wy * ux)
    k = P[I_SPIN_DECAY]
    out[6] = -k * wx
    out[7] = -k * wy
    out[8] = -k * wz


@njit(**_NJIT)
def flight_jacobian(s, P, out):
    """Jacobian of the free-flight derivative (eq. 8 with its effects) at ``s``, into ``out``.

    With u = v - wind, S = |u|, K_D = rho A / (2 m), K_M = 4/3 pi rho r^3 / m and the
    coefficients C_D(S, |w|), C_M(S, |w|) of :func:`flight_derivative`:

        a = g - K_D C_D S u + K_M C_M (w x u)
        da/dv = -K_D (C_D (S I + u u^T / S) + S u dC_D/du^T) + K_M (C_M [w]x + (w x u) dC_M/du^T)
        da/dw = -K_D S u dC_D/dw^T + K_M (-C_M [u]x + (w x u) dC_M/dw^T)
        dp'/dv = I,   dw'/dw = -spin_decay I.

    Parameters
    ----------
    s, P : ndarray (9,), ndarray
        State [p (m), v (m/s), w (rad/s)] and packed parameters, as for
        :func:`flight_derivative`.
    out : ndarray (9, 9)
        Receives d(ds/dt)/ds, rows and columns in the order of ``s``; each entry in the unit
        of its row's derivative over its column's state (e.g. 1/s for dv'/dv, m/(s rad) for
        dv'/dw).

    Returns
    -------
    ndarray (9, 9)
        ``out``. At S = 0 the drag terms are taken as 0 (the derivative's kink).
    """
    ux, uy, uz, speed, c_d, c_m, k_d, k_m = _aero(s, P)
    r = P[I_RADIUS]
    wx, wy, wz = s[6], s[7], s[8]
    u = np.array([ux, uy, uz])
    w = np.array([wx, wy, wz])
    spin = math.sqrt(wx * wx + wy * wy + wz * wz)
    dcd_du = np.zeros(3)                                # gradients of C_D, C_M (effects)
    dcd_dw = np.zeros(3)
    dcm_du = np.zeros(3)
    dcm_dw = np.zeros(3)
    if speed > 0.0:
        dcd_du += P[I_CD_SLOPE] * u / speed
    if (P[I_CM_SLOPE] != 0.0 or P[I_CD_SPIN_SLOPE] != 0.0) and speed > 0.0:
        dratio_du = -r * spin / speed ** 3 * u
        dratio_dw = r / (speed * spin) * w if spin > 0.0 else np.zeros(3)
        dcd_du += P[I_CD_SPIN_SLOPE] * dratio_du
        dcd_dw += P[I_CD_SPIN_SLOPE] * dratio_dw
        dcm_du += P[I_CM_SLOPE] * dratio_du
        dcm_dw += P[I_CM_SLOPE] * dratio_dw
    wxu = np.array([wy * uz - wz * uy, wz * ux - wx * uz, wx * uy - wy * ux])
    for i in range(9):
        for j in range(9):
            out[i, j] = 0.0
    for i in range(3):
        out[i, 3 + i] = 1.0
        out[6 + i, 6 + i] = -P[I_SPIN_DECAY]
    for i in range(3):
        for j in range(3):
            dv = -k_d * speed * u[i] * dcd_du[j] + k_m * wxu[i] * dcm_du[j]
            if speed > 0.0:
                dv -= k_d * c_d * u[i] * u[j] / speed
            if i == j:
                dv -= k_d * c_d * speed
            out[3 + i, 3 + j] = dv
            out[3 + i, 6 + j] = -k_d * speed * u[i] * dcd_dw[j] + k_m * wxu[i] * dcm_dw[j]
    # Magnus: d(w x u)/dv = [w]x, d(w x u)/dw = -[u]x
    out[3, 4] += -k_m * c_m * wz
    out[3, 5] += k_m * c_m * wy
    out[4, 3] += k_m * c_m * wz
    out[4, 5] += -k_m * c_m * wx
    out[5, 3] += -k_m * c_m * wy
    out[5, 4] += k_m * c_m * wx
    out[3, 7] += k_m * c_m * uz
    out[3, 8] += -k_m * c_m * uy
    out[4, 6] += -k_m * c_m * uz
    out[4, 8] += k_m * c_m * ux
    out[5, 6] += k_m * c_m * uy
    out[5, 7] += -k_m * c_m * ux
    return out


@njit(**_NJIT)
def edge_distance(x, y):
    """Distance from a table point to the nearest edge of the playing surface's outline.

    Parameters
    ----------
    x, y : float
        Table-frame coordinates of the point, m.

    Returns
    -------
    float
        Distance, m (0 on an edge or off the table).
    """
    return max(min(HALF_LENGTH - abs(x), HALF_WIDTH - abs(y)), 0.0)


@njit(**_NJIT)
def edge_gradient(x, y):
    """The derivative of :func:`edge_distance` along x and along y (1/0, 0/1 and their
    signs: it is the distance to the nearer of the end and side lines; 0, 0 off the table).

    Parameters
    ----------
    x, y : float
        Table-frame coordinates of the point, m.

    Returns
    -------
    gx, gy : float
        d(distance)/dx, d(distance)/dy (dimensionless).
    """
    ax, ay = HALF_LENGTH - abs(x), HALF_WIDTH - abs(y)
    if min(ax, ay) <= 0.0:
        return 0.0, 0.0
    if ax <= ay:
        return (-1.0 if x > 0.0 else 1.0), 0.0
    return 0.0, (-1.0 if y > 0.0 else 1.0)


@njit(**_NJIT)
def table_restitution(s, P):
    """The table restitution e_t of eqs. 1-6 with its effects, before the clip to [0, 1].

    e_t + e_t_speed_slope (|v_z| - IMPACT_SPEED_REF) + e_t_spin_slope r|w|
    + e_t_edge exp(-d / EDGE_LENGTH_REF), d the bounce's distance to the table's edge.

    Parameters
    ----------
    s : ndarray (9,)
        State [p (m), v (m/s), w (rad/s)] at contact, table frame.
    P : ndarray
        Packed model parameters (:meth:`tt_prediction.params.ModelParams.packed`).

    Returns
    -------
    float
        e_t (dimensionless; the rebound clips it to [0, 1]).
    """
    spin = math.sqrt(s[6] * s[6] + s[7] * s[7] + s[8] * s[8])
    e_t = (P[I_ET] + P[I_ET_SLOPE] * (abs(s[5]) - IMPACT_SPEED_REF)
           + P[I_ET_SPIN_SLOPE] * P[I_RADIUS] * spin)
    if P[I_ET_EDGE] != 0.0:
        e_t += P[I_ET_EDGE] * math.exp(-edge_distance(s[0], s[1]) / EDGE_LENGTH_REF)
    return e_t


@njit(**_NJIT)
def table_rebound_inplace(s, P):
    """Apply the table rebound (eqs. 1-6, MODEL.md) to the velocity and spin of ``s``.

    The contact point is (0, 0, -r) from the centre. Sliding while the slip ratio
    s = mu (1 + e_t) |v_z| / |v_T| stays below the grip ratio 2/5 (1 + e_x), with alpha = s;
    gripping otherwise, alpha = 2/5 (1 + e_x), which leaves the contact velocity at
    v_T' = (1 - 5 alpha / 2) v_T = -e_x v_T. The paper has e_x = 0 (``e_t_tangential``, the
    ball's tangential compliance): nu_s = 1 - 5/2 s > 0 is sliding, rolling (v_T' = 0)
    otherwise. The effects enter through e_t (impact speed, spin, the place on the table:
    :func:`table_restitution`), mu (spin, slip speed) and e_x.

    Parameters
    ----------
    s : ndarray (9,)
        State [p (m), v (m/s), w (rad/s)] at contact (v_z < 0); v and w are overwritten with
        the values just after the bounce, p is left as it is.
    P : ndarray
        Packed model parameters (:meth:`tt_prediction.params.ModelParams.packed`).

    Returns
    -------
    None
    """
    r = P[I_RADIUS]
    vx, vy, vz = s[3], s[4], s[5]
    wx, wy, wz = s[6], s[7], s[8]
    spin = math.sqrt(wx * wx + wy * wy + wz * wz)
    vtx = vx - r * wy                                   # tangential contact velocity
    vty = vy + r * wx
    vt = math.sqrt(vtx * vtx + vty * vty)
    e_t = min(max(table_restitution(s, P), 0.0), 1.0)
    mu = P[I_MU] + P[I_MU_SLOPE] * spin + P[I_MU_SLIP_SLOPE] * (vt - SLIP_SPEED_REF)
    mu = max(mu, 0.0)
    grip = 0.4 * (1.0 + P[I_ET_TANGENTIAL])             # 2/5 (1 + e_x); 2/5 in the paper
    alpha = grip                                        # gripping (rolling for e_x = 0)
    if vt > 1e-12:
        slip = mu * (1.0 + e_t) * abs(vz) / vt
        if slip < grip:                                 # nu_s > 0: sliding (fixed 5/2)
            alpha = slip
    s[3] = (1.0 - alpha) * vx + alpha * r * wy          # eq. 1-6, A_v (fixed row 2)
    s[4] = (1.0 - alpha) * vy - alpha * r * wx
    s[5] = -e_t * vz
    s[6] = (1.0 - 1.5 * alpha) * wx - 1.5 * alpha / r * vy   # A_w
    s[7] = (1.0 - 1.5 * alpha) * wy + 1.5 * alpha / r * vx
    s[8] = wz


@njit(**_NJIT)
def racket_rebound_inplace(s, P, normal, racket_velocity):
    """Apply the racket rubber rebound (eq. 7, MODEL.md) to the velocity and spin of ``s``.

    In the racket frame (z = normal) with v the ball velocity relative to the racket,
    K_v = k_p / m (dimensionless) and K_w = k_p / I (1/m^2), k_p in kg:
        v_t' = (1 - K_v) v_t + K_v r (w x n),   v_n' = -e_r v_n,
        w_t' = (1 - K_w r^2) w_t + K_w r (n x v),   w_n' = w_n,
    the frame-free form of eq. 7 (its rows for x and y are the components of these).

    Parameters
    ----------
    s : ndarray (9,)
        State [p (m), v (m/s), w (rad/s)], table frame, at the hit; v and w are overwritten
        with the values just after it.
    P : ndarray
        Packed model parameters (:meth:`tt_prediction.params.ModelParams.packed`).
    normal : ndarray (3,)
        Unit face normal, table frame, pointing to the side the ball leaves from.
    racket_velocity : ndarray (3,)
        The racket's linear velocity at impact, table frame, m/s.

    Returns
    -------
    None
    """
    m = P[I_MASS]
    r = P[I_RADIUS]
    k_v = P[I_KP] / m
    k_w = P[I_KP] / (2.0 / 3.0 * m * r * r)
    nx, ny, nz = normal[0], normal[1], normal[2]
    vx = s[3] - racket_velocity[0]
    vy = s[4] - racket_velocity[1]
    vz = s[5] - racket_velocity[2]
    wx, wy, wz = s[6], s[7], s[8]
    vn = vx * nx + vy * ny + vz * nz
    wn = wx * nx + wy * ny + wz * nz
    vtx, vty, vtz = vx - vn * nx, vy - vn * ny, vz - vn * nz
    wtx, wty, wtz = wx - wn * nx, wy - wn * ny, wz - wn * nz
    # w x n and n x v (tangential by construction)
    cx, cy, cz = wy * nz - wz * ny, wz * nx - wx * nz, wx * ny - wy * nx
    dx, dy, dz = ny * vz - nz * vy, nz * vx - nx * vz, nx * vy - ny * vx
    e_r = P[I_ER]
    s[3] = racket_velocity[0] + (1.0 - k_v) * vtx + k_v * r * cx - e_r * vn * nx
    s[4] = racket_velocity[1] + (1.0 - k_v) * vty + k_v * r * cy - e_r * vn * ny
    s[5] = racket_velocity[2] + (1.0 - k_v) * vtz + k_v * r * cz - e_r * vn * nz
    a = 1.0 - k_w * r * r
    s[6] = a * wtx + k_w * r * dx + wn * nx
    s[7] = a * wty + k_w * r * dy + wn * ny
    s[8] = a * wtz + k_w * r * dz + wn * nz


def table_rebound(velocity, spin, params, position=(0.0, 0.0, 0.0)):
    """Velocity and spin just after a table bounce (eqs. 1-6 with the model's effects).

    Parameters
    ----------
    velocity : array_like (3,)
        Ball velocity at contact, table frame, m/s (v_z < 0).
    spin : array_like (3,)
        Ball spin at contact, rad/s.
    params : ModelParams
        The model.
    position : array_like (3,)
        Where the ball meets the table, table frame, m (the centre by default; only
        ``e_t_edge`` depends on it).

    Returns
    -------
    velocity, spin : ndarray (3,)
        Just after the bounce, m/s and rad/s.
    """
    s = np.zeros(9)
    s[:3], s[3:6], s[6:9] = position, velocity, spin
    table_rebound_inplace(s, params.packed())
    return s[3:6].copy(), s[6:9].copy()


def racket_rebound(velocity, spin, normal, racket_velocity, params):
    """Ball velocity and spin just after the racket hit (eq. 7), table frame.

    Eq. 7 is applied as it stands: the caller checks that the ball meets the face (its
    velocity relative to the racket, along ``normal``, negative). For a ball moving away from
    the face, or a racket outrunning it, the numbers returned are eq. 7's, not a hit's (the
    strike solver refuses such strokes, tt_strike.solver's SHOT_BEHIND).

    Parameters
    ----------
    velocity, spin : array_like (3,)
        Ball velocity (m/s) and spin (rad/s) at the hit.
    normal : array_like (3,)
        Racket face normal (normalised here), pointing to the side the ball leaves from.
    racket_velocity : array_like (3,)
        The racket's linear velocity, m/s.
    params : ModelParams
        The model (e_r, k_p).

    Returns
    -------
    velocity, spin : ndarray (3,)
        Just after the hit, m/s and rad/s.
    """
    normal = np.asarray(normal, dtype=float)
    normal = normal / np.linalg.norm(normal)
    s = np.zeros(9)
    s[3:6], s[6:9] = velocity, spin
    racket_rebound_inplace(s, params.packed(), normal,
                           np.asarray(racket_velocity, dtype=float))
    return s[3:6].copy(), s[6:9].copy()


def flight_acceleration(position, velocity, spin, params):
    """Ball acceleration in free flight (eq. 8 with the model's effects).

    Parameters
    ----------
    position, velocity, spin : array_like (3,)
        Table frame: m, m/s, rad/s.
    params : ModelParams
        The model.

    Returns
    -------
    ndarray (3,)
        Acceleration, m/s^2 (gravity included).
    """
    s = np.concatenate([position, velocity, spin]).astype(float)
    out = np.empty(9)
    flight_derivative(s, params.packed(), out)
    return out[3:6]
