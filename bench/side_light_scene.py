"""Side-light scenes: an independent ray-cast renderer of table-tennis ball flights for
``bench_side_light`` (numpy and OpenCV only).

Written apart from ``tt_perception.synth`` and ``src/tt_perception/test/independent_scene.py``
(nothing imported from or shared with either, the rig's calibration included: it makes its own
cameras and writes its own ``rig.yaml``), to judge ``tt-perceive`` on choices those renderers
don't make:

- a green table with white lines and a dark-green edge, a light-grey floor (albedo 0.62; 0.12
  in the ``darkfloor`` cases), plain or striped walls and people-like ellipsoids (``pattern``);
- a key light from the +y side at 45 degrees elevation (Lambert ball with a Phong highlight),
  a dim fill and ambient light; cast shadows of the ball on table and floor and of the table
  on the floor (hard, from the key light);
- a net with a mesh of threads and a white top tape, which hides the ball in part;
- cameras of different sizes and lenses: 1280 x 1024 behind and above the robot's end (barrel
  distortion) and 800 x 600 at the side (slight pincushion), off-centre principal points,
  100 fps (200 fps in ``fps200``), a linear response (pixel = 255 x 0.92 x radiance);
- optional motion blur (sub-exposures over the exposure), rolling shutter (top-to-bottom
  readout), Gaussian noise and JPEG;
- its own flight: RK4 with gravity, quadratic drag and Magnus, a table bounce with vertical
  restitution 0.9, horizontal speed x 0.78 and spin x 0.7; three served balls per scene
  (flat, topspin, backspin with sidespin), 0.25 s apart.

Geometry: table frame, x along the table, z up, surface z = 0, net at x = 0. Camera model
X_cam = R X + t, OpenCV plumb-bob distortion. Pixel centres at integer coordinates.
:func:`render_case` writes ``OUT/CASE/`` (``rig.yaml``, ``camN.yaml``, ``camN/%06d.png``,
``truth.csv``, ``meta.json``); :func:`check` is the renderer's self-check.
Usage: python bench/side_light_scene.py CASE [--out FOLDER] [--max-frames N]
"""

import argparse
import csv
import json
import os

import cv2
import numpy as np
import yaml

R_BALL = 0.02
HALF_L, HALF_W = 1.37, 0.7625
NET_H, NET_OVER = 0.1525, 0.1525
FLOOR_Z = -0.76
ROOM = (6.0, 4.5, 3.5)            # half x, half y, height of walls
G = np.array([0.0, 0.0, -9.81])
_UNDIST = getattr(cv2, 'undistortPointsIter', cv2.undistortPoints)

KEY_DIR = np.array([0.0, 1.0, 1.0]) / np.sqrt(2.0)     # toward the key light (+y side, 45 deg)
KEY_I = 1.0
FILL_DIR = np.array([-0.3, -0.5, 0.81])
FILL_DIR /= np.linalg.norm(FILL_DIR)
FILL_I = 0.22
AMBIENT = 0.10
FLOOR_ALB = [0.62, 0.62, 0.60]
GAIN = 0.92                        # pixel = 255 * GAIN * radiance (linear camera)


# ----------------------------------------------------------------------------- cameras
def look_at(eye, target):
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    f = target - eye
    f /= np.linalg.norm(f)
    right = np.cross(f, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(f, right)
    R = np.stack([right, down, f])
    return R, -R @ eye


class Cam:
    def __init__(self, name, w, h, f, eye, target, dist):
        self.name, self.w, self.h = name, w, h
        self.K = np.array([[f, 0, (w - 1) / 2.0 + 3.3], [0, f * 1.002, (h - 1) / 2.0 - 2.1],
                           [0, 0, 1.0]])
        self.dist = np.asarray(dist, float)
        self.R, self.t = look_at(eye, target)
        self.C = np.asarray(eye, float)

    def rays(self, pix):
        """Distorted pixel coords (n,2) -> unit world directions (n,3)."""
        p = np.ascontiguousarray(pix, dtype=np.float64).reshape(-1, 1, 2)
        n = _UNDIST(p, self.K, self.dist, R=np.eye(3), P=np.eye(3),
                    criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-12)
                    ).reshape(-1, 2)
        d = np.column_stack([n, np.ones(len(n))]) @ self.R      # R^T d_cam
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def project(self, X):
        """World points (n,3) -> distorted pixels (n,2), own implementation of plumb-bob."""
        Xc = np.atleast_2d(X) @ self.R.T + self.t
        x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
        k1, k2, p1, p2, k3 = self.dist
        r2 = x * x + y * y
        rad = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.column_stack([self.K[0, 0] * xd + self.K[0, 2],
                                self.K[1, 1] * yd + self.K[1, 2]])

    def depth(self, X):
        return (np.atleast_2d(X) @ self.R.T + self.t)[:, 2]


