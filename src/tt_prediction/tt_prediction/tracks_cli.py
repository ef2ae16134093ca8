"""tt-predict --tracks DIR --out OUT: replay measured tracks through the live filter and predictor.

DIR is a data set as tt-identify reads it (track CSVs ``t,x,y,z[,...]`` and an optional
index.csv with measured spin). For every input sample OUT/<track file name> gets a row
``t,x,y,z,vx,vy,vz,wx,wy,wz,bounce_t,bounce_x,bounce_y,hit_t,hit_x,hit_y,hit_z`` (empty where
there is no estimate or prediction) and OUT/summary.json the hit-point error against each
track's measured crossing of the hitting plane at lead times 300, 200, 150, 100 and 50 ms,
for this filter + predictor and for the textbook refit; OUT/model.yaml and OUT/params.yaml
(a ROS 2 parameters file) hand what the replay learned to the nodes. Everything is read and
checked before anything is written; the output is written to a temporary folder and renamed
into place, so a file that cannot be read leaves no partial output (one-line error naming
it, exit 2).
"""

import argparse
import dataclasses
import json
import math
import os
import re
import shlex
import sys

import numpy as np
from tt_ros.errors import one_line_reason
from tt_ros.yamlfile import load_yaml
import yaml

from .ball import load_model
from .ball_filter import FilterConfig, estimate_measurement_noise
from .cli import HIT_PLANE_HELP, add_version, hit_plane_error
from .identify.data import DataError, clean_samples, folder_tracks, index_path, read_track_csv
from .identify.frame import frame_warnings
from .predict import DEFAULT_HIT_PLANE_X
from .replay import COLUMNS, Learning, given_spin_warning, replay_tracks
from .staged import interruptible, output_folder_error, staged_folder
from .units import outside_room

# Predicted times to the ns, positions to the um; the input's t as the shortest decimal that
# reads back as it (rows are joined to the input's by their t: at %.6f an input's 0.005658100
# came out 0.005658, at %.9f an epoch stamp's 1765084800.123 1765084800.122999907; walk-
# throughs, 6 and 7 Dec 2026).
_FORMATS = ((None,) + ('%.6f',) * 3 + ('%.5f',) * 3 + ('%.3f',) * 3
            + ('%.9f',) + ('%.6f',) * 2 + ('%.9f',) + ('%.6f',) * 3)


def _cell(fmt, v):
    """One value of an output row: '' where there is none, the input's t (``fmt`` None) as
    its shortest decimal."""
    if not math.isfinite(v):
        return ''
    return np.format_float_positional(v, unique=True, trim='-') if fmt is None else fmt % v


def read_tracks(folder):
    """Every track of ``folder`` as read, uncleaned: [(file name, t, p, spin or None)].

    Raises DataError (naming the file) for a folder or file that cannot be read."""
    files, index = folder_tracks(folder)
    tracks = []
    for name in files:
        path = os.path.join(folder, name)
        t, p = read_track_csv(path)
        p[outside_room(p)] = np.nan     # a wild sample: not fed to the filter (data.clean_samples)
        valid = np.isfinite(t) & np.all(np.isfinite(p), axis=1)
        times = len(np.unique(t[valid]))
        if times < 2:
            raise DataError(f'{path}: {int(valid.sum())} valid sample(s) at {times} time(s); '
                            'a track needs 2 times')
        tracks.append((name, t, p, index.get(name, (None,))[0]))
    return tracks


def measured_noise(tracks):
    """(position noise m, stamp noise s) the tracks' own scatter gives
    (:func:`tt_prediction.ball_filter.estimate_measurement_noise`), NaN when they are too
    short for it. On the samples as the replay takes them (:func:`tt_prediction.identify.
    data.clean_samples`): in time order, as the estimate fits runs of consecutive samples (a
    file's rows need not be sorted; rows shuffled gave 50 mm of noise instead of 0.5), and
    with a stamp given twice merged (every row written twice halved the estimate, 0.57 to
    0.31 mm on mpi_launcher, and the filter trusted each sample twice as much)."""
    return estimate_measurement_noise([clean_samples(name, t, p)[:2]
                                       for name, t, p, _ in tracks])


