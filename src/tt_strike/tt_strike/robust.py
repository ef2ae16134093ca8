"""Probability that a stroke lands in its target zone, given the incoming state covariance.

Pure module (no rclpy). The racket (normal, velocity) is fixed; the incoming ball state at the
hit point is uncertain with covariance C (9x9, table frame, SI units). The landing point
L(x) = first table contact after eq. 7 and the flight is propagated with sigma points at
+-1 sigma along the columns of a square root S of C (the divided-difference filter of
Norgaard et al., 2000: second-order mean, first-order covariance):

    mean = L(x0) + 1/2 sum_i [L(x0 + S_i) + L(x0 - S_i) - 2 L(x0)]
    cov  = 1/4 sum_i [L(x0 + S_i) - L(x0 - S_i)] [.]^T

(19 forward runs), and the in-zone probability is the Gaussian mass of the zone's rectangle.
"""

import math

from numba import njit
import numpy as np
from scipy.optimize import minimize
from scipy.special import ndtr
from tt_prediction.integrate import DEFAULT_STEP, EVENT_BOUNCE, EVENT_FLOOR, rollout_kernel
from tt_prediction.model import racket_rebound_inplace
from tt_prediction.table import zone_bounds

_NJIT = {'cache': True, 'nogil': True}
_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)


@njit(**_NJIT)
def landings(states, normal, racket_velocity, P, out):
    """Landing (x, y) of each incoming state (n, 9) hit by the given racket, into out (n, 2).

    The landing is the first crossing of z = r on the table, or of the floor beyond its edge
    (so off the table), with the net ignored; NaN when neither happens within 3 s.
    """
    ev_kind = np.zeros(4, dtype=np.int64)
    ev_t = np.zeros(4)
    ev_s = np.zeros((4, 9))
    empty_t = np.empty(0)
    samples = np.empty((0, 9))
    for k in range(states.shape[0]):
        s = states[k].copy()
        racket_rebound_inplace(s, P, normal, racket_velocity)
        n = rollout_kernel(s, 0.0, P, 3.0, DEFAULT_STEP, math.nan, 0, 1, empty_t, samples,
                           ev_kind, ev_t, ev_s)
        out[k, 0] = math.nan
        out[k, 1] = math.nan
        if n > 0 and (ev_kind[n - 1] == EVENT_BOUNCE or ev_kind[n - 1] == EVENT_FLOOR):
            out[k, 0] = ev_s[n - 1, 0]
            out[k, 1] = ev_s[n - 1, 1]


def _sqrt_cov(cov):
    """Symmetric square root columns of a covariance (eigen-decomposition; tolerates rank loss)."""
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    return vecs * np.sqrt(np.clip(vals, 0.0, None))


def landing_distribution(hit_state, covariance, normal, racket_velocity, params):
    """Mean (2,) and covariance (2, 2) of the landing point, m, by +-1 sigma points.

    Returns (mean, cov, nominal) with nominal the landing of hit_state itself.
    """
    P = params if isinstance(params, np.ndarray) else params.packed()
    x0 = np.asarray(hit_state, dtype=float)
    root = _sqrt_cov(np.asarray(covariance, dtype=float))
    pts = np.vstack([x0, x0 + root.T, x0 - root.T])
    out = np.empty((pts.shape[0], 2))
    landings(pts, np.asarray(normal, float), np.asarray(racket_velocity, float), P, out)
    f0, fp, fm = out[0], out[1:10], out[10:19]
    mean = f0 + 0.5 * np.sum(fp + fm - 2.0 * f0, axis=0)
    d = fp - fm
    cov = 0.25 * d.T @ d
    return mean, cov, f0