def make_cams(variant='base'):
    # cam0: high behind the robot's end (x<0) looking down the table; 1280x1024, barrel.
    eye0 = (-3.25, -0.25, 1.55) if variant != 'lowcam' else (-3.3, -0.1, 0.42)
    tgt0 = (0.4, 0.0, 0.0) if variant != 'lowcam' else (0.4, 0.0, 0.12)
    c0 = Cam('cam0', 1280, 1024, 1050.0, eye0, tgt0, [-0.09, 0.03, 0.0004, -0.0003, 0.0])
    # cam1: side (-y), table height + 1 m, toward the far half; 800x600, slight pincushion.
    c1 = Cam('cam1', 800, 600, 640.0, (0.45, -2.45, 1.76), (0.2, 0.0, 0.05),
             [0.04, -0.01, 0.0, 0.0, 0.0])
    return [c0, c1]


# ----------------------------------------------------------------------------- scene
PEOPLE = [((3.6, 0.9, 0.05), (0.22, 0.18, 0.85), (0.55, 0.10, 0.08)),
          ((3.9, -1.3, 0.10), (0.24, 0.20, 0.90), (0.15, 0.20, 0.45)),
          ((0.9, 3.2, 0.05), (0.25, 0.20, 0.88), (0.80, 0.80, 0.76)),   # white shirt
          ((-1.6, 3.0, 0.0), (0.22, 0.19, 0.80), (0.45, 0.35, 0.25)),
          ((-4.2, 1.8, 0.05), (0.23, 0.20, 0.86), (0.75, 0.70, 0.65))]


def scene_hit(C, d, pattern):
    """Static scene along rays from C: depth (n,), point (n,3), normal (n,3), albedo (n,3),
    shadowable (n,) (table/floor: receives the ball's shadow)."""
    n = len(d)
    depth = np.full(n, np.inf)
    alb = np.zeros((n, 3))
    nor = np.zeros((n, 3))
    kind = np.zeros(n, np.int8)

    def take(s, mask, a, nn, k):
        m = mask & (s > 1e-6) & (s < depth)
        depth[m] = s[m]
        alb[m] = a[m] if np.ndim(a) == 2 else a
        nor[m] = nn
        kind[m] = k
    with np.errstate(divide='ignore', invalid='ignore'):
        # walls (box), floor
        for axis, half in ((0, ROOM[0]), (1, ROOM[1])):
            for sign in (-1, 1):
                s = (sign * half - C[axis]) / d[:, axis]
                P = C + s[:, None] * d
                nn = np.zeros(3)
                nn[axis] = -sign
                u = P[:, 1 - axis]
                if pattern:
                    stripe = (np.floor(u / 0.22) % 2).astype(bool)
                    a = np.where(stripe[:, None], [0.62, 0.58, 0.50], [0.18, 0.22, 0.32])
                    band = (P[:, 2] > 0.9) & (P[:, 2] < 1.2)
                    a[band] = [0.75, 0.75, 0.72]
                else:
                    a = np.tile([0.45, 0.45, 0.43], (n, 1))
                take(s, np.ones(n, bool), a, nn, 4)
        s = (FLOOR_Z - C[2]) / d[:, 2]
        take(s, d[:, 2] < 0, np.array(FLOOR_ALB), [0, 0, 1], 2)
        # people (ellipsoids)
        if pattern:
            for c, ax, col in PEOPLE:
                c, ax = np.asarray(c), np.asarray(ax)
                o = (C - c) / ax
                dd = d / ax
                A = (dd * dd).sum(1)
                B = (dd * o).sum(1)
                Cc = o @ o - 1
                disc = B * B - A * Cc
                s = (-B - np.sqrt(np.maximum(disc, 0))) / A
                P = C + s[:, None] * d
                nn = (P - c) / ax ** 2
                nn /= np.linalg.norm(nn, axis=1, keepdims=True)
                m = (disc > 0) & (s > 0) & (s < depth)
                depth[m] = s[m]
                alb[m] = col
                nor[m] = nn[m]
                kind[m] = 5
        # table top
        s = -C[2] / d[:, 2]
        P = C + s[:, None] * d
        on = (np.abs(P[:, 0]) <= HALF_L) & (np.abs(P[:, 1]) <= HALF_W)
        line = ((np.abs(P[:, 0]) > HALF_L - 0.02) | (np.abs(P[:, 1]) > HALF_W - 0.02)
                | (np.abs(P[:, 1]) < 0.0015))
        a = np.where(line[:, None], [0.80, 0.80, 0.78], [0.05, 0.30, 0.12])
        take(s, on & (d[:, 2] < 0), a, [0, 0, 1], 1)
        # table edge (front faces at x=+-HALF_L, 25 mm thick), dark green
        for sign in (-1, 1):
            s = (sign * HALF_L - C[0]) / d[:, 0]
            P = C + s[:, None] * d
            m = (np.abs(P[:, 1]) <= HALF_W) & (P[:, 2] <= 0) & (P[:, 2] >= -0.025)
            take(s, m, np.array([0.04, 0.20, 0.08]), [sign, 0, 0], 3)
        # net: plane x=0, threads + top tape; holes pass through
        s = -C[0] / d[:, 0]
        P = C + s[:, None] * d
        inn = (np.abs(P[:, 1]) <= HALF_W + NET_OVER) & (P[:, 2] >= 0) & (P[:, 2] <= NET_H)
        tape = P[:, 2] >= NET_H - 0.015
        fy = np.mod(P[:, 1], 0.014) < 0.0022
        fz = np.mod(P[:, 2], 0.014) < 0.0022
        solid = inn & (tape | fy | fz)
        a = np.where(tape[:, None], [0.85, 0.85, 0.85], [0.03, 0.03, 0.07])
        take(s, solid, a, [-np.sign(C[0]) or -1.0, 0, 0], 6)
    P = C + np.where(np.isfinite(depth), depth, 0)[:, None] * d
    return depth, P, nor, alb, kind


