"""Structure of the residual: what the model misses, in physical terms.

Flight: the residual r(t) = measured - model position of each free flight (between bounces)
is smoothed by a cubic in time per axis; its second derivative is the *residual
acceleration*, the force per unit mass the model lacks (m/s^2). Its mean per axis (a steady
force: draft, gravity) and its correlation with time since launch (spin decay), air speed
(Reynolds drag), spin and spin ratio (lift) and heading point to a mechanism.
Rebounds: the restitution measured at each bounce against the model's, versus impact speed
and spin.
"""

import numpy as np
import scipy.stats

from ..ball import edge_distance, table_restitution
from . import fitting

MIN_FLIGHT_SAMPLES = 10
"""Shortest free flight whose residual is differentiated."""


def flight_residuals(tracks, globals_, states):
    """Residuals along every track under a fitted model.

    Returns a dict of arrays over the used samples of free flights: ``t`` (s since the
    track's first sample), ``res`` (n, 3) measured - model (m), ``acc`` (n, 3) residual
    acceleration (m/s^2, NaN on short flights), ``speed`` (m/s), ``spin`` |w_perp|, the spin
    across the velocity (rad/s), ``spin_ratio`` r|w_perp|/|v|, ``heading`` (v_x / |v|).
    """
    P, k = globals_.packed(), globals_.spin_scale
    r = globals_.base.radius
    cols = {key: [] for key in ('t', 'res', 'acc', 'speed', 'spin', 'spin_ratio', 'heading')}
    for tr, x in zip(tracks, states, strict=True):
        model = fitting.simulate(fitting.full_state(tr, x, k), P, tr.t, tr.n_bounces + 1)
        ok = tr.mask & np.all(np.isfinite(model), axis=1)
        res = tr.p - model[:, :3]
        acc = np.full((len(tr.t), 3), np.nan)
        edges = [tr.t[0] - 1.0] + [b.t for b in tr.bounces] + [tr.t[-1] + 1.0]
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            sel = ok & (tr.t > a) & (tr.t < b)
            if sel.sum() >= MIN_FLIGHT_SAMPLES:
                ts = tr.t[sel] - tr.t[sel].mean()
                coef = np.polyfit(ts, res[sel], 3)          # (4, 3): cubic per axis
                acc[sel] = 6.0 * coef[0] * ts[:, None] + 2.0 * coef[1]
        v, w = model[:, 3:6], model[:, 6:9]
        speed = np.linalg.norm(v, axis=1)
        v_hat = v / np.maximum(speed, 1e-6)[:, None]
        # Spin across the velocity: the part that makes lift (the part along it is unobserved).
        spin = np.linalg.norm(w - np.sum(w * v_hat, axis=1)[:, None] * v_hat, axis=1)
        cols['t'].append(tr.t[ok])
        cols['res'].append(res[ok])
        cols['acc'].append(acc[ok])
        cols['speed'].append(speed[ok])
        cols['spin'].append(spin[ok])
        cols['spin_ratio'].append((r * spin / np.maximum(speed, 1e-6))[ok])
        cols['heading'].append((v[:, 0] / np.maximum(speed, 1e-6))[ok])
    return {key: np.concatenate(v) if v else np.empty(0) for key, v in cols.items()}


def _corr(a, b):
    if len(a) < 3 or np.std(a) == 0.0 or np.std(b) == 0.0:
        return 0.0
    return float(np.corrcoef(a, b)[0, 1])


def _corr_p(a, b):
    """Two-sided p-value of Pearson's r between ``a`` and ``b`` under no correlation (the
    t-test with n - 2 degrees of freedom); 1 where r cannot be formed."""
    if len(a) < 3 or np.std(a) == 0.0 or np.std(b) == 0.0:
        return 1.0
    return float(scipy.stats.pearsonr(a, b).pvalue)


def _held(a, z):
    """``a`` less its least-squares line in ``z``: what of it ``z`` does not explain."""
    A = np.column_stack([np.ones(len(z)), z])
    return a - A @ np.linalg.lstsq(A, a, rcond=None)[0]


def _partial(a, b, z):
    """Partial correlation of ``a`` and ``b`` with ``z`` held, and its two-sided p-value
    (Student's t with n - 3 degrees of freedom); (0, 1) where it cannot be formed."""
    n = len(a)
    if n < 4:
        return 0.0, 1.0
    a_held, b_held = _held(a, z), _held(b, z)
    # What z explains of a or b whole leaves rounding (1e-17), not a variable: no r.
    if any(np.std(h) <= 1e-9 * (np.std(x) + abs(np.mean(x))) for h, x in ((a_held, a),
                                                                          (b_held, b))):
        return 0.0, 1.0
    r = _corr(a_held, b_held)
    if abs(r) >= 1.0:
        return r, 0.0
    t = r * np.sqrt((n - 3) / (1.0 - r * r))
    return r, float(2.0 * scipy.stats.t.sf(abs(t), n - 3))


