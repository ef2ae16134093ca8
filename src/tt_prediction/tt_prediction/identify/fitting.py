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

from ..ball import DEFAULT_STEP, INDEX, SLOT_BOUNDS, ModelParams, rollout_kernel

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

GLOBAL_BOUNDS = {**SLOT_BOUNDS, SPIN_SCALE: (-0.5, 0.5)}
"""Physical ranges of the global parameters: the plausible ranges declared in
tt_prediction.params.FIELDS, and the measurement model's spin scale."""


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
        self.accepted_steps = None
        """Steps a pooled fit that returned these globals accepted (None: not fitted)."""
        self.blocking = []
        """Names of the tracks whose cost rose at the most damped step a pooled fit
        tried last without accepting it (those that held the globals in place)."""

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
                P[INDEX[name]] = value
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


SPIN_STARTS = (0.0, 150.0, -150.0)
"""Unmeasured spin: starting spins about the horizontal axis across the flight (rad/s; the
sign tells top- from backspin), each track keeps its best fit (the fit has local minima)."""
FIRST_SPIN_STARTS = SPIN_STARTS + (400.0, -400.0)
"""The same for a track's first state, fitted from nothing (:func:`fit_starts` without
``current``): a ball of 180 rad/s with a bounce, started from 150, stays at 145 rad/s, 1.1
mm RMS off its noise-free track, and is found from 400 (a new user's walk-through, 6 Dec
2026). Later fits start from the state found (``current`` competes), so this costs once."""


def fit_starts(tracks, globals_, max_nfev=40, current=None):
    """Every track's initial state fitted alone with the globals fixed, from the quadratic
    start of ``initial_guess`` and, for unmeasured spin, each of SPIN_STARTS (of
    FIRST_SPIN_STARTS without ``current``); ``current`` (states) competes too. Returns the
    best state of each track."""
    P, k = globals_.packed(), globals_.spin_scale

    def cost(i, x):
        return _robust_cost(track_residual(x, tracks[i], P, k))
    best = [None] * len(tracks) if current is None else [np.array(x, float) for x in current]
    best_cost = [np.inf if x is None else cost(i, x) for i, x in enumerate(best)]
    for spin in SPIN_STARTS if current is not None else FIRST_SPIN_STARTS:
        idx = [i for i, tr in enumerate(tracks) if tr.spin is None or spin == 0.0]
        starts = [initial_guess(tracks[i]) for i in idx]
        for i, x in zip(idx, starts, strict=True):
            if tracks[i].spin is None:
                axis = np.cross([0.0, 0.0, 1.0], x[3:6])
                x[6:9] = spin * axis / max(np.linalg.norm(axis), 1e-9)
        _, fitted = fit_pooled([tracks[i] for i in idx], globals_, starts, max_nfev=max_nfev,
                               fit_globals=False)
        for i, x in zip(idx, fitted, strict=True):
            c = cost(i, x)
            if c < best_cost[i]:
                best[i], best_cost[i] = x, c
    return best


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


def gate(tracks, states, P, spin_scale=0.0):
    """Gate isolated spikes: samples more than GATE from the fitted model track and more
    than GATE / 2 farther than both neighbours. A contiguous misfit is the model's residual,
    not an outlier, and stays. Returns the number gated."""
    dropped = 0
    for tr, x in zip(tracks, states, strict=True):
        pred = simulate(full_state(tr, x, spin_scale), P, tr.t, tr.n_bounces + 1)[:, :3]
        dist = np.linalg.norm(pred - tr.p, axis=1)
        dist[~np.isfinite(dist)] = 0.0
        nb = np.maximum(np.r_[dist[1:], 0.0], np.r_[0.0, dist[:-1]])
        bad = tr.mask & (dist > GATE) & (dist - nb > 0.5 * GATE)
        tr.mask &= ~bad
        dropped += int(bad.sum())
    return dropped


def _robust_cost(res):
    """Soft-L1 cost of residuals (m): sum of 2 f^2 (sqrt(1 + (r/f)^2) - 1), f = NOISE_SCALE."""
    return float(np.sum(2.0 * NOISE_SCALE ** 2 * (np.sqrt(1.0 + (res / NOISE_SCALE) ** 2) - 1)))