def table_blocks_key(P):
    """Floor points whose path to the key light crosses the table top (static shadow)."""
    s = -P[:, 2] / KEY_DIR[2]
    Q = P + s[:, None] * KEY_DIR
    return (P[:, 2] < -0.01) & (np.abs(Q[:, 0]) <= HALF_L) & (np.abs(Q[:, 1]) <= HALF_W)


def shade(P, nor, alb, kind, key_vis, view):
    ndl = np.clip(nor @ KEY_DIR, 0, None) * key_vis
    ndf = np.clip(nor @ FILL_DIR, 0, None)
    rad = alb * (AMBIENT + KEY_I * ndl + FILL_I * ndf)[:, None]
    return rad


def sphere_hit(C, d, c):
    """Rays from C (d (n,3)) against spheres at c ((n,3) or (3,)): distance or inf."""
    oc = C - c
    b = (d * oc).sum(-1)
    cc = (oc * oc).sum(-1) - R_BALL ** 2
    disc = b * b - cc
    s = -b - np.sqrt(np.maximum(disc, 0))
    return np.where((disc > 0) & (s > 0), s, np.inf)


def ball_blocks_key(P, c):
    """Points P (n,3) whose path toward the key light passes through the ball at c (n,3)."""
    oc = P - c
    b = oc @ KEY_DIR if oc.ndim == 1 else (oc * KEY_DIR).sum(-1)
    cc = (oc * oc).sum(-1) - R_BALL ** 2
    disc = b * b - cc
    return (disc > 0) & (-b - np.sqrt(np.maximum(disc, 0)) > 0)


BALL_ALB = {'white': np.array([0.86, 0.86, 0.84]), 'orange': np.array([0.92, 0.38, 0.06])}


def radiance_samples(cam, d, centres, colour, pattern, static=None):
    """Radiance (n,3) of rays d from cam with the ball at centres (n,3) (None: no ball);
    also returns the ball-hit mask."""
    C = cam.C
    if static is None:
        static = scene_hit(C, d, pattern)
    depth, P, nor, alb, kind = static
    key_vis = np.ones(len(d))
    key_vis[table_blocks_key(P)] = 0.0
    view = -d
    if centres is None:
        return shade(P, nor, alb, kind, key_vis, view), np.zeros(len(d), bool)
    recv = (kind == 1) | (kind == 2) | (kind == 3)
    sh = recv & ball_blocks_key(P, centres)
    key_vis[sh] = 0.0
    rad = shade(P, nor, alb, kind, key_vis, view)
    s = sphere_hit(C, d, centres)
    hit = s < depth
    if hit.any():
        Q = C + s[hit, None] * d[hit]
        nb = (Q - centres[hit]) / R_BALL
        a = BALL_ALB[colour]
        ndl = np.clip(nb @ KEY_DIR, 0, None)
        ndf = np.clip(nb @ FILL_DIR, 0, None)
        refl = 2 * (nb @ KEY_DIR)[:, None] * nb - KEY_DIR
        spec = 0.45 * np.clip((refl * -d[hit]).sum(1), 0, None) ** 40 * (ndl > 0)
        rad[hit] = a * (AMBIENT + KEY_I * ndl + FILL_I * ndf)[:, None] + spec[:, None]
    return rad, hit


