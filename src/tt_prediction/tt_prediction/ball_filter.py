"""Extended Kalman filter of one ball, s = [p, v, w] (9,), through flight and table bounces.

Frames and units: ``table`` frame (MODEL.md), p in m, v in m/s, w (spin) in rad/s, t in s.
No rclpy: perception_node (triangulated points, ``tt_perception.pipeline``) and the replay of
measured tracks (``tt_prediction.replay``, 3-D positions) run this same filter.

Flight. The state follows eq. 8 (drag + Magnus, with the effects of model.yaml) by one RK4
step of the model's own derivative; the covariance by Phi = I + F h + (F h)^2 / 2 with F the
analytic Jacobian of eq. 8 (:func:`tt_prediction.ball.flight_jacobian`) and the process
noise of a white unmodelled acceleration (``accel_noise``) and a spin random walk
(``spin_noise``). The spin enters the positions only through the Magnus term k_M w x u,
so flight observes the spin across the velocity (from the curvature of the path) and not
the component along it: that component keeps its prior variance, it is not invented.

Bounce. When the predicted centre reaches the contact height (z = r, the table surface)
moving down over the table, the state is taken to the contact, the rebound of eqs. 1-6 is
applied with its analytic Jacobian (:func:`rebound_jacobian`), so the covariance of the spin
(along the velocity too) goes through the bounce, and extra noise for the rebound's own
uncertainty is added. The rebound turns the spin into tangential velocity (eqs. 1-2: the
change of v_T at the contact is alpha (v_T + r w x n)), so the post-bounce samples fused
next measure r w through the cross-covariance the Jacobian built. A ball that bounced earlier
or later than the model's contact height says so by a kink the gate rejects; the filter then
tries a few contact heights around the nominal one and keeps the one that explains the sample
(:meth:`BallFilter.update` with ``rebounce``).

Measurements: positions (3,) with covariance R (3, 3); an innovation whose squared
Mahalanobis distance exceeds ``gate`` (3 dof) is rejected, one beyond ``robust`` counts with a
proportionally inflated covariance (Huber-like).

Offline, :func:`smooth` takes a filter's run (its states after each update) back through the
same flight and rebound (Rauch-Tung-Striebel): every state then rests on the samples after it
too.

:class:`TrackFilter` wraps it for a stream of measured positions: NaN rows and out-of-order or
duplicate stamps are skipped, spikes gated, gaps coasted over, and the filter re-started from
the data after a run of rejected samples (a racket hit, a missed bounce) or a long gap.
"""

import copy
import dataclasses
import math

from numba import njit
import numpy as np

from .ball import (
    EDGE_LENGTH_REF,
    HALF_LENGTH,
    HALF_WIDTH,
    I_ET_EDGE,
    I_ET_SLOPE,
    I_ET_SPIN_SLOPE,
    I_ET_TANGENTIAL,
    I_MU,
    I_MU_SLIP_SLOPE,
    I_MU_SLOPE,
    I_RADIUS,
    SLIP_SPEED_REF,
    ModelParams,
    edge_distance,
    edge_gradient,
    flight_derivative,
    flight_jacobian,
    rk4_advance,
    table_rebound_inplace,
    table_restitution,
)

__all__ = ['AccelNoiseLearner', 'BallFilter', 'FilterConfig', 'SpinPriorLearner', 'TrackFilter',
           'estimate_measurement_noise', 'rebound_jacobian',
           'rebound_map', 'spin_likelihood_per_axis', 'spin_outlier_log_odds',
           'velocity_frame']

_NJIT = {'cache': True, 'nogil': True}


_POSITIVE = frozenset(('gate', 'robust', 'max_step', 'max_gap'))
_SIGNED = frozenset(('spin_prior_mean',))
"""FilterConfig fields that must be > 0, and those that may be negative (the others >= 0)."""


@dataclasses.dataclass
class FilterConfig:
    """Noise, gating and track handling of :class:`BallFilter` / :class:`TrackFilter` (SI)."""

    accel_noise: float = 0.05
    """Unmodelled acceleration as a white-noise density, m/s^2 / sqrt(Hz), of a ball at rest;
    at speed |v| it is accel_noise sqrt(1 + (|v| / accel_noise_speed)^4)."""
    accel_noise_speed: float = 3.0
    """Speed (m/s) at which the unmodelled acceleration's aerodynamic part, which grows as
    the drag and Magnus forces (|v|^2), equals its part at rest (``accel_noise``); 0: the same
    at every speed. Measured on the MPI sets (docs/prediction_measured.md, "The unmodelled
    acceleration grows with speed")."""
    spin_noise: float = 2.0
    """Random walk of the spin, rad/s / sqrt(s)."""
    spin_prior: float = 250.0
    """Prior standard deviation of the spin about the horizontal axis across the velocity
    (top/back spin), rad/s; of every component unless the two below are set."""
    spin_prior_side: float = None
    """Prior standard deviation of the side spin (about the axis across the velocity in
    the vertical plane), rad/s; None: ``spin_prior``."""
    spin_prior_along: float = None
    """Prior standard deviation of the spin along the velocity (gyro spin, which flight
    cannot observe), rad/s; None: ``spin_prior``."""
    spin_prior_mean: tuple = (0.0, 0.0, 0.0)
    """Prior mean of the spin on the same axes (:func:`velocity_frame`), rad/s: top/back
    spin (topspin positive: the ball's top moves along v), side spin (about the axis across
    v in the vertical plane; for a level v, counter-clockwise seen from above positive) and
    spin along v. A ball's spin before the data has spoken is this, expressed in the frame
    of its velocity at the start."""
    spin_outlier_prior: float = 250.0
    """Standard deviation of each spin component (rad/s, mean 0) of a ball whose spin is not
    of the population the spin prior describes (a launcher's rare strongly spun ball among
    its slow ones): the second component of the spin's mixture prior
    (``spin_outlier_rate``)."""
    spin_outlier_rate: float = 0.05
    """Prior probability (0 to below 1) that a ball's spin is ``spin_outlier_prior``'s, not
    the spin prior's. Where the spin prior is tighter than ``spin_outlier_prior`` across the
    velocity, :class:`BallFilter` runs a second filter with ``spin_outlier_prior`` alongside
    until the first bounce and keeps the state of the more probable component, given the
    spin the data show; 0: never."""
    spin_outlier_wait: float = 0.15
    """Time from a track's start (s) before the second filter's state may be used: its first
    spin estimates carry the start's velocity error."""
    bounce_velocity_noise: float = 0.15
    """Standard deviation added to each velocity component at a bounce, m/s."""
    bounce_spin_noise: float = 25.0
    """Standard deviation added to each spin component at a bounce, rad/s."""
    gate: float = 25.0
    """Squared Mahalanobis distance above which a measurement is an outlier (3 dof)."""
    robust: float = 9.0
    """Squared Mahalanobis distance above which a measurement's covariance is inflated."""
    max_step: float = 1.0 / 150.0
    """Longest integration step, s."""
    position_noise: float = 1.5e-3
    """Standard deviation of a measured position per axis (TrackFilter, replay), m."""
    stamp_noise: float = 0.0
    """Standard deviation of a sample's time stamp against its exposure (TrackFilter), s: a
    stamp off by dt puts the ball off by v dt along its velocity, so the measurement
    covariance is position_noise^2 I + stamp_noise^2 v v^T."""
    start_velocity_noise: float = 0.3
    """Velocity standard deviation per axis added to the two-sample start (drag, jitter), m/s."""
    max_rejects: int = 3
    """TrackFilter restarts from the data after this many rejected samples in a row."""
    max_gap: float = 0.2
    """TrackFilter restarts after a gap without accepted samples longer than this, s."""
    bounce_transform: str = 'linear'
    """How the covariance goes through a bounce: 'linear' (the Jacobian of eqs. 1-6 with the
    saltation term) or 'unscented' (sigma points through eqs. 1-6)."""
    rebounce_range: float = 0.015
    """Contact heights tried around z = r when a sample near a bounce fails the gate, +-m."""

    def __post_init__(self):
        """ValueError naming the first field out of its range (all finite; noises, priors
        and ranges >= 0; steps, gates and gaps > 0; a known bounce_transform)."""
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == 'bounce_transform':
                if value not in ('linear', 'unscented'):
                    raise ValueError(f"bounce_transform must be 'linear' or 'unscented', "
                                     f'not {value!r}')
                continue
            values = () if value is None else value if isinstance(value, tuple) else (value,)
            for v in values:
                if not math.isfinite(v):
                    raise ValueError(f'{f.name} must be finite, not {v}')
                if f.name in _POSITIVE and v <= 0.0:
                    raise ValueError(f'{f.name} must be > 0, not {v}')
                if f.name not in _SIGNED and v < 0.0:
                    raise ValueError(f'{f.name} must be >= 0, not {v}')
        if self.spin_outlier_rate >= 1.0:
            raise ValueError(f'spin_outlier_rate must be below 1, not {self.spin_outlier_rate}')

    def sample_cov(self, velocity):
        """Covariance (3, 3) of a measured position of a ball moving with ``velocity`` (m/s):
        ``position_noise``^2 I, and along v its stamp's jitter, ``stamp_noise``^2 v v^T
        (m^2)."""
        return _sample_cov(np.asarray(velocity, dtype=float), self.position_noise ** 2,
                           self.stamp_noise)

    def spin_prior_axes(self):
        """Prior standard deviations of the spin (top/back, side, along v), rad/s: the
        ``spin_prior*`` fields with their defaults filled in."""
        top = self.spin_prior
        side = top if self.spin_prior_side is None else self.spin_prior_side
        along = top if self.spin_prior_along is None else self.spin_prior_along
        return top, side, along


