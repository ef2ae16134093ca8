"""tt-predict: predict bounce, hit point and landing for ball states given as JSON Lines.

Input (stdin or --input FILE), one ball state per line, table frame, SI units:
    {"t": 0.0, "p": [x, y, z], "v": [vx, vy, vz], "w": [wx, wy, wz]}
Output (stdout), one line per input line:
    {"status": ..., "reason": ..., "bounce": {t, p, zone, half} | null,
     "hit": {t, p, v, w} | null, "landing": {t, p, zone, half} | null}
``hit`` is where the ball, after one bounce on the robot's half, crosses x = --hit-plane-x;
``landing`` is the first table contact. Blank lines are skipped. Every line is checked before
anything is written: a bad line (not JSON, a missing, unknown or malformed field, a state
that is not a ball in flight) stops the command with a one-line reason naming the line, exit
status 2.
"""

import argparse
import difflib
import json
import math
import sys

import numpy as np

from .ball import load_model
from .predict import DEFAULT_HIT_PLANE_X, HIT_PLANE_X_RANGE, check_state, predict, predict_many
from .units import MAX_TIME_S, ROOM_HALF_EXTENT_M, position_error, time_error

FIELDS = (('t', 1), ('p', 3), ('v', 3), ('w', 3))
BATCH_MIN = 16
"""From this many lines on, tt-predict predicts them in one call of the compiled batch kernel
(:func:`predict_many`, the same numbers as line by line); fewer go one by one."""


class InputError(ValueError):
    """A bad input line; the message names it."""


class _GivenTwiceError(Exception):
    """A JSON object's key given twice (args: the key)."""


def _each_once(pairs):
    """A JSON object's dict, its keys given once each: json keeps the last of two without a
    word (a line's "target_zone" twice aimed at the second; a walk-through, 6 Dec 2026)."""
    data = {}
    for key, value in pairs:
        if key in data:
            raise _GivenTwiceError(key)
        data[key] = value
    return data


def parse_object(text, lineno, fields=tuple(key for key, _ in FIELDS)):
    """The JSON object of one line (a dict) whose keys are among ``fields``; raises
    InputError naming the line, and an unknown field with the nearest name (a misspelt or
    per-line "hit_plane_x" was left out without a word)."""
    try:
        data = json.loads(text, object_pairs_hook=_each_once)
    except json.JSONDecodeError as exc:
        raise InputError(f'line {lineno}: not valid JSON: {exc.msg}') from None
    except _GivenTwiceError as exc:
        raise InputError(f'line {lineno}: field {json.dumps(exc.args[0])} given twice') from None
    if not isinstance(data, dict):
        raise InputError(f'line {lineno}: expected a JSON object with t, p, v, w')
    unknown = [k for k in data if k not in fields]
    if unknown:
        near = difflib.get_close_matches(unknown[0], fields, n=1)
        raise InputError(f'line {lineno}: unknown field {json.dumps(unknown[0])}'
                         + (f' (did you mean "{near[0]}"?)' if near else
                            f" (the fields: {', '.join(fields)})"))
    return data


_NUMBER = (int, float)        # what JSON numbers decode to (bool, an int subclass, is not one)


def _fast_values(data):
    """The 10 numbers [t, p, v, w] of a well-formed line (exact types, as JSON decodes them),
    or None for anything else (the full check then names what is wrong)."""
    try:
        t, p, v, w = data['t'], data['p'], data['v'], data['w']
    except KeyError:
        return None
    if (type(t) not in _NUMBER or type(p) is not list or type(v) is not list
            or type(w) is not list or len(p) != 3 or len(v) != 3 or len(w) != 3):
        return None
    values = [t, *p, *v, *w]
    for c in values:
        if type(c) not in _NUMBER:
            return None
    try:
        return [float(c) for c in values]
    except OverflowError:                   # an integer of hundreds of digits
        return None


def parse_state(data, lineno, radius):
    """(t, state9) of one line's JSON object ``data``; raises InputError naming the line."""
    fast = _fast_values(data)
    if fast is not None and abs(fast[0]) <= MAX_TIME_S:         # finite, not nanoseconds
        reason = check_state(fast[1:], radius)
        if not reason and max(map(abs, fast[1:4])) <= ROOM_HALF_EXTENT_M:
            return fast[0], fast[1:]
    values = []
    for key, size in FIELDS:
        if key not in data:
            raise InputError(f'line {lineno}: missing "{key}"')
        value = data[key]
        items = [value] if size == 1 else value
        if (not isinstance(items, list) or len(items) != size
                or not all(isinstance(c, (int, float)) and not isinstance(c, bool)
                           for c in items)):
            what = 'a number' if size == 1 else f'an array of {size} numbers'
            raise InputError(f'line {lineno}: "{key}" must be {what}, got '
                             f'{json.dumps(value)}')
        try:
            values.extend(float(c) for c in items)
        except OverflowError:
            raise InputError(f'line {lineno}: "{key}" holds an integer too large for a '
                             'number of metres, seconds or rad/s') from None
    if not math.isfinite(values[0]):
        raise InputError(f'line {lineno}: "t" is not finite')
    reason = (time_error(values[0], '"t"') or position_error(values[1:4], '"p"')
              or check_state(values[1:], radius))
    if reason:
        raise InputError(f'line {lineno}: {reason}')
    return values[0], values[1:]


