"""An independent renderer of table-tennis camera scenes, to judge tt_perception (issue 15).

Test-only: nothing in the tt packages imports this module, and it uses nothing of
``tt_perception.synth`` or ``tt_prediction`` (only the rig's calibration, which perception has
too). Its flight, lighting, shading, sensor and codec are written here from the physics, so
that perception is judged on images it was not developed against.

Frames and units (MODEL.md): the ``table`` frame has its origin at the centre of the playing
surface, x along the table (the robot's end at x = -1.37), y across, z up (surface z = 0,
floor z = -0.76). Lengths in m, times in s, velocities in m/s, spin in rad/s; image
coordinates in pixels with pixel (i, j) centred on (u, v) = (j, i) (OpenCV's convention, the
one ``cv2.projectPoints`` and the detector use). Radiance is in relative linear units: 1.0 is
a white (albedo 1) horizontal surface at the table's centre under the direct light alone.

Parts:

- Flight: :func:`simulate` integrates gravity, quadratic drag and the Magnus force
  (``scipy.integrate.solve_ivp``, DOP853) with rigid-body impulse bounces on the table top
  (Coulomb friction, limited by rolling; thin-shell inertia); :func:`serve` aims a ball from
  the opponent's side at a point of the robot's half. :class:`Flight` holds the truth.
- Scene: the table (a 3 cm thick box, dark blue, 20 mm white border lines, 3 mm centre line),
  the net (dark mesh, white top tape), a textured floor and walls of other greys, and still
  balls (white and orange) lying on the table and on the floor; lit by three rectangular
  ceiling panels (each sampled by a 3 x 3 grid of points), a hemisphere of ambient light
  from above and the light bounced from below (for the ball, ray cast: the blue table under
  it, the warm grey floor beyond; weak), with a 100 Hz ripple of the lamps. Every shadow
  (the table's on the floor, the net's, the still balls', the flying ball's on table and
  floor while it is within 0.6 m of them) is the fraction of the light samples a shadow
  ray finds occluded, so penumbrae are physical.
- Shading: Oren-Nayar diffuse reflection (rough matte ball) plus a broad sheen lobe; the
  background surfaces are Lambertian.
- Camera: for every pixel in a box around a moving object, 4 x 4 sub-pixel rays (undistorted
  with ``cv2.undistortPoints`` and the camera's K and distortion) at 8 instants over the
  exposure (motion blur), intersected analytically with the object and depth-tested against
  the static scene. The static background is ray cast once per camera (2 x 2 samples a pixel).
- Sensor (:class:`Sensor`): radial-polynomial vignetting, an RGGB Bayer mosaic, shot noise
  (Gaussian with the Poisson variance) and read noise in electrons, a 12-bit ADC, OpenCV's
  bilinear demosaicing, a gamma 2.2 response with a soft shoulder, and JPEG at quality 30
  with 4:2:0 chroma subsampling (encoded and decoded with OpenCV).

Entry point: :func:`render_scene` yields ``(t, camera_index, frame)`` in time order (``t`` the
exposure mid-time, s, on the common clock; ``frame`` uint8 BGR) and returns the truth.
"""

import copy
import dataclasses

import cv2
import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

# --- Ball and air (MODEL.md, nominal constants) ---------------------------------------------
RADIUS = 0.020
"""Ball radius, m."""
MASS = 2.7e-3
"""Ball mass, kg."""
GRAVITY = 9.8
"""m/s^2, along -z."""
AIR_DENSITY = 1.184
"""kg/m^3."""
AREA = 12.5e-4
"""Projected area of the ball, m^2."""
DRAG_COEFF = 0.54
MAGNUS_COEFF = 0.069
RESTITUTION = 0.93
"""Normal coefficient of restitution of the table."""
FRICTION = 0.25
"""Ball-table dynamic friction coefficient."""

# --- Hall geometry, m, table frame ----------------------------------------------------------
TABLE_HALF_LENGTH = 1.37
TABLE_HALF_WIDTH = 0.7625
TABLE_THICKNESS = 0.03
NET_HEIGHT = 0.1525
NET_HALF_WIDTH = 0.915
NET_TAPE = 0.015
"""Height of the net's white top tape, m."""
BORDER_LINE = 0.020
CENTRE_LINE = 0.003
FLOOR_Z = -0.76
WALLS = {'x+': 5.5, 'x-': -6.5, 'y+': 4.0, 'y-': -5.0}
"""Plane positions of the four walls, m."""
CEILING_Z = 3.8
SPARE_BALLS = (((-1.20, 0.60, RADIUS), 'white'), ((-1.12, 0.64, RADIUS), 'orange'),
               ((-0.50, 1.30, FLOOR_Z + RADIUS), 'white'),
               ((-0.62, 1.22, FLOOR_Z + RADIUS), 'orange'))
"""Still balls lying on the table (near the robot's left corner, in both cameras' views) and
on the floor beside it (centre, colour)."""

BALL_ALBEDO = {'white': (0.86, 0.85, 0.83), 'orange': (0.95, 0.45, 0.08)}
"""Diffuse reflectance (R, G, B) of the balls."""

# Surface ids of the static scene.
NOTHING, FLOOR, WALL, CEILING, TABLE_TOP, TABLE_SIDE, NET, SPARE = range(8)


# ============================================================================================
# Flight
# ============================================================================================

def acceleration(v, w, drag=True, magnus=True):
    """Acceleration (3,), m/s^2, of a ball flying at velocity ``v`` (3,), m/s, with spin ``w``
    (3,), rad/s: gravity, quadratic drag -1/2 C_D rho A |v| v / m and the Magnus force
    (4/3) C_M pi rho r^3 (w x v) / m."""
    a = np.array([0.0, 0.0, -GRAVITY])
    if drag:
        a = a - 0.5 * DRAG_COEFF * AIR_DENSITY * AREA * np.linalg.norm(v) * v / MASS
    if magnus:
        a = a + (4.0 / 3.0) * MAGNUS_COEFF * np.pi * AIR_DENSITY * RADIUS ** 3 \
            * np.cross(w, v) / MASS
    return a


def bounce(state, restitution=RESTITUTION, friction=FRICTION):
    """State (9,) [p, v, w] just after an impact on the table top (normal +z) of the ball in
    ``state`` (9,), just before it.

    An impulse at the contact point c = (0, 0, -r) from the centre: normally it turns v_z into
    -e v_z (impulse J_n = m (1 + e) |v_z|); tangentially it opposes the slip velocity
    u = v_t + w x c of the contact point. For a thin shell (I = 2/3 m r^2) a tangential
    impulse J changes u by (1/m + r^2/I) J = 5/2 J/m, so slip stops at J = -2/5 m u; Coulomb
    friction caps |J| at mu J_n. Spin changes by (c x J) / I.
    """
    p, v, w = state[:3].copy(), state[3:6].copy(), state[6:].copy()
    c = np.array([0.0, 0.0, -RADIUS])
    jn = MASS * (1.0 + restitution) * abs(v[2])
    slip = v + np.cross(w, c)
    slip[2] = 0.0
    speed = np.linalg.norm(slip)
    if speed > 0.0:
        jt = -slip / speed * min(friction * jn, 0.4 * MASS * speed)
    else:
        jt = np.zeros(3)
    inertia = (2.0 / 3.0) * MASS * RADIUS ** 2
    v_new = v + jt / MASS
    v_new[2] = -restitution * v[2]
    w_new = w + np.cross(c, jt) / inertia
    return np.concatenate([p, v_new, w_new])


