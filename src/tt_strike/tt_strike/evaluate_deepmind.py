"""Strike solver over the DeepMind measured ball states, per target zone.

    python -m tt_strike.evaluate_deepmind [--data DIR] [--json FILE] [--limit N]
        [--workspace FILE] [--strokes FILE]      (hit point along the path, the default)
    python -m tt_strike.evaluate_deepmind [--data DIR] [--json FILE] [--limit N]
        --hit-plane-x X [--monte-carlo K]        (the old fixed plane)

The 15,792 states of ``data/deepmind_states/states_all.csv.gz`` (D'Ambrosio et al., ICRA 2025;
CC BY 4.0, see that folder's README; ``states.csv`` there is a 100-state sample) are real ball
states just after a hit, already rotated into the table frame. Those moving towards the robot
(v_x < 0) are incoming balls as they are. Those moving away (v_x > 0, the hitter stood at the
robot's end) are turned half a turn about the vertical axis through the table centre, (x, y, z)
-> (-x, -y, z) for p, v and w alike, which the table's symmetry makes an equally real incoming
ball. Each is predicted to the hitting plane (``tt_prediction.predict``, serves through their
first bounce on the server's half); those without a hit point are skipped and counted by
reason. Every remaining ball is then solved for each target zone 1..9 and the solution checked
forward (racket_rebound + predict_landing, the table as a body). By default the hit point is
chosen along the path inside the workspace (tt_strike.hitpoint, the template workspace unless
``--workspace``): a ball is *reachable* for a zone unless its status is no_hit_point,
unreachable or too_late, and the table gives the share of reachable balls that are feasible.
With ``--hit-plane-x`` the old fixed plane. Prints a Markdown table; ``--json`` writes the
numbers; ``--strokes`` (workspace only) writes every feasible stroke (hit state, normal,
racket velocity, zone) as JSON Lines, for an independent replay
(src/tt_strike/test/judge_strokes.py). ``--monte-carlo K`` (with ``--hit-plane-x`` only)
also compares, for K of the balls and every zone, the solver's in-zone probability under
sigma 2 mm position, 2 % velocity, 10 % spin with a Monte-Carlo run of 2000 random draws
through racket_rebound + predict_landing. Options of the other mode are refused. """

import argparse
import collections
import csv
import gzip
import json
import os
import pathlib
import re
import sys
import time

import numpy as np
from tt_prediction.ball import load_model
from tt_prediction.cli import hit_plane_error
from tt_prediction.predict import DEFAULT_HIT_PLANE_X

from .cli import range_error
from .hitpoint import choose
from .incoming import hit_point
from .robust import monte_carlo_in_zone, noise_covariance
from .solver import NET_CLEARANCE_RANGE, StrikeSettings, solve
from .workspace import load_workspace

DEFAULT_DATA = pathlib.Path(__file__).resolve().parents[3] / 'data' / 'deepmind_states'
FULL_SET = 'states_all.csv.gz'
"""The full set (gzip); ``states.csv`` beside it is the 100-state sample."""


def load_states(path):
    """States (n, 9) and serve flags (n,) from states.csv (or .csv.gz), turned to move
    towards the robot."""
    states, serve = [], []
    opener = gzip.open if str(path).endswith('.gz') else open
    with opener(path, 'rt', newline='') as f:
        for row in csv.DictReader(f):
            states.append([float(row[k]) for k in
                           ('x', 'y', 'z', 'vx', 'vy', 'vz', 'wx', 'wy', 'wz')])
            serve.append(row['set'] == 'serve')
    states = np.array(states)
    away = states[:, 3] > 0.0
    states[np.ix_(away, [0, 1, 3, 4, 6, 7])] *= -1.0      # half a turn about z
    return states, np.array(serve), away


