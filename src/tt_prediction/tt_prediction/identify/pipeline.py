"""The identification run: prepare, fit the baseline, test the effects, select, report data.

``identify(tracks, ...)`` returns a plain dict (the content of report.json plus arrays for the
plots under the key ``_plots``). Selection is greedy forward: each applicable effect of the
library is added to the current model and scored by the held-out fit RMS of K-fold
cross-validation; the best one is kept if its relative gain exceeds PENALTY_PER_PARAM per
added parameter and it moves the modelled tracks by more than MIN_EFFECT_SIZE, then the
remaining effects that also paid are tried on top of it. On fewer than effects.MIN_TRACKS
usable tracks nothing is tested or selected, and the report says so (``selection_note``).
"""

import dataclasses
import math

import numpy as np

from ..ball import ModelParams
from ..ball_filter import estimate_measurement_noise
from . import diagnose, evaluate, fitting
from .blas import blas_threads
from .data import LOADER_REMOVED, DataError
from .effects import LIBRARY, applicable, too_small
from .frame import frame_warnings, height_warning, tilt_warning
from .segment import MAX_GAP, segment

PENALTY_PER_PARAM = 0.02
"""Relative held-out gain an effect must bring per added parameter to be selected."""
MIN_EFFECT_SIZE = 0.002
"""An effect must move the modelled tracks by more than this RMS (about the measurement
noise) to be selected, m."""
MAX_EFFECTS = 2
"""At most this many effects are selected (greedy rounds)."""


def prepare(tracks, radius):
    """Segment tracks; returns (prepared, dropped {name: reason}, notes totals)."""
    prepared, dropped, notes = [], {}, {}
    for tr in tracks:
        seg, found = segment(tr, radius, notes_out=notes)
        if seg is None:
            dropped[tr.name] = found        # the reason (what each step removed is in notes)
            continue
        for key, n in seg.notes.items():
            notes[key] = notes.get(key, 0) + n
        t0 = seg.t[0]
        bounces = [dataclasses.replace(b, t=b.t - t0) for b in found]
        prepared.append(fitting.Prepared(seg.name, seg.t - t0, seg.p, seg.spin, len(bounces),
                                         seg.label, bounces=bounces))
    return prepared, dropped, notes


LEFT_OUT_WARNING = 0.25
"""Cleaning that leaves out more than this fraction of the samples (or drops a track) is
said on the command line, not only in report.json."""


def cleaning_warning(tracks, prepared, dropped, notes):
    """One line when cleaning dropped a track or left out over LEFT_OUT_WARNING of the
    samples: how much, the steps that took most, and what a file is read as; '' otherwise.
    (A walk-through's one file a session of flights lost 74 % of its samples without a
    word on the command line.)"""
    # The rows the loader removed (clean_samples) count too; unsorted rows are all kept; a
    # ball held still before its launch is no flight (its samples are not counted).
    loaded = (sum(len(tr.t) for tr in tracks) + sum(notes.get(k, 0) for k in LOADER_REMOVED)
              - notes.get('samples_held_still', 0))
    used = sum(len(tr.t) for tr in prepared)
    if not dropped and (not loaded or used >= (1.0 - LEFT_OUT_WARNING) * loaded):
        return ''
    steps = sorted(((n, k) for k, n in notes.items()
                    if k not in ('samples_of_dropped_tracks', 'unsorted_rows',
                                 'samples_held_still') and n),
                   reverse=True)[:3]
    most = ', '.join(f'{k} {n}' for n, k in steps)
    gone = f' and dropped {len(dropped)} of {len(tracks)} tracks' if dropped else ''
    left_out = 100.0 * (1.0 - used / loaded) if loaded else 100.0    # all held still
    return (f'cleaning left out {left_out:.0f} % of the samples'
            f'{gone} ({most}): a file is read as one flight, which a gap over {MAX_GAP:g} s, '
            'a jump to another ball, a racket contact, an unresolved bounce or a roll ends '
            '(report.json: data.samples_dropped, data.tracks_dropped)')


def _mean_std(values):
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if not len(values):
        return None
    return {'mean': round(float(values.mean()), 4), 'std': round(float(values.std()), 4),
            'n': int(len(values))}


def _round(d, nd=5):
    return {k: round(float(v), nd) for k, v in d.items()}