@dataclasses.dataclass
class Flight:
    """The truth of one ball's flight: a list of integrated segments between impacts.

    ``t0`` the launch time and ``t_end`` the end (s): the end of the simulated interval or the
    instant the ball reaches the floor. ``bounces``: (time, state before, state after) of each
    table impact. :meth:`state` gives the state [p (m), v (m/s), w (rad/s)] at any times.
    """

    t0: float
    t_end: float
    segments: list
    bounces: list
    end: str

    def state(self, t):
        """States (n, 9) at the times ``t`` (n,), s; NaN outside [t0, t_end]."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.full((t.size, 9), np.nan)
        for a, b, sol, w in self.segments:
            inside = (t >= a) & (t <= b)
            if inside.any():
                out[inside, :6] = sol(t[inside]).T
                out[inside, 6:] = w
        return out

    @property
    def bounce_times(self):
        return [b[0] for b in self.bounces]


def _rhs(drag, magnus, w):
    def f(_, y):
        return np.concatenate([y[3:6], acceleration(y[3:6], w, drag, magnus)])
    return f


def _on_table(p):
    return abs(p[0]) <= TABLE_HALF_LENGTH and abs(p[1]) <= TABLE_HALF_WIDTH


def simulate(state, t0=0.0, t_end=1.0, drag=True, magnus=True, restitution=RESTITUTION,
             friction=FRICTION, max_bounces=3, rtol=1e-11, atol=1e-12):
    """Integrate a ball from ``state`` (9,) at ``t0`` until ``t_end`` (s) or the floor.

    Spin is constant in flight (MODEL.md); it changes only at impacts. An impact is the
    ball's centre coming down through z = r over the table's footprint (:func:`bounce`);
    off the footprint the ball falls on to the floor, where the flight ends. Returns a
    :class:`Flight`.
    """
    y = np.asarray(state, dtype=float).copy()
    t = float(t0)
    segments, bounces = [], []
    table_armed = y[2] > RADIUS
    end = 'time'
    while t < t_end:
        w = y[6:].copy()

        def table(_, s):
            return s[2] - RADIUS
        table.terminal = True
        table.direction = -1

        def floor(_, s):
            return s[2] - (FLOOR_Z + RADIUS)
        floor.terminal = True
        floor.direction = -1
        events = [floor, table] if table_armed else [floor]
        sol = solve_ivp(_rhs(drag, magnus, w), (t, t_end), y[:6], method='DOP853',
                        rtol=rtol, atol=atol, dense_output=True, events=events)
        t_stop = float(sol.t[-1])
        segments.append((t, t_stop, sol.sol, w))
        t = t_stop
        if sol.status != 1:
            break
        y_stop = np.concatenate([sol.y[:, -1], w])
        if sol.t_events[0].size:                       # the floor: the flight ends
            end = 'floor'
            break
        if _on_table(y_stop) and len(bounces) < max_bounces:
            after = bounce(y_stop, restitution, friction)
            bounces.append((t, y_stop, after))
            y = after
        else:                                          # past the table's edge: falls on
            table_armed = False
            y = y_stop
            if len(bounces) >= max_bounces and _on_table(y_stop):
                end = 'bounces'
                break
    return Flight(float(t0), t, segments, bounces, end)


def serve(speed=8.0, topspin_rps=0.0, sidespin_rps=0.0, start=(1.5, 0.1, 0.3),
          target=(-0.7, -0.1)):
    """Initial state (9,) of a ball served from ``start`` (m) toward the robot's half.

    Horizontal speed ``speed`` (m/s) toward ``target`` (x, y); the vertical velocity is solved
    (Brent's method on this module's flight) so that the first impact is at x = target x.
    ``topspin_rps`` spins it about the horizontal axis across its path (positive: topspin, the
    top of the ball moving forward: w along z x d for a path along d), ``sidespin_rps`` about
    +z. Raises ValueError when the ball would not clear the net.
    """
    p = np.asarray(start, dtype=float)
    d = np.array([target[0] - p[0], target[1] - p[1], 0.0])
    d /= np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    w = 2.0 * np.pi * (topspin_rps * np.cross(z, d) + sidespin_rps * z)

    def landing(vz):
        s0 = np.concatenate([p, speed * d + vz * z, w])
        f = simulate(s0, 0.0, 3.0, max_bounces=1)
        return f

    def miss(vz):
        f = landing(vz)
        if not f.bounces:
            return -10.0
        return f.bounces[0][1][0] - target[0]

    vz = brentq(miss, -3.0, 4.0, xtol=1e-12)
    state = np.concatenate([p, speed * d + vz * z, w])
    f = landing(vz)
    # Height when crossing the net.
    ts = np.linspace(f.t0, f.bounce_times[0], 2000)
    s = f.state(ts)
    i = int(np.argmin(np.abs(s[:, 0])))
    if s[i, 2] < NET_HEIGHT + RADIUS:
        raise ValueError(f'the ball does not clear the net (z = {s[i, 2]:.3f} m at x = 0)')
    return state


# ============================================================================================
# Lighting and shading
# ============================================================================================

@dataclasses.dataclass
class Lighting:
    """The hall's light.

    ``panels``: rectangular ceiling lamps (centre (3,), m; size along x and y, m; relative
    power), each a Lambertian emitter facing down, sampled by ``samples`` x ``samples``
    points. Their total is scaled so that the direct irradiance on a horizontal surface at the
    table's centre is ``direct`` (radiance units, per channel times ``colour``).
    ``sky``: ambient irradiance from the upper hemisphere (walls, ceiling), RGB; ``bounce``:
    from the lower (the floor; warm, weak), for the static surfaces: one of normal n gets
    sky (1 + n_z) / 2 + bounce (1 - n_z) / 2. Moving objects (the ball) get the lower
    hemisphere's light by ray casting the scene below them instead
    (:meth:`Renderer.environment_below`). ``flicker``: relative amplitude of the lamps'
    100 Hz ripple (``flicker_hz``), integrated over each exposure.
    """

    panels: tuple = (((-1.6, 0.9, 3.4), (1.25, 0.3), 1.0),
                     ((0.3, -1.2, 3.3), (1.25, 0.3), 0.9),
                     ((2.0, 0.7, 3.5), (1.25, 0.3), 1.1))
    samples: int = 3
    direct: float = 1.0
    colour: tuple = (1.0, 0.97, 0.92)
    sky: tuple = (0.21, 0.22, 0.24)
    bounce: tuple = (0.075, 0.06, 0.045)
    flicker: float = 0.03
    flicker_hz: float = 100.0

    def points(self):
        """Light sample positions (J, 3), m, and their weights (J, 3): radiance x area, scaled
        as the class says."""
        pts, power = [], []
        n = self.samples
        grid = (np.arange(n) + 0.5) / n - 0.5
        for centre, (sx, sy), pw in self.panels:
            for gx in grid:
                for gy in grid:
                    pts.append((centre[0] + gx * sx, centre[1] + gy * sy, centre[2]))
                    power.append(pw / n ** 2)
        pts = np.array(pts)
        power = np.array(power)
        # Direct irradiance at the table's centre (normal +z) with unit weights.
        rel = pts - np.array([0.0, 0.0, 0.0])
        d2 = np.sum(rel ** 2, axis=1)
        cos = rel[:, 2] / np.sqrt(d2)
        e0 = np.sum(power * cos * cos / d2)
        weights = (power * self.direct / e0)[:, None] * np.asarray(self.colour)[None, :]
        return pts, weights

    def gain(self, t, exposure):
        """Mean relative light level over an exposure of ``exposure`` s centred on ``t``."""
        if self.flicker == 0.0 or exposure <= 0.0:
            return 1.0 + self.flicker * np.cos(2 * np.pi * self.flicker_hz * t)
        x = np.pi * self.flicker_hz * exposure
        return 1.0 + self.flicker * np.cos(2 * np.pi * self.flicker_hz * t) * np.sin(x) / x


@dataclasses.dataclass
class Material:
    """Reflectance of a surface: diffuse ``albedo`` (R, G, B), Oren-Nayar ``roughness`` (rad,
    0: Lambert), ``sheen`` weight and ``sheen_power`` of a broad (n . h)^p lobe."""

    albedo: tuple
    roughness: float = 0.0
    sheen: float = 0.0
    sheen_power: float = 4.0


def ball_material(colour):
    """A table-tennis ball's surface (matte plastic: rough diffuse plus a broad sheen)."""
    albedo = BALL_ALBEDO[colour] if isinstance(colour, str) else tuple(colour)
    return Material(albedo, roughness=0.35, sheen=0.08, sheen_power=4.0)


