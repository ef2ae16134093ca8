"""Least-squares identification (paper eq. 9) over initial states and global parameters.

Each prepared track has its own unknown initial state at its first sample: position p0 and
velocity v0 (m, m/s) and, where index.csv has no measured spin, the spin w0 (rad/s), held
by a weak prior because spin along the velocity leaves no trace in flight. *Global*
parameters are shared by all tracks: fields of ModelParams (c_d, e_t, effect coefficients,
gravity) and the measurement model's ``spin_scale`` (measured spin = true spin / (1 +
spin_scale)). Residuals are model minus measured positions at the measured times, through
the table bounces (the compiled rollout of tt_prediction.integrate), with a robust loss
(soft L1 at NOISE_SCALE) after explicit gating of gross outliers.
"""

import dataclasses
import math

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from ..integrate import DEFAULT_STEP, rollout_kernel
from ..params import PACKED_FIELDS, ModelParams

NOISE_SCALE = 0.005
"""Residual (m) beyond which the soft-L1 loss turns linear."""
GATE = 0.03
"""An isolated sample farther than this from the fitted track is an outlier, m."""
SPIN_PRIOR = 300.0
"""Standard deviation of the weak zero-mean prior on unmeasured spin components, rad/s."""
PRIOR_WEIGHT = 0.002
"""A spin one prior standard deviation away counts like a position residual of this, m."""
MISSING_RESIDUAL = 0.1
"""Residual for samples after the model's ball stopped (floor, rolling), m."""
SPIN_SCALE = 'spin_scale'
"""Name of the measurement-model global: w_true = (1 + spin_scale) w_measured."""

GLOBAL_BOUNDS = {
    'c_d': (0.1, 1.5), 'c_m': (-0.5, 0.5), 'e_t': (0.5, 1.0), 'mu': (0.0, 1.0),
    'gravity': (8.0, 12.0), 'spin_decay': (0.0, 10.0), 'wind_x': (-5.0, 5.0),
    'wind_y': (-5.0, 5.0), 'wind_z': (-5.0, 5.0), 'c_d_speed_slope': (-0.2, 0.2),
    'c_m_spin_ratio_slope': (-1.0, 1.0), 'c_d_spin_ratio_slope': (-1.0, 1.0),
    'e_t_speed_slope': (-0.3, 0.3),
    'mu_spin_slope': (-2e-3, 2e-3), SPIN_SCALE: (-0.5, 0.5),
}
"""Physical ranges of the global parameters (SI units; slopes per the params.py docs)."""


@dataclasses.dataclass
class Prepared:
    """A segmented track ready for fitting: times from its first sample, gating mask."""

    name: str
    t: np.ndarray
    """Sample times from the first sample, s."""
    p: np.ndarray
    spin: np.ndarray
    """Measured spin (3,) rad/s or None."""
    n_bounces: int
    label: str = ''
    mask: np.ndarray = None
    """Samples used in the fit (gated outliers False)."""
    bounces: list = dataclasses.field(default_factory=list)

    def __post_init__(self):
        if self.mask is None:
            self.mask = np.ones(len(self.t), dtype=bool)

    @property
    def n_state(self):
        """Number of unknowns of the initial state (6, or 9 with unmeasured spin)."""
        return 6 if self.spin is not None else 9