def _noise_mm(prepared):
    """The tracks' position noise per axis (mm, from local fits: estimate_measurement_noise),
    or None where no piece of track allows it (JSON has no NaN)."""
    noise = estimate_measurement_noise((tr.t[tr.mask], tr.p[tr.mask]) for tr in prepared)[0]
    return round(1e3 * noise, 3) if math.isfinite(noise) else None


def _pooled_from_tracks_c_m(prepared, g, states, c_m, max_nfev):
    """The pooled fit started again from the tracks' own C_M (the median of the per-track fits
    with measured spin) when it is more than 10 % from the pooled one; the better of the two
    by the pooled cost. With unmeasured spin beside measured, the pooled C_M can stay where
    the free spins absorb it (a user's 500 Hz set: 0.036 pooled, 0.067 per track, truth
    0.069, the held-out fit 2.16 against 1.99 mm from the truth)."""
    i = g.names.index('c_m')
    if not np.isfinite(c_m) or abs(c_m - g.values[i]) <= 0.1 * abs(c_m):
        return g, states
    values = g.values.copy()
    values[i] = c_m
    g2, states2 = fitting.fit_pooled_restarted(prepared, g.with_values(values), states,
                                               max_nfev)
    if fitting.pooled_cost(prepared, g2, states2) < fitting.pooled_cost(prepared, g, states):
        return g2, states2
    return g, states


def fit_baseline(prepared, base, notes, max_nfev=40):
    """The paper's identification (eq. 9) on prepared tracks: per-track starts with the
    nominal model, gating of isolated outliers (counted in ``notes``), the pooled fit of
    the baseline globals (c_d; c_m where spin is measured; e_t, mu where the data bounce),
    and per-trajectory C_D (and C_M) for the paper's mean +- std.

    Returns ``(globals, states, paper)``.
    """
    has_spin = any(tr.spin is not None for tr in prepared)
    has_bounces = any(tr.n_bounces for tr in prepared)
    names = ['c_d'] + (['c_m'] if has_spin else []) + (['e_t', 'mu'] if has_bounces else [])
    g_base = fitting.Globals(base, names)
    states = fitting.fit_starts(prepared, g_base, max_nfev)
    notes['samples_gated_by_fit'] = fitting.gate(prepared, states, base.packed())
    g_base, states = fitting.fit_pooled_restarted(prepared, g_base, states, max_nfev)
    per_track = fitting.fit_each(prepared, g_base, states,
                                 ['c_d', 'c_m'] if has_spin else ['c_d'])
    paper = {'c_d': _mean_std(per_track[:, 0])}
    if has_spin:        # a track without measured spin fits C_M times its own free spin
        measured = [tr.spin is not None for tr in prepared]
        paper['c_m'] = _mean_std(per_track[measured, 1])
        g_base, states = _pooled_from_tracks_c_m(prepared, g_base, states,
                                                 np.median(per_track[measured, 1]), max_nfev)
    else:
        spins = np.array([np.linalg.norm(x[6:9]) for x in states])
        paper['c_m'] = {'fixed': base.c_m, 'note': (
            'spin not measured: C_M and spin are not separately identifiable from a flight '
            "(the Magnus force is their product); C_M is fixed at the starting model's value "
            "(the nominal one, or --model's) and each "
            "track's spin is estimated jointly with its state; where the data bounce, the "
            'rebound separates them and C_M is tested as the effect lift_from_bounces')}
        paper['spin_abs_rad_s'] = _mean_std(spins)
    return g_base, states, paper


def identify(tracks, base=None, folds=5, hit_plane_x=-1.5, progress=None, max_nfev=20):
    """Run the whole identification. ``progress(total, label)``, called at the start of each
    round of effect tests, returns a callable ticked once per cross-validation fold fit of
    the round (a progress bar), or None. OpenBLAS runs on one thread meanwhile (blas.py)."""
    with blas_threads(1):
        return _identify(tracks, base, folds, hit_plane_x, progress, max_nfev)