def background(cam, pattern, ss=2):
    """Static image radiance (h,w,3) with ss x ss supersampling."""
    out = np.zeros((cam.h, cam.w, 3))
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    ys = np.arange(cam.h)
    for r0 in range(0, cam.h, 64):
        rows = ys[r0:r0 + 64]
        acc = np.zeros((len(rows), cam.w, 3))
        for oy in offs:
            for ox in offs:
                uu, vv = np.meshgrid(np.arange(cam.w) + ox, rows + oy)
                d = cam.rays(np.column_stack([uu.ravel(), vv.ravel()]))
                rad, _ = radiance_samples(cam, d, None, 'white', pattern)
                acc += rad.reshape(len(rows), cam.w, 3)
        out[r0:r0 + 64] = acc / ss ** 2
    return out


# ----------------------------------------------------------------------------- physics
K_D = 0.5 * 1.2 * 0.50 * np.pi * R_BALL ** 2 / 0.0027     # quadratic drag, 1/m
K_M = 0.5 * 1.2 * np.pi * R_BALL ** 3 / 0.0027              # Magnus a = K_M*C_L'*(w x v)


def _acc(vx, vy, vz, wx, wy, wz):
    sp = (vx * vx + vy * vy + vz * vz) ** 0.5
    km = 0.9 * K_M
    return (-K_D * sp * vx + km * (wy * vz - wz * vy),
            -K_D * sp * vy + km * (wz * vx - wx * vz),
            -9.81 - K_D * sp * vz + km * (wx * vy - wy * vx))


def simulate(p0, v0, w0, T, dt=1e-4):
    """RK4 flight (gravity, quadratic drag, Magnus), table bounce (e_z 0.9, horizontal
    speed x0.78, spin x0.7). Scalar Python for speed."""
    n = int(round(T / dt)) + 1
    ts = np.arange(n) * dt
    P = np.zeros((n, 3))
    V = np.zeros((n, 3))
    x, y, z = map(float, p0)
    vx, vy, vz = map(float, v0)
    wx, wy, wz = map(float, w0)
    bounces = []
    h = dt
    for i in range(n):
        P[i] = (x, y, z)
        V[i] = (vx, vy, vz)
        a1 = _acc(vx, vy, vz, wx, wy, wz)
        b = (vx + .5 * h * a1[0], vy + .5 * h * a1[1], vz + .5 * h * a1[2])
        a2 = _acc(*b, wx, wy, wz)
        c = (vx + .5 * h * a2[0], vy + .5 * h * a2[1], vz + .5 * h * a2[2])
        a3 = _acc(*c, wx, wy, wz)
        d = (vx + h * a3[0], vy + h * a3[1], vz + h * a3[2])
        a4 = _acc(*d, wx, wy, wz)
        xn = x + h / 6 * (vx + 2 * b[0] + 2 * c[0] + d[0])
        yn = y + h / 6 * (vy + 2 * b[1] + 2 * c[1] + d[1])
        zn = z + h / 6 * (vz + 2 * b[2] + 2 * c[2] + d[2])
        vxn = vx + h / 6 * (a1[0] + 2 * a2[0] + 2 * a3[0] + a4[0])
        vyn = vy + h / 6 * (a1[1] + 2 * a2[1] + 2 * a3[1] + a4[1])
        vzn = vz + h / 6 * (a1[2] + 2 * a2[2] + 2 * a3[2] + a4[2])
        if zn < R_BALL <= z and vzn < 0 and abs(xn) <= HALF_L and abs(yn) <= HALF_W:
            f = (z - R_BALL) / (z - zn)
            xc, yc = x + f * (xn - x), y + f * (yn - y)
            ux, uy, uz = vx + f * (vxn - vx), vy + f * (vyn - vy), vz + f * (vzn - vz)
            ux, uy, uz = 0.78 * ux, 0.78 * uy, -0.9 * uz
            wx, wy, wz = 0.7 * wx, 0.7 * wy, 0.7 * wz
            bounces.append(ts[i] + f * dt)
            r = (1 - f) * dt
            xn, yn, zn = xc + r * ux, yc + r * uy, R_BALL + r * uz
            vxn, vyn, vzn = ux, uy, uz
        x, y, z, vx, vy, vz = xn, yn, zn, vxn, vyn, vzn
    return {'t': ts, 'p': P, 'v': V, 'bounces': bounces}