def _segment_hits_sphere(P, S, centres, radius):
    """(M, J) fraction of the ``centres`` (T, 3) at which a sphere of ``radius`` crosses the
    segment from the points P (M, 3) to the light samples S (J, 3) (all above the points).

    The segment P + u D (D = S - P, 0 < u < 1) meets the sphere where
    |D|^2 u^2 + 2 D.(P - c) u + |P - c|^2 - r^2 = 0. Points that no segment to a light can
    bring near the sphere (far to its side, or above it) are skipped.
    """
    out = np.zeros((len(P), len(S)))
    centres = np.atleast_2d(centres)
    reach_xy = np.linalg.norm(P[:, :2], axis=1) + np.linalg.norm(S[:, :2], axis=1).max()
    s_low = S[:, 2].min()
    for c in centres:
        rise = c[2] + radius - P[:, 2]
        with np.errstate(divide='ignore', invalid='ignore'):
            reach = 2.0 * radius + rise / (s_low - P[:, 2]) * reach_xy
        near = (rise > 0.0) & (np.linalg.norm(P[:, :2] - c[:2], axis=1) <= reach)
        if not near.any():
            continue
        p = P[near]
        D = S[None, :, :] - p[:, None, :]                     # (m, J, 3)
        dd = np.einsum('mjk,mjk->mj', D, D)
        pc = p - c
        b = np.einsum('mjk,mk->mj', D, pc)
        cc = np.einsum('mk,mk->m', pc, pc)[:, None] - radius ** 2
        disc = b * b - dd * cc
        hit = disc > 0.0
        root = (-b - np.sqrt(np.where(hit, disc, 0.0))) / dd
        out[near] += hit & (root > 1e-6) & (root < 1.0) & (cc > 0.0)
    return out / len(centres)


def _static_blocked(P, S):
    """(M, J) True where the segment from P (M, 3) to light sample S (J, 3) is blocked by the
    table top, the net or a spare ball."""
    blocked = np.zeros((len(P), len(S)), bool)
    # Table top (plane z = 0), for points below it.
    below = P[:, 2] < -1e-7
    if below.any():
        p = P[below]
        u = -p[:, 2:3] / (S[None, :, 2] - p[:, 2:3])
        x = p[:, 0:1] + u * (S[None, :, 0] - p[:, 0:1])
        y = p[:, 1:2] + u * (S[None, :, 1] - p[:, 1:2])
        blocked[below] = (np.abs(x) <= TABLE_HALF_LENGTH) & (np.abs(y) <= TABLE_HALF_WIDTH)
    # Net (plane x = 0), for segments crossing it.
    cross = (P[:, 0:1] * S[None, :, 0]) < 0.0
    rows = cross.any(axis=1)
    if rows.any():
        p = P[rows]
        u = -p[:, 0:1] / (S[None, :, 0] - p[:, 0:1])
        y = p[:, 1:2] + u * (S[None, :, 1] - p[:, 1:2])
        z = p[:, 2:3] + u * (S[None, :, 2] - p[:, 2:3])
        blocked[rows] |= cross[rows] & (np.abs(y) <= NET_HALF_WIDTH) & (z >= 0.0) \
            & (z <= NET_HEIGHT)
    for centre, _ in SPARE_BALLS:
        blocked |= _segment_hits_sphere(P, S, np.asarray(centre)[None], RADIUS) > 0
    return blocked


class Shader:
    """Shading of surface points under a :class:`Lighting`."""

    def __init__(self, lighting):
        self.lighting = lighting
        self.light_pts, self.light_w = lighting.points()
        self.sky = np.asarray(lighting.sky, dtype=float)
        self.bounce = np.asarray(lighting.bounce, dtype=float)

    def ambient(self, N, below=None):
        """Ambient irradiance (M, 3) at normals N (M, 3): the sky's uniform upper hemisphere,
        sky (1 + n_z) / 2, plus the lower hemisphere: uniform ``bounce`` (1 - n_z) / 2, or
        ``below`` = (directions (E, 3), radiance (E, 3)) of E uniform samples of it, which
        give (2 / E) sum_i L_i max(0, n . d_i) (radiance in this module's units, albedo
        times irradiance, so a uniform L gives L on a surface facing down)."""
        up = 0.5 * (1.0 + N[:, 2:3])
        if below is None:
            return up * self.sky + (1.0 - up) * self.bounce
        dirs, rad = below
        return up * self.sky + (2.0 / len(dirs)) * np.clip(N @ dirs.T, 0.0, None) @ rad

    def irradiance(self, P, N, static=True, occluders=None):
        """Direct irradiance (M, 3) at points P (M, 3) of unit normals N (M, 3), shadowed by
        the static scene and by spheres of radius r at ``occluders`` (T, 3) (the mean over
        those positions: a moving ball over the exposure)."""
        return self._direct(P, N, None, Material((1, 1, 1)), static, occluders)[0]

    def radiance(self, P, N, V, material, static=False, occluders=None, below=None):
        """Radiance (M, 3) leaving points P (M, 3), unit normals N (M, 3), toward unit view
        directions V (M, 3) (from the point to the eye); ``below``: see :meth:`ambient`."""
        diffuse, sheen = self._direct(P, N, V, material, static, occluders)
        albedo = np.asarray(material.albedo, dtype=float)
        return albedo * (diffuse + self.ambient(N, below)) + material.sheen * sheen

    def occluded(self, P, N, centres):
        """Direct irradiance (M, 3) that balls at ``centres`` (T, 3) take from points P (M, 3)
        of normals N (M, 3) (the mean over the centres: a ball moving over the exposure):
        the light samples whose shadow ray the ball crosses and nothing static blocks."""
        S = self.light_pts
        occ = _segment_hits_sphere(P, S, centres, RADIUS)           # (M, J)
        rows = occ.any(axis=1)
        out = np.zeros((len(P), 3))
        if rows.any():
            p, n = P[rows], N[rows]
            L = [S[None, :, i] - p[:, i:i + 1] for i in range(3)]
            d2 = L[0] * L[0] + L[1] * L[1] + L[2] * L[2]
            inv = 1.0 / np.sqrt(d2)
            cos_i = (L[0] * n[:, 0:1] + L[1] * n[:, 1:2] + L[2] * n[:, 2:3]) * inv
            geo = np.clip(L[2] * inv, 0.0, None) / d2
            vis = (cos_i > 0.0) & ~_static_blocked(p, S)
            out[rows] = (occ[rows] * geo * cos_i * vis) @ self.light_w
        return out

    def _direct(self, P, N, V, material, static, occluders, chunk=20000):
        """Direct diffuse irradiance (times the Oren-Nayar factor when V is given) and the
        sheen lobe's irradiance, each (M, 3). Vectors are handled by components, (m, J)
        arrays for m points and J light samples."""
        M = len(P)
        diffuse = np.zeros((M, 3))
        sheen = np.zeros((M, 3))
        S = self.light_pts
        for a in range(0, M, chunk):
            b = min(a + chunk, M)
            p, n = P[a:b], N[a:b]
            L = [S[None, :, i] - p[:, i:i + 1] for i in range(3)]    # toward the lights
            d2 = L[0] * L[0] + L[1] * L[1] + L[2] * L[2]
            inv = 1.0 / np.sqrt(d2)
            L = [c * inv for c in L]
            cos_i = L[0] * n[:, 0:1] + L[1] * n[:, 1:2] + L[2] * n[:, 2:3]
            geo = np.clip(L[2], 0.0, None) / d2                      # emitter faces down
            vis = (cos_i > 0.0).astype(float)
            if static:
                vis *= ~_static_blocked(p, S)
            if occluders is not None and len(occluders):
                vis *= 1.0 - _segment_hits_sphere(p, S, occluders, RADIUS)
            factor = geo * cos_i * vis                                # (m, J)
            if V is not None and material.roughness > 0.0:
                factor = factor * self._oren_nayar(L, n, V[a:b], cos_i, material.roughness)
            diffuse[a:b] = factor @ self.light_w
            if V is not None and material.sheen > 0.0:
                v = V[a:b]
                H = [L[i] + v[:, i:i + 1] for i in range(3)]
                hn = np.sqrt(H[0] * H[0] + H[1] * H[1] + H[2] * H[2])
                nh = np.clip((H[0] * n[:, 0:1] + H[1] * n[:, 1:2] + H[2] * n[:, 2:3]) / hn,
                             0.0, None)
                sheen[a:b] = (geo * cos_i * vis * nh ** material.sheen_power) @ self.light_w
        return diffuse, sheen

    @staticmethod
    def _oren_nayar(L, n, V, cos_i, sigma):
        """Oren-Nayar's (qualitative model) factor over Lambert, (m, J):
        A + B max(0, cos(phi_i - phi_r)) sin(alpha) tan(beta), alpha and beta the larger and
        smaller of the angles of incidence and view, sigma the roughness (rad). ``L``: the
        three (m, J) components of the unit directions to the lights."""
        s2 = sigma * sigma
        A = 1.0 - 0.5 * s2 / (s2 + 0.33)
        B = 0.45 * s2 / (s2 + 0.09)
        cos_r = np.clip(np.sum(V * n, axis=1), 1e-6, 1.0)[:, None]        # (m, 1)
        ci = np.clip(cos_i, 1e-6, 1.0)
        li = [L[i] - ci * n[:, i:i + 1] for i in range(3)]                 # tangent parts
        vr = V - cos_r * n                                                 # (m, 3)
        li_norm = np.sqrt(li[0] ** 2 + li[1] ** 2 + li[2] ** 2)
        norm = li_norm * np.linalg.norm(vr, axis=1)[:, None]
        dot = li[0] * vr[:, 0:1] + li[1] * vr[:, 1:2] + li[2] * vr[:, 2:3]
        cos_phi = np.where(norm > 1e-12, dot / np.maximum(norm, 1e-12), 0.0)
        c_small = np.minimum(ci, cos_r)                  # the larger angle alpha
        c_large = np.maximum(ci, cos_r)                  # the smaller angle beta
        sin_a = np.sqrt(1.0 - c_small ** 2)
        tan_b = np.sqrt(1.0 - c_large ** 2) / c_large
        return A + B * np.clip(cos_phi, 0.0, None) * sin_a * tan_b