def _identify(tracks, base, folds, hit_plane_x, progress, max_nfev):
    base = base or ModelParams()
    warnings = frame_warnings([(tr.name, tr.t, tr.p) for tr in tracks], base,
                              hit_plane_x)
    prepared, dropped, notes = prepare(tracks, base.radius)
    contacts = [b.p for tr in prepared for b in tr.bounces]
    warnings += [w for w in (cleaning_warning(tracks, prepared, dropped, notes),
                             tilt_warning(contacts), height_warning(contacts, base.radius))
                 if w]
    if len(prepared) < 2:
        first = next(iter(dropped.items()), None)
        why = f'; {first[0]}: {first[1]}' if first else ''
        # A frame's hint, not the plane's: too short a track crosses no plane either.
        hint = next((f'; {w}' for w in warnings if not w.startswith('no track crosses')), '')
        raise DataError(f'{len(prepared)} usable trajectory(ies) after cleaning '
                        f'({len(tracks)} loaded{why}); identification needs at least 2{hint}')
    if folds > len(prepared):       # cut without a word before (report.json's data.folds)
        warnings.append(f'--folds {folds}: only {len(prepared)} usable tracks, so '
                        f'{len(prepared)} folds (each track held out once)')
        folds = len(prepared)
    g_base, states, paper = fit_baseline(prepared, base, notes, 2 * max_nfev)
    start = fitting.Globals(base, g_base.names)
    stuck_by = g_base.blocking if not g_base.accepted_steps else None
    fold_of = evaluate.fold_ids(len(prepared), folds)

    n_bounces = int(sum(tr.n_bounces for tr in prepared))
    n_spin = sum(tr.spin is not None for tr in prepared)
    small = too_small(len(prepared))
    candidates = [(e, small or applicable(e, n_bounces, n_spin)) for e in LIBRARY]
    tested = [{'name': e.name, 'mechanism': e.mechanism, 'tested': False, 'reason': reason,
               'params': {}, 'heldout_gain': 0.0} for e, reason in candidates if reason]
    current, best = [], (None, None, None, g_base, states)
    stages = []             # (selected names, fit) after each round's selection
    pool = [e for e, reason in candidates if not reason]
    for round_ in range(MAX_EFFECTS):
        # The round's fold fits: the reference, then every effect of the pool.
        tick = progress(folds * (1 + len(pool)), f'round {round_ + 1}') if progress else None
        # The reference gets the same fitting budget as each effect, so that a gain is the
        # effect's and not that of more iterations on the tracks' states.
        best = _refit(prepared, best, fold_of, max_nfev, tick)
        if round_ == 0:
            base_rms, base_folds, g_base, base_states = best[1:]
            if stuck_by is not None and np.array_equal(g_base.values, start.values):
                warnings.append(stuck_warning(start, g_base.blocking or stuck_by,
                                              len(prepared)))
        results = []
        for e in pool:
            entry, fit = _test_effect(prepared, e, best, fold_of, max_nfev, tick)
            tested.append({**entry, 'round': round_ + 1, 'on_top_of': list(current)})
            if entry['pays']:
                results.append((entry['heldout_gain'] - entry['penalty'], e, fit))
        if not results:
            break
        results.sort(key=lambda r: -r[0])
        best = results[0][2]
        current.append(results[0][1].name)
        stages.append((list(current), best))
        pool = [r[1] for r in results[1:]]
        if not pool:
            break
    before, before_tracks = evaluate.predictive_errors(prepared, fold_of, base_folds,
                                                       hit_plane_x)
    # Selected only where the held-out prediction error drops too: the last selected effect
    # is dropped while it does not (a better fit of whole tracks that predicts worse from
    # their start is not what a robot needs).
    after, after_tracks, dropped_effects = before, before_tracks, []
    best = (None, base_rms, base_folds, g_base, base_states)
    while stages:
        names, fit = stages[-1]
        errors, per_track = evaluate.predictive_errors(prepared, fold_of, fit[2], hit_plane_x)
        if _prediction_improves(before, errors):
            current, best, after, after_tracks = names, fit, errors, per_track
            break
        dropped_effects.insert(0, names[-1])
        stages.pop()
    else:
        current = []
    _, cur_rms, cur_folds, g_final, states = best
    warnings += bound_warnings(g_final, g_base.names, n_spin > 0)
    diag_before = diagnose.flight_residuals(prepared, g_base, base_states)
    diag_after = diagnose.flight_residuals(prepared, g_final, states)
    rebound_before = diagnose.rebound_summary(prepared, g_base, base_states)
    rebound_after = diagnose.rebound_summary(prepared, g_final, states)
    result = {
        'data': {
            'tracks_loaded': len(tracks), 'tracks_used': len(prepared),
            'tracks_dropped': dropped, 'samples_dropped': notes,
            'samples_used': int(sum(tr.mask.sum() for tr in prepared)),
            'bounces': n_bounces,
            'spin_measured': n_spin > 0, 'tracks_spin_measured': int(n_spin),
            'tracks_spin_estimated': sum(tr.spin_source == 'estimated' for tr in tracks),
            'folds': folds, 'hit_plane_x': hit_plane_x,
            'predict_window_s': evaluate.PREDICT_WINDOW,
            'position_noise_mm': _noise_mm(prepared),
        },
        'paper_style': {'per_trajectory': paper, 'pooled': _round(g_base.as_dict())},
        'baseline': {'params': _round(g_base.as_dict()), 'heldout_fit_rms_mm':
                     round(1e3 * base_rms, 3), **before,
                     'residual': diagnose.flight_summary(diag_before),
                     'rebound': _strip(rebound_before)},
        'final': {'params': _round(g_final.as_dict()), 'heldout_fit_rms_mm':
                  round(1e3 * cur_rms, 3), **after,
                  'residual': diagnose.flight_summary(diag_after),
                  'rebound': _strip(rebound_after)},
        'effects_tested': tested,
        'selected_effects': current,
        'selection_note': small,
        'warnings': warnings,
        'dropped_for_prediction': dropped_effects,
        'selection_rule': (f'greedy forward; an effect is kept when its relative gain in '
                           f'held-out fit RMS ({folds}-fold, by trajectory) exceeds '
                           f'{PENALTY_PER_PARAM} per added parameter, switching it off '
                           f'moves the fitted tracks by more than '
                           f'{1e3 * MIN_EFFECT_SIZE:.0f} mm RMS, its parameters are not '
                           f'at a bound of their plausible range, and the held-out '
                           f'prediction errors (along the track and at the hitting plane) '
                           f'drop with it'),
    }
    result['_model'] = g_final.params()
    result['_plots'] = {'diag_before': diag_before, 'diag_after': diag_after,
                        'pred_before': before_tracks, 'pred_after': after_tracks,
                        'rebound': rebound_after}
    return result


