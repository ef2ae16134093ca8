"""Probability that a stroke lands in its target zone, given the incoming state covariance.

Pure module (no rclpy). The racket (normal, velocity) is fixed; the incoming ball state at the
hit point is uncertain, Gaussian with covariance C (9x9, table frame, SI units). The landing
point L(x) (eq. 7, then the flight to the table's height) is computed for a fixed ensemble of
incoming states x_k = x0 + S xi_k, S S^T = C, with xi_k a scrambled Sobol sequence (seeded,
so the estimate is deterministic) mapped to standard normals; the in-zone probability is the
share of the L(x_k) inside the zone's cell.

Why an ensemble and not sigma points: with 10 % spin noise the landing depends on the spin
nonlinearly and with interactions (a skewed landing spread of 15 cm over a 46 cm cell); a
Gaussian fitted through 19 sigma points was 6 percentage points off the Monte-Carlo share in
such cases, an additive per-axis quartic still 3 to 5. The quasi-random ensemble of 1024 is
within 1 point (docs/strike.md).
"""

import functools
import math

from numba import njit
import numpy as np
from scipy.optimize import minimize
from scipy.special import ndtr, ndtri
from scipy.stats import qmc
from tt_prediction.ball import (
    CONTACT_EDGE,
    CONTACT_FLOOR,
    CONTACT_OFF,
    CONTACT_TOP,
    FL_CROSS_X,
    FL_CROSS_Y,
    FL_S,
    FLIGHT_N,
    landing_flight,
    packed_params,
    racket_rebound,
    racket_rebound_inplace,
    zone_bounds,
)
from tt_prediction.predict import predict_landing
from tt_prediction.uncertainty import check_spread, check_symmetric, covariance_eigen

_NJIT = {'cache': True, 'nogil': True}
ENSEMBLE_SIZE = 1024
"""Incoming states in the ensemble (a power of two for the Sobol sequence)."""


@njit(**_NJIT)
def landings(states, normal, racket_velocity, P, out):
    """Landing (x, y) of each incoming state (n, 9) hit by the given racket, into out (n, 2).

    The first contact of ``tt_prediction.predict.landing_flight`` with the table as a body:
    on the top, its point; on a face or edge, the contact point (just beside the table); past
    the table to the floor, where the centre came down through the contact height z = r
    beside the table. These keep the landing offsets continuous across the edge for
    :func:`aim_in_zone`; all of them are outside every zone. NaN when the ball meets the net
    or a post, or does not come down within 3 s.
    """
    res = np.empty(FLIGHT_N)
    for k in range(states.shape[0]):
        s = states[k].copy()
        racket_rebound_inplace(s, P, normal, racket_velocity)
        kind = landing_flight(s, 0.0, P, True, res)
        out[k, 0] = math.nan
        out[k, 1] = math.nan
        if kind == CONTACT_TOP or kind == CONTACT_EDGE:
            out[k, 0] = res[FL_S]
            out[k, 1] = res[FL_S + 1]
        elif kind == CONTACT_FLOOR:
            out[k, 0] = res[FL_CROSS_X]
            out[k, 1] = res[FL_CROSS_Y]


_JACOBIAN_STEPS = np.array([1e-3, 1e-3, 1e-3, 0.1, 0.1, 0.1])
"""Finite-difference steps of landing_jacobian for velocity (m/s) and spin (rad/s)."""


@njit(**_NJIT)
def landing_jacobian(hit_state, normal, racket_velocity, P, jac):
    """Jacobian (2, 9) of the landing (x, y) with respect to the incoming hit state, the
    racket fixed, into jac. Velocity and spin columns: forward differences of the plane-model
    landing (smooth across the net and edges; 7 flights). Position columns: a hit point
    moved by (dx, dy, dz) is taken to land moved by (dx, dy) (the flight is nearly the same
    from a point millimetres away), which spares 3 flights. Returns False when a perturbed
    ball does not come down."""
    res = np.empty(FLIGHT_N)
    base = np.empty(2)
    for i in range(2):
        for j in range(3):
            jac[i, j] = 1.0 if i == j else 0.0
    for k in range(7):
        s = hit_state.copy()
        if k > 0:
            s[2 + k] += _JACOBIAN_STEPS[k - 1]
        racket_rebound_inplace(s, P, normal, racket_velocity)
        kind = landing_flight(s, 0.0, P, False, res)
        if kind != CONTACT_TOP and kind != CONTACT_OFF:
            return False
        if k == 0:
            base[0] = res[FL_S]
            base[1] = res[FL_S + 1]
        else:
            jac[0, 2 + k] = (res[FL_S] - base[0]) / _JACOBIAN_STEPS[k - 1]
            jac[1, 2 + k] = (res[FL_S + 1] - base[1]) / _JACOBIAN_STEPS[k - 1]
    return True


def linear_in_zone_probability(hit_state, covariance, normal, racket_velocity, params,
                               landing, zone):
    """In-zone probability of a stroke, linearised: the landing taken as Gaussian about
    ``landing`` (x, y), m, with covariance J C J^T (J: :func:`landing_jacobian`, C the 9x9
    incoming covariance), its x and y spreads taken as independent over the zone's cell.
    A cheap score for ranking hit points (7 flights), 0..1; 0 when it cannot be
    evaluated."""
    P = packed_params(params)
    jac = np.empty((2, 9))
    if not landing_jacobian(np.asarray(hit_state, dtype=float), np.asarray(normal, float),
                            np.asarray(racket_velocity, float), P, jac):
        return 0.0
    cov = jac @ np.asarray(covariance, dtype=float) @ jac.T
    sx, sy = math.sqrt(max(cov[0, 0], 1e-12)), math.sqrt(max(cov[1, 1], 1e-12))
    x0, x1, y0, y1 = zone_bounds(zone, 1)
    px = ndtr((x1 - landing[0]) / sx) - ndtr((x0 - landing[0]) / sx)
    py = ndtr((y1 - landing[1]) / sy) - ndtr((y0 - landing[1]) / sy)
    return float(px * py)


