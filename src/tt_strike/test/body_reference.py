"""Independent reference for the tests: a stroke and its flight with the table as a body.

Written from /work/shared/docs/MODEL.md alone (constants, eq. 7 in the racket frame, eq. 8,
"Frames and the table"), with scipy's solve_ivp (DOP853) and its event location; it shares
no code with tt_prediction or tt_strike, so that it cannot share their mistakes. Tests only
(slow: about 10 ms a flight).

Table frame, SI units, spin in rad/s.
"""

import math

import numpy as np
from scipy.integrate import solve_ivp

# MODEL.md, "Constants (nominal)".
M = 2.7e-3                  # kg
R = 0.020                   # m
G = 9.8                     # m/s^2, along -z
RHO = 1.184                 # kg/m^3
AREA = 12.5e-4              # m^2
C_D = 0.54
C_M = 0.069
E_R = 0.81
K_P = 1.9e-3                # kg/s
INERTIA = 2.0 / 3.0 * M * R * R

# MODEL.md, "Frames and the table".
LENGTH, WIDTH = 2.74, 1.525
FACE_DEPTH = 0.03           # end and side faces: z from -0.03 to 0
NET_H = 0.1525
NET_OVERHANG = 0.1525       # beyond each side line
FLOOR_Z = -0.76


def rebound_racket_frame(v_ball, w_ball, normal, v_racket, k_p=K_P, e_r=E_R):
    """Eq. 7 as printed (corrected) in MODEL.md, in an explicit racket frame.

    The frame: z = the unit normal, x any unit vector in the face, y = z x x. The ball's
    velocity relative to the racket and its spin are rotated into that frame, the two 3 x 3
    matrices of eq. 7 applied, and the result rotated back; the racket velocity is added
    back. Returns (v_out, w_out), world frame.
    """
    z = np.asarray(normal, float) / np.linalg.norm(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.vstack([x, y, z])              # rows: racket axes in world coordinates
    v = rot @ (np.asarray(v_ball, float) - np.asarray(v_racket, float))
    w = rot @ np.asarray(w_ball, float)
    k_v = k_p / M
    k_w = k_p / INERTIA
    a_v = np.array([[1 - k_v, 0, 0], [0, 1 - k_v, 0], [0, 0, -e_r]])
    b_v = np.array([[0, k_v * R, 0], [-k_v * R, 0, 0], [0, 0, 0]])
    a_w = np.array([[0, -k_w * R, 0], [k_w * R, 0, 0], [0, 0, 0]])
    b_w = np.diag([1 - k_w * R * R, 1 - k_w * R * R, 1.0])
    v_new = a_v @ v + b_v @ w
    w_new = a_w @ v + b_w @ w
    return rot.T @ v_new + np.asarray(v_racket, float), rot.T @ w_new


def _derivative(_t, y):
    """Eq. 8: m a = m g - 1/2 C_D rho A |v| v + 4/3 C_M pi rho r^3 (w x v); w constant."""
    v = y[3:6]
    w = y[6:9]
    speed = math.sqrt(v @ v)
    acc = (np.array([0.0, 0.0, -G]) - 0.5 * C_D * RHO * AREA * speed * v / M
           + 4.0 / 3.0 * C_M * math.pi * RHO * R ** 3 * np.cross(w, v) / M)
    return np.concatenate([v, acc, np.zeros(3)])


def _box_distance(p, lo, hi):
    """Euclidean distance from point p to the axis-aligned box [lo, hi] (0 inside)."""
    return float(np.linalg.norm(p - np.clip(p, lo, hi)))


_TABLE_LO = np.array([-LENGTH / 2, -WIDTH / 2, -FACE_DEPTH])
_TABLE_HI = np.array([LENGTH / 2, WIDTH / 2, 0.0])
_NET_LO = np.array([0.0, -(WIDTH / 2 + NET_OVERHANG), -FACE_DEPTH])
_NET_HI = np.array([0.0, WIDTH / 2 + NET_OVERHANG, NET_H])


def _table_event(_t, y):
    return _box_distance(y[:3], _TABLE_LO, _TABLE_HI) - R


def _net_event(_t, y):
    return _box_distance(y[:3], _NET_LO, _NET_HI) - R


def _floor_event(_t, y):
    return y[2] - (FLOOR_Z + R)


def _net_plane_event(_t, y):
    return y[0]


for _ev in (_table_event, _net_event, _floor_event):
    _ev.terminal = True
    _ev.direction = -1
_net_plane_event.terminal = False


def first_contact(state, t_max=3.0, max_step=2e-3):
    """First contact of a ball in free flight from ``state`` (9,) with the table body, the
    net (with posts) or the floor.

    Returns a dict: kind ('top' from above over the footprint, 'table_edge', 'net',
    'net_post', 'floor' or 'none'), t (s), p (3,) at the contact, and net_z: the centre's
    height where it first crosses x = 0 (NaN if it does not).
    """
    sol = solve_ivp(_derivative, (0.0, t_max), np.asarray(state, float), method='DOP853',
                    rtol=1e-10, atol=1e-12, max_step=max_step,
                    events=(_table_event, _net_event, _floor_event, _net_plane_event))
    net_z = sol.y_events[3][0][2] if len(sol.t_events[3]) else math.nan
    hits = [(sol.t_events[i][0], i) for i in range(3) if len(sol.t_events[i])]
    if not hits:
        return {'kind': 'none', 't': math.nan, 'p': None, 'net_z': net_z}
    t, i = min(hits)
    p = sol.y_events[i][0][:3]
    if i == 0:
        inside = abs(p[0]) <= LENGTH / 2 and abs(p[1]) <= WIDTH / 2 and p[2] > 0.0
        kind = 'top' if inside else 'table_edge'
    elif i == 1:
        kind = 'net' if abs(p[1]) <= WIDTH / 2 else 'net_post'
    else:
        kind = 'floor'
    return {'kind': kind, 't': float(t), 'p': p, 'net_z': net_z}


def zone_of_point(x, y):
    """Zone 1..9 on the opponent's half (MODEL.md, "The 9 areas"), 0 anywhere else."""
    if not (0.0 < x <= LENGTH / 2 and abs(y) <= WIDTH / 2):
        return 0
    row = min(int(x / (LENGTH / 6)), 2)
    col = min(int((WIDTH / 2 - y) / (WIDTH / 3)), 2)
    return 3 * row + col + 1


def replay_stroke(hit_state, normal, racket_velocity):
    """Replay a racket command: eq. 7 at the hit state, then the flight to the first contact.

    Returns (zone, contact): the zone of the first contact when it is the top of the
    opponent's half (0 otherwise) and the :func:`first_contact` dict.
    """
    s = np.asarray(hit_state, float).copy()
    s[3:6], s[6:9] = rebound_racket_frame(s[3:6], s[6:9], normal, racket_velocity)
    contact = first_contact(s)
    if contact['kind'] != 'top':
        return 0, contact
    return zone_of_point(contact['p'][0], contact['p'][1]), contact
