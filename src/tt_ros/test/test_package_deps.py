"""The tt packages declare what they import, in package.xml and setup.py, without a cycle.

Every import (at module level or inside a function) in a package's modules of anything but
the standard library, the package itself and its tests' own helper modules must be an
``exec_depend`` (or ``depend``) of its package.xml, its tests' also a ``test_depend``: a tt or
other ROS package by its name, a third-party Python package by its rosdep key
(:data:`ROSDEP_KEYS`), or, for one without a key (:data:`PYPI_ONLY`), named in a comment of the
package.xml that says it comes from PyPI (``ros2 pkg xml`` and rosdep are what a ROS user
reads; numba, imported by the ball model, was named by none: a walk-through, 6 Dec 2026).
The Python packages among them are in setup.py's ``install_requires``, and the declared
graph has no cycle (colcon builds it in an order, and no package needs itself through
another).
"""

import ast
import pathlib
import re
import sys
import xml.etree.ElementTree as ET

import pytest

SRC = pathlib.Path(__file__).resolve().parents[2]


ROSDEP_KEYS = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'cv2': 'python3-opencv',
               'yaml': 'python3-yaml', 'ruamel': 'python3-ruamel.yaml',
               'numba': 'python3-numba', 'matplotlib': 'python3-matplotlib',
               'tqdm': 'python3-tqdm', 'pytest': 'python3-pytest'}
"""The rosdep keys of the third-party Python packages the tt packages import, by import name."""
PYPI_ONLY = ('rosbags', 'mcap')
"""Third-party Python packages without a rosdep key (requirements.txt installs them)."""


def package_deps(package_xml):
    """(run-time deps, test deps) named in a package.xml; a package of :data:`PYPI_ONLY`
    named in a comment that says it comes from PyPI counts as a run-time dependency."""
    root = ET.parse(package_xml).getroot()
    run = {e.text.strip() for tag in ('depend', 'exec_depend', 'build_depend')
           for e in root.iter(tag)}
    test = {e.text.strip() for e in root.iter('test_depend')}
    comments = ' '.join(c for c in re.findall(r'<!--(.*?)-->', package_xml.read_text(), re.S)
                        if 'PyPI' in c)
    run |= {name for name in PYPI_ONLY if re.search(rf'\b{name}\b', comments)}
    return run, test


def dependency_key(name):
    """What a package.xml names for the imported top-level ``name``: its rosdep key, or the
    name itself (a ROS package, or one of :data:`PYPI_ONLY` in a comment)."""
    return ROSDEP_KEYS.get(name, name)


def setup_requires(setup_py):
    """The strings of ``install_requires`` in a setup.py (read, not run)."""
    for node in ast.walk(ast.parse(setup_py.read_text())):
        if isinstance(node, ast.keyword) and node.arg == 'install_requires':
            return {ast.literal_eval(e) for e in node.value.elts}
    return set()