NOISE_RATIO = 10.0
"""A position_noise set this many times off the tracks' own scatter, either way, is warned of."""


def noise_warning(position_noise, est, path):
    """One line when the ``position_noise`` (m) set in the file ``path`` is over NOISE_RATIO
    times off the tracks' own scatter ``est`` (m, NaN: unknown) (a millimetre value read as
    metres weighed each sample as if 1 m off: 124 mm at 50 ms instead of 6), else ''."""
    if not (math.isfinite(est) and est > 0.0):
        return ''
    ratio = position_noise / est
    if 1.0 / NOISE_RATIO <= ratio <= NOISE_RATIO:
        return ''
    return (f'{path}: position_noise {position_noise:g} m is {ratio:.3g} times the '
            f"{est * 1e3:.2f} mm the tracks' own scatter gives: is it in metres? ('auto' "
            'takes that estimate)')


def load_filter_config(path, tracks, warnings=None):
    """FilterConfig from a YAML mapping of its fields (``path``), or the defaults; a
    ``position_noise`` or ``stamp_noise`` of ``auto`` (the default) is estimated from the data
    (:func:`tt_prediction.ball_filter.estimate_measurement_noise`), or takes FilterConfig's
    default where the tracks are too short for that (no 7 samples of a moving ball). A
    ``warnings`` list gets :func:`noise_warning`'s line for a position_noise set in the
    file (the estimate made once for both)."""
    data = {}
    if path:
        try:
            with open(path) as f:
                data = load_yaml(f) or {}
        except OSError as exc:
            raise DataError(f'{path}: cannot read filter config: {exc.strerror}') from None
        except yaml.YAMLError as exc:
            raise DataError(f'{path}: not valid YAML: {one_line_reason(exc)}') from None
        if not isinstance(data, dict):
            raise DataError(f'{path}: filter config must be a mapping')
    names = {f.name for f in dataclasses.fields(FilterConfig)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise DataError(f'{path}: unknown filter setting(s) {", ".join(unknown)}')
    noise = data.pop('position_noise', 'auto')
    stamp = data.pop('stamp_noise', 'auto')
    checked = noise != 'auto' and warnings is not None
    if 'auto' in (noise, stamp) or checked:
        est_noise, est_stamp = measured_noise(tracks)
        scatter = est_noise
        if not math.isfinite(est_noise):       # no 7 samples of a moving ball: the defaults
            est_noise, est_stamp = FilterConfig.position_noise, FilterConfig.stamp_noise
        noise = est_noise if noise == 'auto' else noise
        stamp = est_stamp if stamp == 'auto' else stamp

    def number(value):
        """Whether ``value`` is a number; PyYAML reads 1e-3 (no dot) as a string."""
        if isinstance(value, str):
            try:
                float(value)
            except ValueError:
                return False
            return True
        return isinstance(value, (int, float)) and not isinstance(value, bool)

    def typed(name, value):
        """``value`` as the setting ``name`` takes it; ValueError naming the setting."""
        default = getattr(FilterConfig, name)
        if isinstance(default, tuple):
            if (not isinstance(value, list) or len(value) != len(default)
                    or not all(number(v) for v in value)):
                raise ValueError(f'{name} must be a list of {len(default)} numbers, got '
                                 f'{value!r}')
            return tuple(float(v) for v in value)
        if isinstance(default, str):
            if not isinstance(value, str):
                raise ValueError(f'{name} must be a word, got {value!r}')
            return value
        if isinstance(default, int):
            if not (number(value) and float(value).is_integer()):
                raise ValueError(f'{name} must be a whole number, got {value!r}')
            return int(value)
        if not number(value):                   # a float (or None: a float when given)
            raise ValueError(f'{name} must be a number, got {value!r}')
        return float(value)

    try:
        config = FilterConfig(**{k: typed(k, v) for k, v in data.items()},
                              position_noise=typed('position_noise', noise),
                              stamp_noise=typed('stamp_noise', stamp))
    except (TypeError, ValueError) as exc:
        raise DataError(f'{path or "filter config"}: {exc}') from None
    if checked:
        warnings += [w for w in [noise_warning(config.position_noise, scatter, path)] if w]
    return config


LEARNED_MODEL = 'model.yaml'
NODE_PARAMS = 'params.yaml'
NODES_WITH_MODEL = ('perception_node', 'prediction_node', 'strike_node')
"""The nodes that read a model_file (their default names), in NODE_PARAMS."""
OUTPUT_FILE = re.compile(r'(?!index\.csv$).+\.csv|summary\.json|model\.yaml|params\.yaml',
                         re.IGNORECASE)
"""The files tt-predict --tracks writes: one CSV per track (not a data set's index.csv),
summary.json, model.yaml and params.yaml."""


def write_rows(path, rows):
    """One CSV of replay rows (COLUMNS), empty fields where NaN."""
    with open(path, 'w') as f:
        f.write(','.join(COLUMNS) + '\n')
        for row in rows:
            f.write(','.join(_cell(fmt, v) for fmt, v in zip(_FORMATS, row, strict=True))
                    + '\n')


def node_params(config, model_path, command):
    """The ROS 2 parameters file of what the replay ended with, for the nodes: perception_node's
    filter settings that the replay learns (accel_noise, with the accel_noise_speed it was
    learned at, bounce_velocity_noise, the spin prior's standard deviations and mean on the
    axes of the velocity) and, for each node that reads one, ``model_path``. ``command``:
    the tt-predict command line, in the header comment. A YAML string."""
    top, side, along = config.spin_prior_axes()
    perception = {
        'model_file': model_path,
        'accel_noise': float(config.accel_noise),
        'accel_noise_speed': float(config.accel_noise_speed),
        'bounce_velocity_noise': float(config.bounce_velocity_noise),
        'spin_prior': float(top), 'spin_prior_side': float(side),
        'spin_prior_along': float(along),
        'spin_prior_mean': [float(v) for v in config.spin_prior_mean],
    }
    nodes = {name: {'ros__parameters': perception if name == 'perception_node'
                    else {'model_file': model_path}} for name in NODES_WITH_MODEL}
    header = (f'# Written by {command}\n'
              '# What the replay ended with (learned from every track unless --no-learn; '
              'docs/prediction.md),\n'
              f'# for: ros2 run <package> <node> --ros-args --params-file {NODE_PARAMS}\n')
    return header + yaml.safe_dump(nodes, sort_keys=False, default_flow_style=None)


def write_output(out_dir, replays, summary, final=None):
    """Write the rows and summary.json into a temporary folder, then put it in place of
    ``out_dir`` (an earlier replay's rows of tracks this set does not have would sit beside
    a summary that does not count them). ``final``: (FilterConfig, ModelParams, meta,
    command) the replay ended with, written as model.yaml and params.yaml
    (:func:`node_params`)."""
    with staged_folder(out_dir, 'tt-predict') as tmp:
        for rp in replays:
            write_rows(os.path.join(tmp, rp.name), rp.rows)
        with open(os.path.join(tmp, 'summary.json'), 'w') as f:
            json.dump(summary, f, indent=2)
        if final is not None:
            config, model, meta, command = final
            model.save(os.path.join(tmp, LEARNED_MODEL), meta=meta)
            model_path = os.path.join(os.path.abspath(out_dir), LEARNED_MODEL)
            with open(os.path.join(tmp, NODE_PARAMS), 'w') as f:
                f.write(node_params(config, model_path, command))


def main(argv=None):
    """The command (Ctrl-C: one line, exit status 130, :func:`interruptible`)."""
    return interruptible('tt-predict', _main, argv)


def _main(argv=None):
    parser = argparse.ArgumentParser(       # the usage line names --tracks as an option
        prog='tt-predict', description=__doc__.splitlines()[0],
        epilog='Output format and measured numbers: see docs/prediction.md.')
    add_version(parser)
    parser.add_argument('--tracks', metavar='DIR', required=True,
                        help='data set: track CSVs t,x,y,z (s, m, table frame) and index.csv '
                             '(spin wx,wy,wz, rad/s)')
    parser.add_argument('--out', metavar='OUT', required=True,
                        help='output folder (replaced as a whole once every row is written)')
    parser.add_argument('--model', metavar='FILE',
                        help='model.yaml written by tt-identify (default: nominal model)')
    parser.add_argument('--hit-plane-x', type=float, default=DEFAULT_HIT_PLANE_X,
                        metavar='X', help=HIT_PLANE_HELP)
    parser.add_argument('--filter-config', metavar='FILE',
                        help='YAML of FilterConfig fields (default: defaults, position noise '
                             'estimated from the data)')
    parser.add_argument('--no-textbook', action='store_true',
                        help='skip the textbook reference predictor in summary.json')
    parser.add_argument('--no-learn', action='store_true',
                        help='keep the configured spin prior, accel_noise, '
                             "bounce_velocity_noise and the model's table restitution, "
                             'Magnus coefficient and gravity (default: learn them from the '
                             'tracks before each one, docs/prediction.md)')
    argv = sys.argv[1:] if argv is None else argv
    if any(a in ('-h', '--help') for a in argv):     # before --tracks, which wants its DIR
        parser.print_help()
        return 0
    args = parser.parse_args(argv)
    plane_error = hit_plane_error(args.hit_plane_x)
    if plane_error:
        print(f'tt-predict: {plane_error}', file=sys.stderr)
        return 2
    out_error = output_folder_error(args.out, OUTPUT_FILE, 'tt-predict --tracks',
                                    csv_header=','.join(COLUMNS))
    if out_error:
        print(f'tt-predict: {out_error}', file=sys.stderr)
        return 2
    try:
        params = load_model(args.model)
        tracks = read_tracks(args.tracks)
        noted = []
        config = load_filter_config(args.filter_config, tracks, noted)
    except ValueError as exc:                  # DataError is a ValueError
        print(f'tt-predict: {exc}', file=sys.stderr)
        return 2
    warnings = frame_warnings([(name, t, p) for name, t, p, _ in tracks], params,
                              args.hit_plane_x)
    warnings += noted
    learning = Learning(config, params)     # with --no-learn unused: the configured values
    replays, summary = replay_tracks(tracks, params, config, args.hit_plane_x,
                                     textbook=not args.no_textbook,
                                     learn=not args.no_learn, learning=learning)
    spin_warning = given_spin_warning(replays, [spin for *_, spin in tracks], params, config,
                                      index_path(args.tracks))
    warnings += [spin_warning] if spin_warning else []
    summary['warnings'] = warnings
    summary['model'] = args.model or 'nominal'
    summary['data'] = args.tracks
    learned = [name for name, learner in (('e_t', learning.restitution),
                                          ('c_m', learning.lift),
                                          ('gravity', learning.gravity))
               if learner.value != learner.generic]      # moved from the model's
    meta = {'written_by': 'tt-predict --tracks', 'sources': [args.tracks],
            'model': args.model or 'nominal', 'learned': learned}
    command = shlex.join(['tt-predict', *(argv if argv is not None else sys.argv[1:])])
    command = command.replace('\n', '\\n')        # one comment line in params.yaml
    try:
        write_output(args.out, replays, summary,
                     (learning.config(config), learning.model(params), meta, command))
    except OSError as exc:
        print(f'tt-predict: {args.out}: cannot write: {exc.strerror}', file=sys.stderr)
        return 2
    for warning in warnings:
        print(f'tt-predict: warning: {warning}', file=sys.stderr)
    print(f'tt-predict: wrote {args.out} ({_outcome(summary)})', file=sys.stderr)
    return 0


def _outcome(summary):
    """One line of summary.json: tracks and the median hit errors against lead time."""

    def medians(errors):
        return '/'.join('-' if v['median_mm'] is None else f"{v['median_mm']:.1f}"
                        for v in errors.values())

    leads = '/'.join(str(lead) for lead in summary['leads_ms'])
    line = (f"{summary['tracks']} tracks, {summary['tracks_with_crossing']} with a measured "
            'crossing')
    if summary['tracks_without_crossing']:
        line += ' (why not the others: tracks_without_crossing in summary.json)'
    line += f"; median hit error at {leads} ms: {medians(summary['hit_error'])} mm"
    if 'textbook_hit_error' in summary:
        line += f", textbook {medians(summary['textbook_hit_error'])} mm"
    return line


if __name__ == '__main__':
    sys.exit(main())