# ============================================================================================
# Static scene
# ============================================================================================

def _value_noise(u, v, cell, seed, size=64):
    """Smooth random texture in [-1, 1] at surface coordinates (u, v) (m): values on a
    periodic lattice of ``cell`` m, interpolated with a smoothstep."""
    rng = np.random.default_rng(seed)
    lattice = rng.uniform(-1.0, 1.0, (size, size))
    x, y = u / cell, v / cell
    i, j = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - i, y - j
    sx, sy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    i0, j0 = i % size, j % size
    i1, j1 = (i + 1) % size, (j + 1) % size
    top = lattice[i0, j0] * (1 - sx) + lattice[i1, j0] * sx
    bot = lattice[i0, j1] * (1 - sx) + lattice[i1, j1] * sx
    return top * (1 - sy) + bot * sy


def intersect_static(origin, dirs):
    """First hit of rays from ``origin`` (3,) along unit ``dirs`` (M, 3) with the static scene:
    distances (M,) (inf: none), surface ids (M,), unit normals (M, 3) facing the ray."""
    M = len(dirs)
    o = np.asarray(origin, dtype=float)
    best = np.full(M, np.inf)
    sid = np.full(M, NOTHING)
    normal = np.zeros((M, 3))
    dx, dy, dz = dirs[:, 0], dirs[:, 1], dirs[:, 2]

    def take(s, ident, n):
        better = (s > 1e-9) & (s < best)
        best[better] = s[better]
        sid[better] = ident
        normal[better] = n[better] if np.ndim(n) == 2 else n

    with np.errstate(divide='ignore', invalid='ignore'):
        take((FLOOR_Z - o[2]) / dz, FLOOR, np.array([0.0, 0.0, 1.0]))
        take((CEILING_Z - o[2]) / dz, CEILING, np.array([0.0, 0.0, -1.0]))
        take((WALLS['x+'] - o[0]) / dx, WALL, np.array([-1.0, 0.0, 0.0]))
        take((WALLS['x-'] - o[0]) / dx, WALL, np.array([1.0, 0.0, 0.0]))
        take((WALLS['y+'] - o[1]) / dy, WALL, np.array([0.0, -1.0, 0.0]))
        take((WALLS['y-'] - o[1]) / dy, WALL, np.array([0.0, 1.0, 0.0]))
        # Table: the slab box |x| <= L, |y| <= W, -thickness <= z <= 0.
        lo = np.array([-TABLE_HALF_LENGTH, -TABLE_HALF_WIDTH, -TABLE_THICKNESS])
        hi = np.array([TABLE_HALF_LENGTH, TABLE_HALF_WIDTH, 0.0])
        t1 = (lo[None] - o[None]) / dirs
        t2 = (hi[None] - o[None]) / dirs
        near = np.minimum(t1, t2)
        far = np.maximum(t1, t2)
        t_in = near.max(axis=1)
        t_out = far.min(axis=1)
        axis = near.argmax(axis=1)
        hit = (t_in <= t_out) & (t_in > 0)
        n = np.zeros((M, 3))
        n[np.arange(M), axis] = -np.sign(dirs[np.arange(M), axis])
        s = np.where(hit, t_in, np.inf)
        top = hit & (axis == 2) & (n[:, 2] > 0)
        take(np.where(top, s, np.inf), TABLE_TOP, n)
        take(np.where(hit & ~top, s, np.inf), TABLE_SIDE, n)
        # Net: x = 0, |y| <= half width, 0 <= z <= height (two-sided).
        s = -o[0] / dx
        y = o[1] + s * dy
        z = o[2] + s * dz
        on = (np.abs(y) <= NET_HALF_WIDTH) & (z >= 0.0) & (z <= NET_HEIGHT)
        n = np.zeros((M, 3))
        n[:, 0] = -np.sign(dx)
        take(np.where(on, s, np.inf), NET, n)
    for centre, _ in SPARE_BALLS:
        c = np.asarray(centre)
        s = sphere_hits(o, dirs, c[None], RADIUS)[:, 0]
        n = (o[None] + s[:, None] * dirs - c) / RADIUS
        take(s, SPARE, np.where(np.isfinite(n), n, 0.0))
    return best, sid, normal


def sphere_hits(origin, dirs, centres, radius):
    """Distances (M, T) along unit rays from ``origin`` (3,) with directions ``dirs`` (M, 3)
    to the first intersection with spheres of ``radius`` at ``centres`` (T, 3); inf: miss.
    The ray o + s d meets |x - c| = r where s^2 + 2 b s + (|o - c|^2 - r^2) = 0,
    b = d . (o - c)."""
    oc = np.asarray(origin, dtype=float)[None, :] - centres            # (T, 3)
    b = dirs @ oc.T                                                    # (M, T)
    cc = np.sum(oc * oc, axis=1) - radius ** 2                         # (T,)
    disc = b * b - cc[None, :]
    s = -b - np.sqrt(np.where(disc > 0, disc, 0.0))
    return np.where((disc > 0) & (s > 0), s, np.inf)