def hit_states(states, serve, params, hit_plane_x=DEFAULT_HIT_PLANE_X):
    """The incoming balls at the hitting plane x = hit_plane_x (m): their hit states (9,)
    (p, v, w) and a Counter of the others by prediction status."""
    skipped = collections.Counter()
    hits = []
    for s, is_serve in zip(states, serve, strict=True):
        pred = hit_point(s, params, hit_plane_x=hit_plane_x, serve=bool(is_serve))
        if pred.status != 'ok':
            skipped[pred.status] += 1
            continue
        hits.append(pred.hit.state)
    return hits, skipped


def _solution_columns(solutions, zone, times):
    """The table columns both evaluations share: of the feasible ``solutions`` for ``zone``,
    how many land in it and their residual (mm) and racket speed (m/s); the median of all
    solve ``times`` (s) in ms."""
    residuals = [sol.residual for sol in solutions]
    speeds = [float(np.linalg.norm(sol.racket_velocity)) for sol in solutions]
    in_zone = sum(sol.landing_zone == zone for sol in solutions)
    return {
        'in_zone': in_zone,
        'in_zone_share': in_zone / len(solutions) if solutions else float('nan'),
        'residual_median_mm': float(np.median(residuals) * 1e3) if residuals else None,
        'residual_max_mm': float(np.max(residuals) * 1e3) if residuals else None,
        'racket_speed_median': float(np.median(speeds)) if speeds else None,
        'solve_median_ms': float(np.median(times) * 1e3),
    }


def evaluate(states, serve, params, settings, hit_plane_x=DEFAULT_HIT_PLANE_X):
    """Per-zone counts: the table's rows and the skipped incoming balls by reason."""
    hits, skipped = hit_states(states, serve, params, hit_plane_x)
    rows = []
    for zone in range(1, 10):
        solutions, times = [], []
        reasons = collections.Counter()
        for h in hits:
            t = time.perf_counter()
            sol = solve(h, params, target_zone=zone, settings=settings)
            times.append(time.perf_counter() - t)
            if not sol.feasible:
                reasons[re.sub(r'-?\d+(\.\d+)?', '#', sol.reason)] += 1   # numbers out
                continue
            solutions.append(sol)
        n = len(hits)
        rows.append({
            'zone': zone, 'balls': n, 'feasible': len(solutions),
            'feasible_share': len(solutions) / n if n else float('nan'),
            **_solution_columns(solutions, zone, times),
            'infeasible_reasons': dict(reasons.most_common()),
        })
    return rows, dict(skipped), len(hits), hits


UNREACHABLE = ('no_hit_point', 'unreachable', 'too_late')


def evaluate_reach(states, serve, params, settings, workspace, strokes=None):
    """Per-zone counts with the hit point chosen along the path inside ``workspace``.

    Returns rows (one per zone: balls, reachable, feasible, feasible share of the reachable,
    in zone, statuses, reasons, solve times). ``strokes``: a list that receives every
    feasible stroke as a dict (zone, hit state, normal, racket velocity)."""
    rows = []
    for zone in range(1, 10):
        statuses, reasons = collections.Counter(), collections.Counter()
        solutions, times, cpu = [], [], []
        for k, (s, is_serve) in enumerate(zip(states, serve, strict=True)):
            t, c = time.perf_counter(), time.thread_time()
            plan = choose(s, params, workspace, target_zone=zone, settings=settings,
                          serve=bool(is_serve))
            times.append(time.perf_counter() - t)
            cpu.append(time.thread_time() - c)
            statuses[plan.status] += 1
            if not plan.feasible:
                if plan.status not in UNREACHABLE:
                    reasons[re.sub(r'-?\d+(\.\d+)?', '#', plan.reason)] += 1
                continue
            sol = plan.solution
            solutions.append(sol)
            if strokes is not None:
                strokes.append({'ball': k, 'zone': zone, 'hit': plan.hit.state.tolist(),
                                'normal': sol.normal.tolist(),
                                'racket_velocity': sol.racket_velocity.tolist(),
                                'landing': sol.landing.tolist()})
        n = len(states)
        reachable = n - sum(statuses[k] for k in UNREACHABLE)
        rows.append({
            'zone': zone, 'balls': n, 'reachable': reachable, 'feasible': len(solutions),
            'feasible_share': len(solutions) / reachable if reachable else float('nan'),
            **_solution_columns(solutions, zone, times),
            'solve_cpu_median_ms': float(np.median(cpu) * 1e3),
            'statuses': dict(statuses.most_common()),
            'infeasible_reasons': dict(reasons.most_common()),
        })
    return rows