class Globals:
    """Values of the free global parameters on top of a base ModelParams."""

    def __init__(self, base, names, values=None):
        self.base = base
        self.names = list(names)
        if values is None:
            values = [self.default(n) for n in self.names]
        self.values = np.array(values, dtype=float)

    def default(self, name):
        """Starting value of a global: the base model's, or 0 for the measurement model."""
        if name == SPIN_SCALE:
            return 0.0
        if name.startswith('wind_'):
            return self.base.wind['xyz'.index(name[-1])]
        return getattr(self.base, name)

    def with_values(self, values):
        return Globals(self.base, self.names, values)

    def packed(self):
        """The model's packed array with the free values set (see ModelParams.packed)."""
        P = self.base.packed()
        for name, value in zip(self.names, self.values, strict=True):
            if name != SPIN_SCALE:
                P[PACKED_FIELDS.index(name)] = value
        return P

    def params(self):
        """The model as ModelParams (measurement-model globals excluded)."""
        return ModelParams.from_packed(self.packed())

    @property
    def spin_scale(self):
        return float(self.values[self.names.index(SPIN_SCALE)]) if SPIN_SCALE in self.names \
            else 0.0

    def bounds(self):
        lo = [GLOBAL_BOUNDS[n][0] for n in self.names]
        hi = [GLOBAL_BOUNDS[n][1] for n in self.names]
        return np.array(lo), np.array(hi)

    def as_dict(self):
        return {n: float(v) for n, v in zip(self.names, self.values, strict=True)}


# Scratch buffers for the kernel's events, which identification does not read.
_EV_KIND = np.zeros(8, dtype=np.int64)
_EV_T = np.zeros(8)
_EV_S = np.zeros((8, 9))


def simulate(state, P, times, max_bounces=3):
    """Model states (k, 9) at ``times`` (from the state's time 0), NaN after a stop."""
    samples = np.full((len(times), 9), np.nan)
    rollout_kernel(state, 0.0, P, float(times[-1]) + 1e-9, DEFAULT_STEP, math.nan, 0,
                   max_bounces, times, samples, _EV_KIND, _EV_T, _EV_S)
    return samples


def full_state(track, x, spin_scale=0.0):
    """The 9-state at the track's first sample from its unknowns x (6 or 9)."""
    if track.spin is not None:
        return np.concatenate([x[:6], (1.0 + spin_scale) * track.spin])
    return np.asarray(x, dtype=float)


def track_residual(x, track, P, spin_scale=0.0, upto=None, prior=None):
    """Residuals (m) of one track: model minus measured positions of the used samples,
    then the spin prior terms (unmeasured spin). ``upto``: use only the first samples up
    to this time; ``prior``: (mean (3,), std (3,)) of the spin prior, rad/s."""
    sel = track.mask if upto is None else track.mask & (track.t <= upto)
    times = track.t[sel]
    pred = simulate(full_state(track, x, spin_scale), P, times, track.n_bounces + 1)[:, :3]
    res = (pred - track.p[sel]).ravel()
    res[~np.isfinite(res)] = MISSING_RESIDUAL
    if track.spin is None:
        mean, std = prior if prior is not None else (np.zeros(3), np.full(3, SPIN_PRIOR))
        res = np.concatenate([res, PRIOR_WEIGHT * (x[6:9] - mean) / std])
    return res


def initial_guess(track, window=0.06):
    """Initial state from a quadratic fit to the first ``window`` s: p0, v0 (and w0 = 0)."""
    sel = track.t <= max(window, track.t[min(5, len(track.t) - 1)])
    sel &= track.mask
    deg = 2 if sel.sum() >= 5 else 1
    coef = np.polyfit(track.t[sel], track.p[sel], deg)
    p0, v0 = coef[-1], coef[-2]
    return np.concatenate([p0, v0] + ([] if track.spin is not None else [np.zeros(3)]))


def fit_state(track, P, x0=None, spin_scale=0.0, upto=None, prior=None, max_nfev=60):
    """Initial state of one track with the global parameters fixed; returns (x, rms_m)."""
    x0 = initial_guess(track) if x0 is None else x0
    sol = least_squares(track_residual, x0, args=(track, P, spin_scale, upto, prior),
                        loss='soft_l1', f_scale=NOISE_SCALE, max_nfev=max_nfev,
                        x_scale='jac')
    return sol.x, fit_rms(track, sol.x, P, spin_scale)


def fit_rms(track, x, P, spin_scale=0.0):
    """RMS of the position residual over the used samples, m."""
    n = int(track.mask.sum()) * 3
    res = track_residual(x, track, P, spin_scale)[:n]
    return float(np.sqrt(np.mean(res ** 2)))