class StaticScene:
    """Albedo of the static scene's surfaces (textures deterministic in ``seed``)."""

    def __init__(self, seed=0):
        self.seed = seed

    def albedo(self, sid, P):
        """Diffuse reflectance (M, 3) at points P (M, 3) on surfaces ``sid`` (M,)."""
        out = np.zeros((len(sid), 3))
        s = self.seed
        m = sid == FLOOR
        if m.any():
            x, y = P[m, 0], P[m, 1]
            tex = 1.0 + 0.16 * _value_noise(x, y, 0.45, s + 1) \
                + 0.07 * _value_noise(x, y, 0.06, s + 2)
            out[m] = np.array([0.20, 0.19, 0.175]) * tex[:, None]
        m = sid == WALL
        if m.any():
            u = P[m, 0] + P[m, 1]
            tex = 1.0 + 0.10 * _value_noise(u, P[m, 2], 0.6, s + 3) \
                + 0.05 * _value_noise(u, P[m, 2], 0.08, s + 4)
            out[m] = np.array([0.40, 0.41, 0.42]) * tex[:, None]
        out[sid == CEILING] = (0.3, 0.3, 0.3)
        m = sid == TABLE_TOP
        if m.any():
            x, y = P[m, 0], P[m, 1]
            tex = 1.0 + 0.03 * _value_noise(x, y, 0.05, s + 5)
            colour = np.array([0.035, 0.07, 0.16]) * tex[:, None]
            line = ((np.abs(x) >= TABLE_HALF_LENGTH - BORDER_LINE)
                    | (np.abs(y) >= TABLE_HALF_WIDTH - BORDER_LINE)
                    | (np.abs(y) <= 0.5 * CENTRE_LINE))
            colour[line] = (0.78, 0.78, 0.76)
            out[m] = colour
        out[sid == TABLE_SIDE] = (0.03, 0.06, 0.13)
        m = sid == NET
        if m.any():
            colour = np.tile([0.06, 0.06, 0.07], (m.sum(), 1))
            colour[P[m, 2] >= NET_HEIGHT - NET_TAPE] = (0.75, 0.75, 0.74)
            out[m] = colour
        m = sid == SPARE
        if m.any():
            for centre, colour in SPARE_BALLS:
                mine = m & (np.linalg.norm(P - np.asarray(centre), axis=1) < RADIUS * 1.01)
                out[mine] = BALL_ALBEDO[colour]
        return out


# ============================================================================================
# Cameras and rendering
# ============================================================================================

UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)


def pixel_rays(cam, uv):
    """Unit ray directions (M, 3) in the table frame through distorted pixel coordinates
    ``uv`` (M, 2) of ``cam`` (undistorted with ``cv2.undistortPoints``, K and distortion of
    the calibration, iterated to 1e-12)."""
    pts = np.ascontiguousarray(uv, dtype=np.float64).reshape(-1, 1, 2)
    und = cv2.undistortPoints(pts, cam.K, cam.dist, R=np.eye(3), P=np.eye(3),
                              criteria=UNDISTORT_CRITERIA).reshape(-1, 2)
    d_cam = np.column_stack([und, np.ones(len(und))])
    d = d_cam @ cam.R                       # rows: R^T d_cam (optical -> table frame)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def camera_centre(cam):
    """Optical centre (3,) of ``cam`` in the table frame, m (X_cam = R X + t)."""
    return -cam.R.T @ cam.t


def _subpixel_grid(x0, y0, x1, y1, n):
    """Sub-pixel sample coordinates (P * n * n, 2) of the pixels of box [x0, x1) x [y0, y1),
    pixel-major (each pixel's n x n samples together)."""
    off = (np.arange(n) + 0.5) / n - 0.5
    ys, xs = np.mgrid[y0:y1, x0:x1]
    oy, ox = np.meshgrid(off, off, indexing='ij')
    u = xs.reshape(-1, 1) + ox.reshape(1, -1)
    v = ys.reshape(-1, 1) + oy.reshape(1, -1)
    return np.stack([u.ravel(), v.ravel()], axis=1)


@dataclasses.dataclass
class Background:
    """One camera's static scene: linear radiance (H, W, 3) and, at pixel centres, the surface
    point (H, W, 3), normal (H, W, 3), id (H, W) and irradiance (H, W, 3) (direct, shadowed
    by the static scene, plus ambient); the n x n sub-pixel rays (H, W, n n, 3) and their
    distances to the static scene (H, W, n n), float32, reused for the distractors."""

    radiance: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    surface: np.ndarray
    light: np.ndarray
    rays: np.ndarray
    depth: np.ndarray


class Sphere:
    """A sphere over an exposure: centres (T, 3), m; ``radius``, m."""

    def __init__(self, centres, radius, material):
        self.centres = np.atleast_2d(np.asarray(centres, dtype=float))
        self.radius = radius
        self.material = material

    def bounding(self):
        return self.centres, np.full(len(self.centres), self.radius)

    def intersect(self, origin, dirs):
        return sphere_hits(origin, dirs, self.centres, self.radius)

    def normals(self, P, k):
        return (P - self.centres[k]) / self.radius


class Disc:
    """A thin disc (a racket blade) over an exposure: centres (T, 3), unit normals (T, 3)."""

    def __init__(self, centres, normals, radius, material):
        self.centres = np.atleast_2d(centres)
        self.normal = np.atleast_2d(normals)
        self.radius = radius
        self.material = material

    def bounding(self):
        return self.centres, np.full(len(self.centres), self.radius)

    def intersect(self, origin, dirs):
        dn = dirs @ self.normal.T                                      # (M, T)
        num = np.sum(self.normal * (self.centres - origin), axis=1)    # (T,)
        with np.errstate(divide='ignore', invalid='ignore'):
            s = num[None, :] / dn
        out = np.full(s.shape, np.inf)
        for k in range(len(self.centres)):
            hit = origin[None] + s[:, k:k + 1] * dirs - self.centres[k]
            ok = np.isfinite(s[:, k]) & (s[:, k] > 0) & (np.sum(hit * hit, axis=1)
                                                         <= self.radius ** 2)
            out[ok, k] = s[ok, k]
        return out

    def normals(self, P, k):
        return np.broadcast_to(self.normal[k], P.shape).copy()


class Capsule:
    """A capsule (a sleeve, a forearm) over an exposure: segment ends a, b (T, 3), radius."""

    def __init__(self, a, b, radius, material):
        self.a = np.atleast_2d(a)
        self.b = np.atleast_2d(b)
        self.radius = radius
        self.material = material

    def bounding(self):
        half = 0.5 * np.linalg.norm(self.b - self.a, axis=1)
        return 0.5 * (self.a + self.b), half + self.radius

    def intersect(self, origin, dirs):
        out = np.full((len(dirs), len(self.a)), np.inf)
        r = self.radius
        for k in range(len(self.a)):
            a, b = self.a[k], self.b[k]
            axis = b - a
            length = np.linalg.norm(axis)
            e = axis / length
            oa = origin - a
            # Infinite cylinder: |(o - a + s d) - ((o - a + s d) . e) e| = r.
            de = dirs @ e
            oae = oa @ e
            dp = dirs - de[:, None] * e
            op = oa - oae * e
            qa = np.sum(dp * dp, axis=1)
            qb = dp @ op
            qc = op @ op - r * r
            disc = qb * qb - qa * qc
            with np.errstate(divide='ignore', invalid='ignore'):
                s = (-qb - np.sqrt(np.where(disc > 0, disc, 0.0))) / qa
            along = oae + s * de
            body = (disc > 0) & (s > 0) & (along >= 0) & (along <= length)
            best = np.where(body, s, np.inf)
            for c in (a, b):                                   # hemispherical caps
                best = np.minimum(best, sphere_hits(origin, dirs, c[None], r)[:, 0])
            out[:, k] = best
        return out

    def normals(self, P, k):
        a, b = self.a[k], self.b[k]
        e = b - a
        h = np.clip((P - a) @ e / (e @ e), 0.0, 1.0)
        return (P - (a + h[:, None] * e)) / self.radius


