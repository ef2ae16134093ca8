"""Writing the identification's outputs: report.json, report.md, PNG plots and model.yaml.

Everything is written into a fresh temporary folder next to DIR and renamed into place at the
end, so an interrupted or failed run never leaves a half-written report that looks complete.
"""

import json
import math
import os

import matplotlib
import numpy as np

from ..ball import FIELD
from ..ball_filter import NOISE_WINDOW
from ..staged import staged_folder
from .diagnose import binned

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (after selecting the non-interactive backend)

PLOTS = ('residual_vs_time.png', 'residual_acceleration.png', 'landing_errors.png',
         'rebound.png')


def write_outputs(result, out_dir, sources, model=None):
    """Write the report of ``result`` (pipeline.identify) atomically into ``out_dir``;
    ``model``: the model.yaml it started from (``--model``), None for the nominal one."""
    with staged_folder(out_dir, 'tt-identify') as tmp:
        public = {k: v for k, v in result.items() if not k.startswith('_')}
        public['sources'] = list(sources)
        meta = {'written_by': 'tt-identify', 'sources': list(sources)}
        if model:       # recorded nowhere before: its values read as the nominal ones
            public['model'] = meta['model'] = str(model)
        with open(os.path.join(tmp, 'report.json'), 'w') as f:
            json.dump(public, f, indent=2)
        result['_model'].save(os.path.join(tmp, 'model.yaml'), meta={
            **meta, 'selected_effects': list(result['selected_effects'])})
        plot_all(result, tmp)
        with open(os.path.join(tmp, 'report.md'), 'w') as f:
            f.write(markdown(public))


def _fmt(value, nd=3):
    if value is None:
        return '–'
    if isinstance(value, float):
        return f'{value:.{nd}g}' if abs(value) < 1e-2 and value != 0 else f'{value:.{nd}f}'
    return str(value)


PAPER_C_D = FIELD['c_d'].default
"""The paper's drag coefficient (MODEL.md, "Constants": the model's default), against which
C_D is reported."""
PAPER_C_M = FIELD['c_m'].default
"""The paper's Magnus coefficient."""
SIGNIFICANCE = 0.05
"""A correlation with a larger two-sided p-value is reported as not significant; of several
tested together, each against SIGNIFICANCE over their number (Bonferroni): with nothing
planted, one of two at p = 0.021 was called significant (a researcher's walk-through)."""


def _correlation(r, p, n, tests=1):
    """'r = -0.35 (n = 16, p = 0.18: not significant at 5%)', one of ``tests`` correlations
    tested together ('at 5% over 3 tests'); p None (a report.json written before p-values
    were) gives r and n alone."""
    if p is None:
        return f'r = {r} (n = {n})'
    verdict = 'significant' if p < SIGNIFICANCE / tests else 'not significant'
    over = f' over {tests} tests' if tests > 1 else ''
    return f'r = {r} (n = {n}, p = {p:.2g}: {verdict} at {SIGNIFICANCE:.0%}{over})'