# ----------------------------------------------------------------------------------------------
# Compiled kernels


@njit(**_NJIT)
def rebound_jacobian(s, P, J):
    """Jacobian (9, 9) of the table rebound (eqs. 1-6) at the pre-contact state ``s`` into J.

    Positions pass unchanged. With v_T = (v_x - r w_y, v_y + r w_x) and the slip ratio
    alpha = mu (1 + e_t) |v_z| / |v_T| while it stays below the grip ratio 2/5 (1 + e_x)
    (that constant otherwise):
        v_x' = (1 - alpha) v_x + alpha r w_y,   w_x' = (1 - 3 alpha/2) w_x - 3 alpha/(2r) v_y,
        v_y' = (1 - alpha) v_y - alpha r w_x,   w_y' = (1 - 3 alpha/2) w_y + 3 alpha/(2r) v_x,
        v_z' = -e_t v_z,                        w_z' = w_z;
    J holds the explicit partials plus (d out / d alpha) (d alpha / d s)^T and
    (d v_z' / d e_t) (d e_t / d s)^T, with the effects in e_t (impact speed, spin, the
    distance to the table's edge) and mu (spin, slip speed) as
    :func:`tt_prediction.ball.table_rebound_inplace` has them.
    """
    for i in range(9):
        for j in range(9):
            J[i, j] = 1.0 if i == j else 0.0
    r = P[I_RADIUS]
    vx, vy, vz = s[3], s[4], s[5]
    wx, wy, wz = s[6], s[7], s[8]
    spin = math.sqrt(wx * wx + wy * wy + wz * wz)
    vtx = vx - r * wy
    vty = vy + r * wx
    vt = math.sqrt(vtx * vtx + vty * vty)
    sgn = 1.0 if vz > 0.0 else -1.0
    # d|w|/dw and d|v_T|/ds (zero where undefined)
    dspin = np.zeros(9)
    if spin > 1e-12:
        dspin[6] = wx / spin
        dspin[7] = wy / spin
        dspin[8] = wz / spin
    dvt = np.zeros(9)
    if vt > 1e-12:
        dvt[3] = vtx / vt
        dvt[4] = vty / vt
        dvt[6] = r * vty / vt
        dvt[7] = -r * vtx / vt
    e_raw = table_restitution(s, P)
    e_t = min(max(e_raw, 0.0), 1.0)
    de = np.zeros(9)
    if 0.0 < e_raw < 1.0:
        de[5] = P[I_ET_SLOPE] * sgn
        for j in range(6, 9):
            de[j] = P[I_ET_SPIN_SLOPE] * r * dspin[j]
        if P[I_ET_EDGE] != 0.0:      # d/dp of e_t_edge exp(-d / L), d the edge distance
            k = (-P[I_ET_EDGE] * math.exp(-edge_distance(s[0], s[1]) / EDGE_LENGTH_REF)
                 / EDGE_LENGTH_REF)
            gx, gy = edge_gradient(s[0], s[1])
            de[0], de[1] = k * gx, k * gy
    mu_raw = P[I_MU] + P[I_MU_SLOPE] * spin + P[I_MU_SLIP_SLOPE] * (vt - SLIP_SPEED_REF)
    mu = max(mu_raw, 0.0)
    dmu = np.zeros(9)
    if mu_raw > 0.0:
        for j in range(9):
            dmu[j] = P[I_MU_SLOPE] * dspin[j] + P[I_MU_SLIP_SLOPE] * dvt[j]
    grip = 0.4 * (1.0 + P[I_ET_TANGENTIAL])
    alpha = grip
    da = np.zeros(9)          # d alpha / d s
    if vt > 1e-12:
        slip = mu * (1.0 + e_t) * abs(vz) / vt
        if slip < grip:
            alpha = slip
            for j in range(9):
                da[j] = (dmu[j] * (1.0 + e_t) * abs(vz) / vt
                         + mu * de[j] * abs(vz) / vt
                         - slip / vt * dvt[j])
            da[5] += mu * (1.0 + e_t) * sgn / vt
    # Explicit partials (alpha and e_t fixed).
    J[3, 3] = 1.0 - alpha
    J[3, 7] = alpha * r
    J[4, 4] = 1.0 - alpha
    J[4, 6] = -alpha * r
    J[5, 5] = -e_t
    J[6, 6] = 1.0 - 1.5 * alpha
    J[6, 4] = -1.5 * alpha / r
    J[7, 7] = 1.0 - 1.5 * alpha
    J[7, 3] = 1.5 * alpha / r
    for j in range(9):
        J[5, j] -= vz * de[j]
    # d out / d alpha
    dout = np.zeros(9)
    dout[3] = -vx + r * wy
    dout[4] = -vy - r * wx
    dout[6] = -1.5 * wx - 1.5 / r * vy
    dout[7] = -1.5 * wy + 1.5 / r * vx
    for i in range(3, 8):
        if dout[i] != 0.0:
            for j in range(9):
                J[i, j] += dout[i] * da[j]


@njit(**_NJIT)
def _propagate(x, C, h, P, q_acc, q_spin, inv_speed4=0.0):
    """State and covariance after ``h`` s of flight: RK4 of eq. 8 and Phi C Phi^T + Q.

    Q is that of a white acceleration of density q_acc (1 + |v|^4 inv_speed4) (|v| at the
    step's start; :attr:`FilterConfig.accel_noise_speed`) and a spin random walk q_spin."""
    F = np.empty((9, 9))
    flight_jacobian(x, P, F)
    Fh = F * h
    Phi = np.eye(9) + Fh + 0.5 * (Fh @ Fh)
    out = rk4_advance(x, h, P)
    Cn = Phi @ C @ Phi.T
    v2 = x[3] * x[3] + x[4] * x[4] + x[5] * x[5]
    a = q_acc * (1.0 + v2 * v2 * inv_speed4) * h
    for i in range(3):
        Cn[i, i] += a * h * h / 3.0
        Cn[i, 3 + i] += a * h / 2.0
        Cn[3 + i, i] += a * h / 2.0
        Cn[3 + i, 3 + i] += a
        Cn[6 + i, 6 + i] += q_spin * h
    return out, Cn


@njit(**_NJIT)
def rebound_map(xc, P):
    """Rebound (eqs. 1-6) of the contact state ``xc`` (9,) and its linear map S (9, 9): the
    Jacobian J plus the saltation term (a state error also moves the contact time,
    dt_c/ds = -e_z / v_z): S = J + (f_out - J f_in) (dt_c/ds)^T. Returns (x_out, S)."""
    J = np.empty((9, 9))
    rebound_jacobian(xc, P, J)
    f_in = np.empty(9)
    flight_derivative(xc, P, f_in)
    x = xc.copy()
    table_rebound_inplace(x, P)       # eqs. 1-6
    f_out = np.empty(9)
    flight_derivative(x, P, f_out)
    jump = f_out - J @ f_in
    vz = min(f_in[2], -1e-3)
    for i in range(9):
        J[i, 2] -= jump[i] / vz
    return x, J