def imported_packages(paths):
    """Top-level names imported anywhere in the Python files ``paths``."""
    names = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names.update(alias.name.split('.')[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split('.')[0])
    return names


def find_cycle(graph):
    """A dependency cycle of ``graph`` (name -> set of names) as a list, or None."""
    state = {}

    def visit(name, trail):
        state[name] = 'open'
        for dep in sorted(graph.get(name, ())):
            if state.get(dep) == 'open':
                return trail[trail.index(dep):] + [dep] if dep in trail else [name, dep]
            if dep not in state:
                found = visit(dep, trail + [dep])
                if found:
                    return found
        state[name] = 'done'
        return None

    for name in sorted(graph):
        if name not in state:
            found = visit(name, [name])
            if found:
                return found
    return None


def check_workspace(src, prefix='tt_'):
    """Problems (one line each) of the packages under ``src`` whose names start with
    ``prefix``: undeclared imports, setup.py out of step with package.xml, a cycle."""
    packages = {p.parent.name: p.parent for p in sorted(src.glob('*/package.xml'))
                if p.parent.name.startswith(prefix)}
    problems, graph = [], {}
    for name, pkg in packages.items():
        run, test = package_deps(pkg / 'package.xml')
        own = {d for d in run if d in packages}
        graph[name] = own
        modules = sorted((pkg / name).rglob('*.py')) if (pkg / name).is_dir() else []
        tests = sorted((pkg / 'test').rglob('*.py')) if (pkg / 'test').is_dir() else []
        local = {name, *sys.stdlib_module_names, *(path.stem for path in tests)}
        for dep in sorted(imported_packages(modules) - local):
            if dependency_key(dep) not in run:
                problems.append(f'{name} imports {dep} without declaring '
                                f'{dependency_key(dep)} in package.xml')
        for dep in sorted(imported_packages(tests) - local):
            if dependency_key(dep) not in run | test:
                problems.append(f'{name} tests import {dep}, not in package.xml')
        if (pkg / 'setup.py').exists():
            python_deps = {d for d in own if (packages[d] / 'setup.py').exists()}
            required = {r for r in setup_requires(pkg / 'setup.py') if r in packages}
            if required != python_deps:
                problems.append(f'{name}: setup.py install_requires {sorted(required)} but '
                                f'package.xml names {sorted(python_deps)}')
    cycle = find_cycle(graph)
    if cycle:
        problems.append('dependency cycle: ' + ' -> '.join(cycle))
    return problems


def test_the_tt_packages_declare_their_imports_without_a_cycle():
    assert check_workspace(SRC) == []


def _package(src, name, deps=(), imports=(), setup_deps=None):
    pkg = src / name
    (pkg / name).mkdir(parents=True)
    xml = ''.join(f'<exec_depend>{d}</exec_depend>' for d in deps)
    (pkg / 'package.xml').write_text(f'<package format="3"><name>{name}</name>{xml}</package>')
    (pkg / name / '__init__.py').write_text(
        ''.join(f'def f{k}():\n    import {m}.sub\n' for k, m in enumerate(imports)))
    req = list(deps if setup_deps is None else setup_deps)
    (pkg / 'setup.py').write_text(f'setup(install_requires={["setuptools", *req]!r})\n')


def test_check_finds_an_undeclared_import_inside_a_function(tmp_path):
    _package(tmp_path, 'tt_a')
    _package(tmp_path, 'tt_b', imports=['tt_a'])
    assert check_workspace(tmp_path) == [
        'tt_b imports tt_a without declaring tt_a in package.xml']


def test_check_finds_an_undeclared_message_package(tmp_path):
    # tt_tools imported sensor_msgs, rosgraph_msgs and diagnostic_msgs at run time, two of
    # them declared for its tests only (a new user's walk-through, 6 Dec 2026).
    _package(tmp_path, 'tt_a', deps=['rclpy'], imports=['rclpy', 'sensor_msgs'])
    assert check_workspace(tmp_path) == [
        'tt_a imports sensor_msgs without declaring sensor_msgs in package.xml']


def test_check_finds_an_undeclared_python_package_by_its_rosdep_key(tmp_path):
    # numba, imported by the ball model, was declared by no package; rosbags has no rosdep
    # key and is named in a comment instead; the standard library needs nothing.
    _package(tmp_path, 'tt_a', deps=['python3-numpy'],
             imports=['numpy', 'numba', 'rosbags', 'mcap', 'json'])
    xml = tmp_path / 'tt_a' / 'package.xml'
    xml.write_text(xml.read_text().replace(
        '</package>', '<!-- rosbags: no rosdep key, it comes from PyPI --></package>'))
    assert check_workspace(tmp_path) == [
        'tt_a imports mcap without declaring mcap in package.xml',
        'tt_a imports numba without declaring python3-numba in package.xml']


def test_check_finds_a_cycle_through_three_packages(tmp_path):
    _package(tmp_path, 'tt_a', deps=['tt_c'])
    _package(tmp_path, 'tt_b', deps=['tt_a'])
    _package(tmp_path, 'tt_c', deps=['tt_b'])
    problems = check_workspace(tmp_path)
    assert len(problems) == 1 and problems[0].startswith('dependency cycle: ')
    names = problems[0].removeprefix('dependency cycle: ').split(' -> ')
    assert names[0] == names[-1] and set(names) == {'tt_a', 'tt_b', 'tt_c'}


def test_check_finds_setup_py_out_of_step_with_package_xml(tmp_path):
    _package(tmp_path, 'tt_a')
    _package(tmp_path, 'tt_b', deps=['tt_a'], imports=['tt_a'], setup_deps=[])
    assert check_workspace(tmp_path) == [
        "tt_b: setup.py install_requires [] but package.xml names ['tt_a']"]


@pytest.mark.parametrize('graph, cycle', [
    ({'a': {'b'}, 'b': set()}, None),
    ({'a': {'a'}}, ['a', 'a']),
    ({'a': {'b', 'c'}, 'b': {'c'}, 'c': set()}, None),
])
def test_find_cycle(graph, cycle):
    assert find_cycle(graph) == cycle