def gate(tracks, states, P):
    """Gate isolated spikes: samples more than GATE from the fitted model track and more
    than GATE / 2 farther than both neighbours. A contiguous misfit is the model's residual,
    not an outlier, and stays. Returns the number gated."""
    dropped = 0
    for tr, x in zip(tracks, states, strict=True):
        pred = simulate(full_state(tr, x), P, tr.t, tr.n_bounces + 1)[:, :3]
        dist = np.linalg.norm(pred - tr.p, axis=1)
        dist[~np.isfinite(dist)] = 0.0
        nb = np.maximum(np.r_[dist[1:], 0.0], np.r_[0.0, dist[:-1]])
        bad = tr.mask & (dist > GATE) & (dist - nb > 0.5 * GATE)
        tr.mask &= ~bad
        dropped += int(bad.sum())
    return dropped


def fit_pooled(tracks, globals_, states, max_nfev=40):
    """Stacked fit of the global parameters and every track's initial state.

    ``states``: starting unknowns per track. Returns ``(globals, states)``. The Jacobian is
    sparse (a track's rows depend on its own state and the globals), which keeps the cost
    of finite differences to about (9 + number of globals) evaluations of all tracks.
    """
    n_g = len(globals_.names)
    sizes = [tr.n_state for tr in tracks]
    offsets = np.concatenate([[n_g], n_g + np.cumsum(sizes)])
    rows = [int(tr.mask.sum()) * 3 + (3 if tr.spin is None else 0) for tr in tracks]
    sparsity = lil_matrix((sum(rows), offsets[-1]), dtype=int)
    r0 = 0
    for i, n in enumerate(rows):
        sparsity[r0:r0 + n, :n_g] = 1
        sparsity[r0:r0 + n, offsets[i]:offsets[i + 1]] = 1
        r0 += n

    def residual(z):
        g = globals_.with_values(z[:n_g])
        P, k = g.packed(), g.spin_scale
        return np.concatenate([track_residual(z[offsets[i]:offsets[i + 1]], tr, P, k)
                               for i, tr in enumerate(tracks)])

    lo, hi = globals_.bounds()
    z0 = np.concatenate([np.clip(globals_.values, lo, hi), *states])
    n_free = offsets[-1] - n_g
    sol = least_squares(residual, z0, jac_sparsity=sparsity, loss='soft_l1',
                        f_scale=NOISE_SCALE, max_nfev=max_nfev, x_scale='jac',
                        bounds=(np.concatenate([lo, np.full(n_free, -np.inf)]),
                                np.concatenate([hi, np.full(n_free, np.inf)])))
    z = sol.x
    return (globals_.with_values(z[:n_g]),
            [z[offsets[i]:offsets[i + 1]] for i in range(len(tracks))])


def fit_each(tracks, globals_, states, names):
    """Per-trajectory fit (the paper's eq. 9 done track by track): the globals ``names``
    and the track's state, the other globals fixed. Returns an array (n_tracks, len(names)).
    """
    out = np.empty((len(tracks), len(names)))
    idx = [globals_.names.index(n) for n in names]
    lo, hi = globals_.bounds()
    for i, (tr, x) in enumerate(zip(tracks, states, strict=True)):
        n_s = tr.n_state

        def residual(z, tr=tr, n_s=n_s):
            values = globals_.values.copy()
            values[idx] = z[n_s:]
            g = globals_.with_values(values)
            return track_residual(z[:n_s], tr, g.packed(), g.spin_scale)

        z0 = np.concatenate([x, globals_.values[idx]])
        sol = least_squares(residual, z0, loss='soft_l1', f_scale=NOISE_SCALE,
                            max_nfev=80, x_scale='jac',
                            bounds=(np.concatenate([np.full(n_s, -np.inf), lo[idx]]),
                                    np.concatenate([np.full(n_s, np.inf), hi[idx]])))
        out[i] = sol.x[n_s:]
    return out
