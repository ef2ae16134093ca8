"""Replay strokes through the independent reference (body_reference.py) and judge them.

    python src/tt_strike/test/judge_strokes.py STROKES.jsonl [--every K] [--low-all]
        [--json FILE]

STROKES.jsonl: one feasible stroke a line, as ``python -m tt_strike.evaluate_deepmind
--strokes`` writes them: {"ball", "zone", "hit": [9], "normal": [3], "racket_velocity": [3],
"landing": [3]}. Each (every K-th with --every) is replayed with eq. 7 in a racket frame and
the flight with solve_ivp, the table and net as bodies; it counts when the first contact is
the top of the opponent's half inside its zone. ``--low-all``: every stroke struck below
the contact height z = r (those that must clear the table's edge) besides every K-th of the
others. Prints and writes the share (the issue's
done-when: at least 99.5 %) and the misses. Tests only: no part of tt imports this.
"""

import argparse
import collections
import json
import pathlib
import sys
import time

from body_reference import replay_stroke
import numpy as np

LOW = 0.02
"""Hit points whose ball centre is below this (the contact height z = r), m."""


def judge(strokes):
    """Share of strokes landing in their zone by the reference, with the misses."""
    ok, misses, kinds, distance = 0, [], collections.Counter(), []
    for s in strokes:
        zone, contact = replay_stroke(s['hit'], s['normal'], s['racket_velocity'])
        kinds[contact['kind']] += 1
        if contact['kind'] == 'top':
            distance.append(float(np.hypot(*(np.array(contact['p'][:2])
                                              - np.array(s['landing'][:2])))))
        if zone == s['zone']:
            ok += 1
        else:
            misses.append({'ball': s['ball'], 'zone': s['zone'], 'reference_zone': zone,
                           'kind': contact['kind'],
                           'p': None if contact['p'] is None else list(contact['p']),
                           'hit_z': s['hit'][2]})
    n = len(strokes)
    return {'strokes': n, 'in_zone': ok, 'share': ok / n if n else float('nan'),
            'first_contacts': dict(kinds),
            'landing_distance_to_tt_median_mm': float(np.median(distance) * 1e3)
            if distance else None,
            'landing_distance_to_tt_max_mm': float(np.max(distance) * 1e3)
            if distance else None,
            'misses': misses}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('strokes')
    parser.add_argument('--every', type=int, default=1)
    parser.add_argument('--low-all', action='store_true')
    parser.add_argument('--json', default=None)
    args = parser.parse_args(argv)
    lines = pathlib.Path(args.strokes).read_text().splitlines()
    every = [json.loads(x) for x in lines]
    low = [s for s in every if args.low_all and s['hit'][2] < LOW]
    strokes = low + [s for s in every if not (args.low_all and s['hit'][2] < LOW)][::args.every]
    start = time.perf_counter()
    result = judge(strokes)
    result.update({'every': args.every, 'of_strokes': len(lines), 'low_all': len(low),
                   'low_in_zone': sum(1 for s in low if not any(
                       m['ball'] == s['ball'] and m['zone'] == s['zone']
                       for m in result['misses'])),
                   'seconds': time.perf_counter() - start})
    print(json.dumps({k: v for k, v in result.items() if k != 'misses'}, indent=1))
    print(f'misses: {result["misses"][:10]}')
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