def aim(p0, speed, yaw, target_x, w0):
    """Elevation such that the first bounce is at x = target_x (bisection)."""
    lo, hi = -0.35, 0.6
    for _ in range(30):
        el = 0.5 * (lo + hi)
        v0 = speed * np.array([np.cos(el) * np.cos(yaw), np.cos(el) * np.sin(yaw), np.sin(el)])
        tr = simulate(p0, v0, w0, 0.6, dt=5e-4)
        if tr['bounces']:
            i = int(tr['bounces'][0] / 5e-4)
            xb = tr['p'][i, 0]
        else:
            xb = 9.0
        if xb > target_x:
            hi = el
        else:
            lo = el
    return v0


def make_flights(kind):
    specs = {
        'std': [(7.0, (-1.50, -0.25, 0.32), 0.80, 0.10, (0, 0, 0)),
                (10.0, (-1.45, 0.30, 0.30), 1.00, -0.45, (0, 120, 0)),    # topspin
                (12.0, (-1.40, 0.05, 0.36), 0.70, 0.30, (0, -60, 40))],   # backspin+side
        'low': [(8.0, (-1.50, -0.20, 0.22), 0.55, 0.10, (0, 60, 0)),
                (6.5, (-1.45, 0.25, 0.25), 0.45, -0.25, (0, 0, 0)),
                (9.5, (-1.40, 0.00, 0.22), 0.65, 0.30, (0, 100, 0))],
    }[kind]
    flights = []
    for speed, p0, tx, ty, w0 in specs:
        p0 = np.array(p0)
        yaw = np.arctan2(ty - p0[1], tx - p0[0])
        v0 = aim(p0, speed, yaw, tx, np.array(w0, float))
        dur = 0.75 if kind == 'std' else 0.7
        tr = simulate(p0, v0, np.array(w0, float), dur)
        i0 = np.argmin(np.abs(tr['p'][:, 0]))
        tr['net_clear'] = tr['p'][i0, 2] - NET_H
        tr['w0'] = w0
        flights.append(tr)
    return flights


def state_at(tr, t):
    x = (t) / (tr['t'][1] - tr['t'][0])
    i = np.clip(np.floor(x).astype(int), 0, len(tr['t']) - 2)
    f = (x - i)[..., None]
    return tr['p'][i] * (1 - f) + tr['p'][i + 1] * f, tr['v'][i] * (1 - f) + tr['v'][i + 1] * f


