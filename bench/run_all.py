"""Run every benchmark (bench/bench_*.py) and write one JSON per benchmark plus a summary.

Each bench module defines ``run() -> dict``: measured numbers, the targets they are held to,
and ``passed``. Speed targets are checked here, as ratios to a reference measured in the same
run where the issue asks for one, never in timed unit tests.
Usage: python bench/run_all.py --out bench/results [--only NAME ...]; one bench alone:
python bench/bench_NAME.py [--out DIR] (:func:`bench_main`).
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


def bench_main(path, run, argv=None, add_arguments=None):
    """The command line of one bench file, ``python bench/bench_NAME.py [--out DIR]``: runs
    ``run()``, prints its JSON, writes DIR/NAME.json with ``--out``; exit status 0 when the
    bench passed, 1 when not (``--help`` describes the bench without running it).
    ``add_arguments(parser)`` adds the bench's own options, passed to ``run`` by name."""
    path = pathlib.Path(path)
    name = path.stem[len('bench_'):]
    doc = (sys.modules['__main__'].__doc__ or '').strip()
    parser = argparse.ArgumentParser(
        prog=f'python bench/{path.name}', description=doc.split('\n\n')[0] or None,
        epilog='make bench runs every bench (bench/run_all.py)')
    parser.add_argument('--out', metavar='DIR',
                        help=f'also write the result to DIR/{name}.json')
    if add_arguments:
        add_arguments(parser)
    options = vars(parser.parse_args(argv))
    out = options.pop('out')
    result = run(**options)
    text = json.dumps(result, indent=2)
    print(text)
    if out:
        out = pathlib.Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / f'{name}.json').write_text(text)
    return 0 if result.get('passed') else 1


if __name__ == '__main__':
    sys.exit(main())