def _difference(r1, r0, h):
    """Forward difference (r1 - r0) / h, zero on rows where the model ball stopped in
    either evaluation (a constant MISSING_RESIDUAL there, not a slope)."""
    d = (r1 - r0) / h
    d[(r0 == MISSING_RESIDUAL) | (r1 == MISSING_RESIDUAL)] = 0.0
    return d


def _blocks(tr, x, r, P, k, g_steps, hg):
    """Normal-equation blocks of one track at its state x with residuals r (IRLS-weighted):
    U = A'WA, W = A'WB, e = -A'Wr, V = B'WB, f = -B'Wr, with A = dr/dx, B = dr/dglobals
    (forward differences; ``g_steps`` are (packed params, spin scale) with one global
    stepped by ``hg``)."""
    eps = np.sqrt(np.finfo(float).eps)
    hx = eps * np.maximum(1.0, np.abs(x))
    A = np.empty((len(r), len(x)))
    for j in range(len(x)):
        xp = x.copy()
        xp[j] += hx[j]
        A[:, j] = _difference(track_residual(xp, tr, P, k), r, hx[j])
    B = np.empty((len(r), len(g_steps)))
    for j, (Pj, kj) in enumerate(g_steps):
        B[:, j] = _difference(track_residual(x, tr, Pj, kj), r, hg[j])
    w = 1.0 / np.sqrt(1.0 + (r / NOISE_SCALE) ** 2)            # soft-L1 IRLS weights
    Aw, Bw = A * w[:, None], B * w[:, None]
    return Aw.T @ A, Aw.T @ B, -Aw.T @ r, Bw.T @ B, -Bw.T @ r


def _damped(M, lam):
    """M with its diagonal scaled by (1 + lam) (Marquardt), kept positive definite."""
    return M + lam * np.diag(np.diag(M)) + 1e-12 * np.eye(len(M))