def markdown(r):
    """The human-readable report (tables of errors, parameters, effects, plots)."""
    d, b, f = r['data'], r['baseline'], r['final']
    lines = ['# tt-identify report', '',
             f"Sources: {', '.join(r['sources'])}"
             + (f"; starting model: {r['model']}" if r.get('model') else ''), '']
    for warning in r.get('warnings', []):
        lines += [f'**Warning:** {warning}', '']
    lines += ['## Data', '',
              f"{d['tracks_used']} of {d['tracks_loaded']} tracks used, {d['samples_used']} "
              f"samples, {d['bounces']} table bounces located; spin measured: "
              f"{'yes' if d['spin_measured'] else 'no'}"
              + (f" ({d['tracks_spin_estimated']} tracks with estimated spin, not used as "
                 'measured)' if d.get('tracks_spin_estimated') else '') + '.', '']
    if d['samples_dropped']:
        lines += ['| samples dropped | count |', '|---|---|']
        lines += [f'| {k} | {v} |' for k, v in d['samples_dropped'].items()]
        lines.append('')
    for name, reason in d['tracks_dropped'].items():
        lines.append(f'- dropped track {name}: {reason}')
    p = r['paper_style']['per_trajectory']
    lines += ['', '## Paper-style coefficients (eq. 9)', '',
              f"Per trajectory: C_D = {p['c_d']['mean']:.3f} ± {p['c_d']['std']:.3f} "
              f"(n = {p['c_d']['n']}); paper {PAPER_C_D} ± 0.074."]
    if 'mean' in p['c_m']:
        lines.append(f"C_M = {p['c_m']['mean']:.3f} ± {p['c_m']['std']:.3f} (n = "
                     f"{p['c_m']['n']}, the tracks with measured spin); paper {PAPER_C_M} "
                     '± 0.029.')
        drag, lift = p['c_d']['mean'] / PAPER_C_D, p['c_m']['mean'] / PAPER_C_M
        lines.append(f"Against the paper's: C_D × {drag:.2f}, C_M × {lift:.2f}." + (
            ' Both off by one factor: flights measure C_D ρ A / m and C_M ρ r³ / m, not the '
            "coefficients and the ball apart, so a ball of another mass than the model's, "
            f'or another air density, reads so (a mass × {1.0 / (0.5 * (drag + lift)):.2f}?). '
            'Change the mass or the coefficients in model.yaml, not both.'
            if abs(drag - lift) < 0.05 and abs(0.5 * (drag + lift) - 1.0) > 0.05 else ''))
    else:
        lines.append(f"C_M fixed at {p['c_m']['fixed']:.4g}: {p['c_m']['note']}. Fitted |ω| = "
                     f"{p['spin_abs_rad_s']['mean']:.0f} ± {p['spin_abs_rad_s']['std']:.0f}"
                     ' rad/s.')
    reb = b.get('rebound')
    if reb:
        lines.append(f"Per bounce (from the flights on both sides): e_t = {reb['e_t_mean']:.3f}"
                     f" ± {reb['e_t_std']:.3f}, μ = {reb['mu_mean']:.3f} ± {reb['mu_std']:.3f}"
                     f" (n = {reb['n_bounces']}).")
    lines += ['', 'Pooled: ' + ', '.join(f'{k} = {_fmt(v, 4)}'
                                         for k, v in r['paper_style']['pooled'].items()), '',
              '## Residual of the baseline model', '',
              'Residual acceleration (second derivative of measured − model along each free '
              'flight), m/s², and its correlation with time, air speed, spin across the '
              'velocity |ω⊥|, spin ratio r|ω⊥|/|v| and heading v_x/|v|:', '',
              '| axis | RMS mm | mean acc | std acc | r(t) | r(speed) | r(spin) | r(ratio) '
              '| r(heading) |', '|---|---|---|---|---|---|---|---|---|']
    for axis, s in b['residual'].items():
        c = s['correlation']
        lines.append(f"| {axis} | {_fmt(s['rms_mm'], 2)} | {_fmt(s['acc_mean'])} | "
                     f"{_fmt(s['acc_std'])} | {c['t']} | {c['speed']} | {c['spin']} | "
                     f"{c['spin_ratio']} | {c['heading']} |")
    if reb:
        n, n_spin = reb['n_bounces'], reb.get('n_bounces_with_spin', reb['n_bounces'])
        held = 'corr_spin_speed_held' in reb               # not in an older report.json
        tests = [('impact speed', 'corr_impact_speed', n)] + (
            [('spin, the impact speed held,', 'corr_spin_speed_held', n_spin),
             ("the distance to the table's nearest edge, the impact speed held,",
              'corr_edge_distance_speed_held', n)] if held else
            [('spin', 'corr_spin', n_spin)])
        lines += ['', 'Rebound: restitution residual correlates with ' + ', with '.join(
            f'{what} ' + _correlation(reb[key], reb.get(key + '_p'), count, len(tests))
            for what, key, count in tests) + '.']
    lines += ['', '## Effects tested', '', r['selection_rule'] + '.', '',
              '| effect | round | fitted parameters (all tracks) | held-out gain | '
              'penalty | effect size mm | pays |', '|---|---|---|---|---|---|---|']
    for e in r['effects_tested']:
        if not e['tested']:
            lines.append(f"| {e['name']} | – | not tested: {e['reason']} | – | – | – | – |")
            continue
        params = ', '.join(f'{k} = {_fmt(v, 4)}' for k, v in e['params'].items())
        lines.append(f"| {e['name']} | {e['round']} | {params} | {100 * e['heldout_gain']:.1f} %"
                     f" | {100 * e['penalty']:.0f} % | {e['effect_size_mm']:.1f} | "
                     f"{'yes' if e['pays'] else 'no'} |")
    sel = r['selected_effects']
    none = ('none. No effect of the library pays for its parameters on held-out data; the '
            'residual shape is shown below.')
    if r.get('dropped_for_prediction'):
        lines += ['', 'Paid on the fit but dropped because the held-out prediction error did '
                  'not drop with them: ' + ', '.join(r['dropped_for_prediction']) + '.']
        none = 'none (what paid is above); the residual shape is shown below.'
    if r.get('selection_note'):
        none = f"none: {r['selection_note']}."

    at_bound = [e['name'] for e in r['effects_tested'] if e.get('at_bound')]
    if at_bound:
        lines += ['', 'Fitted at a bound of the plausible range (not selected): '
                  + ', '.join(dict.fromkeys(at_bound)) + '.']
    mechanisms = {e['name']: e.get('mechanism') for e in r['effects_tested']}
    lines += ['', '**Selected:** ' + ('; '.join(f'{name} ({mechanisms[name]})'
                                               if mechanisms.get(name) else name
                                               for name in sel) if sel else none),
              '', '## Held-out errors before and after', '',
              f"{d['folds']}-fold cross-validation by trajectory; prediction from the first "
              f"{1e3 * d['predict_window_s']:.0f} ms of each track; hitting plane "
              f"x = {d['hit_plane_x']} m.", '',
              '| | fit RMS mm | prediction RMS mm | bounce error mm | hit-plane error mm '
              '(median) | 9-area accuracy |', '|---|---|---|---|---|---|']
    for name, s in (('baseline', b), ('final', f)):
        lines.append(f"| {name} | {_fmt(s['heldout_fit_rms_mm'], 2)} | {_fmt(s['rms_mm'], 1)}"
                     f" | {_fmt(s['bounce_err_mm'], 1)} | {_fmt(s['hit_err_mm'], 1)} "
                     f"({_fmt(s['hit_err_median_mm'], 1)}) | {_fmt(s['zone_accuracy'])} |")
    noise = d.get('position_noise_mm')
    if noise and math.isfinite(noise):
        ratio = f['heldout_fit_rms_mm'] / noise
        lines += ['', f"The final model's held-out fit RMS, {f['heldout_fit_rms_mm']:.2f} mm, is "
                      f"{ratio:.1f} times the tracks' own noise ({noise:.2f} mm per axis, from "
                      f'local fits of {NOISE_WINDOW} samples): ' + (
                          'the data hold something neither the model nor its library has; '
                          'the residual plots show where along the tracks.' if ratio > 2.0
                          else 'the model follows the data to about their noise.')]
    names = list(dict.fromkeys([*b['params'], *f['params']]))
    lines += ['', '## Parameters', '', '| parameter | baseline | final |', '|---|---|---|']
    lines += [f"| {n} | {_fmt(b['params'].get(n), 4)} | {_fmt(f['params'].get(n), 4)} |"
              for n in names]
    lines += ['', '## Plots', ''] + [f'![{p[:-4]}]({p})' for p in PLOTS] + ['']
    return '\n'.join(lines)