def _sqrt_cov(cov):
    """Symmetric square root columns of a covariance (eigen-decomposition; tolerates rank loss)."""
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    return vecs * np.sqrt(np.clip(vals, 0.0, None))


@functools.lru_cache(maxsize=4)
def _normal_points(n):
    """n quasi-random standard normal points (n, 9): scrambled Sobol, fixed seed."""
    return ndtri(qmc.Sobol(9, scramble=True, seed=0).random(n))


def landing_ensemble(hit_state, covariance, normal, racket_velocity, params, n=ENSEMBLE_SIZE):
    """Landing points (n, 2), m, of the incoming ensemble around hit_state (see module doc)."""
    P = packed_params(params)
    states = (np.asarray(hit_state, dtype=float)
              + _normal_points(n) @ _sqrt_cov(np.asarray(covariance, dtype=float)).T)
    out = np.empty((n, 2))
    landings(states, np.asarray(normal, float), np.asarray(racket_velocity, float), P, out)
    return out


def in_zone_probability(points, zone):
    """Share of the landing points (n, 2), m (:func:`landing_ensemble`; NaN a miss) inside
    ``zone`` (1..9, opponent's half): the in-zone probability, 0..1."""
    x0, x1, y0, y1 = zone_bounds(zone, 1)
    x, y = points[:, 0], points[:, 1]
    return float(np.mean((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)))


def aim_in_zone(hit_state, normal, racket_velocity, params, points, centre, zone, inset=0.01,
                blur=0.01):
    """Aim point (x, y) inside ``zone`` that maximises the in-zone probability, m.

    ``points``: the ensemble's landings (n, 2), m (:func:`landing_ensemble`) of the stroke
    (normal, racket_velocity) aimed at ``centre``. Their offsets d_k = L(x_k) - L(x0) from
    the nominal landing are taken as the same for any aim across the zone (and net hits as
    misses); the aim maximises the share of aim + d_k inside the cell, each point blurred by
    a Gaussian of ``blur`` m so that the share is smooth (Nelder-Mead), kept ``inset`` m
    inside the zone.
    """
    nominal = landing_ensemble(hit_state, np.zeros((9, 9)), normal, racket_velocity, params,
                               1)[0]
    d = points - nominal
    n_all = d.shape[0]
    d = d[np.all(np.isfinite(d), axis=1)]           # net hits count as misses below
    x0, x1, y0, y1 = zone_bounds(zone, 1)
    lo = np.array([x0 + inset, y0 + inset])
    hi = np.array([x1 - inset, y1 - inset])
    if d.shape[0] == 0:
        return np.asarray(centre, dtype=float)

    def cost(aim):
        a = np.clip(aim, lo, hi)
        px = ndtr((x1 - a[0] - d[:, 0]) / blur) - ndtr((x0 - a[0] - d[:, 0]) / blur)
        py = ndtr((y1 - a[1] - d[:, 1]) / blur) - ndtr((y0 - a[1] - d[:, 1]) / blur)
        return -np.sum(px * py) / n_all

    start = np.clip(np.asarray(centre, dtype=float) - np.median(d, axis=0), lo, hi)
    res = minimize(cost, start, method='Nelder-Mead',
                   options={'xatol': 1e-3, 'fatol': 1e-4, 'maxiter': 200})
    return np.clip(res.x, lo, hi)


def check_covariance(cov, name='covariance'):
    """Check the square covariance ``cov`` as given by a user or message: raises ValueError
    ('<name> is not finite', 'is not symmetric (...)', 'is not positive semi-definite
    (eigenvalue ...)', wider than tt_prediction's SPREAD_LIMITS: tt_prediction.uncertainty's
    check_symmetric, covariance_eigen, check_spread)."""
    cov = np.asarray(cov, dtype=float)
    check_symmetric(cov, name)
    covariance_eigen(cov, name)
    check_spread(cov, name)


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
    """Monte-Carlo check: share of n random incoming states ~ N(hit_state, covariance) whose
    first table contact, after eq. 7 (``racket_rebound``) and the flight with the net
    (``tt_prediction.predict.predict_landing``), is in ``zone`` of the opponent's half.

    ``params``: a ModelParams; ``rng``: a numpy Generator. Returns (share, landings (n, 2),
    NaN where there is no contact on the table).
    """
    x0 = np.asarray(hit_state, dtype=float)
    states = x0 + rng.standard_normal((n, 9)) @ _sqrt_cov(np.asarray(covariance, float)).T
    out = np.full((n, 2), np.nan)
    hits = 0
    for k, s in enumerate(states):
        s = s.copy()
        s[3:6], s[6:9] = racket_rebound(s[3:6], s[6:9], normal, racket_velocity, params)
        pred = predict_landing(s, params)
        if pred.landing is not None:
            out[k] = pred.landing.p[:2]
        hits += pred.status == 'ok' and pred.landing.zone == zone and pred.landing.half == 1
    return hits / n, out