class Renderer:
    """Renders linear radiance images of the rig's cameras (see the module docstring).

    ``subpixels``: n x n rays per pixel for moving objects; ``time_samples`` instants over
    the ``exposure`` (s); ``object_subpixels``: n x n rays per pixel for the distractors
    (large, not measured); ``flat``: objects shaded with their albedo alone (no lights, no
    shadows) and no flicker, for tests of the geometry.
    """

    def __init__(self, rig, lighting=None, exposure=2e-3, subpixels=4, time_samples=8,
                 background_subpixels=2, object_subpixels=2, seed=0, flat=False):
        self.rig = rig
        self.cameras = rig.cameras
        self.lighting = lighting or Lighting()
        self.shader = Shader(self.lighting)
        self.scene = StaticScene(seed)
        self.exposure = exposure
        self.subpixels = subpixels
        self.time_samples = time_samples
        self.background_subpixels = background_subpixels
        self.object_subpixels = object_subpixels
        self.flat = flat
        self._backgrounds = {}

    def variant(self, **options):
        """A copy with other options (e.g. ``flat=True``) sharing this one's backgrounds."""
        other = copy.copy(self)
        for name, value in options.items():
            if not hasattr(other, name):
                raise AttributeError(f'Renderer has no option {name!r}')
            setattr(other, name, value)
        return other

    def sample_times(self, t):
        """The instants (T,) of the exposure centred on ``t``, s (stratified)."""
        n = self.time_samples
        return t + ((np.arange(n) + 0.5) / n - 0.5) * self.exposure

    # --- static background ----------------------------------------------------------------
    def background(self, k):
        """Camera ``k``'s :class:`Background` (ray cast once, then cached)."""
        if k not in self._backgrounds:
            self._backgrounds[k] = self._render_background(self.cameras[k])
        return self._backgrounds[k]

    def _render_background(self, cam, rows=32):
        h, w = cam.height, cam.width
        n = self.background_subpixels
        q = n * n
        o = camera_centre(cam)
        radiance = np.zeros((h, w, 3), np.float32)
        point = np.zeros((h, w, 3))
        normal = np.zeros((h, w, 3))
        surface = np.zeros((h, w), np.int8)
        centre_light = np.ones((h, w, 3))
        rays = np.zeros((h, w, q, 3), np.float32)
        depth = np.zeros((h, w, q), np.float32)
        for y0 in range(0, h, rows):
            y1 = min(y0 + rows, h)
            # Pixel centres: the geometry kept for the shadows cast on the background.
            dc = pixel_rays(cam, _subpixel_grid(0, y0, w, y1, 1))
            sc, idc, nc = intersect_static(o, dc)
            pc = o[None] + np.where(np.isfinite(sc), sc, 0.0)[:, None] * dc
            point[y0:y1] = pc.reshape(y1 - y0, w, 3)
            normal[y0:y1] = nc.reshape(y1 - y0, w, 3)
            surface[y0:y1] = idc.reshape(y1 - y0, w)
            # n x n samples a pixel for the albedo (lines, edges); the light at the pixel
            # centre where all samples see the same flat surface, else at each sample.
            d = pixel_rays(cam, _subpixel_grid(0, y0, w, y1, n))
            s, sid, nrm = intersect_static(o, d)
            rays[y0:y1] = d.reshape(y1 - y0, w, q, 3)
            depth[y0:y1] = s.reshape(y1 - y0, w, q)
            P = o[None] + np.where(np.isfinite(s), s, 0.0)[:, None] * d
            flat = (np.all(sid.reshape(-1, q) == idc[:, None], axis=1)
                    & (idc != SPARE) & (idc != NOTHING))
            lit = (idc != SPARE) & (idc != NOTHING)
            e = np.ones((len(pc), 3))
            e[lit] = self.shader.irradiance(pc[lit], nc[lit], static=True) \
                + self.shader.ambient(nc[lit])
            centre_light[y0:y1] = e.reshape(y1 - y0, w, 3)
            light = np.zeros((len(P), 3))
            light.reshape(-1, q, 3)[flat] = e[flat][:, None, :]
            rest = ~np.repeat(flat, q)
            rad = self._static_radiance(P, nrm, -d, sid, light, rest)
            radiance[y0:y1] = rad.reshape(y1 - y0, w, q, 3).mean(axis=2)
        return Background(radiance, point, normal, surface, centre_light, rays, depth)

    def _static_radiance(self, P, N, V, sid, light, todo):
        """Radiance (M, 3) of static surface points; ``light`` (M, 3) the irradiance (direct
        plus ambient) where it is known already, computed where ``todo``."""
        albedo = self.scene.albedo(sid, P)
        lambert = todo & (sid != NOTHING) & (sid != SPARE)
        if lambert.any():
            light[lambert] = self.shader.irradiance(P[lambert], N[lambert], static=True) \
                + self.shader.ambient(N[lambert])
        out = albedo * light
        spare = sid == SPARE
        if spare.any():
            for centre, colour in SPARE_BALLS:
                mine = spare & (np.linalg.norm(P - np.asarray(centre), axis=1) < RADIUS * 1.01)
                if mine.any():
                    out[mine] = self.shader.radiance(P[mine], N[mine], V[mine],
                                                     ball_material(colour), static=True)
        return out

    # --- moving objects -------------------------------------------------------------------
    def _box(self, cam, obj, margin=2):
        """Pixel box (x0, y0, x1, y1) holding ``obj``'s image over the exposure, or None."""
        centres, radii = obj.bounding()
        pc = cam.to_camera(centres)
        if np.any(pc[:, 2] <= radii + 0.05):
            return None
        if np.any(np.abs(pc[:, :2] / pc[:, 2:3]) > 1.2):
            return None                     # far outside the field of view
        # The camera's x and y axes in the table frame, a quarter longer than the radius
        # (the silhouette of an off-axis sphere reaches slightly beyond it).
        pts = np.concatenate([centres + sign * 1.25 * radii[:, None] * axis
                              for axis in (cam.R[0], cam.R[1]) for sign in (-1.0, 1.0)])
        px = cam.project(pts)
        lo = np.floor(px.min(axis=0)).astype(int) - margin
        hi = np.ceil(px.max(axis=0)).astype(int) + margin + 1
        x0, y0 = max(lo[0], 0), max(lo[1], 0)
        x1, y1 = min(hi[0], cam.width), min(hi[1], cam.height)
        if x1 <= x0 or y1 <= y0:
            return None
        return x0, y0, x1, y1

    def coverage(self, k, obj, instants=None, subpixels=None):
        """Ray-cast ``obj`` in camera ``k``: (box, coverage (h, w), radiance sum (h, w, 3)).

        Coverage is the fraction of the box pixels' sub-pixel rays x ``instants`` (default:
        the object's own number of positions) that see the object before the static scene;
        the radiance sum is the object's radiance summed over those rays, divided by the
        number of rays per pixel (so that the pixel's value is radiance sum + (1 - coverage)
        background). An object present at fewer instants than the exposure's (a ball
        launched or ending within it) covers the pixel for that part only. ``subpixels``:
        n x n rays a pixel (default: the renderer's). None when the object is out of view.
        """
        cam = self.cameras[k]
        box = self._box(cam, obj)
        if box is None:
            return None
        x0, y0, x1, y1 = box
        n = subpixels or self.subpixels
        o = camera_centre(cam)
        if n == self.background_subpixels and k in self._backgrounds:
            bg = self._backgrounds[k]
            d = bg.rays[y0:y1, x0:x1].reshape(-1, 3).astype(float)
            s_static = bg.depth[y0:y1, x0:x1].ravel()
        else:
            d = pixel_rays(cam, _subpixel_grid(x0, y0, x1, y1, n))
            s_static = intersect_static(o, d)[0]
        s = obj.intersect(o, d)                                        # (M, T)
        seen = s < s_static[:, None]
        ray, inst = np.nonzero(seen)
        T = s.shape[1]
        per_pixel = n * n * max(T, instants or T)
        h, w = y1 - y0, x1 - x0
        cover = seen.reshape(h * w, n * n * T).sum(axis=1) / per_pixel
        total = np.zeros((h * w, 3))
        if ray.size:
            P = o[None] + s[ray, inst][:, None] * d[ray]
            V = -d[ray]
            N = np.empty_like(P)
            for kk in np.unique(inst):
                sel = inst == kk
                N[sel] = obj.normals(P[sel], kk)
            flip = np.sum(N * V, axis=1) < 0             # two-sided thin objects
            N[flip] *= -1.0
            if self.flat:
                rad = np.broadcast_to(np.asarray(obj.material.albedo, float), P.shape)
            elif isinstance(obj, Sphere):
                below = self.environment_below(obj.bounding()[0].mean(axis=0))
                rad = self.shader.radiance(P, N, V, obj.material, below=below)
            else:
                rad = self._shade_by_normal(obj, N, V)
            pix = ray // (n * n)
            np.add.at(total, pix, rad)
        return box, cover.reshape(h, w), (total / per_pixel).reshape(h, w, 3)

    def environment_below(self, centre, n=64):
        """The lower hemisphere seen from ``centre`` (3,): n directions (n, 3) spread evenly
        over it (a Fibonacci lattice) and the radiance (n, 3) of the static scene along each
        (table, floor, spare balls, lit and shadowed as in the background): the light that
        the scene bounces on to an object's underside (the table's blue over the table, the
        floor's warm grey beyond it)."""
        i = np.arange(n) + 0.5
        z = -i / n                                       # uniform in z: uniform in solid angle
        phi = np.pi * (1.0 + np.sqrt(5.0)) * i
        r = np.sqrt(1.0 - z * z)
        dirs = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
        s, sid, nrm = intersect_static(centre, dirs)
        P = centre[None] + np.where(np.isfinite(s), s, 0.0)[:, None] * dirs
        rad = self._static_radiance(P, nrm, -dirs, sid, np.zeros((n, 3)), np.ones(n, bool))
        return dirs, rad

    def _shade_by_normal(self, obj, N, V, rows=32):
        """Radiance (K, 3) of a large distractor's hits of normals N (K, 3): shaded exactly
        on a rows x 2 rows grid of normals (polar angle, azimuth) at the object's centre and
        mean view direction, then looked up by each hit's normal (its lights and view hardly
        change over it; the balls are shaded exactly at every hit)."""
        centre = obj.bounding()[0].mean(axis=0)
        view = V.mean(axis=0)
        view /= np.linalg.norm(view)
        theta = (np.arange(rows) + 0.5) / rows * np.pi
        phi = (np.arange(2 * rows) + 0.5) / (2 * rows) * 2 * np.pi - np.pi
        th, ph = np.meshgrid(theta, phi, indexing='ij')
        G = np.column_stack([(np.sin(th) * np.cos(ph)).ravel(),
                             (np.sin(th) * np.sin(ph)).ravel(), np.cos(th).ravel()])
        m = len(G)
        table = self.shader.radiance(np.tile(centre, (m, 1)), G, np.tile(view, (m, 1)),
                                     obj.material, below=self.environment_below(centre))
        i = np.clip((np.arccos(np.clip(N[:, 2], -1, 1)) / np.pi * rows).astype(int), 0,
                    rows - 1)
        j = ((np.arctan2(N[:, 1], N[:, 0]) + np.pi) / (2 * np.pi) * 2 * rows).astype(int) \
            % (2 * rows)
        return table[i * 2 * rows + j]

    def _draw(self, img, k, obj, subpixels=None, instants=None):
        got = self.coverage(k, obj, instants, subpixels)
        if got is None:
            return
        (x0, y0, x1, y1), cover, total = got
        patch = img[y0:y1, x0:x1]
        img[y0:y1, x0:x1] = patch * (1.0 - cover[:, :, None]) + total

    # --- shadows of moving balls ----------------------------------------------------------
    def shadow_factor(self, P, N, centres, light=None):
        """Ratio (M, 3) of the light at points P (M, 3), normals N (M, 3), with balls at
        ``centres`` (T, 3) (averaged over them) to the light without (``light`` (M, 3), the
        irradiance there without the balls, when known): 1 outside the shadow."""
        if light is None:
            light = self.shader.irradiance(P, N, static=True) + self.shader.ambient(N)
        return 1.0 - self.shader.occluded(P, N, centres) / np.maximum(light, 1e-9)

    SHADOW_REACH = 0.6
    """Largest height of a ball above the table top or the floor at which its shadow there is
    rendered, m (higher, it takes less than a few per cent of the light)."""

    def _shadow_box(self, cam, centres):
        """Pixel box where balls at ``centres`` (T, 3) may shade the table top or the floor."""
        S = self.shader.light_pts
        corners = []
        c = centres.mean(axis=0)
        for plane, table in ((0.0, True), (FLOOR_Z, False)):
            height = c[2] - plane
            if height <= 0.0 or height > self.SHADOW_REACH:
                continue
            if table and not (abs(c[0]) < TABLE_HALF_LENGTH + 0.3
                              and abs(c[1]) < TABLE_HALF_WIDTH + 0.3):
                continue
            # The ball's shadow centre from each light sample on the plane, and its radius.
            f = (S[:, 2] - plane) / (S[:, 2] - c[2])
            foot = S[:, :2] + (c[None, :2] - S[:, :2]) * f[:, None]
            r = RADIUS * f.max() * 1.6 + np.ptp(centres[:, :2], axis=0).max() + 0.01
            lo, hi = foot.min(axis=0) - r, foot.max(axis=0) + r
            corners += [(lo[0], lo[1], plane), (hi[0], lo[1], plane),
                        (hi[0], hi[1], plane), (lo[0], hi[1], plane)]
        if not corners:
            return None
        corners = np.array(corners)
        if not np.all(cam.in_front(corners)):
            return None
        px = cam.project(corners)
        lo = np.floor(px.min(axis=0)).astype(int) - 1
        hi = np.ceil(px.max(axis=0)).astype(int) + 2
        x0, y0 = max(lo[0], 0), max(lo[1], 0)
        x1, y1 = min(hi[0], cam.width), min(hi[1], cam.height)
        if x1 <= x0 or y1 <= y0:
            return None
        return x0, y0, x1, y1

    def _shade_under(self, img, k, centres, shadow_samples=3):
        """Darken camera ``k``'s image ``img`` where balls at ``centres`` (T, 3) (the
        exposure's instants; ``shadow_samples`` of them are used) shade the table top or the
        floor. Both are Lambertian, so the pixel's radiance scales with its irradiance."""
        cam = self.cameras[k]
        box = self._shadow_box(cam, centres)
        if box is None:
            return
        x0, y0, x1, y1 = box
        bg = self.background(k)
        sid = bg.surface[y0:y1, x0:x1]
        recv = ((sid == TABLE_TOP) | (sid == FLOOR)) \
            & (bg.point[y0:y1, x0:x1, 2] < centres[:, 2].max())
        if not recv.any():
            return
        P = bg.point[y0:y1, x0:x1][recv]
        N = bg.normal[y0:y1, x0:x1][recv]
        pick = np.round(np.linspace(0, len(centres) - 1,
                                    min(shadow_samples, len(centres)))).astype(int)
        factor = self.shadow_factor(P, N, centres[pick], bg.light[y0:y1, x0:x1][recv])
        patch = img[y0:y1, x0:x1]
        patch[recv] = patch[recv] * factor

    # --- frames -----------------------------------------------------------------------------
    def render_linear(self, k, t, balls=(), objects=()):
        """Camera ``k``'s linear radiance image (H, W, 3) float32, RGB, for the exposure
        centred on ``t`` (s). ``balls``: (centres (T, 3) at :meth:`sample_times`, material)
        of flying balls (they cast shadows, and a ball present at only some of the instants
        covers its pixels for that part of the exposure); ``objects``: other moving objects
        (no shadow), each at its own instants over the exposure (large: fewer rays, see
        ``object_subpixels``)."""
        img = self.background(k).radiance.copy()
        if not self.flat:
            for centres, _ in balls:
                self._shade_under(img, k, centres)
        for obj in objects:
            self._draw(img, k, obj, self.object_subpixels)
        for centres, material in balls:
            self._draw(img, k, Sphere(centres, RADIUS, material), instants=self.time_samples)
        if not self.flat:
            img *= np.float32(self.lighting.gain(t, self.exposure))
        return img


