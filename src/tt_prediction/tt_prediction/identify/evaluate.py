"""Held-out evaluation by trajectory-wise K-fold cross-validation.

Two held-out measures, both with the global parameters fitted on the other folds only:

- *fit RMS*: the held-out track's initial state is fitted to its whole track, the global
  parameters stay fixed; the RMS position residual (m) measures how well the model's physics,
  not a track's own state, explains the track. Effect selection uses it.
- *prediction*: what a robot sees. The state is estimated from the first PREDICT_WINDOW s
  only (unmeasured spin held by a prior from the training folds' fitted spins, per label),
  the model predicts the rest; errors are the position RMS along the rest of the track, the
  first bounce point, the crossing of the hitting plane, and the 9-area criterion.
"""

import dataclasses

import numpy as np

from ..ball import rollout, zone_of
from . import fitting

PREDICT_WINDOW = 0.1
"""Length of the start of a track from which the held-out prediction starts, s."""
MAX_BOUNCES = 3
"""Held-out predictions integrate through at most this many table bounces: a fixed bound,
not the held-out track's own count (which a predictor cannot know)."""
SPIN_PRIOR_FLOOR = 20.0
"""Smallest standard deviation of the training-fold spin prior, rad/s."""


def fold_ids(n, k, seed=0):
    """Fold index of each of n tracks: a seeded shuffle dealt into k folds."""
    ids = np.empty(n, dtype=int)
    ids[np.random.default_rng(seed).permutation(n)] = np.arange(n) % k
    return ids


def gated_heldout(tracks, globals_, states, max_nfev=20):
    """Copies of held-out tracks gated with a fit that never saw them.

    Each track's samples are all restored (its mask from the all-track gating is not used),
    its initial state is fitted with the fold's globals fixed, isolated spikes are gated
    against that fit (fitting.gate) and the state is fitted again if any was. Returns
    ``(tracks, states)``.
    """
    held = [dataclasses.replace(tr, mask=None) for tr in tracks]
    P, k = globals_.packed(), globals_.spin_scale
    _, xs = fitting.fit_pooled(held, globals_, states, max_nfev=max_nfev, fit_globals=False)
    if fitting.gate(held, xs, P, k):
        _, xs = fitting.fit_pooled(held, globals_, xs, max_nfev=max_nfev, fit_globals=False)
    return held, xs


def cross_validate(tracks, globals_, states, folds, max_nfev=20, progress=None):
    """Fit the globals on each training split; returns (held-out fit RMS m, fold fits).

    ``fold_fits[f] = (globals, {track index: state})`` with the states of the training
    tracks of fold f. The held-out tracks are gated with the fold's fit (gated_heldout).
    ``progress``: called once per fold.
    """
    sq, n = 0.0, 0
    fold_fits = []
    for f in range(folds.max() + 1):
        train = np.flatnonzero(folds != f)
        g, st = fitting.fit_pooled([tracks[i] for i in train], globals_,
                                   [states[i] for i in train], max_nfev=max_nfev)
        fold_fits.append((g, dict(zip(train.tolist(), st, strict=True))))
        held = np.flatnonzero(folds == f)
        held_tracks, held_states = gated_heldout([tracks[i] for i in held], g,
                                                 [states[i] for i in held], max_nfev)
        P = g.packed()
        for tr, x in zip(held_tracks, held_states, strict=True):
            rms = fitting.fit_rms(tr, x, P, g.spin_scale)
            m = int(tr.mask.sum())
            sq += rms ** 2 * m
            n += m
        if progress:
            progress()
    return float(np.sqrt(sq / max(n, 1))), fold_fits


def spin_prior(tracks, states, track):
    """Mean and std (3,) of the fitted spins of training tracks with ``track``'s label (all
    training tracks when fewer than 3 share it), rad/s; None when spin is measured."""
    if track.spin is not None:
        return None
    same = [states[i][6:9] for i in states if tracks[i].label == track.label
            and tracks[i].spin is None]
    if len(same) < 3:
        same = [states[i][6:9] for i in states if tracks[i].spin is None]
    if len(same) < 2:
        return np.zeros(3), np.full(3, fitting.SPIN_PRIOR)
    w = np.array(same)
    return w.mean(axis=0), np.maximum(w.std(axis=0), SPIN_PRIOR_FLOOR)