@njit(**_NJIT)
def _rebound_linear(xc, Cc, P):
    """Rebound (eqs. 1-6) of the contact state ``xc`` and its covariance through
    :func:`rebound_map`'s S (Jacobian and saltation term)."""
    x, S = rebound_map(xc, P)
    return x, S @ Cc @ S.T


@njit(**_NJIT)
def _rebound_unscented(xc, Cc, P, contact_z):
    """Rebound (eqs. 1-6) of the contact state ``xc`` and covariance ``Cc`` by the unscented
    transform: the rebound is far from linear in the spin the flight could not observe (the
    slip ratio alpha of eqs. 1-6 depends on |v_T| = |v - r w x n|, and sliding turns into
    rolling at alpha = 2/5), so 2n sigma points at +-sqrt(n) standard deviations go through
    it. Each point meets the table at its own time, t_c + d with d = (z - z_c) / -v_z: it is
    moved to its contact along its flight derivative, rebounded, and moved back by d along
    its new derivative, so the spread of contact times (the saltation term) is in the
    result too. Returns the mean and covariance at the mean's contact time."""
    n = 9
    Cs = 0.5 * (Cc + Cc.T)
    for i in range(n):
        Cs[i, i] += 1e-12
    L = np.linalg.cholesky(Cs) * math.sqrt(n)
    Y = np.empty((2 * n, n))
    f = np.empty(9)
    for k in range(2 * n):
        X = xc + (L[:, k % n] if k < n else -L[:, k % n])
        vz = min(X[5], -0.05)
        d = (X[2] - contact_z) / -vz
        flight_derivative(X, P, f)
        X = X + f * d
        X[5] = vz
        X[2] = contact_z
        table_rebound_inplace(X, P)
        flight_derivative(X, P, f)
        Y[k] = X - f * d
    mean = np.zeros(n)
    for k in range(2 * n):
        mean += Y[k]
    mean /= 2 * n
    cov = np.zeros((n, n))
    for k in range(2 * n):
        dy = Y[k] - mean
        cov += np.outer(dy, dy)
    cov /= 2 * n
    return mean, cov


@njit(**_NJIT)
def _predict_to(x, C, t, t_end, P, cfg, contact_z, bounce):
    """Advance (x, C) from t to t_end, bouncing on the table at centre height ``contact_z``.

    cfg = (accel_noise^2, spin_noise^2, bounce_velocity_noise^2, bounce_spin_noise^2,
    max_step, 1 for the unscented rebound else 0, accel_noise_speed^-4 or 0). ``bounce`` (4,)
    receives the last contact (t, x, y, contact_z); returns the new state and the number of
    contacts: (x, C, n).
    """
    r = P[I_RADIUS]
    n_bounce = 0
    while t_end - t > 1e-9:
        h = min(cfg[4], t_end - t)
        z0 = x[2]
        xn, Cn = _propagate(x, C, h, P, cfg[0], cfg[1], cfg[6])
        on_table = abs(xn[0]) <= HALF_LENGTH + r and abs(xn[1]) <= HALF_WIDTH + r
        if xn[2] < contact_z <= z0 and xn[5] < 0.0 and on_table:
            tau = h * (z0 - contact_z) / max(z0 - xn[2], 1e-12)
            if tau <= 1e-9:
                # Already in contact (rolling on the surface): no impact, stay on it.
                xn[2] = contact_z
                xn[5] = max(xn[5], 0.0)
                x, C = xn, Cn
                t += h
                continue
            for _ in range(2):          # Newton on the contact time (z linear in tau)
                xc, Cc = _propagate(x, C, tau, P, cfg[0], cfg[1], cfg[6])
                if xc[5] >= 0.0:
                    break
                step = (xc[2] - contact_z) / xc[5]
                tau = min(max(tau + step, 1e-9), h)
            xc, Cc = _propagate(x, C, tau, P, cfg[0], cfg[1], cfg[6])
            xc[2] = contact_z
            if cfg[5] > 0.0:
                xc, Cc = _rebound_unscented(xc, Cc, P, contact_z)
            else:
                xc, Cc = _rebound_linear(xc, Cc, P)
            for i in range(3):
                Cc[3 + i, 3 + i] += cfg[2]
                Cc[6 + i, 6 + i] += cfg[3]
            x, C = xc, Cc
            t += tau
            n_bounce += 1
            bounce[0] = t
            bounce[1] = x[0]
            bounce[2] = x[1]
            bounce[3] = contact_z
            continue
        x, C = xn, Cn
        t += h
    return x, C, n_bounce


@njit(**_NJIT)
def _fuse_position(x, C, z, R, gate, robust):
    """Kalman update with a position z (3,), covariance R; returns (x, C, d2, accepted)."""
    y = z - x[:3]
    S = C[:3, :3] + R
    Si = np.linalg.inv(S)
    d2 = y @ Si @ y
    if d2 > gate:
        return x, C, d2, False
    if d2 > robust:
        R = R * (d2 / robust)
        S = C[:3, :3] + R
        Si = np.linalg.inv(S)
    K = np.ascontiguousarray(C[:, :3]) @ np.ascontiguousarray(Si)    # P H^T S^-1
    xn = x + K @ y
    IKH = np.eye(9)
    IKH[:, :3] -= K
    Cn = IKH @ C @ IKH.T + K @ R @ K.T     # Joseph form
    return xn, 0.5 * (Cn + Cn.T), d2, True


@njit(**_NJIT)
def _sample_cov(v, position_var, stamp_noise):
    """Covariance (3, 3), m^2, of a measured position of a ball moving with ``v`` (3,), m/s:
    ``position_var`` I (m^2) and, along v, the stamp's jitter (stamp_noise^2 v v^T, s)."""
    R = np.empty((3, 3))
    for i in range(3):
        ji = stamp_noise * v[i]
        for k in range(3):
            R[i, k] = (position_var if i == k else 0.0) + ji * (stamp_noise * v[k])
    return R


@njit(**_NJIT)
def _predict_fuse(x, C, t, t_end, P, cfg, contact_z, bounce, z, noise):
    """One measured sample in one compiled call: :func:`_predict_to` from t to ``t_end`` (s),
    then :func:`_fuse_position` of the position ``z`` (3,), m, with the sample's covariance
    (:func:`_sample_cov`) at the predicted velocity. ``noise`` = (position_noise^2,
    stamp_noise, gate, robust). Returns (x_pred, C_pred, n, R, x, C, d2, accepted): the
    prediction and its number of contacts, then the update (x, C the prediction's when
    rejected)."""
    xp, Cp, n = _predict_to(x, C, t, t_end, P, cfg, contact_z, bounce)
    R = _sample_cov(xp[3:6], noise[0], noise[1])
    xu, Cu, d2, ok = _fuse_position(xp, Cp, z, R, noise[2], noise[3])
    return xp, Cp, n, R, xu, Cu, d2, ok


def velocity_frame(velocity):
    """Rows (3, 3): the unit axes of the spin prior for a ball moving with ``velocity``:
    top/back spin (horizontal, across v: z x v), side spin (v x (z x v), ~vertical) and along
    v (table frame). A vertical velocity takes y as the top/back axis."""
    v = np.asarray(velocity, dtype=float)
    e1 = v / max(float(np.linalg.norm(v)), 1e-9)
    e2 = np.array([-e1[1], e1[0], 0.0])            # z x e1
    n2 = float(np.linalg.norm(e2))
    e2 = np.array([0.0, 1.0, 0.0]) if n2 < 1e-6 else e2 / n2
    e3 = np.cross(e1, e2)
    return np.stack([e2, e3, e1])


# ----------------------------------------------------------------------------------------------
# The filter


_FILTER_STATE = ('x', 'P', '_prev', 'contact_z', 'last_d2')
"""What :class:`BallFilter` and its second filter trade when the more probable of the two
changes (both run to the same time, before any bounce, from the same start)."""