def plot_all(result, folder):
    """The report's plots as PNG files in ``folder``."""
    pl = result['_plots']
    fig, axes = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    for j, ax in enumerate(axes):
        for key, label in (('diag_before', 'baseline'), ('diag_after', 'final')):
            dg = pl[key]
            c, m, s = binned(dg['t'], 1e3 * dg['res'][:, j]) if len(dg['t']) else (
                [], [], [])
            ax.errorbar(c, m, yerr=s, capsize=2, marker='o', label=label)
        ax.axhline(0, color='k', lw=0.5)
        ax.set_ylabel(f'{"xyz"[j]} residual, mm')
    axes[0].legend()
    axes[0].set_title('Measured − model along the tracks (full-data fit, mean ± std)')
    axes[-1].set_xlabel('time since track start, s')
    fig.tight_layout()
    fig.savefig(os.path.join(folder, 'residual_vs_time.png'), dpi=90)
    plt.close(fig)

    dg = pl['diag_before']
    fig, axes = plt.subplots(3, 3, figsize=(10, 7), sharey='row')
    for j in range(3):
        ok = np.isfinite(dg['acc'][:, j])
        for k, feat in enumerate(('t', 'speed', 'spin_ratio')):
            ax = axes[j, k]
            if ok.any():
                c, m, s = binned(dg[feat][ok], dg['acc'][ok, j])
                ax.errorbar(c, m, yerr=s, capsize=2, marker='o')
            ax.axhline(0, color='k', lw=0.5)
            if k == 0:
                ax.set_ylabel(f'{"xyz"[j]} residual acc, m/s²')
            if j == 2:
                ax.set_xlabel({'t': 'time, s', 'speed': 'speed, m/s',
                               'spin_ratio': 'spin ratio r|ω⊥|/|v|'}[feat])
    fig.suptitle('Baseline residual acceleration against time, speed and spin ratio')
    fig.tight_layout()
    fig.savefig(os.path.join(folder, 'residual_acceleration.png'), dpi=90)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7, 4))
    for shift, (key, label) in zip((-0.2, 0.2), (('pred_before', 'baseline'),
                                                 ('pred_after', 'final')), strict=True):
        errs = {}
        for tr in pl[key]:
            if tr and 'bounce_err' in tr:
                errs.setdefault(tr['zone_true'][0], []).append(1e3 * tr['bounce_err'])
        zones = sorted(errs)
        ax.bar(np.array(zones) + shift, [np.mean(errs[z]) for z in zones], width=0.4,
               label=label)
    ax.set_xticks(range(0, 10))
    ax.set_xlabel('measured landing area (0 = off the table)')
    ax.set_ylabel('mean bounce-point error, mm')
    ax.set_title('Held-out first-bounce error per area (prediction from the first 100 ms)')
    ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(folder, 'landing_errors.png'), dpi=90)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    reb = pl['rebound']
    if reb:
        speed = np.array(reb['impact_speed'])
        ax.plot(speed, reb['e_t_measured'], '.', label='measured bounces')
        grid = np.linspace(speed.min(), speed.max(), 20)
        for key in ('baseline', 'final'):
            prm = result[key]['params']
            e = prm.get('e_t', 0.93) + prm.get('e_t_speed_slope', 0.0) * (grid - 3.0)
            ax.plot(grid, e, label=f'{key} model')
        ax.legend()
    ax.set_xlabel('normal impact speed |v_z|, m/s')
    ax.set_ylabel('table restitution e_t')
    fig.tight_layout()
    fig.savefig(os.path.join(folder, 'rebound.png'), dpi=90)
    plt.close(fig)

