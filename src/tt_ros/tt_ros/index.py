"""The ament index without ament_index_python: where a package is installed."""

import os


def prefixes(ament_prefix_path=None):
    """The install prefixes of the search path, in order.

    ``ament_prefix_path``: the search path (default: ``$AMENT_PREFIX_PATH``), ``os.pathsep``
    separated; empty entries are left out.
    """
    search = os.environ.get('AMENT_PREFIX_PATH', '') if ament_prefix_path is None else (
        ament_prefix_path)
    return [prefix for prefix in search.split(os.pathsep) if prefix]


def _package_index(prefix):
    """The directory of ``prefix`` holding one marker file per package it installs."""
    return os.path.join(prefix, 'share', 'ament_index', 'resource_index', 'packages')


def package_prefix(package, ament_prefix_path=None):
    """The install prefix holding ``package`` in the ament index, or None when unknown.

    The first prefix (:func:`prefixes`) registering the package wins, as in
    ament_index_python.
    """
    for prefix in prefixes(ament_prefix_path):
        if os.path.isfile(os.path.join(_package_index(prefix), package)):
            return prefix
    return None


def packages(ament_prefix_path=None):
    """Sorted names of the packages in the ament index (every prefix of the search path)."""
    names = set()
    for prefix in prefixes(ament_prefix_path):
        index = _package_index(prefix)
        if os.path.isdir(index):
            names.update(os.listdir(index))
    return sorted(names)


def interface_file(pkg, kind, name, ament_prefix_path=None):
    """Where ``pkg`` installs the definition of ``pkg/kind/name`` (kind 'msg', 'srv' or
    'action'): ``<prefix>/share/<pkg>/<kind>/<name>.<kind>``, which may not exist; None when
    ``pkg`` is not in the index."""
    prefix = package_prefix(pkg, ament_prefix_path)
    if prefix is None:
        return None
    return os.path.join(prefix, 'share', pkg, kind, f'{name}.{kind}')


def interfaces(ament_prefix_path=None):
    """Sorted ``'pkg/kind/Name'`` of every interface (kind 'msg', 'srv' or 'action') the
    ament index registers (``rosidl_interfaces`` resources: one ``kind/Name.idl`` or
    ``.msg`` ... line per file); the first prefix registering a package wins."""
    found, seen = set(), set()
    for prefix in prefixes(ament_prefix_path):
        index = os.path.join(prefix, 'share', 'ament_index', 'resource_index',
                             'rosidl_interfaces')
        if not os.path.isdir(index):
            continue
        for pkg in sorted(os.listdir(index)):
            if pkg in seen:
                continue
            seen.add(pkg)
            with open(os.path.join(index, pkg), encoding='utf-8') as f:
                for line in f.read().split('\n'):
                    kind, _, name = line.strip().partition('/')
                    stem, dot, _ = name.rpartition('.')
                    if kind in ('msg', 'srv', 'action') and dot and stem:
                        found.add(f'{pkg}/{kind}/{stem}')
    return sorted(found)