class BallFilter:
    """EKF of one ball. Create, :meth:`start`, then :meth:`predict` and :meth:`update`.

    Attributes: ``x`` (9,) state [p, v, w] (m, m/s, rad/s, table frame), ``P`` (9, 9) its
    covariance, ``t`` its time (s), ``bounces`` table contacts so far, ``last_bounce`` (t, x, y)
    of the latest contact (s, m) or None.
    """

    def __init__(self, params=None, config=None):
        self.params = params or ModelParams()
        self.config = config or FilterConfig()
        self.P_model = self.params.packed()
        c = self.config
        self._cfg = np.array([c.accel_noise ** 2, c.spin_noise ** 2,
                              c.bounce_velocity_noise ** 2, c.bounce_spin_noise ** 2,
                              c.max_step, 1.0 if c.bounce_transform == 'unscented' else 0.0,
                              # below 1 mm/s the aerodynamic part is all there is anyway
                              max(c.accel_noise_speed, 1e-3) ** -4 if c.accel_noise_speed
                              else 0.0])
        self._noise = np.array([c.position_noise ** 2, c.stamp_noise, c.gate, c.robust])
        self.x = np.zeros(9)
        self.P = np.eye(9)
        self.t = self._start_t = 0.0
        self.start_velocity = np.zeros(3)
        self.bounces = 0
        self.last_bounce = None
        self._bounce = np.zeros(4)
        self._prev = None          # (x, P, t, bounces, last_bounce) before the last predict
        self.contact_z = self.params.radius
        """Centre height at contact (m) of the prediction that led to the current state (the
        one :meth:`update`'s ``rebounce`` kept, when it did): what :func:`smooth` needs to
        retrace it."""
        self.outlier = None
        """The second filter, its spin prior ``spin_outlier_prior``'s, run alongside this one
        until the first bounce (FilterConfig ``spin_outlier_rate``), or None. While
        :attr:`took_outlier` the two have traded states: this one's state is then the
        second filter's, and the second's the spin prior's."""
        self.took_outlier = False
        """True while the state is the second filter's (and, after the first bounce, when it
        was then): the data put the ball's spin outside the population the spin prior
        describes."""
        self._outlier_config = _outlier_config(c)
        self._outlier_fused = None

    def start(self, t, position, velocity, position_cov, velocity_cov, spin=None,
              spin_cov=None):
        """Initialise at time ``t`` (s) from a position (m) and velocity (m/s) with their
        covariances (3, 3); the spin (rad/s) is the prior's (``spin_prior_mean``,
        ``spin_prior*``) unless given."""
        self.t = self._start_t = float(t)
        w = self.spin_prior_mean(velocity) if spin is None else np.asarray(spin, dtype=float)
        self.x = np.concatenate([position, velocity, w]).astype(float)
        self.start_velocity = np.array(velocity, dtype=float)   # the spin prior's frame
        self.P = np.zeros((9, 9))
        self.P[:3, :3] = position_cov
        self.P[3:6, 3:6] = velocity_cov
        self.P[6:, 6:] = self.spin_prior_cov(velocity) if spin_cov is None else spin_cov
        self.bounces = 0
        self.last_bounce = None
        self._prev = None
        self.outlier = None
        self.took_outlier = False
        if spin is None and self._outlier_config is not None:
            o = self.outlier = BallFilter(self.params, self._outlier_config)
            o.start(t, position, velocity, position_cov, velocity_cov)
            # its spin prior's covariance, mean and axes, and the mixture's two components
            c = self.config
            self._outlier_prior = (o.P[6:, 6:].copy(), o.x[6:].copy(), velocity_frame(velocity),
                                   np.array(c.spin_prior_axes(), dtype=float),
                                   np.array(c.spin_prior_mean, dtype=float),
                                   float(c.spin_outlier_prior), float(c.spin_outlier_rate))

    def spin_prior_mean(self, velocity):
        """Prior mean (3,) of the spin, rad/s, table frame, for a ball moving with
        ``velocity``: ``spin_prior_mean`` on the axes of :func:`velocity_frame`."""
        return velocity_frame(velocity).T @ np.asarray(self.config.spin_prior_mean, float)

    def spin_prior_cov(self, velocity):
        """Prior covariance (3, 3) of the spin, (rad/s)^2, for a ball moving with
        ``velocity``: ``spin_prior`` about the horizontal axis across it (top/back spin),
        ``spin_prior_side`` about the third axis and ``spin_prior_along`` along it."""
        top, side, along = self.config.spin_prior_axes()
        if side == top == along:
            return np.eye(3) * top ** 2
        E = velocity_frame(velocity)
        return E.T @ np.diag([top ** 2, side ** 2, along ** 2]) @ E

    def predict(self, t, contact_z=None):
        """Advance to time ``t`` (s), bouncing on the table (eqs. 1-6) when the ball does;
        ``contact_z``: centre height at contact (default the radius: the table surface)."""
        if t <= self.t:
            return
        cz = self.params.radius if contact_z is None else contact_z
        x, P, n = _predict_to(self.x, self.P, self.t, float(t), self.P_model, self._cfg, cz,
                              self._bounce)
        self._advance(t, cz, x, P, n)
        if self.outlier is not None:
            self.outlier.predict(t, contact_z)

    def predict_fuse(self, t, z):
        """:meth:`predict` to ``t`` (s, after :attr:`t`) at the nominal contact height, and
        the gated fusion of the position ``z`` (3,), m, measured then with the covariance
        :meth:`FilterConfig.sample_cov` of the predicted velocity, in one compiled call
        (:func:`_predict_fuse`). The filter is left predicted; the update is returned, not
        applied: ``(R, fused)`` to pass to :meth:`update` as ``update(z, R, fused=fused)``,
        the same as ``update(z, config.sample_cov(x[3:6]))`` after ``predict(t)``."""
        cz = self.params.radius
        xp, Cp, n, R, x, P, d2, ok = _predict_fuse(self.x, self.P, self.t, float(t),
                                                   self.P_model, self._cfg, cz, self._bounce,
                                                   z, self._noise)
        self._advance(t, cz, xp, Cp, n)
        if self.outlier is not None:
            self._outlier_fused = (self.t, *self.outlier.predict_fuse(t, z))
        return R, (x, P, d2, ok)

    def _advance(self, t, cz, x, P, n):
        """Take the prediction to ``t`` (s) at contact height ``cz`` (m): state ``x``,
        covariance ``P`` and ``n`` contacts (the last one in ``_bounce``)."""
        self._prev = (self.x, self.P, self.t, self.bounces, self.last_bounce)
        self.contact_z = cz
        self.x, self.P, self.t = x, P, float(t)
        if n:
            self.bounces += n
            self.last_bounce = (float(self._bounce[0]), float(self._bounce[1]),
                                float(self._bounce[2]))

    def earlier_state(self, t):
        """State (9,) and covariance (9, 9) at an earlier time ``t`` (s) of the same flight:
        the current estimate carried back by eq. 8 integrated backward, the covariance by
        the inverse flight map, with no process noise. That is what a fixed-interval
        smoother gives when the process noise is negligible over the interval (a few frames):
        the states of a track's first frames once later ones have confirmed it. None when
        the ball bounced since ``t`` (a contact this filter saw, or the path back passing
        below the table's surface over the table)."""
        r = self.params.radius
        x, C, now = self.x, self.P, self.t
        if t > now or (self.last_bounce is not None and self.last_bounce[0] > t):
            return None
        while now - t > 1e-9:
            h = -min(self.config.max_step, now - t)
            x, C = _propagate(x, C, h, self.P_model, 0.0, 0.0)
            now += h
            if x[2] < r and abs(x[0]) <= HALF_LENGTH + r and abs(x[1]) <= HALF_WIDTH + r:
                return None
        return x.copy(), C.copy()

    def innovation(self, z, R):
        """Innovation y (3,), its covariance S (3, 3) and squared Mahalanobis distance."""
        y = np.asarray(z, dtype=float) - self.x[:3]
        S = self.P[:3, :3] + R
        return y, S, float(y @ np.linalg.solve(S, y))

    def update(self, z, R, rebounce=False, fused=None):
        """Fuse a position measurement ``z`` (3,), m, covariance ``R`` (3, 3), m^2.

        Returns False (and leaves the state) when it fails the Mahalanobis gate. With
        ``rebounce``, a sample that fails the gate right after the last :meth:`predict`
        near the table is tried against contact heights within ``rebounce_range`` of z = r
        (an earlier or later bounce, seen as a kink); the best one that passes is kept.
        ``fused``: the fusion of ``z`` already computed (:meth:`predict_fuse`).

        Before the first bounce, the second filter (:attr:`outlier`) fuses ``z`` too, and the
        state is that of the more probable of the two (:meth:`_update_outlier`).
        """
        z = np.asarray(z, dtype=float)
        R = np.asarray(R, dtype=float)
        ok = self._update(z, R, rebounce, fused)
        if self.outlier is not None:
            self._update_outlier(z, R, fused is not None)
        return ok

    def _update(self, z, R, rebounce, fused):
        """:meth:`update` of this filter alone."""
        cfg = self.config
        if fused is None:
            fused = _fuse_position(self.x, self.P, z, R, cfg.gate, cfg.robust)
        x, P, d2, ok = fused
        self.last_d2 = d2
        if ok:
            self.x, self.P = x, P
            return True
        if not rebounce or self._prev is None:
            return False
        x0, P0, t0, b0, lb0 = self._prev
        r = self.params.radius
        near = self.bounces > b0 or (x0[2] < r + 4.0 * cfg.rebounce_range and x0[5] < 0.0)
        if not near:
            return False
        t = self.t
        best = None
        for cz in r + np.linspace(-cfg.rebounce_range, cfg.rebounce_range, 11):
            bounce = np.zeros(4)
            xb, Pb, n = _predict_to(x0, P0, t0, t, self.P_model, self._cfg, cz, bounce)
            if n == 0:
                continue
            xu, Pu, d2, ok = _fuse_position(xb, Pb, z, R, cfg.gate, cfg.robust)
            if ok and (best is None or d2 < best[0]):
                best = (d2, xu, Pu, n, bounce, cz)
        if best is None:
            return False
        _, self.x, self.P, n, bounce, self.contact_z = best
        self.bounces = b0 + n
        self.last_bounce = (float(bounce[0]), float(bounce[1]), float(bounce[2]))
        return True

    def __copy__(self):
        """A shallow copy (perception's trial update) with a shallow copy of its own of the
        second filter, which :meth:`update` changes in place."""
        new = object.__new__(BallFilter)
        new.__dict__.update(self.__dict__)
        if self.outlier is not None:
            new.outlier = copy.copy(self.outlier)
        return new

    def _update_outlier(self, z, R, fused):
        """Fuse ``z`` (3,), m, covariance ``R`` (3, 3) in the second filter too, with the
        fusion its :meth:`predict_fuse` made when ``fused``, and keep as this filter's state
        the more probable of the two (the mixture's MAP component): the second filter's
        (:attr:`took_outlier`) where, from ``spin_outlier_wait`` after the start, the spin
        the data alone show (:func:`spin_likelihood_per_axis` of its posterior, with its
        prior ``spin_outlier_prior``) is more probable under ``spin_outlier_prior`` than
        under the spin prior, ``spin_outlier_rate`` being the prior probability of the first
        (:func:`spin_outlier_log_odds`), and the spin prior's again where it is not (a flight
        the model gets wrong can read as a strong spin for a moment). At the first bounce
        (of either) the other one is dropped: the state goes on from the one kept."""
        pending, self._outlier_fused = self._outlier_fused, None
        o = self.outlier
        if self.bounces:
            self.outlier = None
            return
        if fused and pending is not None and pending[0] == self.t:
            o.update(z, pending[1], fused=pending[2])
        else:
            o.update(z, R)
        if o.bounces:
            self.outlier = None
            return
        if self.t - self._start_t < self.config.spin_outlier_wait:
            return
        wide = self if self.took_outlier else o
        want = _outlier_log_odds(wide.x[6:], wide.P[6:, 6:], *self._outlier_prior) < 0.0
        if want != self.took_outlier:
            for name in _FILTER_STATE:          # the two filters trade states
                mine = getattr(self, name)
                setattr(self, name, getattr(o, name))
                setattr(o, name, mine)
            self.took_outlier = want

    def rebound_noise(self, velocity_noise, spin_noise, t=None):
        """The covariance (9, 9) at ``t`` (s; None: now) of extra standard deviations
        ``velocity_noise`` (m/s) and ``spin_noise`` (rad/s) of the last bounce's rebound,
        injected at the contact and carried to ``t`` as a free flight would (a velocity error
        dv there is a position error dv (t - t_contact) at t); None when there was no
        bounce."""
        if self.last_bounce is None:
            return None
        dt = (self.t if t is None else t) - self.last_bounce[0]
        eye = np.eye(3) * velocity_noise ** 2
        Q = np.zeros((9, 9))
        Q[:3, :3] = dt * dt * eye
        Q[:3, 3:6] = Q[3:6, :3] = dt * eye
        Q[3:6, 3:6] = eye
        Q[6:, 6:] = np.eye(3) * spin_noise ** 2
        return Q

    def update_after_bounce(self, z, R, Q):
        """Fuse a position ``z`` (3,), m, covariance ``R`` (3, 3), that :meth:`update` gated
        out after a bounce, as the observed kink: with the covariance ``Q`` (9, 9) added, the
        rebound's own error (:meth:`rebound_noise`), for a rebound the model got wrong (a
        flight model that read the spin wrong, a table of another grip). Returns False (and
        leaves the state) when it still fails the gate. :func:`smooth` takes ``Q`` as a
        step's extra process noise."""
        cfg = self.config
        x, P, d2, ok = _fuse_position(self.x, self.P + Q, np.asarray(z, dtype=float),
                                      np.asarray(R, dtype=float), cfg.gate, cfg.robust)
        if ok:
            self.x, self.P = x, P
            self.last_d2 = d2
        return ok

    def update_spin(self, w, R):
        """Fuse a measured spin ``w`` (3,), rad/s, covariance ``R`` (3, 3) (e.g. from a marked
        ball); it fills in the component along the velocity that flight cannot observe. The
        second filter (:attr:`outlier`) is dropped: the measured spin decides."""
        self.outlier = None
        y = np.asarray(w, dtype=float) - self.x[6:]
        S = self.P[6:, 6:] + R
        K = np.linalg.solve(S, self.P[6:, :]).T
        self.x = self.x + K @ y
        IKH = np.eye(9)
        IKH[:, 6:] -= K
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T

    def spin_variance_along_velocity(self):
        """Variance (rad/s)^2 of the spin component along the current velocity."""
        u = self.x[3:6] / max(np.linalg.norm(self.x[3:6]), 1e-9)
        return float(u @ self.P[6:, 6:] @ u)