FEATURES = ('t', 'speed', 'spin', 'spin_ratio', 'heading')


def flight_summary(diag):
    """Per axis: RMS residual (mm), mean residual acceleration +- standard error (m/s^2),
    and its correlation with each feature (the strongest points to a mechanism)."""
    out = {}
    for j, axis in enumerate('xyz'):
        acc = diag['acc'][:, j]
        ok = np.isfinite(acc)
        a = acc[ok]
        corr = {f: round(_corr(a, diag[f][ok]), 3) for f in FEATURES}
        out[axis] = {
            'rms_mm': round(1e3 * float(np.sqrt(np.mean(diag['res'][:, j] ** 2))), 2)
            if len(diag['res']) else None,
            'acc_mean': round(float(a.mean()), 4) if len(a) else None,
            'acc_std': round(float(a.std()), 4) if len(a) else None,
            'correlation': corr,
        }
    return out


def binned(t, values, bins=12):
    """Bin centres and the mean and std of ``values`` (n,) in equal-time bins."""
    edges = np.linspace(t.min(), t.max(), bins + 1) if len(t) else np.zeros(bins + 1)
    idx = np.clip(np.digitize(t, edges) - 1, 0, bins - 1)
    mean = np.array([values[idx == b].mean() if np.any(idx == b) else np.nan
                     for b in range(bins)])
    std = np.array([values[idx == b].std() if np.any(idx == b) else np.nan
                    for b in range(bins)])
    return 0.5 * (edges[1:] + edges[:-1]), mean, std


def rebound_summary(tracks, globals_, states):
    """Measured bounces against the model: the per-bounce restitution e_t = -v_z'/v_z and
    friction mu = |dv_horizontal| / ((1 + e_t) |v_z|) (exact while the ball slides), their
    mean +- std, and the correlation of the restitution residual with impact speed and with
    the fitted spin at impact, each with its p-value (``corr_*_p``): a few bounces give
    sizeable r by chance (r = -0.35 from 16 bounces has p = 0.18); and, with the impact
    speed held (partial correlations, ``*_speed_held``), with the spin and with the bounce's
    distance to the table's nearest edge (m; a table livelier in its middle)."""
    P, k = globals_.packed(), globals_.spin_scale
    e, mu, speed, spin, e_model, edge = [], [], [], [], [], []
    for tr, x in zip(tracks, states, strict=True):
        if not tr.bounces:
            continue
        times = np.array([b.t - 1e-4 for b in tr.bounces])
        model = fitting.simulate(fitting.full_state(tr, x, k), P, times, tr.n_bounces + 1)
        for b, m in zip(tr.bounces, model, strict=True):
            ei = b.restitution
            e.append(ei)
            mu.append(np.linalg.norm(b.v_out[:2] - b.v_in[:2]) / ((1 + ei) * abs(b.v_in[2])))
            speed.append(abs(b.v_in[2]))
            edge.append(edge_distance(b.p[0], b.p[1]))
            spin.append(float(np.linalg.norm(m[6:9])) if np.all(np.isfinite(m)) else np.nan)
            w = m[6:9] if np.all(np.isfinite(m)) else np.zeros(3)
            e_model.append(table_restitution(np.concatenate([b.p, b.v_in, w]), P))
    if not e:
        return None
    e, mu, speed, spin, edge = map(np.array, (e, mu, speed, spin, edge))
    res = e - np.clip(np.array(e_model), 0.0, 1.0)
    ok = np.isfinite(spin)
    # Spin and place with the impact speed held: a launcher's faster balls land nearer the
    # end line, and its edge correlation was the speed's (r 0.29 raw, 0.14 held).
    spin_held = _partial(res[ok], spin[ok], speed[ok])
    edge_held = _partial(res, edge, speed)
    return {
        'n_bounces': len(e),
        'e_t_mean': round(float(e.mean()), 4), 'e_t_std': round(float(e.std()), 4),
        'mu_mean': round(float(mu.mean()), 4), 'mu_std': round(float(mu.std()), 4),
        'restitution_residual_mean': round(float(res.mean()), 4),
        'corr_impact_speed': round(_corr(res, speed), 3),
        'corr_impact_speed_p': _corr_p(res, speed),
        'corr_spin': round(_corr(res[ok], spin[ok]), 3),
        'corr_spin_p': _corr_p(res[ok], spin[ok]),
        'n_bounces_with_spin': int(ok.sum()),
        'corr_spin_speed_held': round(spin_held[0], 3),
        'corr_spin_speed_held_p': spin_held[1],
        'corr_edge_distance_speed_held': round(edge_held[0], 3),
        'corr_edge_distance_speed_held_p': edge_held[1],
        'impact_speed': speed.tolist(), 'e_t_measured': e.tolist(),
    }
