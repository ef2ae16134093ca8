"""``ros2 run <package> <executable> [args...]``: find it through the ament index, exec it."""

import os
import shlex
import shutil

from tt_ros.index import package_prefix


class RunError(Exception):
    """A package or executable that cannot be run (one-line message)."""


def _is_executable(path):
    return os.path.isfile(path) and os.access(path, os.X_OK)


def _libdir(package, ament_prefix_path):
    """``<prefix>/lib/<package>`` of an indexed package; RunError when the package is unknown."""
    prefix = package_prefix(package, ament_prefix_path)
    if prefix is None:
        raise RunError(f"Package '{package}' not found")
    return os.path.join(prefix, 'lib', package)


def executables(package, ament_prefix_path=None):
    """Sorted names of the executables installed in ``<prefix>/lib/<package>``."""
    libdir = _libdir(package, ament_prefix_path)
    if not os.path.isdir(libdir):
        return []
    return sorted(name for name in os.listdir(libdir)
                  if _is_executable(os.path.join(libdir, name)))


def find_executable(package, executable, ament_prefix_path=None):
    """Absolute path of ``executable`` of ``package``; RunError with a one-line reason."""
    path = os.path.join(_libdir(package, ament_prefix_path), executable)
    if os.path.basename(executable) != executable or not _is_executable(path):
        raise RunError(f"No executable '{executable}' found in package '{package}'")
    return path


def main(args):
    """Replace this process with the executable (signals then reach it directly)."""
    path = find_executable(args.package, args.executable)
    argv = [path, *args.argv]
    if args.prefix:
        try:
            argv = [*shlex.split(args.prefix), *argv]
        except ValueError as exc:                   # an unclosed quote
            raise RunError(f'--prefix {args.prefix!r}: {exc}') from None
        if not argv[0] or not shutil.which(argv[0]):
            raise RunError(f'--prefix {args.prefix!r}: no command {argv[0]!r} on PATH')
    os.execvp(argv[0], argv)