def plane_crossing(t, p, plane_x):
    """First crossing of x = plane_x by the measured track, linearly interpolated: (t, p)."""
    g = p[:, 0] - plane_x
    idx = np.flatnonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0)
    if not len(idx):
        return None
    i = idx[0]
    w = g[i] / (g[i] - g[i + 1])
    return t[i] + w * (t[i + 1] - t[i]), (1 - w) * p[i] + w * p[i + 1]


def predict_track(track, globals_, prior, hit_plane_x, window=PREDICT_WINDOW):
    """Held-out prediction errors of one track from its first ``window`` s (None if the
    track is too short): dict with rms (m), bounce and hit errors (m), zones."""
    rest = track.mask & (track.t > window)
    if (track.mask & (track.t <= window)).sum() < 5 or rest.sum() < 5:
        return None
    P, k = globals_.packed(), globals_.spin_scale
    x, _ = fitting.fit_state(track, P, spin_scale=k, upto=window, prior=prior, max_nfev=40)
    s0 = fitting.full_state(track, x, k)
    pred = fitting.simulate(s0, P, track.t, MAX_BOUNCES)[:, :3]
    err = np.linalg.norm(pred - track.p, axis=1)
    err[~np.isfinite(err)] = fitting.MISSING_RESIDUAL
    out = {'rms': float(np.sqrt(np.mean(err[rest] ** 2)))}
    if track.bounces and track.bounces[0].t > window:
        after = rest & (track.t > track.bounces[0].t)
        if after.any():
            out['post_bounce_rms'] = float(np.sqrt(np.mean(err[after] ** 2)))
        events, _ = rollout(s0, P, stop_at_plane=False, stop_at_net=False, max_bounces=1)
        b = track.bounces[0]
        out['zone_true'] = zone_of(*b.p[:2])
        out['zone_pred'] = (0, 0)                   # predicted to miss the table
        if events[-1].kind in ('bounce', 'roll'):
            out['bounce_err'] = float(np.linalg.norm(events[-1].state[:2] - b.p[:2]))
            out['zone_pred'] = zone_of(*events[-1].state[:2])
    crossing = plane_crossing(track.t, track.p, hit_plane_x)
    if crossing is not None and crossing[0] > window:
        events, _ = rollout(s0, P, plane_x=hit_plane_x, stop_at_net=False,
                            max_bounces=MAX_BOUNCES)
        if events[-1].kind == 'plane':
            out['hit_err'] = float(np.linalg.norm(events[-1].state[:3] - crossing[1]))
    return out


def predictive_errors(tracks, folds, fold_fits, hit_plane_x):
    """Held-out prediction errors of every track with its fold's globals.

    Every held-out track is gated with its fold's fit (gated_heldout), never with a fit
    that saw it. Returns ``(summary, per_track)``: summary with rms_mm (mean over tracks of
    the RMS along the rest of each track), post_bounce_rms_mm (the same after the first
    measured bounce), bounce_err_mm, hit_err_mm (means; None where the data
    has none), zone_accuracy (fraction of first bounces predicted in the measured area and
    half), and counts.
    """
    per_track = [None] * len(tracks)
    for f, (g, train_states) in enumerate(fold_fits):
        held = np.flatnonzero(folds == f)
        starts = [fitting.initial_guess(tracks[i]) for i in held]
        gated, _ = gated_heldout([tracks[i] for i in held], g, starts)
        for i, tr in zip(held, gated, strict=True):
            prior = spin_prior(tracks, train_states, tr)
            per_track[i] = predict_track(tr, g, prior, hit_plane_x)
    done = [r for r in per_track if r is not None]
    bounce = [r['bounce_err'] for r in done if 'bounce_err' in r]
    hit = [r['hit_err'] for r in done if 'hit_err' in r]
    post = [r['post_bounce_rms'] for r in done if 'post_bounce_rms' in r]
    zones = [r['zone_true'] == r['zone_pred'] for r in done if 'zone_true' in r]

    def mm(values):
        return round(1e3 * float(np.mean(values)), 2) if values else None

    summary = {
        'rms_mm': mm([r['rms'] for r in done]),
        'post_bounce_rms_mm': mm(post),
        'bounce_err_mm': mm(bounce),
        'hit_err_mm': mm(hit),
        'hit_err_median_mm': round(1e3 * float(np.median(hit)), 2) if hit else None,
        'zone_accuracy': round(float(np.mean(zones)), 3) if zones else None,
        'n_tracks': len(done), 'n_bounces': len(bounce), 'n_hits': len(hit),
    }
    return summary, per_track