def _flight_map_jacobian(x, t, t_end, P, cfg, contact_z, x_end, n):
    """Jacobian (9, 9) of the state at ``t_end`` with respect to the state ``x`` at ``t``
    under :func:`_predict_to` (flight, and a bounce in between with its contact time), by
    central differences; ``x_end`` and ``n``: what :func:`_predict_to` gives for ``x`` (the
    state at ``t_end``, the number of contacts). Where a step moves the state across a
    contact at ``t_end`` (a bounce in one of the two evaluations only), the side that
    bounces as ``x`` does is used alone."""
    C = np.zeros((9, 9))
    bounce = np.zeros(4)
    F = np.empty((9, 9))
    for j, eps in enumerate((1e-5,) * 3 + (1e-4,) * 3 + (1e-2,) * 3):
        sides = []
        for sign in (1.0, -1.0):
            xj = x.copy()
            xj[j] += sign * eps
            yj, _, nj = _predict_to(xj, C, t, t_end, P, cfg, contact_z, bounce)
            sides.append(yj if nj == n else None)
        plus, minus = sides
        if plus is not None and minus is not None:
            F[:, j] = (plus - minus) / (2.0 * eps)
        elif plus is not None:
            F[:, j] = (plus - x_end) / eps
        elif minus is not None:
            F[:, j] = (x_end - minus) / eps
        else:
            F[:, j] = 0.0
    return F