def markdown_reach(rows):
    lines = ['| zone | balls | reachable | feasible | feasible share of reachable | '
             'in zone (of feasible) | racket speed median, m/s |',
             '|---|---|---|---|---|---|---|']
    for r in rows:
        spd = '-' if r['racket_speed_median'] is None else f"{r['racket_speed_median']:.2f}"
        lines.append(f"| {r['zone']} | {r['balls']} | {r['reachable']} | {r['feasible']} | "
                     f"{100 * r['feasible_share']:.2f} % | {100 * r['in_zone_share']:.2f} % | "
                     f'{spd} |')
    return '\n'.join(lines)


def monte_carlo_check(hits, params, settings, n_draws=2000, seed=0):
    """Solver's in-zone probability against Monte Carlo for each ball and zone 1..9."""
    rng = np.random.default_rng(seed)
    pairs = []
    for h in hits:
        cov = noise_covariance(h, 0.002, 0.02, 0.10)
        for zone in range(1, 10):
            sol = solve(h, params, target_zone=zone, settings=settings, covariance=cov)
            if not sol.feasible:
                continue
            share, _ = monte_carlo_in_zone(h, cov, sol.normal, sol.racket_velocity, params,
                                           zone, n_draws, rng)
            pairs.append((sol.in_zone_probability, share))
    diff = np.array([abs(a - b) for a, b in pairs])
    return {'cases': len(pairs), 'draws': n_draws,
            'abs_diff_pp_max': float(diff.max() * 100),
            'abs_diff_pp_mean': float(diff.mean() * 100),
            'probability_min': float(min(b for _, b in pairs)),
            'probability_mean': float(np.mean([b for _, b in pairs]))}


def markdown(rows):
    lines = ['| zone | balls | feasible | feasible share | in zone (of feasible) | '
             'residual median / max, mm | racket speed median, m/s |',
             '|---|---|---|---|---|---|---|']
    for r in rows:
        res = ('-' if r['residual_max_mm'] is None else
               f"{r['residual_median_mm']:.3f} / {r['residual_max_mm']:.3f}")
        spd = '-' if r['racket_speed_median'] is None else f"{r['racket_speed_median']:.2f}"
        lines.append(f"| {r['zone']} | {r['balls']} | {r['feasible']} | "
                     f"{100 * r['feasible_share']:.2f} % | {100 * r['in_zone_share']:.2f} % | "
                     f'{res} | {spd} |')
    return '\n'.join(lines)


