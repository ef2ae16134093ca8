"""The ament index without ament_index_python: where a package is installed."""

import os


def package_prefix(package, ament_prefix_path=None):
    """The install prefix holding ``package`` in the ament index, or None when unknown.

    ``ament_prefix_path``: the search path (default: ``$AMENT_PREFIX_PATH``), ``os.pathsep``
    separated; the first prefix registering the package wins, as in ament_index_python.
    """
    search = os.environ.get('AMENT_PREFIX_PATH', '') if ament_prefix_path is None else (
        ament_prefix_path)
    for prefix in filter(None, search.split(os.pathsep)):
        marker = os.path.join(prefix, 'share', 'ament_index', 'resource_index', 'packages',
                              package)
        if os.path.isfile(marker):
            return prefix
    return None