def smooth(steps, params=None, config=None):
    """Fixed-interval (Rauch-Tung-Striebel) smoothing of one :class:`BallFilter` run.

    Parameters
    ----------
    steps : list of (t, x, P, contact_z[, Q])
        The filter's time (s), state (9,) and covariance (9, 9) at its start and after each
        update that followed, in time order, and the :attr:`BallFilter.contact_z` of the
        prediction that led to each (the start's is not used); ``Q`` (9, 9), where given and
        not None, the extra covariance that update added to the prediction
        (:meth:`BallFilter.update_after_bounce`).
    params, config : ModelParams, FilterConfig
        Those the filter ran with.

    Returns
    -------
    list of (x (9,), P (9, 9))
        The state and covariance at each step's time given every measurement of the run, those
        after it too: x_k + G (x_{k+1}^s - x_{k+1|k}), P_k + G (P_{k+1}^s - P_{k+1|k}) G^T with
        G = P_k F^T P_{k+1|k}^-1 (where that covariance is not positive semi-definite, the same
        sum in a form that is). The prediction x_{k+1|k}, P_{k+1|k} is retraced with the
        filter's own flight, rebound and process noise (:func:`_predict_to`); F is the
        Jacobian of the same map (:func:`_flight_map_jacobian`), a bounce in between
        included. For offline use (``tt-perceive``): a state that waits for later frames is
        of no use to a robot.
    """
    f = BallFilter(params, config)           # the packed model and noise settings
    out = [None] * len(steps)
    out[-1] = (steps[-1][1].copy(), steps[-1][2].copy())
    bounce = np.zeros(4)
    for k in range(len(steps) - 2, -1, -1):
        t0, x0, C0 = steps[k][:3]
        t1, _, _, contact_z, *extra = steps[k + 1]
        x_pred, C_pred, n = _predict_to(x0, C0, t0, t1, f.P_model, f._cfg, contact_z, bounce)
        if extra and extra[0] is not None:
            C_pred = C_pred + extra[0]
        F = _flight_map_jacobian(x0, t0, t1, f.P_model, f._cfg, contact_z, x_pred, n)
        G = np.linalg.solve(C_pred, F @ C0).T          # C0 F^T C_pred^-1 (both symmetric)
        x_next, C_next = out[k + 1]
        C = C0 + G @ (C_next - C_pred) @ G.T
        C = 0.5 * (C + C.T)
        sd = np.sqrt(np.maximum(np.diag(C0), 1e-300))
        if np.linalg.eigvalsh(C / np.outer(sd, sd))[0] < 0.0:
            # The difference lost its sign where C_pred, propagated with the filter's own
            # linearisation, and this finite-difference F imply a process noise Q = C_pred -
            # F C0 F^T a little indefinite (under perception's spin prior of 250 rad/s:
            # tt-perceive --smooth wrote covariances with eigenvalues down to -108; a
            # walk-through, 7 Dec 2026). The same sum for this G, with C_pred = F C0 F^T + Q,
            # as positive semi-definite terms, Q's negative part left out (a little wider).
            A = np.eye(9) - G @ F
            Q = _positive_part(C_pred - F @ C0 @ F.T, np.sqrt(np.diag(C_pred)))
            C = A @ C0 @ A.T + G @ (Q + C_next) @ G.T
            C = 0.5 * (C + C.T)
        out[k] = (x0 + G @ (x_next - x_pred), C)
    return out


def _positive_part(Q, scale):
    """The positive semi-definite part of the symmetric ``Q``: its negative eigenvalues set to
    0, in the coordinates where ``scale`` (each state's standard deviation) is 1."""
    scale = np.maximum(scale, 1e-150)
    Qs = Q / np.outer(scale, scale)
    values, vectors = np.linalg.eigh(0.5 * (Qs + Qs.T))
    Qs = (vectors * np.maximum(values, 0.0)) @ vectors.T
    return Qs * np.outer(scale, scale)


# ----------------------------------------------------------------------------------------------
# A stream of measured positions


SAME_BOUNCE_S = 0.03
"""Two contacts on the robot's half closer in time than this are one bounce (placed again by
a kink), s; a ball's second bounce comes 0.1 s or more after its first."""


class TrackFilter:
    """Runs a :class:`BallFilter` over one ball's stream of measured positions.

    :meth:`add` takes samples in arrival order: a NaN row or a stamp not after the filter's
    time (duplicate, out of order) is skipped (the filter coasts); a sample failing the gate
    is rejected; after ``max_rejects`` rejections in a row or a gap over ``max_gap`` the
    filter restarts from the last two samples. ``robot_bounced`` says whether the ball has
    bounced on the robot's half (x < 0) on its way in (reset once it moves away, vx > 0);
    ``robot_bounces`` how many times (a second one before the stroke: a double bounce, not a
    ball the robot may return).
    """

    SKIPPED, COASTED, REJECTED, ACCEPTED, STARTED = range(5)

    def __init__(self, params=None, config=None):
        self.params = params or ModelParams()
        self.config = config or FilterConfig()
        self.filter = None
        self.updates = 0
        self.rejects = 0
        self.last_accept = -math.inf
        self.robot_bounced = False
        self.robot_bounce = None
        self.robot_bounces = 0
        self._counted_t = -math.inf   # time of the last bounce counted in robot_bounces
        self.nis = []              # squared Mahalanobis distances of the accepted samples
        self._last = None          # the latest valid sample (t, p)
        self._before = None        # the one before it
        self._seen_bounce = None
        self._g = self.params.gravity_vector
        self._R = np.eye(3) * self.config.position_noise ** 2

    @property
    def running(self):
        return self.filter is not None

    def _start(self, t, p):
        t1, p1 = self._last
        dt = t - t1
        v = (p - p1) / dt + 0.5 * self._g * dt    # velocity at t (constant acceleration)
        cfg = self.config
        vcov = np.eye(3) * (2.0 * cfg.position_noise ** 2 / dt ** 2
                            + cfg.start_velocity_noise ** 2)
        spin = spin_cov = None
        f = BallFilter(self.params, cfg)
        f_prior = f.spin_prior_cov
        if self.filter is not None and not (self.filter.x[3] > 0.0 > v[0]):
            # Keep what is known of the spin (it changes little at a bounce the model
            # missed), with the prior's variance added back for what it might have done to
            # it. A ball struck back towards the robot has a spin of its own, of the
            # population the prior describes: the prior's.
            spin = self.filter.x[6:].copy()
            spin_cov = self.filter.P[6:, 6:] + f_prior(v)
        f.start(t, p, v, self._R, vcov, spin, spin_cov)
        if self.filter is not None and not self.robot_bounced:
            # Restarted from a kink near the table on the robot's half: a bounce the model
            # missed (its contact height or time was off).
            old = self.filter
            if old.x[2] < self.params.radius + 0.05 and p[0] < 0.0 and v[2] > 0.0:
                self.robot_bounced = True
                self.robot_bounce = (float(t1), float(p1[0]), float(p1[1]))
                self.robot_bounces = 1
                self._counted_t = float(t1)
        self.filter = f
        self.updates = 1
        self.rejects = 0
        self.last_accept = t

    def add(self, t, p):
        """Feed one sample: time ``t`` (s), measured position ``p`` (3,) (m, may hold NaN).
        Returns one of SKIPPED, COASTED, REJECTED, ACCEPTED, STARTED."""
        t = float(t)
        p = np.asarray(p, dtype=float)
        cfg = self.config
        f = self.filter
        if not math.isfinite(t) or (f is not None and t <= f.t) or (
                self._last is not None and t <= self._last[0]):
            return self.SKIPPED
        if not math.isfinite(p[0] + p[1] + p[2]):
            if f is not None:
                self._predict(t)
            return self.COASTED
        status = self.REJECTED
        if f is not None and t - self.last_accept > cfg.max_gap:
            self.filter = f = None           # too long without data: start afresh,
            self.robot_bounced = False       # a new ball (a file of two flights kept the
            self.robot_bounce = None         # first one's bounce through the second)
            self.robot_bounces = 0
        if f is not None:
            R, fused = f.predict_fuse(t, p)      # = predict(t), fusion of p with sample_cov
            self._note_bounce()
            if f.update(p, R, rebounce=True, fused=fused):
                self.nis.append(f.last_d2)
                self.updates += 1
                self.rejects = 0
                self.last_accept = t
                status = self.ACCEPTED
                self._note_bounce()
            else:
                self.rejects += 1
        if ((f is None or self.rejects >= cfg.max_rejects) and self._consistent(t, p)):
            self._start(t, p)
            status = self.STARTED
        self._before, self._last = self._last, (t, p)
        return status

    def _consistent(self, t, p):
        """True when the last two samples and (t, p) lie on one flight within ``max_gap``:
        the third within 15 mm of the second's ballistic extrapolation (a start from a spike
        would follow a wrong velocity)."""
        if self._last is None or self._before is None:
            return False
        (t0, p0), (t1, p1) = self._before, self._last
        if t - t0 > self.config.max_gap or not (t0 < t1 < t):
            return False
        v = (p1 - p0) / (t1 - t0) + 0.5 * self._g * (t1 - t0)
        dt = t - t1
        return bool(np.linalg.norm(p1 + v * dt + 0.5 * self._g * dt * dt - p) < 0.015)

    def _predict(self, t):
        self.filter.predict(t)
        self._note_bounce()

    def _note_bounce(self):
        """Track the ball's bounce on the robot's half (the predictor's ``bounced``)."""
        f = self.filter
        if f.x[3] > 0.0:
            self.robot_bounced = False          # moving away (returned): a new ball comes
            self.robot_bounce = None
            self.robot_bounces = 0
        elif (f.last_bounce is not None and f.last_bounce is not self._seen_bounce
                and f.last_bounce[1] < 0.0):
            # A contact re-placed by a kink (update's rebounce) is the same bounce again.
            again = (self.robot_bounce is not None
                     and abs(f.last_bounce[0] - self._counted_t) < SAME_BOUNCE_S)
            if not again:
                self.robot_bounces += 1
                self._counted_t = f.last_bounce[0]
            if self.robot_bounces <= 1:
                self.robot_bounce = f.last_bounce
            self.robot_bounced = True
        if f.last_bounce is not None:
            self._seen_bounce = f.last_bounce


