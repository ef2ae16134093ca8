"""Hit-point error against lead time for the report: baseline model against the final one.

``python -m tt_prediction.lead_report --data DIR --model FILE --out FOLDER [--hit-plane-x X]
[--filter-config FILE]`` replays DIR's tracks (:mod:`tt_prediction.replay`) with the nominal
model (the baseline) and with FILE (the model.yaml tt-identify selected), and writes into
FOLDER: ``lead_time.png`` (median and p90 hit-point error against lead time, both models and
the textbook refit), ``lead_time.md`` (the same numbers as a table) and ``lead_time.json``.
When FOLDER holds tt-identify's ``report.md``, its "Hit-point error against lead time" section
(the table and the plot) is written into it, replacing that section from an earlier run.
"""

import argparse
import json
import math
import os
import sys

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (after selecting the non-interactive backend)

from .ball import load_model  # noqa: E402
from .cli import hit_plane_error  # noqa: E402
from .predict import DEFAULT_HIT_PLANE_X  # noqa: E402
from .replay import LEADS_MS, Learning, replay_tracks  # noqa: E402
from .staged import replace_file  # noqa: E402
from .tracks_cli import load_filter_config, read_tracks  # noqa: E402


def lead_time_errors_for(data_dir, model_file, hit_plane_x, filter_config=None):
    """Summaries (``replay_tracks``) of DIR with the nominal model and with ``model_file``:
    ``{'baseline': summary, 'final': summary}`` (the textbook refit in the final one). The
    baseline holds the nominal model's gravity: learnt, it would be the effect that
    tt-identify's ``gravity_or_scale`` brings to the final model, not the baseline's."""
    tracks = read_tracks(data_dir)
    config = load_filter_config(filter_config, tracks)
    out = {}
    for key, path in (('baseline', None), ('final', model_file)):
        params = load_model(path)
        _, summary = replay_tracks(tracks, params, config, hit_plane_x,
                                   textbook=key == 'final',
                                   learning=Learning(config, params, gravity=key == 'final'))
        summary['model'] = path or 'nominal'
        out[key] = summary
    return out


def table(result):
    """Markdown table: lead (ms) | baseline | final | textbook, median / p90 mm (missing)."""
    base, final = result['baseline'], result['final']

    def cell(s):
        if s['median_mm'] is None:
            return '–'
        miss = f", {s['missing']} missing" if s['missing'] else ''
        return f"{s['median_mm']:.1f} / {s['p90_mm']:.1f}{miss}"

    lines = ['| lead, ms | baseline (nominal) model | final model (model.yaml) '
             '| textbook refit (final model) |', '|---|---|---|---|']
    for lead in base['leads_ms']:
        k = str(lead)
        lines.append(f"| {lead} | {cell(base['hit_error'][k])} | {cell(final['hit_error'][k])}"
                     f" | {cell(final['textbook_hit_error'][k])} |")
    lines.append('')
    lines.append(f"Hit-point error at x = {final['hit_plane_x']} m, median / p90 in mm over "
                 f"{final['tracks_with_crossing']} tracks with a measured crossing "
                 f"(of {final['tracks']}).")
    floor = final.get('reference_error', {})
    if floor.get('median_mm') is not None:
        lines.append(f"The measured crossing is itself uncertain: a perfect predictor would score "
                     f"{floor['median_mm']:.2f} / {floor['p90_mm']:.2f} mm (median / p90; the "
                     "tracks redrawn with their own noise).")
    learned = final.get('spin_prior_learned')
    if learned:
        lines.append('')
        lift = final.get('lift_learned', {})
        bounce = final.get('bounce_noise_learned', {})
        gravity = final.get('gravity_learned', {})
        lines.append("Spin prior, accel_noise, the rebound's velocity noise, the table "
                     'restitution, the Magnus coefficient and (final model only) gravity '
                     'learned causally from the tracks before each one (docs/prediction.md); '
                     'at the end (final model): '
                     'top/back, side, along v '
                     f"{', '.join(f'{v + 0.0:g}' for v in learned['final_mean'])} rad/s "
                     f"(mean), {', '.join(f'{v:g}' for v in learned['final'])} rad/s "
                     f"(standard deviation), accel_noise {learned['accel_noise_final']:g} "
                     'm/s^2/sqrt(Hz), bounce_velocity_noise '
                     f"{bounce.get('final', math.nan):g} m/s (from "
                     f"{bounce.get('tracks_informing', 0)} bounces), e_t "
                     f"{final['restitution_learned']['final']:g}, C_M "
                     f"{lift.get('final', math.nan):g} (from {lift.get('tracks_informing', 0)} "
                     f"gripping bounces), g {gravity.get('final', math.nan):g} m/s^2.")
    return '\n'.join(lines)