# ----------------------------------------------------------------------------- frames
def render_ball_window(cam, img, flight, t_local, opts):
    """Add the ball (and its shadow) to img (radiance, h,w,3) for the frame whose middle
    (middle row with rolling shutter) is at flight-local time t_local. Returns visible
    fraction of the ball at mid time (samples hit / samples of the unoccluded disc)."""
    nsub = opts['nsub']
    exp = opts['exposure']
    rs = opts['rolling']                 # top-to-bottom readout span, s
    tsub = (np.arange(nsub) + 0.5) / nsub * exp - exp / 2 if nsub > 1 else np.zeros(1)
    span = np.array([-exp / 2 - rs / 2, exp / 2 + rs / 2])
    tt = np.linspace(span[0], span[1], 9) + t_local
    tt = np.clip(tt, 0, flight['t'][-1])
    pos, _ = state_at(flight, tt)
    # shadow centres on z=0 and on the floor
    sh0 = pos - (pos[:, 2:3] / KEY_DIR[2]) * KEY_DIR
    sh1 = pos - ((pos[:, 2:3] - FLOOR_Z) / KEY_DIR[2]) * KEY_DIR
    vis_frac = 0.0
    windows = []
    for pts, rad_m in ((pos, R_BALL), (sh0, R_BALL * 1.6), (sh1, R_BALL * 1.6)):
        z = cam.depth(pts)
        if np.any(z < 0.05):
            continue
        uv = cam.project(pts)
        rpx = cam.K[0, 0] * rad_m / z.min() * 1.15 + 3
        u0, v0 = np.floor(uv.min(0) - rpx).astype(int)
        u1, v1 = np.ceil(uv.max(0) + rpx).astype(int)
        u0, v0 = max(u0, 0), max(v0, 0)
        u1, v1 = min(u1, cam.w - 1), min(v1, cam.h - 1)
        if u1 < u0 or v1 < v0 or (u1 - u0) * (v1 - v0) > 250000:
            continue
        windows.append((u0, v0, u1, v1))
    if windows:
        # merge overlapping windows to one box when they overlap
        merged = []
        for w in windows:
            for j, m in enumerate(merged):
                if not (w[2] < m[0] or m[2] < w[0] or w[3] < m[1] or m[3] < w[1]):
                    merged[j] = (min(w[0], m[0]), min(w[1], m[1]), max(w[2], m[2]),
                                 max(w[3], m[3]))
                    break
            else:
                merged.append(w)
        ss = opts['ss']
        offs = (np.arange(ss) + 0.5) / ss - 0.5
        for (u0, v0, u1, v1) in merged:
            uu, vv = np.meshgrid(np.arange(u0, u1 + 1), np.arange(v0, v1 + 1))
            hh, ww = uu.shape
            su = (uu[..., None, None] + offs[None, None, None, :]).repeat(ss, 2)
            sv = (vv[..., None, None] + offs[None, None, :, None]).repeat(ss, 3)
            pix = np.column_stack([su.ravel(), sv.ravel()])
            d = cam.rays(pix)
            static = scene_hit(cam.C, d, opts['pattern'])
            row_t = (pix[:, 1] / (cam.h - 1) - 0.5) * rs if rs > 0 else np.zeros(len(pix))
            acc = np.zeros((len(pix), 3))
            for k, ts in enumerate(tsub):
                tk = np.clip(t_local + ts + row_t, 0, flight['t'][-1])
                c, _ = state_at(flight, tk)
                rad, hit = radiance_samples(cam, d, c, opts['colour'], opts['pattern'], static)
                acc += rad
                if k == len(tsub) // 2 or nsub == 1:
                    cm, _ = state_at(flight, np.full(len(pix), t_local))
                    s_free = sphere_hit(cam.C, d, cm)
                    free = np.isfinite(s_free)
                    if free.sum():
                        vis_frac = max(vis_frac, (free & (s_free < static[0])).sum()
                                       / free.sum())
            acc /= len(tsub)
            img[v0:v1 + 1, u0:u1 + 1] = acc.reshape(hh, ww, ss, ss, 3).mean((2, 3))
    return vis_frac


def finish(img_rad, opts, rng):
    x = 255.0 * GAIN * img_rad
    if opts['noise'] > 0:
        x = x + rng.normal(0, opts['noise'], x.shape)
    x = np.clip(np.round(x), 0, 255).astype(np.uint8)[..., ::-1].copy()   # RGB -> BGR
    if opts['jpeg'] > 0:
        ok, buf = cv2.imencode('.jpg', x, [cv2.IMWRITE_JPEG_QUALITY, opts['jpeg']])
        x = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return x


def write_rig(out, cams, fps):
    entries = []
    for c in cams:
        info = {'image_width': c.w, 'image_height': c.h, 'camera_name': c.name,
                'camera_matrix': {'rows': 3, 'cols': 3, 'data': c.K.ravel().tolist()},
                'distortion_model': 'plumb_bob',
                'distortion_coefficients': {'rows': 1, 'cols': 5, 'data': c.dist.tolist()},
                'rectification_matrix': {'rows': 3, 'cols': 3,
                                         'data': np.eye(3).ravel().tolist()},
                'projection_matrix': {'rows': 3, 'cols': 4,
                                      'data': np.hstack([c.K, np.zeros((3, 1))]).ravel().tolist()}}
        with open(os.path.join(out, c.name + '.yaml'), 'w') as f:
            yaml.safe_dump(info, f, sort_keys=False)
        e = {'name': c.name, 'camera_info': c.name + '.yaml', 'source': f'{c.name}/%06d.png',
             'rotation': c.R.ravel().tolist(), 'translation': c.t.tolist()}
        if c.name != 'cam0':
            e['time_offset'] = 0.0
        entries.append(e)
    with open(os.path.join(out, 'rig.yaml'), 'w') as f:
        yaml.safe_dump({'frame_id': 'table', 'fps': float(fps), 'cameras': entries}, f,
                       sort_keys=False, default_flow_style=None)


