"""Who may import the ball model's modules (issue 13, item 1), read from the source with ast.

- The ball model is params, model, integrate and table (and the flight kernel that
  predict.py holds). Every module but those imports it through ``tt_prediction.ball``: no
  ``tt_prediction.params`` (``.params``), ``.model``, ``.integrate`` or ``.table`` import,
  and a name ``ball`` exports is not taken from predict.py either. The prediction API
  (``predict``, ``predict_landing``, ``Hit``, ``uncertainty``) stays where it is.
- No module imports a private name (``_x``) of another package (test/, bench/ and scripts/
  belong to none).

tt_prediction's own tests (src/tt_prediction/test) may test the modules behind the interface.
"""

import ast
from pathlib import Path
import sys

from tt_prediction import ball

ROOT = Path(__file__).resolve().parents[3]
MODEL_MODULES = {f'tt_prediction.{m}' for m in ('params', 'model', 'integrate', 'table')}
# The ball model itself: these may import each other.
BEHIND_THE_INTERFACE = MODEL_MODULES | {'tt_prediction.predict', 'tt_prediction.ball'}
# The node glue, being rewritten in another branch (tt_ros): still `load_model` from params.
def _sources():
    """(path relative to ROOT, dotted module name or None, package name or None)."""
    for path in sorted((ROOT / 'src').glob('*/*/**/*.py')):
        rel = path.relative_to(ROOT)
        pkg_dir, inner = rel.parts[1], rel.parts[2]
        if inner == pkg_dir:        # the Python package itself: src/<pkg>/<pkg>/...
            dotted = '.'.join(rel.with_suffix('').parts[2:])
            yield rel, dotted.removesuffix('.__init__'), pkg_dir
        else:                       # the package's tests and tools
            yield rel, None, pkg_dir
    for top in ('test', 'bench', 'scripts'):
        for path in sorted((ROOT / top).glob('**/*.py')):
            yield path.relative_to(ROOT), None, None


def _imports(path, dotted):
    """(line, absolute module, [names]) of every import; names empty for `import x`."""
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, []
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ''
            if node.level:
                assert dotted, f'{path}:{node.lineno}: relative import outside a package'
                is_init = path.name == '__init__.py'
                base = dotted.split('.') if is_init else dotted.split('.')[:-1]
                base = base[:len(base) - node.level + 1]
                module = '.'.join(base + ([module] if module else []))
            yield node.lineno, module, [a.name for a in node.names]


def _violations():
    exported = set(ball.__all__)
    found = []
    for rel, dotted, pkg in _sources():
        if dotted in BEHIND_THE_INTERFACE or (pkg == 'tt_prediction' and dotted is None):
            continue        # the model itself, and its package's own tests of its parts
        for line, module, names in _imports(ROOT / rel, dotted):
            where = f'{rel}:{line}'
            targets = [module] + [f'{module}.{n}' for n in names]
            if any(t in MODEL_MODULES for t in targets):
                found.append(f'{where}: imports {module} {names} (use tt_prediction.ball)')
            if module == 'tt_prediction.predict' and exported & set(names):
                found.append(f'{where}: takes {sorted(exported & set(names))} from predict '
                             '(use tt_prediction.ball)')
            other = module.split('.')[0] != pkg
            private = [n for n in names if n.startswith('_') and not n.startswith('__')]
            if module.startswith('tt_') and other and private:
                found.append(f'{where}: imports private {private} of {module}')
    return found


def test_only_the_ball_interface_is_imported_and_no_private_name_of_another_package():
    assert _violations() == []


def test_the_check_sees_a_model_module_import_and_a_private_import(tmp_path, monkeypatch):
    # The check itself: a module written the forbidden ways is reported, line by line.
    src = tmp_path / 'src' / 'tt_strike' / 'tt_strike'
    src.mkdir(parents=True)
    (src / 'bad.py').write_text('from tt_prediction.params import ModelParams\n'
                                'from tt_prediction import table\n'
                                'from tt_prediction.predict import solid_gap, predict\n'
                                'from tt_prediction.identify.data import _read_index\n'
                                'from tt_prediction.ball import rollout\n'
                                'from ._own import _fine\n')
    monkeypatch.setattr(sys.modules[__name__], 'ROOT', tmp_path)
    found = _violations()
    assert [f.split(':')[1] for f in found] == ['1', '2', '3', '4'], found