INFORMED = 1e-8
"""Information (rad/s)^-2 above which a track's data inform an axis of the spin (a standard
deviation under 10,000 rad/s) (:func:`spin_likelihood_per_axis`)."""


def spin_likelihood_per_axis(mean, cov, prior_cov, velocity, prior_mean=None):
    """What one track's data say about its spin, per axis of the prior's velocity frame.

    ``mean`` (3,), ``cov`` (3, 3): the posterior of the spin (rad/s) given the track's data
    under the prior of mean ``prior_mean`` (3,), table frame (None: zero) and covariance
    ``prior_cov`` (3, 3); ``velocity`` (3,) m/s defines the axes (:func:`velocity_frame`:
    top/back, side, along v). Dividing the prior out (information form,
    Lambda = C^-1 - C0^-1, eta = C^-1 m - C0^-1 m0) leaves the likelihood, N(y, Lambda^-1)
    on the axes the data informed: y is the spin the data alone give and s^2 the diagonal
    of Lambda^-1 there (each axis's marginal variance: a bounce that measures the spin along
    v and to the side only together leaves each of them uncertain, and its y unbiased).
    Returns ``(y (3,), s2 (3,))``; y is 0 and s2 inf on an axis the data did not inform.
    """
    y = np.empty(3)
    s2 = np.empty(3)
    m0 = np.zeros(3) if prior_mean is None else np.asarray(prior_mean, dtype=float)
    _spin_likelihood(np.asarray(mean, dtype=float), np.asarray(cov, dtype=float),
                     np.asarray(prior_cov, dtype=float), m0, velocity_frame(velocity), y, s2)
    return y, s2


@njit(**_NJIT)
def _spin_likelihood(mean, cov, prior_cov, prior_mean, E, y, s2):
    """:func:`spin_likelihood_per_axis` with the frame's rows ``E`` (3, 3) given, into ``y``
    and ``s2`` (3,) (compiled: the second filter runs it on every update)."""
    Ci = np.linalg.inv(0.5 * (cov + cov.T))
    C0i = np.linalg.inv(0.5 * (prior_cov + prior_cov.T))
    lam = E @ (Ci - C0i) @ E.T
    eta = E @ (Ci @ mean - C0i @ prior_mean)
    y[:] = 0.0
    s2[:] = np.inf
    seen = np.array([lam[k, k] > INFORMED for k in range(3)])
    while seen.any():
        axes = np.nonzero(seen)[0]
        n = len(axes)
        sub = np.empty((n, n))
        for i in range(n):
            for j in range(n):
                sub[i, j] = lam[axes[i], axes[j]]
        if np.all(np.linalg.eigvalsh(sub) > 0.0):
            cov_axes = np.linalg.inv(sub)
            for i in range(n):
                y[axes[i]] = 0.0
                for j in range(n):
                    y[axes[i]] += cov_axes[i, j] * eta[axes[j]]
                s2[axes[i]] = cov_axes[i, i]
            return
        least = axes[0]                         # the least informed: not seen
        for k in axes:
            if lam[k, k] < lam[least, least]:
                least = k
        seen[least] = False


@njit(**_NJIT)
def spin_outlier_log_odds(y, s2, prior_sd, prior_mean, outlier_sd, rate):
    """Natural log of the posterior odds of a ball's spin being the spin prior's against the
    outlier component's, given what its data alone show.

    The prior is a mixture, per axis of the velocity frame (top/back, side, along v): with
    probability 1 - ``rate`` N(``prior_mean``, ``prior_sd``^2), with ``rate``
    N(0, ``outlier_sd``^2). ``y`` (3,), ``s2`` (3,): the spin the data alone show and its
    variances (:func:`spin_likelihood_per_axis`; an axis with s2 inf says nothing), so that
    y_k is N(mu_k, L_k^2 + s2_k) under the first component and N(0, W^2 + s2_k) under the
    second:
    log((1 - rate) / rate) + sum_k [log N(y_k; mu_k, L_k^2 + s2_k)
    - log N(y_k; 0, W^2 + s2_k)] (L the prior's, W the outlier's sd). Below 0 the outlier
    component is the more probable. ``rate`` in (0, 1); arrays (3,) (compiled).
    """
    odds = math.log((1.0 - rate) / rate)
    for k in range(3):
        if math.isfinite(s2[k]):
            a = prior_sd[k] ** 2 + s2[k]
            b = outlier_sd ** 2 + s2[k]
            odds += 0.5 * (y[k] ** 2 / b - (y[k] - prior_mean[k]) ** 2 / a + math.log(b / a))
    return odds


@njit(**_NJIT)
def _outlier_log_odds(mean, cov, prior_cov, prior_mean, E, prior_sd, mixture_mean,
                      outlier_sd, rate):
    """:func:`spin_outlier_log_odds` of the second filter's spin posterior ``mean`` (3,),
    ``cov`` (3, 3) under its prior (``prior_cov``, ``prior_mean``, axes ``E``), through
    :func:`_spin_likelihood`; the mixture's spin prior ``prior_sd``, ``mixture_mean`` (3,)
    on the axes, ``outlier_sd`` and ``rate``."""
    y = np.empty(3)
    s2 = np.empty(3)
    _spin_likelihood(mean, cov, prior_cov, prior_mean, E, y, s2)
    return spin_outlier_log_odds(y, s2, prior_sd, mixture_mean, outlier_sd, rate)


def _outlier_config(config):
    """The FilterConfig of :attr:`BallFilter.outlier`: ``config`` with the spin prior
    ``spin_outlier_prior`` on every axis, mean 0, and no second filter of its own; None when
    there is none (``spin_outlier_rate`` 0, or a spin prior across the velocity, top/back or
    side, no tighter than ``spin_outlier_prior``)."""
    top, side, _ = config.spin_prior_axes()
    if config.spin_outlier_rate <= 0.0 or min(top, side) >= config.spin_outlier_prior:
        return None
    return dataclasses.replace(config, spin_prior=config.spin_outlier_prior,
                               spin_prior_side=None, spin_prior_along=None,
                               spin_prior_mean=(0.0, 0.0, 0.0), spin_outlier_rate=0.0)