def stuck_warning(start, blocking, n_tracks):
    """One line: the pooled fit accepted no step, its parameters are its start's."""
    names = ', '.join(blocking[:3]) + (f' and {len(blocking) - 3} more'
                                       if len(blocking) > 3 else '')
    why = (f'; the fit of {len(blocking)} of {n_tracks} tracks ({names}) got worse at the '
           'smallest step (a jump: e.g. a model ball landing on the edge of the table)'
           if blocking else '')
    values = ', '.join(f'{k} = {v:g}' for k, v in start.as_dict().items())
    return (f'the pooled fit did not move from its start ({values}): no step lowered the '
            f'cost of all tracks together{why}; the pooled parameters are not identified')


def _refit(prepared, current, fold_of, max_nfev, tick):
    """The current model refitted on all tracks and cross-validated, no parameter added;
    in and out in the form (effect, held-out RMS, fold fits, globals, states)."""
    effect, _, _, g, states = current
    g, states = fitting.fit_pooled_restarted(prepared, g, states, 2 * max_nfev)
    rms, fits = evaluate.cross_validate(prepared, g, states, fold_of, max_nfev, tick)
    return effect, rms, fits, g, states


def effect_size(prepared, globals_, effect, states):
    """RMS change of the modelled tracks when the effect's fitted parameters are switched
    back off (to the base model's values), m. A held-out gain without a change of the tracks
    is not the effect's (it is the optimiser's path), so it cannot select the effect."""
    off = globals_.with_values(globals_.values.copy())
    for p in effect.slots:
        off.values[off.names.index(p)] = off.default(p)
    P_on, P_off, k = globals_.packed(), off.packed(), globals_.spin_scale
    sq, n = 0.0, 0
    for tr, x in zip(prepared, states, strict=True):
        s0 = fitting.full_state(tr, x, k)
        on = fitting.simulate(s0, P_on, tr.t, tr.n_bounces + 1)[:, :3]
        s0 = fitting.full_state(tr, x, off.spin_scale)
        diff = on - fitting.simulate(s0, P_off, tr.t, tr.n_bounces + 1)[:, :3]
        diff = diff[np.all(np.isfinite(diff), axis=1)]
        sq += float(np.sum(diff ** 2))
        n += len(diff)
    return float(np.sqrt(sq / max(n, 1)))