def rectangle_probability(mean, cov, x0, x1, y0, y1):
    """Mass of the Gaussian N(mean, cov) (2-D) inside [x0, x1] x [y0, y1].

    Conditional form: integral over x of N(x) [Phi((y1 - m(x)) / s) - Phi((y0 - m(x)) / s)],
    m(x) = mu_y + c_xy / c_xx (x - mu_x), s^2 = c_yy - c_xy^2 / c_xx, by 48-point
    Gauss-Legendre over [x0, x1] clipped to mu_x +- 8 sigma_x.
    """
    if not np.all(np.isfinite(mean)) or not np.all(np.isfinite(cov)):
        return math.nan
    cxx, cxy, cyy = cov[0, 0] + 1e-14, cov[0, 1], cov[1, 1] + 1e-14
    sx = math.sqrt(cxx)
    s = math.sqrt(max(cyy - cxy * cxy / cxx, 1e-14))
    a, b = max(x0, mean[0] - 8 * sx), min(x1, mean[0] + 8 * sx)
    if b <= a:
        return 0.0
    x = 0.5 * (b - a) * _GL_X + 0.5 * (a + b)
    pdf = np.exp(-0.5 * ((x - mean[0]) / sx) ** 2) / (sx * math.sqrt(2 * math.pi))
    m = mean[1] + cxy / cxx * (x - mean[0])
    inner = ndtr((y1 - m) / s) - ndtr((y0 - m) / s)
    return float(np.clip(0.5 * (b - a) * np.sum(_GL_W * pdf * inner), 0.0, 1.0))


def in_zone_probability(hit_state, covariance, normal, racket_velocity, params, zone):
    """Probability that the stroke lands in ``zone`` (1..9, opponent's half), 0..1."""
    mean, cov, _ = landing_distribution(hit_state, covariance, normal, racket_velocity, params)
    return rectangle_probability(mean, cov, *zone_bounds(zone, 1))


def aim_in_zone(hit_state, covariance, normal, racket_velocity, params, centre, zone,
                inset=0.01):
    """Aim point (x, y) inside ``zone`` that maximises the in-zone probability, m.

    The landing spread (bias of the mean and covariance) measured for the stroke aimed at
    ``centre`` is taken as independent of the aim across the zone; the aim then maximises the
    rectangle's Gaussian mass (Nelder-Mead), kept ``inset`` m inside the zone's edges.
    """
    mean, cov, nominal = landing_distribution(hit_state, covariance, normal, racket_velocity,
                                              params)
    x0, x1, y0, y1 = zone_bounds(zone, 1)
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
        return np.asarray(centre, dtype=float)
    bias = mean - nominal
    lo = np.array([x0 + inset, y0 + inset])
    hi = np.array([x1 - inset, y1 - inset])

    def cost(aim):
        aim = np.clip(aim, lo, hi)
        return -rectangle_probability(aim + bias, cov, x0, x1, y0, y1)

    start = np.clip(np.asarray(centre, dtype=float) - bias, lo, hi)
    res = minimize(cost, start, method='Nelder-Mead',
                   options={'xatol': 1e-3, 'fatol': 1e-5, 'maxiter': 200})
    return np.clip(res.x, lo, hi)


def noise_covariance(hit_state, sigma_position=0.002, velocity_fraction=0.02,
                     spin_fraction=0.10):
    """Diagonal 9x9 covariance: sigma_position (m) on each position component, and on each
    velocity (spin) component the given fraction of the speed (spin magnitude)."""
    s = np.asarray(hit_state, dtype=float)
    sig = np.empty(9)
    sig[:3] = sigma_position
    sig[3:6] = velocity_fraction * np.linalg.norm(s[3:6])
    sig[6:9] = spin_fraction * np.linalg.norm(s[6:9])
    return np.diag(sig ** 2)


def monte_carlo_in_zone(hit_state, covariance, normal, racket_velocity, params, zone, n,
                        rng):
    """Monte-Carlo share of n incoming states ~ N(hit_state, covariance) landing in zone.

    Landing per MODEL.md: first table contact in the zone's cell on the opponent's half.
    Returns (share, landings (n, 2)).
    """
    P = params if isinstance(params, np.ndarray) else params.packed()
    x0 = np.asarray(hit_state, dtype=float)
    states = x0 + rng.standard_normal((n, 9)) @ _sqrt_cov(np.asarray(covariance, float)).T
    out = np.empty((n, 2))
    landings(states, np.asarray(normal, float), np.asarray(racket_velocity, float), P, out)
    bx0, bx1, by0, by1 = zone_bounds(zone, 1)
    inside = ((out[:, 0] >= bx0) & (out[:, 0] <= bx1) & (out[:, 1] >= by0)
              & (out[:, 1] <= by1))
    return float(np.mean(inside)), out