CASES = {
    # name: overrides of the base options (one change at a time, then combinations)
    'base': {},
    'pattern': {'pattern': True},
    'blur': {'nsub': 7, 'exposure': 3e-3},
    'noise': {'noise': 3.0},
    'jpeg': {'jpeg': 50},
    'rolling': {'rolling': 5e-3},
    'fps200': {'fps': 200.0},
    'lowcam': {'camvariant': 'lowcam', 'flights': 'low'},
    'darkfloor': {'floor': [0.12, 0.12, 0.12]},
    'all': {'pattern': True, 'nsub': 7, 'exposure': 3e-3, 'noise': 3.0, 'jpeg': 50},
    'all_rs': {'pattern': True, 'nsub': 7, 'exposure': 3e-3, 'noise': 3.0, 'jpeg': 50,
               'rolling': 5e-3},
    'all_orange': {'pattern': True, 'nsub': 7, 'exposure': 3e-3, 'noise': 3.0, 'jpeg': 50,
                   'colour': 'orange'},
    'all_orange_dark': {'pattern': True, 'nsub': 7, 'exposure': 3e-3, 'noise': 3.0, 'jpeg': 50,
                        'colour': 'orange', 'floor': [0.12, 0.12, 0.12]},
    'all_200': {'pattern': True, 'nsub': 7, 'exposure': 3e-3, 'noise': 3.0, 'jpeg': 50,
                'fps': 200.0},
}
BASE = {'pattern': False, 'nsub': 1, 'exposure': 0.0, 'noise': 0.0, 'jpeg': 0, 'rolling': 0.0,
        'fps': 100.0, 'camvariant': 'base', 'flights': 'std', 'colour': 'white', 'ss': 3,
        'floor': [0.62, 0.62, 0.60]}