def plot(result, path):
    """PNG of median (solid) and p90 (dashed) hit error against lead time."""
    fig, ax = plt.subplots(figsize=(7, 4))
    series = (('baseline', 'hit_error', 'baseline (nominal) model', 'C0'),
              ('final', 'hit_error', 'final model', 'C1'),
              ('final', 'textbook_hit_error', 'textbook refit', 'C2'))
    for key, field, label, color in series:
        stats = result[key][field]
        leads = [lead for lead in LEADS_MS if stats[str(lead)]['median_mm'] is not None]
        ax.plot(leads, [stats[str(lead)]['median_mm'] for lead in leads], 'o-', color=color,
                label=f'{label}, median')
        ax.plot(leads, [stats[str(lead)]['p90_mm'] for lead in leads], 's--', color=color,
                alpha=0.6, label=f'{label}, p90')
    floor = result['final'].get('reference_error', {}).get('median_mm')
    if floor is not None:
        ax.axhline(floor, color='0.5', lw=1, ls=':', label='perfect predictor, median')
    ax.set_yscale('log')
    ax.set_xlabel('lead time before the hitting-plane crossing, ms')
    ax.set_ylabel('hit-point error, mm')
    ax.set_title('Replay through the ball filter and predictor')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


SECTION_BEGIN = '<!-- lead_time: written by tt_prediction.lead_report -->'
SECTION_END = '<!-- /lead_time -->'


def report_section(result):
    """The markdown section for report.md: table, plot and a link to lead_time.md."""
    return (f'{SECTION_BEGIN}\n## Hit-point error against lead time\n\n'
            'Every track replayed through the live ball filter and predictor '
            '(`tt-predict --tracks`), baseline (nominal) model against the final model.yaml; '
            'also in [lead_time.md](lead_time.md) and lead_time.json.\n\n'
            f'{table(result)}\n\n![lead time](lead_time.png)\n{SECTION_END}\n')


def embed_in_report(report_path, section):
    """Replace (or append) the lead-time section of tt-identify's report.md."""
    with open(report_path) as f:
        text = f.read()
    begin, end = text.find(SECTION_BEGIN), text.find(SECTION_END)
    if begin >= 0 and end > begin:
        text = text[:begin] + section + text[end + len(SECTION_END):].lstrip('\n')
    else:
        text = text.rstrip('\n') + '\n\n' + section
    replace_file(report_path, text)


def write(result, folder):
    """lead_time.png, lead_time.md and lead_time.json into ``folder``, and the section into
    ``folder``/report.md when tt-identify wrote one there."""
    os.makedirs(folder, exist_ok=True)
    plot(result, os.path.join(folder, 'lead_time.png'))
    replace_file(os.path.join(folder, 'lead_time.md'),
                  '# Hit-point error against lead time\n\n' + table(result)
                  + '\n\n![lead time](lead_time.png)\n')
    replace_file(os.path.join(folder, 'lead_time.json'), json.dumps(result, indent=2))
    report = os.path.join(folder, 'report.md')
    if os.path.isfile(report):
        embed_in_report(report, report_section(result))


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m tt_prediction.lead_report',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--data', required=True, metavar='DIR',
                        help='data set: track CSVs t,x,y,z and index.csv (as tt-identify and '
                             'tt-predict --tracks read it)')
    parser.add_argument('--model', required=True, metavar='FILE',
                        help='the final model.yaml (written by tt-identify), replayed against '
                             'the nominal model')
    parser.add_argument('--out', required=True, metavar='FOLDER',
                        help="folder for lead_time.png, .md and .json; tt-identify's "
                             'report.md there gets the section')
    parser.add_argument('--hit-plane-x', type=float, default=DEFAULT_HIT_PLANE_X, metavar='X',
                        help="hitting plane x, m (default: %(default)s, tt-identify's and "
                             "tt-predict's; make report gives -1.2, which the MPI sets' "
                             'tracks cross)')
    parser.add_argument('--filter-config', metavar='FILE',
                        help='YAML of FilterConfig fields (default: defaults, position noise '
                             'estimated from the data)')
    args = parser.parse_args(argv)
    plane_error = hit_plane_error(args.hit_plane_x)
    if plane_error:
        parser.error(plane_error)
    try:
        result = lead_time_errors_for(args.data, args.model, args.hit_plane_x,
                                      args.filter_config)
    except ValueError as exc:           # DataError is one
        print(f'lead_report: {exc}', file=sys.stderr)
        return 2
    write(result, args.out)
    print(table(result))
    return 0


if __name__ == '__main__':
    sys.exit(main())