def fit_pooled(tracks, globals_, states, max_nfev=40, ftol=1e-7, fit_globals=True):
    """Stacked fit of the global parameters and every track's initial state (eq. 9).

    ``states``: starting unknowns per track. Returns ``(globals, states)``.

    Levenberg-Marquardt on the block-arrow structure of the problem (a track's residuals
    depend on its own state and the globals only), as in bundle adjustment: each iteration
    forms the small normal-equation blocks of every track from a forward-difference
    Jacobian (about 9 + number of globals rollouts per track), eliminates the track states
    (Schur complement: U_i^-1, 6x6 or 9x9) and solves exactly for the globals, then back-
    substitutes the states. Each track has its own damping, raised when its cost rose. The
    soft-L1 loss enters as reweighting of the rows (IRLS), the globals are kept inside
    their bounds (GLOBAL_BOUNDS) by projection. Exact steps matter: a spin along the
    velocity leaves almost no trace, which makes the blocks ill conditioned; an iterative
    inner solver (trust region with LSMR) then needs hundreds of iterations per step and
    stops short. ``max_nfev``: at most this many Jacobians; the fit stops earlier when an
    accepted step lowers the cost by less than ``ftol`` (relative). ``fit_globals=False``
    keeps the globals fixed: every track's state is then fitted alone, accepted track by
    track, and a converged track is not evaluated again. The returned globals carry the
    number of steps accepted (``accepted_steps``) and, when the last step was refused, the
    tracks whose cost rose even at its smallest trial (``blocking``): a fit of the globals
    that accepted no step has not moved from its start.
    """
    lo, hi = globals_.bounds()
    n_g = len(globals_.names) if fit_globals else 0        # number of free globals
    eps = np.sqrt(np.finfo(float).eps)

    def packs(values):
        g = globals_.with_values(values)
        return g.packed(), g.spin_scale

    gv = np.asarray(globals_.values, dtype=float)
    gv = np.clip(gv, lo, hi) if fit_globals else gv
    P, k = packs(gv)
    xs = [np.array(x, dtype=float) for x in states]
    res = [track_residual(x, tr, P, k) for tr, x in zip(tracks, xs, strict=True)]
    costs = np.array([_robust_cost(r) for r in res])
    lam, lam_g = np.full(len(tracks), 1e-3), 1e-3
    active = np.ones(len(tracks), dtype=bool)     # tracks still moving (fixed globals only)
    accepted, blocking = 0, []
    for _ in range(max_nfev):
        if not active.any():
            break
        hg = eps * np.maximum(1.0, np.abs(gv))
        g_steps = []
        for j in range(n_g):
            v = gv.copy()
            v[j] += hg[j]
            g_steps.append(packs(v))
        idx = np.flatnonzero(active)
        blocks = {i: _blocks(tracks[i], xs[i], res[i], P, k, g_steps, hg) for i in idx}
        V = sum(blocks[i][3] for i in idx) if n_g else np.zeros((0, 0))
        f = sum(blocks[i][4] for i in idx) if n_g else np.zeros(0)
        pending = idx
        for _try in range(12):
            # Eliminate the states: S dg = rhs, then dx_i = U_i^-1 (e_i - W_i dg).
            S, rhs, Y = _damped(V, lam_g), f.copy(), {}
            for i in pending:
                U, Wi, e = blocks[i][:3]
                Y[i] = np.linalg.solve(_damped(U, lam[i]), np.column_stack([Wi, e]))
                S -= Wi.T @ Y[i][:, :n_g]
                rhs -= Wi.T @ Y[i][:, n_g]
            g_new = gv.copy()
            if n_g:
                g_new = np.clip(gv + np.linalg.solve(S, rhs), lo, hi)
            dg = (g_new - gv)[:n_g]
            P_new, k_new = packs(g_new)
            trial = {}
            for i in pending:
                x = xs[i] + Y[i][:, n_g] - Y[i][:, :n_g] @ dg
                r = track_residual(x, tracks[i], P_new, k_new)
                trial[i] = (x, r, _robust_cost(r))
            worse = np.array([trial[i][2] >= costs[i] for i in pending], dtype=bool)
            lam[pending[worse]] *= 4.0
            if n_g:         # coupled: the step is taken by all tracks or none
                new_total = sum(trial[i][2] for i in pending)
                if new_total < costs[pending].sum():
                    # Damping eased only with the step taken: eased on a refused one, the
                    # better tracks' next steps grew as the others' shrank, and a fit could
                    # refuse all its trials with the cost's gradient far from zero.
                    lam[pending[~worse]] = np.maximum(lam[pending[~worse]] / 3.0, 1e-9)
                    drop = (costs.sum() - new_total) / max(costs.sum(), 1e-300)
                    gv, P, k, lam_g = g_new, P_new, k_new, max(lam_g / 3.0, 1e-9)
                    for i in pending:
                        xs[i], res[i], costs[i] = trial[i]
                    accepted, blocking = accepted + 1, []
                    break
                rise = sorted(((trial[i][2] - costs[i], i) for i in pending
                               if trial[i][2] > costs[i]), reverse=True)
                blocking = [tracks[i].name for _, i in rise]
                lam_g *= 4.0
                continue
            lam[pending[~worse]] = np.maximum(lam[pending[~worse]] / 3.0, 1e-9)
            for i in pending[~worse]:           # independent tracks: each on its own
                old = costs[i]
                xs[i], res[i], costs[i] = trial[i]
                if old - costs[i] < ftol * old:
                    active[i] = False
            pending = pending[worse]
            if not len(pending):
                break
        else:
            if n_g:
                break                       # no step lowers the cost: converged
            active[pending] = False
        if n_g and drop < ftol:
            break
    out = globals_.with_values(gv)
    if n_g:
        out.accepted_steps, out.blocking = accepted, blocking
    return out, xs


def fit_pooled_restarted(tracks, globals_, states, max_nfev=40):
    """``fit_pooled``, then, where spin is not measured, every track's state restarted under
    the fitted globals (``fit_starts``, the current state competing) and the pooled fit
    again. A track's state fitted under other globals (a model without an effect) can sit in
    another basin of the spin than the one the new globals make best: without the restart a
    correct effect gains too little and a wrong one can gain by moving tracks between basins.
    """
    g, states = fit_pooled(tracks, globals_, states, max_nfev=max_nfev)
    if all(tr.spin is not None for tr in tracks):
        return g, states
    states = fit_starts(tracks, g, max_nfev, current=states)
    g2, states = fit_pooled(tracks, g, states, max_nfev=max_nfev)
    if g.accepted_steps is not None:
        g2.accepted_steps += g.accepted_steps
        g2.blocking = g2.blocking or g.blocking
    return g2, states


def pooled_cost(tracks, globals_, states):
    """The pooled fit's robust cost: soft-L1 over every track's residuals, m^2."""
    P = globals_.packed()
    return sum(_robust_cost(track_residual(x, tr, P, globals_.spin_scale))
               for tr, x in zip(tracks, states, strict=True))


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