class SpinPriorLearner:
    """Empirical-Bayes prior of the spin, per axis of the velocity frame, from finished tracks.

    The filter's spin prior has a mean and standard deviations on the axes top/back, side
    and along v (:meth:`BallFilter.spin_prior_mean`, :meth:`BallFilter.spin_prior_cov`).
    Each finished track adds, per axis, a measurement y_i of its spin with variance s_i^2
    (:func:`spin_likelihood_per_axis`; in the replay the pre-bounce spin as the flight's
    curvature and the bounce measured it). With y_i = w_i + e_i, w_i drawn from the
    population N(mu, tau^2), the method of moments gives mu = mean(y_i) and
    tau^2 = var(y_i) - mean(s_i^2), over the tracks whose s_i is below ``max_sigma`` (an axis
    the data did not see says nothing: 150 rad/s; at 60 an axis measured about that well, as
    mpi_pam's side spin, informed few tracks or none, by chance, and kept the generic prior
    or took the floor: docs/prediction_measured.md), each y_i clipped to +-``cap``; tau is
    then floored at ``floor`` and capped at ``cap``. A population whose spin along v is
    consistent but smaller than what one track can measure of it (a launcher's gyro spin) has
    tau at the floor and the mean where the tracks put it. Until ``min_tracks`` tracks informed
    an axis it keeps the generic prior. Only what was :meth:`observe`-d is used: the caller
    decides which tracks (in the replay, those before the current one).

    Parameters: ``generic`` (3,) rad/s, the standard deviations before anything is learned,
    ``generic_mean`` (3,) rad/s, the mean; ``min_tracks``; ``floor``, ``cap``,
    ``max_sigma`` rad/s.
    """

    def __init__(self, generic=(250.0, 250.0, 250.0), generic_mean=(0.0, 0.0, 0.0),
                 min_tracks=5, floor=5.0, cap=600.0, max_sigma=150.0):
        self.generic = np.asarray(generic, dtype=float) * np.ones(3)
        self.generic_mean = np.asarray(generic_mean, dtype=float) * np.ones(3)
        self.min_tracks = int(min_tracks)
        self.floor = float(floor)
        self.cap = float(cap)
        self.max_sigma = float(max_sigma)
        self._y = [[], [], []]
        self._s2 = [[], [], []]

    def observe(self, y, s2):
        """Add one track's per-axis spin measurement ``y`` (3,) rad/s, variances ``s2`` (3,)
        (rad/s)^2 (inf: not measured), in the order top/back, side, along v."""
        for k in range(3):
            if math.isfinite(y[k]) and s2[k] <= self.max_sigma ** 2:
                self._y[k].append(min(max(float(y[k]), -self.cap), self.cap))
                self._s2[k].append(float(s2[k]))

    def counts(self):
        """Tracks that informed each axis (top/back, side, along v)."""
        return [len(a) for a in self._y]

    def moments(self):
        """Mean (3,) and standard deviations (3,) of the learned prior, rad/s: top/back,
        side, along v."""
        mean, sd = self.generic_mean.copy(), self.generic.copy()
        for k in range(3):
            n = len(self._y[k])
            if n >= self.min_tracks:
                y = np.array(self._y[k])
                mean[k] = float(np.mean(y))
                tau2 = float(np.var(y, ddof=1) - np.mean(self._s2[k]))
                sd[k] = min(max(math.sqrt(max(tau2, 0.0)), self.floor), self.cap)
        return mean, sd

    def prior(self):
        """Standard deviations (3,) rad/s: top/back, side, along v."""
        return self.moments()[1]

    def config(self, base):
        """``base`` (FilterConfig) with the learned spin prior."""
        mean, sd = self.moments()
        top, side, along = (float(v) for v in sd)
        return dataclasses.replace(base, spin_prior=top, spin_prior_side=side,
                                   spin_prior_along=along,
                                   spin_prior_mean=tuple(float(v) for v in mean))


class AccelNoiseLearner:
    """The filter's ``accel_noise`` learned from finished tracks' innovations.

    With the right noise the squared Mahalanobis distances (NIS) of a filter's accepted
    samples follow chi-square(3), whose median is 2.366; a too small accel_noise makes them
    larger (the model's error is not covered), a too large one smaller. The median keeps
    bounces and spikes out. After each track the noise moves by
    log q <- log q + gain (log median(NIS) - log 2.366), clipped to [``low``, ``high``]
    (measured on mpi_launcher: d log median / d log q ~ -0.3, so a gain of 1 is a third of
    a Newton step and averages the per-track medians over a few tracks).
    """

    CHI2_3_MEDIAN = 2.3660

    def __init__(self, start=0.05, gain=1.0, low=0.01, high=1.0, min_samples=20):
        self.value = float(start)
        self.gain = float(gain)
        self.low, self.high = float(low), float(high)
        self.min_samples = int(min_samples)
        self.tracks = 0

    def observe(self, nis):
        """Add one finished track's NIS values (accepted samples, run with ``value``)."""
        nis = np.asarray(nis, dtype=float)
        if len(nis) < self.min_samples:
            return
        step = self.gain * math.log(max(float(np.median(nis)), 1e-6) / self.CHI2_3_MEDIAN)
        self.value = min(max(self.value * math.exp(step), self.low), self.high)
        self.tracks += 1


NOISE_OUTLIER = 6.0
"""A window of :func:`estimate_measurement_noise` with a residual over this many of the noise's
standard deviations holds an outlier (or a bounce): it is left out of the estimate."""


NOISE_WINDOW = 7
"""Samples of each local fit of :func:`estimate_measurement_noise`."""


def estimate_measurement_noise(tracks, window=NOISE_WINDOW):
    """Position and stamp noise of measured tracks, from local fits: (m, s).

    Each run of ``window`` consecutive samples gets a least-squares quadratic in time per axis
    (flight over ~40 ms is a parabola to far below 0.1 mm). Its residuals across the fitted
    velocity give the position noise; along it they hold the stamp jitter too, var_along =
    sigma_p^2 + sigma_t^2 |v|^2. Medians over windows (scaled to the mean of their chi-square
    distributions) keep most bounces and spikes out; windows with a residual over
    :data:`NOISE_OUTLIER` standard deviations of the estimate are then left out and the
    medians taken again, until the windows kept no longer change (5 % of samples moved 1-3 cm
    put a window in three over the median: 0.63 mm was read as 0.98 mm on mpi_pam).
    ``tracks``: iterable of (t (n,), p (n, 3)). Returns ``(position_noise, stamp_noise)``.
    """
    across, along, speed = [], [], []
    for t, p in tracks:
        for a in range(0, len(t) - window + 1, window):
            tt = t[a:a + window] - t[a + window // 2]
            A = np.stack([np.ones(window), tt, tt * tt], axis=1)
            coef, *_ = np.linalg.lstsq(A, p[a:a + window], rcond=None)
            res = p[a:a + window] - A @ coef
            v = coef[1]
            sp = float(np.linalg.norm(v))
            if sp < 0.5:
                continue
            ra = res @ (v / sp)
            across.append(res - np.outer(ra, v / sp))
            along.append(ra)
            speed.append(sp)
    if not across:
        return math.nan, math.nan
    across, along, speed = np.array(across), np.array(along), np.array(speed)
    # Per window: the largest residual across v and along it, and the variance estimates.
    worst_across = np.max(np.linalg.norm(across, axis=2), axis=1)
    worst_along = np.max(np.abs(along), axis=1)
    var_across = np.sum(across * across, axis=(1, 2)) / (2 * (window - 3))
    var_along = np.sum(along * along, axis=1) / (window - 3)

    def median_ratio(dof):          # median of chi2(dof) / dof (Wilson-Hilferty)
        return (1.0 - 2.0 / (9.0 * dof)) ** 3

    def medians(keep):
        var_p = float(np.median(var_across[keep])) / median_ratio(2 * (window - 3))
        extra = (var_along[keep] / median_ratio(window - 3) - var_p) / speed[keep] ** 2
        return math.sqrt(var_p), math.sqrt(max(float(np.median(extra)), 0.0))

    keep = np.ones(len(speed), dtype=bool)
    sigma_p, sigma_t = medians(keep)
    for _ in range(5):
        kept = ((worst_across <= NOISE_OUTLIER * sigma_p)
                & (worst_along <= NOISE_OUTLIER * np.hypot(sigma_p, sigma_t * speed)))
        if np.array_equal(kept, keep) or not kept.any():
            break
        keep = kept
        sigma_p, sigma_t = medians(keep)
    return sigma_p, sigma_t
