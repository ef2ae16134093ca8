"""Rewrite the ROS wheels' stale CMake include paths to this venv's own (idempotent).

The Jazzy wheels on PyPI were built in manylinux containers; their exported CMake targets name
``/opt/python/cpXY-cpXY/include/pythonX.Y`` and that interpreter's numpy include directory.
CMake refuses targets whose include directories do not exist, so building a message package
against them fails until the paths point at this interpreter's headers and numpy. Paths of
any other interpreter are rewritten too (an installer's cache may carry another venv's).
Written by hand: no installable tool does this rewrite.
"""

import os
import pathlib
import re
import sys
import sysconfig

import numpy


def main(venv):
    python_include = sysconfig.get_paths()['include']
    numpy_include = numpy.get_include()
    # Any other interpreter's numpy or Python headers: the wheels' build machine
    # (/opt/python/cpXY-cpXY/...) or, where an installer shares files between venvs through
    # its cache, another venv's.
    stale_numpy = re.compile(r'/[^;"\s]*/site-packages/numpy/(?:_core|core)/include')
    stale_python = re.compile(r'/[^;"\s]*/include/python\d+\.\d+')
    changed = 0
    for path in pathlib.Path(venv, 'share').rglob('*.cmake'):
        text = path.read_text()
        if '/include/python' not in text and '/numpy/' not in text:
            continue
        new = stale_numpy.sub(lambda m: numpy_include, text)
        new = stale_python.sub(lambda m: python_include, new)
        if new != text:
            # A new file, not an edit in place: the old one may be a hard link into an
            # installer's cache that other venvs share.
            tmp = path.with_name(path.name + '.tt-tmp')
            tmp.write_text(new)
            os.replace(tmp, path)
            changed += 1
    print(f'tt-setup: rewrote stale include paths in {changed} CMake files', file=sys.stderr)


if __name__ == '__main__':
    main(sys.argv[1])
