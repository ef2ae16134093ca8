"""Run every benchmark (bench/bench_*.py) and write one JSON per benchmark plus a summary.

Each bench module defines ``run() -> dict``: measured numbers, the targets they are held to,
and ``passed``. Speed targets are checked here, as ratios to a reference measured in the same
run where the issue asks for one, never in timed unit tests.
Usage: python bench/run_all.py --out bench/results [--only NAME ...]
"""

import argparse
import importlib.util
import json
import pathlib
import platform
import sys
import time
import traceback


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', default='bench/results', help='folder for the JSON files')
    here = pathlib.Path(__file__).parent
    names = [p.stem[len('bench_'):] for p in sorted(here.glob('bench_*.py'))]
    parser.add_argument('--only', nargs='+', metavar='NAME',
                        help=f'bench names to run (of {", ".join(names)})')
    args = parser.parse_args(argv)
    unknown = sorted(set(args.only or ()) - set(names))
    if unknown:
        parser.error(f'--only: no bench {", ".join(unknown)} (there are {", ".join(names)})')
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    summary = {'machine': platform.platform(), 'python': sys.version.split()[0], 'benches': {}}
    ok = True
    for name in names:
        path = here / f'bench_{name}.py'
        if args.only and name not in args.only:
            continue
        print(f'bench {name} ...', flush=True)
        start = time.perf_counter()
        try:
            spec = importlib.util.spec_from_file_location(path.stem, path)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            result = module.run()
        except Exception:  # noqa: BLE001 - a broken bench is reported, the others still run
            result = {'passed': False, 'error': traceback.format_exc()}
        result['wall_s'] = round(time.perf_counter() - start, 2)
        (out / f'{name}.json').write_text(json.dumps(result, indent=2))
        summary['benches'][name] = {'passed': bool(result.get('passed')),
                                    'wall_s': result['wall_s']}
        ok &= bool(result.get('passed'))
        print(f'bench {name}: {"PASS" if result.get("passed") else "FAIL"} '
              f'({result["wall_s"]} s) -> {out / (name + ".json")}', flush=True)
    (out / 'summary.json').write_text(json.dumps(summary, indent=2))
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
