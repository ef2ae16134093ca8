"""tt-strike: racket normal and velocity that return incoming balls to a target, JSON Lines.

Input (stdin or --input FILE), one incoming ball per line, table frame, SI units:
    {"t": 0.0, "p": [x, y, z], "v": [vx, vy, vz], "w": [wx, wy, wz],
     "target_zone": 1..9 | "target_point": [x, y], "covariance": [81 numbers] (optional)}
Each ball is predicted through its bounce on the robot's half, and the hit point is chosen
along its path inside the robot's reach (--workspace, default the template
config/workspace.yaml) where the in-zone probability is best (tt_strike.hitpoint); the
input's t is the time of the decision, for the workspace's min_time_before_hit. With
--hit-plane-x X the old behaviour: the hit point is the crossing of the plane x = X (the
workspace's racket speed limit and min_time_before_hit still apply, as in strike_node).
Output (stdout), one line per input line:
    {"status": "ok" | "infeasible" | "no_hit_point" | "unreachable" | "too_late",
     "reason": ...,
     "hit": {t, p, v, w} | null,
     "racket": {normal, velocity, orientation_xyzw, position} | null,
     "ball_out": {v, w} | null, "landing": {t, p, zone} | null,
     "target": {zone, point}, "net_clearance", "margin", "residual", "in_zone_probability"}
Every line is checked before anything is written: a bad line (not JSON, a missing, unknown or
malformed field, NaN, a target zone outside 1..9, a target point that is not 2 numbers or
is off the opponent's half, a covariance not symmetric or not positive semi-definite)
stops the command with a one-line reason naming the line, exit status 2; so does a bad
workspace file (naming the key).
"""

import argparse
import functools
import json
import math
import sys

import numpy as np
from tt_prediction.cli import (
    InputError,
    add_version,
    hit_plane_error,
    parse_object,
    parse_state,
    read_input,
)
from tt_prediction.predict import DEFAULT_HIT_PLANE_X

from .hitpoint import StrikePlan, choose
from .incoming import hit_point
from .robust import check_covariance
from .solver import (
    MAX_RACKET_SPEED_RANGE,
    NET_CLEARANCE_RANGE,
    StrikeSettings,
    resolve_target,
    solve,
)
from .workspace import load_workspace

INPUT_FIELDS = ('t', 'p', 'v', 'w', 'target_zone', 'target_point', 'covariance')
"""The fields of an input line; any other is refused (a misspelt "covarience" was left out
without a word, and the stroke went out without its in-zone probability)."""


def parse_strike_line(text, lineno, radius, needs_covariance=False):
    """(t, state9, zone or None, point or None, covariance or None) of one input line;
    ``needs_covariance`` (--aim-inside-zone): a line without one is refused (it was answered
    without a word, aimed at the zone's centre)."""
    data = parse_object(text, lineno, INPUT_FIELDS)
    t, state = parse_state(data, lineno, radius)
    zone, point = data.get('target_zone'), data.get('target_point')
    if point is not None and not (
            isinstance(point, list) and len(point) == 2
            and all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in point)):
        raise InputError(f'line {lineno}: "target_point" must be 2 numbers [x, y], got '
                         f'{json.dumps(point)}')
    try:
        resolve_target(zone, point)
    except ValueError as exc:
        raise InputError(f'line {lineno}: {exc}') from None
    cov = data.get('covariance')
    if cov is None and needs_covariance:
        raise InputError(f'line {lineno}: --aim-inside-zone needs "covariance" (81 numbers, '
                         "9x9: the state's, to aim where the ball lands in the zone most often)")
    if cov is not None:
        ok = (isinstance(cov, list) and len(cov) == 81
              and all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in cov))
        if not ok or not all(math.isfinite(c) for c in cov):
            raise InputError(f'line {lineno}: "covariance" must be 81 finite numbers (9x9)')
        cov = np.array(cov, dtype=float).reshape(9, 9)
        try:
            check_covariance(cov, '"covariance"')
        except ValueError as exc:
            raise InputError(f'line {lineno}: {exc}') from None
    return t, np.array(state), zone, point, cov


def range_error(option, value, bounds, unit):
    """Why ``value`` cannot be the value of ``option``, or '' (also for None, an option not
    given): it must lie within ``bounds`` (lo, hi), strike_node's range of the parameter."""
    lo, hi = bounds
    if value is None or lo <= value <= hi:       # nan is outside
        return ''
    return f'{option} must be a number in [{lo:g}, {hi:g}] {unit}, got {value:g}'


def _vec(a):
    return [float(x) for x in a]


