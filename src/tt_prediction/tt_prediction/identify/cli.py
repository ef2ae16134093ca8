"""``tt-identify DATA... --out DIR``: identify the ball model from measured tracks.

DATA are trajectory folders (CSV, DESIGN.md) or rosbag2 bags (BallState or PointStamped).
Writes DIR/report.json, DIR/report.md, plots and DIR/model.yaml (the model for
``--model`` of tt-predict and the nodes). Bad input: one line on stderr, exit status 2.
"""

import argparse
import re
import sys

from ..ball import load_model
from ..cli import HIT_PLANE_HELP, add_version, hit_plane_error
from ..staged import output_folder_error
from .data import DataError, load
from .pipeline import identify
from .report import PLOTS, write_outputs


def _progress_factory(enabled):
    """A progress bar per round of effect tests (on stderr), or None."""
    if not enabled:
        return None
    bars = []

    def make(total, label):
        from tqdm import tqdm
        if bars:
            bars.pop().close()
        bar = tqdm(total=total, desc=f'tt-identify: {label}, cross-validation fits',
                   unit='fit', file=sys.stderr)
        bars.append(bar)
        return lambda: bar.update(1)

    make.close = lambda: bars and bars.pop().close()
    return make


REPORT_FILE = re.compile('|'.join(map(re.escape, ('report.json', 'report.md', 'model.yaml')
                                      + PLOTS))
                         + r'|lead_time\.(json|md|png)')
"""The files of a report folder: tt-identify's and those lead_report adds (``make report``)."""


def main(argv=None):
    parser = argparse.ArgumentParser(prog='tt-identify',
                                     description=__doc__.splitlines()[0].replace('``', ''))
    add_version(parser)
    parser.add_argument('data', nargs='+', metavar='DATA',
                        help='trajectory folder (track CSVs t,x,y,z in s and m, table frame; '
                             'index.csv with spin wx,wy,wz in rad/s) or rosbag2 bag')
    parser.add_argument('--out', required=True, metavar='DIR',
                        help='output folder (replaced as a whole once the report is complete)')
    parser.add_argument('--model', default='', help='base model.yaml (default: nominal)')
    parser.add_argument('--topic', default=None, help='bag topic (default: the only one)')
    parser.add_argument('--folds', type=int, default=5,
                        help='cross-validation folds (by trajectory), >= 2 '
                             '(default: %(default)s)')
    parser.add_argument('--hit-plane-x', type=float, default=-1.5,
                        metavar='X', help=HIT_PLANE_HELP)
    parser.add_argument('--no-progress', action='store_true', help='no progress bar')
    args = parser.parse_args(argv)
    # One line, as every other bad input (argparse's error printed its usage block first).
    out_error = ('--folds must be at least 2' if args.folds < 2
                 else hit_plane_error(args.hit_plane_x)
                 or output_folder_error(args.out, REPORT_FILE, 'tt-identify'))
    if out_error:
        print(f'tt-identify: {out_error}', file=sys.stderr)
        return 2
    progress = _progress_factory(not args.no_progress)
    writing = False
    try:
        base = load_model(args.model)
        tracks = load(args.data, args.topic)
        result = identify(tracks, base, folds=args.folds, hit_plane_x=args.hit_plane_x,
                          progress=progress)
        if progress:
            progress.close()
        writing = True
        write_outputs(result, args.out, args.data, args.model)
    except (DataError, ValueError) as exc:
        print(f'tt-identify: {exc}', file=sys.stderr)
        return 2
    except OSError as exc:      # a write names --out: its staging folder means nothing to a user
        where = f'--out {args.out}: cannot write' if writing else exc.filename or args.out
        print(f'tt-identify: {where}: {exc.strerror or exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('tt-identify: interrupted, nothing written', file=sys.stderr)
        return 130
    for warning in result.get('warnings', []):
        print(f'tt-identify: warning: {warning}', file=sys.stderr)
    if result.get('selection_note'):
        print(f"tt-identify: {result['selection_note']}", file=sys.stderr)
    print(f'tt-identify: wrote {args.out} (selected effects: '
          f"{', '.join(result['selected_effects']) or 'none'})", file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