def _test_effect(prepared, effect, current, fold_of, max_nfev, tick):
    """Add ``effect`` to the current fit, fit it on all tracks (its parameters start off),
    cross-validate. ``current`` = (_, held-out RMS, fold fits, globals, states).

    Returns the report entry and the new fit in the form of ``current``.
    """
    _, cur_rms, _, cur_globals, states = current
    g = fitting.Globals(cur_globals.params(), cur_globals.names + list(effect.slots))
    g.values[:len(cur_globals.names)] = cur_globals.values
    g, e_states = fitting.fit_pooled_restarted(prepared, g, states, 2 * max_nfev)
    rms, fits = evaluate.cross_validate(prepared, g, e_states, fold_of, max_nfev, tick)
    gain = 1.0 - rms / cur_rms
    penalty = PENALTY_PER_PARAM * len(effect.slots)
    size = effect_size(prepared, g, effect, e_states)
    fold_values = {p: [f[0].values[f[0].names.index(p)] for f in fits] for p in effect.slots}
    at_bound = _at_bound(g, effect.slots)
    entry = {
        'name': effect.name, 'mechanism': effect.mechanism, 'tested': True,
        'params': {p: round(float(g.values[g.names.index(p)]), 5) for p in effect.slots},
        'params_fold_std': {p: round(float(np.std(v)), 5) for p, v in fold_values.items()},
        'heldout_rms_mm': round(1e3 * rms, 3),
        'heldout_gain': round(gain, 4),
        'penalty': penalty,
        'effect_size_mm': round(1e3 * size, 2),
        'at_bound': at_bound,
        'pays': bool(gain > penalty and size > MIN_EFFECT_SIZE and not at_bound),
    }
    return entry, (effect, rms, fits, g, e_states)


def _prediction_improves(before, after):
    """Whether the held-out prediction errors ``after`` are lower than ``before``: the RMS
    along the rest of the tracks, and the hit-plane error where tracks cross the plane."""
    if after['rms_mm'] is None or before['rms_mm'] is None:
        return False
    if after['rms_mm'] >= before['rms_mm']:
        return False
    if before['hit_err_mm'] is not None and after['hit_err_mm'] is not None:
        return after['hit_err_mm'] < before['hit_err_mm']
    return True


def bound_warnings(globals_, physical, spin_measured):
    """One line for each parameter of the written model fitted at a bound of its plausible
    range: the bound, not the ball, set it, and the data are usually in other units or
    another frame (a measured spin in rev/s read as rad/s put C_M at 0.5, of the same spin
    with the other sign at 0). ``physical``: the names for which the lower bound 0 is not a
    ball's value either (the baseline's drag, lift, restitution, friction), not an effect
    switched off."""
    lo, hi = globals_.bounds()
    spin = ', the measured spin (index.csv) in rad/s' if spin_measured else ''
    out = []
    for name in _at_bound(globals_, [n for n in globals_.names if n != fitting.SPIN_SCALE],
                          physical):
        i = globals_.names.index(name)
        out.append(f'{name} = {globals_.values[i]:.4g} was fitted at a bound of its plausible '
                   f'range ({lo[i]:g} to {hi[i]:g}): the bound set it, not the data; are the '
                   f'positions in metres{spin} and both in the table frame?')
    return out


def _at_bound(globals_, params, physical=()):
    """The parameters fitted at (within 0.1 % of the range of) a bound of their declared
    plausible range: the bound, not the data, set their value. A lower bound of 0 counts
    only for the names in ``physical`` (elsewhere it is an effect switched off)."""
    lo, hi = globals_.bounds()
    out = []
    for p in params:
        i = globals_.names.index(p)
        tol = 1e-3 * (hi[i] - lo[i])
        v = globals_.values[i]
        if (v - lo[i] < tol and (lo[i] != 0.0 or p in physical)) or hi[i] - v < tol:
            out.append(p)
    return out


def _strip(summary):
    """Rebound summary without its per-bounce arrays (kept for the plots only)."""
    if summary is None:
        return None
    return {k: v for k, v in summary.items() if not isinstance(v, list)}