# ============================================================================================
# Sensor
# ============================================================================================

@dataclasses.dataclass
class Sensor:
    """A small colour camera's sensor and codec.

    ``exposure_scale``: fraction of the full well per unit radiance (linear). ``full_well``
    and ``read_noise`` in electrons (after the analog gain). ``vignetting`` (a2, a4):
    relative illumination 1 + a2 r^2 + a4 r^4, r the distance from the principal point over
    the half diagonal. ``knee``: start of the soft shoulder of the response (fraction of full
    scale). ``gamma``: the response's exponent is 1/gamma. ``jpeg_quality``: None for no
    JPEG. ``noise``, ``bayer``: switches (tests).
    """

    exposure_scale: float = 0.62
    full_well: float = 2500.0
    read_noise: float = 6.0
    adc_bits: int = 12
    vignetting: tuple = (-0.22, -0.05)
    knee: float = 0.8
    gamma: float = 2.2
    jpeg_quality: int | None = 30
    noise: bool = True
    bayer: bool = True

    def response(self, v):
        """8-bit output (float) of linear signal ``v`` (fraction of full scale): a soft
        shoulder above ``knee`` (same slope there, saturating at 1), then v^(1/gamma)."""
        v = np.clip(np.asarray(v, dtype=float), 0.0, None)
        k = self.knee
        s = np.where(v < k, v, k + (1.0 - k) * (1.0 - np.exp(-(v - k) / (1.0 - k))))
        return 255.0 * s ** (1.0 / self.gamma)

    def _lut(self):
        levels = 2 ** self.adc_bits
        return np.clip(np.round(self.response(np.arange(levels) / (levels - 1))), 0,
                       255).astype(np.uint8)

    def vignetting_map(self, cam):
        ys, xs = np.mgrid[0:cam.height, 0:cam.width].astype(float)
        half_diag = 0.5 * np.hypot(cam.width, cam.height)
        r2 = ((xs - cam.K[0, 2]) ** 2 + (ys - cam.K[1, 2]) ** 2) / half_diag ** 2
        a2, a4 = self.vignetting
        return (1.0 + a2 * r2 + a4 * r2 * r2).astype(np.float32)

    def capture(self, linear, cam, rng, cache=None):
        """uint8 BGR frame of the linear RGB radiance image ``linear`` (H, W, 3) of ``cam``.

        ``cache``: a dict kept between frames of one camera (vignetting map, LUT)."""
        cache = {} if cache is None else cache
        if 'vig' not in cache:
            cache['vig'] = self.vignetting_map(cam)
            cache['lut'] = self._lut()
        levels = 2 ** self.adc_bits - 1
        if self.bayer:
            raw = np.empty(linear.shape[:2], np.float32)       # RGGB: R at (0, 0)
            raw[0::2, 0::2] = linear[0::2, 0::2, 0]
            raw[0::2, 1::2] = linear[0::2, 1::2, 1]
            raw[1::2, 0::2] = linear[1::2, 0::2, 1]
            raw[1::2, 1::2] = linear[1::2, 1::2, 2]
            raw *= cache['vig'] * np.float32(self.exposure_scale * self.full_well)
        else:
            raw = linear * (cache['vig'][:, :, None]
                            * np.float32(self.exposure_scale * self.full_well))
        if self.noise:
            sigma = np.sqrt(np.maximum(raw, 0.0) + np.float32(self.read_noise ** 2))
            raw += sigma * rng.standard_normal(raw.shape, dtype=np.float32)
        dn = np.clip(np.rint(raw * np.float32(levels / self.full_well)), 0,
                     levels).astype(np.uint16)
        if self.bayer:
            # OpenCV names Bayer patterns by the second row and column: a sensor with R at
            # (0, 0) (RGGB) is its "BayerBG" (its "BayerRG" would swap red and blue).
            rgb_or_bgr = cv2.cvtColor(dn, cv2.COLOR_BayerBG2BGR)
            bgr = cache['lut'][rgb_or_bgr]
        else:
            bgr = cache['lut'][dn[:, :, ::-1]]
        bgr = np.ascontiguousarray(bgr)
        if self.jpeg_quality is not None:
            ok, data = cv2.imencode('.jpg', bgr, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality,
                                                  cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
                                                  cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420])
            assert ok
            bgr = cv2.imdecode(data, cv2.IMREAD_COLOR)
        return bgr