def strike_to_dict(pred, sol, plan=None):
    """The output line of one ball: its prediction and (when there is a hit point) solution;
    or, with ``plan`` (tt_strike.hitpoint.StrikePlan), the chosen hit point's. Every key is
    in every line, null where there is no value (a line without a stroke left out the
    solver's keys: a script reading them failed on it; a walk-through, 6 Dec 2026)."""
    out = {'status': 'no_hit_point', 'reason': f'{pred.status}: {pred.reason}', 'hit': None,
           'racket': None, 'ball_out': None, 'landing': None, 'target': None,
           'net_clearance': None, 'margin': None, 'residual': None, 'in_zone_probability': None}
    if plan is not None:
        out['status'], out['reason'] = plan.status, plan.reason
        if plan.solution is None:
            return out
        hit, sol = plan.hit, plan.solution
    elif pred.status != 'ok':
        return out
    else:
        hit = pred.hit
        out['status'], out['reason'] = sol.status, sol.reason
    out['hit'] = hit.to_dict()
    out['target'] = {'zone': sol.target_zone, 'point': _vec(sol.target_point)}
    if sol.normal is None:
        return out
    out['racket'] = {'normal': _vec(sol.normal), 'velocity': _vec(sol.racket_velocity),
                     'orientation_xyzw': _vec(sol.orientation_xyzw),
                     'position': _vec(sol.racket_position)}
    out['ball_out'] = {'v': _vec(sol.ball_out_v), 'w': _vec(sol.ball_out_w)}
    if sol.landing is not None:
        out['landing'] = {'t': hit.t + sol.flight_time, 'p': _vec(sol.landing),
                          'zone': sol.landing_zone}
    for key in ('net_clearance', 'margin', 'residual', 'in_zone_probability'):
        value = float(getattr(sol, key))
        out[key] = value if math.isfinite(value) else None
    return out


def main(argv=None):
    defaults = StrikeSettings()
    parser = argparse.ArgumentParser(
        prog='tt-strike', description=__doc__.splitlines()[0],
        epilog="Input and output formats and the solver's choices: see docs/strike.md.")
    add_version(parser, 'tt_strike')
    parser.add_argument('--input', metavar='FILE', help='JSON Lines file (default: stdin)')
    parser.add_argument('--model', metavar='FILE',
                        help='model.yaml written by tt-identify (default: nominal model)')
    parser.add_argument('--workspace', metavar='FILE',
                        help='workspace YAML: reach of the racket centre, racket-speed limit, '
                        'least time before the hit (default: the template '
                        'config/workspace.yaml)')
    parser.add_argument('--hit-plane-x', type=float, default=None, metavar='X',
                        help='old behaviour: hit where the ball crosses the plane x = X, m '
                        f'(e.g. {DEFAULT_HIT_PLANE_X}), instead of choosing along the path')
    parser.add_argument('--net-clearance', type=float, default=defaults.net_clearance,
                        metavar='M', help='gap between ball and net top at x = 0, m '
                        '(the free direction; default: %(default)s)')
    parser.add_argument('--max-racket-speed', type=float, default=None, metavar='V',
                        help="racket speed limit, m/s, where below the workspace's (default: "
                        "the workspace's)")
    parser.add_argument('--aim-inside-zone', action='store_true',
                        help='aim where the in-zone probability is highest (needs covariance)')
    args = parser.parse_args(argv)
    errors = [hit_plane_error(args.hit_plane_x) if args.hit_plane_x is not None else '',
              range_error('--net-clearance', args.net_clearance, NET_CLEARANCE_RANGE, 'm'),
              range_error('--max-racket-speed', args.max_racket_speed, MAX_RACKET_SPEED_RANGE,
                          'm/s')]
    for error in filter(None, errors):
        print(f'tt-strike: {error}', file=sys.stderr)
        return 2
    try:
        # Read with --hit-plane-x too: its racket speed limit and least time before the hit
        # apply there as in strike_node's use_hit_plane (a missing file was not even named).
        workspace = load_workspace(args.workspace)
        params, balls = read_input(args.model, args.input, functools.partial(
            parse_strike_line, needs_covariance=args.aim_inside_zone))
    except ValueError as exc:                  # InputError, WorkspaceError are ValueErrors
        print(f'tt-strike: {exc}', file=sys.stderr)
        return 2
    workspace = workspace.slowed_to(args.max_racket_speed)      # the lower, as strike_node
    settings = StrikeSettings(net_clearance=args.net_clearance,
                              max_racket_speed=workspace.max_racket_speed,
                              aim_inside_zone=args.aim_inside_zone)
    out = []
    for t, state, zone, point, cov in balls:
        if args.hit_plane_x is None:
            plan = choose(state, params, workspace, t0=t, target_zone=zone, target_point=point,
                          settings=settings, covariance=cov)
            out.append(json.dumps(strike_to_dict(plan.prediction, None, plan)))
            continue
        pred = hit_point(state, params, t0=t, hit_plane_x=args.hit_plane_x)
        if pred.status == 'ok' and pred.hit.t - t < workspace.min_time_before_hit:
            plan = StrikePlan('too_late', f'hit in {pred.hit.t - t:.3f} s, below '
                              f'min_time_before_hit {workspace.min_time_before_hit:.3f} s')
            out.append(json.dumps(strike_to_dict(pred, None, plan)))
            continue
        sol = None
        if pred.status == 'ok':
            sol = solve(pred.hit.state, params, target_zone=zone, target_point=point,
                        settings=settings, covariance=cov)
        out.append(json.dumps(strike_to_dict(pred, sol)))
    if out:
        sys.stdout.write('\n'.join(out) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