def parse_line(text, lineno, radius):
    """(t, state9) of one JSON line; raises InputError naming the line."""
    return parse_state(parse_object(text, lineno), lineno, radius)


def _read_error(exc):
    """Why a file could not be read, in a few plain words (the file is named by the caller)."""
    if isinstance(exc, UnicodeDecodeError):
        return 'not a UTF-8 text file'
    if isinstance(exc, FileNotFoundError):
        return 'no such file'
    return f'cannot read: {(exc.strerror or str(exc)).lower()}'


def read_input(model_file, input_file, parse):
    """The model (``model_file`` or the nominal one) and every non-blank input line parsed by
    ``parse(line, lineno, radius)``, from ``input_file`` or stdin. Everything is read and
    checked before any output, so a bad line leaves nothing half-written. Raises InputError
    or ValueError with a one-line reason, naming ``input_file`` once (then the line)."""
    for option, path in (('--model', model_file), ('--input', input_file)):
        if path == '':          # an unset shell variable: the nominal model, stdin, silently
            raise InputError(f"{option} '': an empty path (a variable not set?)")
    params = load_model(model_file)
    from_file = input_file is not None and input_file != '-'       # '-': stdin
    where = f'{input_file}: ' if from_file else ''
    try:
        if from_file:
            with open(input_file, encoding='utf-8-sig') as f:     # a BOM, as Notepad writes
                lines = f.readlines()
        else:
            lines = sys.stdin.readlines()
            if lines:
                lines[0] = lines[0].removeprefix('\ufeff')
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f'{input_file if from_file else "stdin"}: {_read_error(exc)}') from None
    try:
        return params, [parse(line, i, params.radius)
                        for i, line in enumerate(lines, start=1) if line.strip()]
    except InputError as exc:
        raise InputError(f'{where}{exc}') from None


def add_version(parser, package='tt_prediction'):
    """``--version`` on ``parser``: the program's name and its package's installed version
    (package.xml's, through setup.cfg)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        number = version(package)
    except PackageNotFoundError:
        number = 'unknown (not installed)'
    parser.add_argument('--version', action='version', version=f'%(prog)s {number}')


HIT_PLANE_HELP = (f'x of the hitting plane, m, in [{HIT_PLANE_X_RANGE[0]:g}, '
                  f"{HIT_PLANE_X_RANGE[1]:g}] (the robot's half) (default: %(default)s)")
"""The ``--hit-plane-x`` option's help, the same in every command."""


def hit_plane_error(value):
    """Why ``value`` cannot be a ``--hit-plane-x``, or '': it must be finite and inside
    HIT_PLANE_X_RANGE, the range of the prediction node's ``hit_plane_x`` parameter too."""
    if not math.isfinite(value):
        return '--hit-plane-x must be finite'
    lo, hi = HIT_PLANE_X_RANGE
    if not lo <= value <= hi:
        return (f"--hit-plane-x must be a number in [{lo:g}, {hi:g}] m (the robot's half, "
                f'x < 0 in the table frame), got {value:g}')
    return ''


def predictions(states, params, hit_plane_x):
    """Predictions of the parsed lines ``states`` [(t, state9), ...]: through the batch kernel
    from BATCH_MIN lines on, else one :func:`predict` call each (identical results)."""
    if len(states) < BATCH_MIN:
        return [predict(state, params, t0=t, hit_plane_x=hit_plane_x) for t, state in states]
    times = np.array([t for t, _ in states])
    return predict_many(np.array([state for _, state in states]), params, t0=times,
                        hit_plane_x=hit_plane_x, checked=True)     # parse_state checked them


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if any(a == '--tracks' or a.startswith('--tracks=') for a in argv):
        from .tracks_cli import main as tracks_main  # replay of measured tracks
        return tracks_main(argv)
    parser = argparse.ArgumentParser(
        prog='tt-predict', description=__doc__.splitlines()[0],
        usage='%(prog)s [-h] [--version] [--input FILE] [--model FILE] [--hit-plane-x X]\n'
              '       %(prog)s --tracks DIR --out OUT [options]   (tt-predict --tracks -h)',
        epilog='Input and output formats: see docs/prediction.md. Replay of measured tracks: '
               'tt-predict --tracks DIR --out OUT (tt-predict --tracks -h).')
    add_version(parser)
    parser.add_argument('--input', metavar='FILE', help="JSON Lines file (default or '-': "
                        'stdin)')
    parser.add_argument('--model', metavar='FILE',
                        help='model.yaml written by tt-identify (default: nominal model)')
    parser.add_argument('--hit-plane-x', type=float, default=DEFAULT_HIT_PLANE_X,
                        metavar='X', help=HIT_PLANE_HELP)
    args = parser.parse_args(argv)
    plane_error = hit_plane_error(args.hit_plane_x)
    if plane_error:
        print(f'tt-predict: {plane_error}', file=sys.stderr)
        return 2
    try:
        params, states = read_input(args.model, args.input, parse_line)
    except ValueError as exc:        # InputError and the model file's errors name the file
        print(f'tt-predict: {exc}', file=sys.stderr)
        return 2
    out = [json.dumps(pred.to_dict()) for pred in predictions(states, params, args.hit_plane_x)]
    if out:
        sys.stdout.write('\n'.join(out) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