# ============================================================================================
# Scenes
# ============================================================================================

def racket_and_sleeve(t, colour='white'):
    """The distractor at the robot's end at instants ``t`` (T,): a racket-sized disc of the
    ball's colour swinging on an arc (about 2 m/s), and a white sleeve (a forearm) holding
    it. Returns [Disc, Capsule]."""
    t = np.atleast_1d(t)
    phase = 2 * np.pi * 0.9 * t
    centre = np.stack([-1.75 + 0.12 * np.cos(phase), 0.45 + 0.32 * np.sin(phase),
                       0.28 + 0.12 * np.cos(2 * phase)], axis=1)
    # The face toward both cameras (behind the robot's end and to its side, above) tilted up
    # to the lamps, wobbling with the swing.
    normal = np.stack([-0.55 + 0.2 * np.cos(phase), -0.45 + 0.35 * np.sin(phase),
                       0.7 * np.ones_like(phase)], axis=1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    wrist = centre + np.array([-0.06, 0.13, -0.05])
    elbow = wrist + np.stack([-0.22 - 0.05 * np.sin(phase), 0.22 + 0.05 * np.cos(phase),
                              -0.08 * np.ones_like(phase)], axis=1)
    albedo = BALL_ALBEDO[colour]
    return [Disc(centre, normal, 0.075, Material(albedo, roughness=0.3, sheen=0.05)),
            Capsule(wrist, elbow, 0.045, Material((0.82, 0.82, 0.80), roughness=0.6))]


def render_scene(rig, flights=(), colour='white', t_begin=-0.2, t_end=0.8, time_offsets=None,
                 distractor=False, seed=0, renderer=None, sensor=None):
    """Frames of the rig's cameras watching the balls of ``flights`` (:class:`Flight`).

    Camera k exposes frames centred on t_begin + n / fps + time_offsets[k] (s) for
    t_begin <= t <= t_end. Returns ``(frames, truth)``: ``frames`` an iterator of
    ``(t, k, frame)`` in time order (frame uint8 H x W x 3 BGR, t the exposure mid-time on
    the common clock); ``truth`` a list, one dict per flight, with ``t`` (n,) camera 0's
    frame times while the ball flies and ``state`` (n, 9) there, and ``bounces`` (times).
    ``distractor``: the racket and sleeve of :func:`racket_and_sleeve` swing at the robot's
    end. ``renderer``: a :class:`Renderer` of this rig to reuse (its backgrounds are kept);
    ``sensor``: a :class:`Sensor`.
    """
    renderer = renderer or Renderer(rig, seed=seed)
    sensor = sensor or Sensor()
    cams = rig.cameras
    fps = rig.fps
    offsets = np.zeros(len(cams)) if time_offsets is None else np.asarray(time_offsets, float)
    n_frames = int(np.floor((t_end - t_begin) * fps + 1e-9)) + 1
    frame_t = t_begin + np.arange(n_frames) / fps
    material = ball_material(colour)
    truth = []
    for f in flights:
        t0 = frame_t + offsets[0]
        st = f.state(t0)
        ok = np.all(np.isfinite(st), axis=1)
        truth.append({'t': t0[ok], 'state': st[ok], 'bounces': f.bounce_times})
    caches = [{} for _ in cams]

    def frames():
        order = sorted((frame_t[n] + offsets[k], k, n) for n in range(n_frames)
                       for k in range(len(cams)))
        for t, k, n in order:
            times = renderer.sample_times(t)
            balls = []
            for f in flights:
                p = f.state(times)[:, :3]
                p = p[np.all(np.isfinite(p), axis=1)]    # launched or ended within it: part
                if len(p):
                    balls.append((p, material))
            objects = racket_and_sleeve(times[1::2], colour) if distractor else []
            img = renderer.render_linear(k, t, balls, objects)
            rng = np.random.default_rng([seed, k, n])
            yield t, k, sensor.capture(img, cams[k], rng, caches[k])

    return frames(), truth