def render_case(name, outdir, max_frames=None):
    opts = dict(BASE, **CASES[name])
    FLOOR_ALB[:] = opts['floor']
    out = os.path.join(outdir, name)
    os.makedirs(out, exist_ok=True)
    cams = make_cams(opts['camvariant'])
    flights = make_flights(opts['flights'])
    fps = opts['fps']
    lead, gap = 0.15, 0.25
    starts, t = [], lead
    for fl in flights:
        starts.append(t)
        t += fl['t'][-1] + gap
    n_frames = int(t * fps)
    if max_frames:
        n_frames = min(n_frames, max_frames)
    bgs = [background(c, opts['pattern']) for c in cams]
    for c in cams:
        os.makedirs(os.path.join(out, c.name), exist_ok=True)
    write_rig(out, cams, fps)
    rng = np.random.default_rng(1)
    rows = []
    for n in range(n_frames):
        tf = n / fps
        fi = None
        for i, (s, fl) in enumerate(zip(starts, flights, strict=True)):
            if s <= tf <= s + fl['t'][-1]:
                fi = i
        vis = []
        for k, c in enumerate(cams):
            img = bgs[k].copy()
            v = 0.0
            if fi is not None:
                v = render_ball_window(c, img, flights[fi], tf - starts[fi], opts)
            vis.append(v)
            cv2.imwrite(os.path.join(out, c.name, f'{n:06d}.png'), finish(img, opts, rng),
                        [cv2.IMWRITE_PNG_COMPRESSION, 1])
        if fi is not None:
            p, vv = state_at(flights[fi], np.array([tf - starts[fi]]))
            uv = [c.project(p)[0].tolist() for c in cams]
            rows.append([fi, n, tf, *p[0], *vv[0], vis[0], vis[1], *uv[0], *uv[1]])
    with open(os.path.join(out, 'truth.csv'), 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(['ball', 'frame', 't', 'x', 'y', 'z', 'vx', 'vy', 'vz', 'vis0', 'vis1',
                    'u0', 'v0', 'u1', 'v1'])
        for r in rows:
            w.writerow([r[0], r[1]] + [f'{x:.7f}' for x in r[2:]])
    meta = {'opts': opts, 'starts': starts,
            'bounces': [[s + b for b in fl['bounces']]
                        for s, fl in zip(starts, flights, strict=True)],
            'ends': [s + fl['t'][-1] for s, fl in zip(starts, flights, strict=True)],
            'net_clear': [float(fl['net_clear']) for fl in flights],
            'speeds': [float(np.linalg.norm(fl['v'][0])) for fl in flights]}
    with open(os.path.join(out, 'meta.json'), 'w') as f:
        json.dump(meta, f, indent=1)
    return out


# ----------------------------------------------------------------------------- self-check
CHECK_LIMITS = {'projection_px': 1e-6, 'ray_round_trip_arcsec': 0.1,
                'radius_rel': 0.08, 'centroid_px': 0.05}
"""Self-check limits. The drawn radius is held to f r / z loosely: off the optical axis and
with distortion the drawn disc is larger than f r / z by up to ~5 % (the side camera's
pincushion); the centroid of the drawn disc is held to the projected centre tightly."""


def check():
    """The renderer's self-check: its own plumb-bob projection against cv2.projectPoints and
    the pixel -> ray -> pixel round trip (both camera variants, 200 random points over the
    table), and, for three still balls per camera, the radius of the drawn ball (from the area
    of its 8 x 8 supersampled ray hits) against f r / z and the hits' centroid against the
    projected centre. Returns the worst numbers per camera and ``passed`` (CHECK_LIMITS)."""
    rng = np.random.default_rng(0)
    out = {'limits': CHECK_LIMITS, 'cameras': {}}
    ok = True
    for variant in ('base', 'lowcam'):
        for c in make_cams(variant):
            X = np.column_stack([rng.uniform(-1.4, 1.4, 200), rng.uniform(-0.8, 0.8, 200),
                                 rng.uniform(0, 0.6, 200)])
            mine = c.project(X)
            ref = cv2.projectPoints(X.reshape(-1, 1, 3), cv2.Rodrigues(c.R)[0], c.t, c.K,
                                    c.dist)[0].reshape(-1, 2)
            inimg = (ref[:, 0] > 0) & (ref[:, 0] < c.w) & (ref[:, 1] > 0) & (ref[:, 1] < c.h)
            d = c.rays(ref[inimg])
            e = X[inimg] - c.C
            e /= np.linalg.norm(e, axis=1, keepdims=True)
            ang = np.degrees(np.arccos(np.clip((d * e).sum(1), -1, 1)))
            row = {'projection_max_diff_px': float(np.abs(mine - ref).max()),
                   'ray_round_trip_max_arcsec': round(float(ang.max() * 3600), 4),
                   'points_in_image': int(inimg.sum())}
            ok &= (row['projection_max_diff_px'] <= CHECK_LIMITS['projection_px']
                   and row['ray_round_trip_max_arcsec'] <= CHECK_LIMITS['ray_round_trip_arcsec'])
            out['cameras'][f'{variant}_{c.name}'] = row
    ss = 8
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    for c in make_cams('base'):
        worst_rel, worst_centroid = 0.0, 0.0
        for X in ([-1.0, 0.2, 0.3], [0.5, -0.3, 0.25], [1.2, 0.3, 0.4]):
            X = np.array(X)
            u, v = c.project(X[None])[0]
            uu, vv = np.meshgrid(np.arange(int(u) - 40, int(u) + 41),
                                 np.arange(int(v) - 40, int(v) + 41))
            cov = np.zeros(uu.shape)
            for oy in offs:
                for ox in offs:
                    d = c.rays(np.column_stack([uu.ravel() + ox, vv.ravel() + oy]))
                    cov += np.isfinite(sphere_hit(c.C, d, X)).reshape(uu.shape)
            cov /= ss * ss
            area = cov.sum()
            expect = c.K[0, 0] * R_BALL / c.depth(X[None])[0]
            worst_rel = max(worst_rel, abs(np.sqrt(area / np.pi) / expect - 1.0))
            centroid = np.array([(cov * uu).sum(), (cov * vv).sum()]) / area
            worst_centroid = max(worst_centroid, float(np.abs(centroid - (u, v)).max()))
        row = out['cameras'][f'base_{c.name}']
        row['drawn_radius_max_rel_diff'] = round(float(worst_rel), 4)
        row['drawn_centroid_max_diff_px'] = round(worst_centroid, 4)
        ok &= (worst_rel <= CHECK_LIMITS['radius_rel']
               and worst_centroid <= CHECK_LIMITS['centroid_px'])
    out['passed'] = bool(ok)
    return out


if __name__ == '__main__':
    ap = argparse.ArgumentParser(description='Render one side-light case (or --check).')
    ap.add_argument('case', nargs='?', choices=sorted(CASES))
    ap.add_argument('--check', action='store_true', help='run the self-check and print it')
    ap.add_argument('--out', default=os.path.join(os.path.dirname(__file__), 'out'))
    ap.add_argument('--max-frames', type=int)
    a = ap.parse_args()
    if a.check or not a.case:
        print(json.dumps(check(), indent=1))
    else:
        print(render_case(a.case, a.out, a.max_frames))