def output_error(option, path):
    """Why ``path`` cannot be written as the output file of ``option``, or '' (also for None,
    an option not given). The files are written at the end of a run of minutes: checked up
    front instead of found out then."""
    if not path:
        return ''
    if os.path.isdir(path):
        return f'{option} {path}: a folder, not a file'
    parent = os.path.dirname(path) or '.'
    if not os.path.isdir(parent):
        return f'{option} {path}: no folder {parent}'
    if not os.access(parent, os.W_OK | os.X_OK) or (
            os.path.exists(path) and not os.access(path, os.W_OK)):
        return f'{option} {path}: not writable'
    return ''


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m tt_strike.evaluate_deepmind',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--data', default=str(DEFAULT_DATA), help='deepmind_states folder')
    parser.add_argument('--model', default=None, help='model.yaml (default: nominal model)')
    parser.add_argument('--workspace', default=None,
                        help='workspace YAML (default: the template config/workspace.yaml)')
    parser.add_argument('--hit-plane-x', type=float, default=None,
                        help=f'old behaviour: hit at the plane x = X (e.g. {DEFAULT_HIT_PLANE_X})')
    parser.add_argument('--net-clearance', type=float, default=StrikeSettings.net_clearance,
                        metavar='M', help='gap between ball and net top at x = 0 the strokes '
                        'aim for, m (default: %(default)s)')
    parser.add_argument('--limit', type=int, default=0, help='use every k-th state only '
                        'so that about this many remain (0: all)')
    parser.add_argument('--json', default=None, help='write the numbers to this file')
    parser.add_argument('--strokes', default=None,
                        help='write the feasible strokes to this file (JSON Lines)')
    parser.add_argument('--monte-carlo', type=int, default=0, metavar='K',
                        help='check the in-zone probability on K balls (every zone)')
    args = parser.parse_args(argv)
    plane = args.hit_plane_x is not None
    if plane and (args.workspace or args.strokes):
        parser.error('--workspace and --strokes choose the hit point in the workspace: not '
                     'with --hit-plane-x')
    if not plane and args.monte_carlo:
        parser.error('--monte-carlo checks the strokes at the plane: it needs --hit-plane-x')
    errors = [hit_plane_error(args.hit_plane_x) if plane else '',
              range_error('--net-clearance', args.net_clearance, NET_CLEARANCE_RANGE,
                          'm'),                                         # as tt-strike
              '--limit must be 0 (all states) or more' if args.limit < 0 else '',
              '--monte-carlo must be 0 (none) or more' if args.monte_carlo < 0 else '']
    errors += [output_error(name, value) for name, value in
               (('--json', args.json), ('--strokes', args.strokes))]
    for error in filter(None, errors):
        print(f'tt_strike.evaluate_deepmind: {error}', file=sys.stderr)
        return 2
    folder = pathlib.Path(args.data)
    path = folder / FULL_SET if (folder / FULL_SET).is_file() else folder / 'states.csv'
    if not path.is_file():
        print(f'tt_strike.evaluate_deepmind: no states.csv in {args.data}', file=sys.stderr)
        return 2
    try:
        params = load_model(args.model)
        workspace = None if args.hit_plane_x is not None else load_workspace(args.workspace)
    except ValueError as exc:
        print(f'tt_strike.evaluate_deepmind: {exc}', file=sys.stderr)
        return 2
    states, serve, away = load_states(path)
    if args.limit:
        step = max(1, len(states) // args.limit)
        states, serve, away = states[::step], serve[::step], away[::step]
    settings = StrikeSettings(net_clearance=args.net_clearance)
    start = time.perf_counter()
    result = {'data': path.name, 'states': len(states), 'turned_half_a_turn': int(away.sum()),
              'net_clearance': args.net_clearance}
    if workspace is None:
        rows, skipped, n_hits, hits = evaluate(states, serve, params, settings,
                                               args.hit_plane_x)
        result.update({'with_hit_point': n_hits, 'skipped': skipped, 'zones': rows,
                       'hit_plane_x': args.hit_plane_x})
        print(f'{len(states)} states ({int(away.sum())} turned half a turn), {n_hits} reach '
              f'the hitting plane x = {args.hit_plane_x}; skipped: {skipped}')
        print(markdown(rows))
    else:
        strokes = [] if args.strokes else None
        rows = evaluate_reach(states, serve, params, settings, workspace, strokes)
        result.update({'workspace': args.workspace or 'template config/workspace.yaml',
                       'workspace_reach': workspace.describe(), 'zones': rows})
        print(f'{len(states)} states ({int(away.sum())} turned half a turn), hit point along '
              f'the path inside {workspace.describe()}')
        print(markdown_reach(rows))
        if strokes is not None:
            pathlib.Path(args.strokes).write_text(
                ''.join(json.dumps(s) + '\n' for s in strokes))
    result['seconds'] = time.perf_counter() - start
    for r in rows:
        if r['infeasible_reasons']:
            print(f"zone {r['zone']} infeasible: {r['infeasible_reasons']}")
    if args.monte_carlo and workspace is None:
        step = max(1, len(hits) // args.monte_carlo)
        result['monte_carlo'] = monte_carlo_check(hits[::step][:args.monte_carlo], params,
                                                  settings)
        print(f"in-zone probability vs Monte Carlo: {result['monte_carlo']}")
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
