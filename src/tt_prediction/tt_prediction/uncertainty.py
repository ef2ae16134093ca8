"""Uncertainty of a prediction from the state covariance: zone probabilities, hit covariance.

The 9x9 covariance of (p, v, w) is propagated through the (non-linear, event-driven) flight
by the unscented transform: 2n + 1 = 19 sigma points (n = 9) at the mean and at
mean +- sqrt(n + kappa) times the columns of a square root of the covariance, with kappa = 1,
so every weight is positive (1/10 at the mean, 1/20 elsewhere) and the points may be read as
a small weighted ensemble. All 19 go through one compiled batch call.

- Hit point: weighted mean and 3x3 covariance of the plane crossings of the points whose
  status is ok, and the standard deviation of the hit time. ``hit_fraction`` is the weight of
  those points (1: every point reaches the plane after one bounce).
- Zone probabilities: the first table contacts on the half where most weight lands give the
  mean and 2x2 covariance of the contact point; the probability of each of the 9 areas is
  that Gaussian's mass in the area (1024 fixed standard-normal draws, so the result is smooth
  in the state and deterministic), times the weight of the points with a contact on that half.
  Index 0 is the rest: off the table, no contact, or a contact on the other half.

Sigma points under the table's surface are lifted on to it (the state estimate cannot put
the ball inside the table); their spin is not limited, as a large spin variance only means
the spin is not observed yet (BallState).
"""

import dataclasses

import numpy as np

from .ball import HALF_LENGTH, HALF_WIDTH, ZONE_LENGTH, ZONE_WIDTH
from .predict import DEFAULT_HIT_PLANE_X, MAX_SPIN, OK, predict_batch

N_STATE = 9
KAPPA = 1.0
"""Unscented-transform spread: points at sqrt(9 + 1) = 3.16 standard deviations."""
N_DRAWS = 1024
_DRAWS = np.random.default_rng(20240601).standard_normal((N_DRAWS, 2))


@dataclasses.dataclass
class Uncertainty:
    """Result of :func:`predict_uncertainty`.

    zone_probabilities (10,): index 0 off the table / no contact, 1..9 the areas of
    ``zone_half`` (+1 opponent, -1 robot); hit_covariance (3, 3) m^2 (zeros when no point
    hits); hit_time_std s; hit_fraction the sigma-point weight that reaches the plane.
    """

    zone_probabilities: np.ndarray
    zone_half: int
    hit_covariance: np.ndarray
    hit_time_std: float
    hit_fraction: float


def covariance_eigen(cov, name='covariance'):
    """Eigenvalues and eigenvectors of the symmetric part of the square matrix ``cov``
    (:func:`numpy.linalg.eigh`); raises ValueError, naming the matrix ``name``, for one that
    is not finite or clearly not positive semi-definite: a variance below -1e-9 of its row's
    largest entry, or a correlation matrix (each variance scaled to 1) with an eigenvalue
    below -1e-9 of its largest. Judged on the correlations, not on the eigenvalues of the
    matrix itself, whose units differ from row to row: beside a spin variance of 150^2, a
    position variance of -1e-6 m^2 passed (a walk-through, 6 Dec 2026)."""
    if not np.all(np.isfinite(cov)):
        raise ValueError(f'{name} is not finite')
    sym = 0.5 * (cov + cov.T)
    eigval, eigvec = np.linalg.eigh(sym)
    variance = np.diag(sym)
    scale = np.sqrt(np.where(variance > 0.0, variance, 1.0))
    corr = np.linalg.eigvalsh(sym / np.outer(scale, scale))
    if (np.any(variance < -1e-9 * np.abs(sym).max(axis=1))
            or corr.min() < -1e-9 * max(float(np.abs(corr).max()), 1.0)):
        raise ValueError(f'{name} is not positive semi-definite (eigenvalue '
                         f'{eigval.min():.3g})')
    return eigval, eigvec


SPREAD_LIMITS = (('position', 'm', 1.0), ('velocity', 'm/s', 30.0),
                 ('spin', 'rad/s', round(MAX_SPIN / np.sqrt(N_STATE + KAPPA))))
"""The largest standard deviation a covariance may give each block of the state (p, v, w):
beyond, it says no more than the table's size, a smash's speed or the spin range would
(all zeros is 'unknown'), and propagated, its sigma points fly off the table and are left
out of the hit covariance, which came out narrower than for a covariance 100 times
smaller (a user's 1e300 gave 0.004 m^2 in y where 0.01 gave 0.0135). The spin's is the
range's 1500 rad/s (a state's largest, predict.MAX_SPIN) over the sigma points' spread
(sqrt(10) standard deviations: 474 rad/s): at 1000 rad/s the points spun at 3162, and the
hit's standard deviation in y came out 42 mm where 400 gave 212 (a walk-through, 6 Dec
2026)."""


SYMMETRY_TOLERANCE = 1e-9
"""Largest |C - C^T| of a covariance C taken as symmetric, relative to its largest |C|."""


def check_symmetric(cov, name='covariance'):
    """Raises ValueError, naming ``name``, when the square covariance ``cov`` is not finite or
    not symmetric beyond :data:`SYMMETRY_TOLERANCE`."""
    cov = np.asarray(cov, dtype=float)
    if not np.all(np.isfinite(cov)):
        # Said here: inf - inf below gave numpy's RuntimeWarning on stderr before the line.
        raise ValueError(f'{name} is not finite')
    asym = float(np.abs(cov - cov.T).max())
    if asym > SYMMETRY_TOLERANCE * float(np.abs(cov).max()) + 1e-300:
        raise ValueError(f'{name} is not symmetric (largest |C - C^T| {asym:.3g})')


def check_spread(cov, name='covariance'):
    """Raises ValueError, naming ``name``, when a diagonal block of the square covariance
    ``cov`` (3, 6 or 9 rows: position, velocity, spin) is wider than SPREAD_LIMITS."""
    sd = np.sqrt(np.clip(np.diag(np.asarray(cov, dtype=float)), 0.0, None))
    for k, (what, unit, limit) in enumerate(SPREAD_LIMITS):
        block = sd[3 * k:3 * k + 3]
        if block.size and block.max() > limit:
            raise ValueError(f'{name}: {what} standard deviation {block.max():.3g} {unit} '
                             f'is beyond {limit:g} {unit} (all zeros means unknown)')


def sigma_points(mean, cov, kappa=KAPPA):
    """Unscented sigma points (2n+1, n) and weights (2n+1,) of N(mean, cov).

    The square root is the symmetric one (eigen-decomposition), which copes with singular
    covariances (unobserved or exactly known components). Raises ValueError for a covariance
    that is not finite, not square, or clearly not positive semi-definite.
    """
    mean = np.asarray(mean, dtype=float)
    n = mean.shape[0]
    eigval, eigvec = covariance_eigen(np.asarray(cov, dtype=float).reshape(n, n))
    root = eigvec * np.sqrt(np.clip(eigval, 0.0, None) * (n + kappa))
    points = np.empty((2 * n + 1, n))
    points[0] = mean
    points[1:n + 1] = mean + root.T
    points[n + 1:] = mean - root.T
    weights = np.full(2 * n + 1, 0.5 / (n + kappa))
    weights[0] = kappa / (n + kappa)
    return points, weights


def zone_probabilities_gaussian(mean_xy, cov_xy, half):
    """Probability of areas 0..9 on ``half`` for a contact point ~ N(mean_xy, cov_xy), (10,)."""
    eigval, eigvec = np.linalg.eigh(0.5 * (cov_xy + cov_xy.T))
    root = eigvec * np.sqrt(np.clip(eigval, 0.0, None))
    xy = mean_xy + _DRAWS @ root.T
    x, y = xy[:, 0], xy[:, 1]
    on = (half * x >= 0.0) & (half * x <= HALF_LENGTH) & (np.abs(y) <= HALF_WIDTH)
    row = np.minimum((np.abs(x) / ZONE_LENGTH).astype(int), 2)
    col = np.clip(((HALF_WIDTH - y) / ZONE_WIDTH).astype(int), 0, 2)
    zone = np.where(on, 3 * row + col + 1, 0)
    return np.bincount(zone, minlength=10) / N_DRAWS


def predict_uncertainty(state9, cov, params=None, t0=0.0, hit_plane_x=DEFAULT_HIT_PLANE_X,
                        bounced=False, outgoing=False):
    """Zone probabilities and hit-point covariance of a ball ~ N(state9, cov) at time t0.

    ``cov`` (9, 9) or 81 numbers row-major, SI units (BallState.covariance). ``outgoing``:
    the landing of a ball leaving the racket (zone probabilities on the opponent's half;
    no hit). Raises ValueError for a bad covariance (not symmetric, not finite, not
    positive semi-definite, wider than SPREAD_LIMITS), naming what is wrong.
    """
    cov = np.asarray(cov, dtype=float).reshape(9, 9)
    check_symmetric(cov)
    check_spread(cov)
    points, weights = sigma_points(state9, cov)
    # predict_batch lifts the points under the table's surface on to it.
    batch = predict_batch(points, params, t0, hit_plane_x, bounced=bounced, outgoing=outgoing,
                          parallel=False, validate=False)
    # Hit point.
    hit = batch.status == OK if not outgoing else np.zeros(len(weights), dtype=bool)
    hit_fraction = min(float(weights[hit].sum()), 1.0)
    hit_cov = np.zeros((3, 3))
    hit_time_std = 0.0
    if hit.sum() >= 2:
        w = weights[hit] / hit_fraction
        p = batch.hit_p[hit]
        dp = p - w @ p
        hit_cov = (w[:, None] * dp).T @ dp
        t = batch.hit_t[hit]
        hit_time_std = float(np.sqrt(w @ (t - w @ t) ** 2))
    # Zone probabilities on the half where most weight makes contact.
    contact = batch.bounce_half != 0
    probs = np.zeros(10)
    half = 1 if outgoing else -1
    if contact.any():
        w_pos = weights[contact & (batch.bounce_half > 0)].sum()
        w_neg = weights[contact & (batch.bounce_half < 0)].sum()
        if w_pos != w_neg:
            half = 1 if w_pos > w_neg else -1
        on_half = contact & (batch.bounce_half == half)
        w_half = min(float(weights[on_half].sum()), 1.0)
        if w_half > 0.0:
            w = weights[on_half] / w_half
            xy = batch.bounce_p[on_half, :2]
            mean = w @ xy
            d = xy - mean
            probs = w_half * zone_probabilities_gaussian(mean, (w[:, None] * d).T @ d, half)
    probs[0] = max(0.0, 1.0 - probs[1:].sum())
    return Uncertainty(probs, half, hit_cov, hit_time_std, hit_fraction)
