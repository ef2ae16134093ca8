"""Rewrite the ROS wheels' stale CMake include paths to this venv's own (idempotent).

The Jazzy wheels on PyPI were built in manylinux containers; their exported CMake targets name
``/opt/python/cpXY-cpXY/include/pythonX.Y`` and that interpreter's numpy include directory.
CMake refuses targets whose include directories do not exist, so building a message package
against them fails until the paths point at this interpreter's headers and numpy.
Written by hand: no installable tool does this rewrite.
"""

import pathlib
import re
import sys
import sysconfig

import numpy


def main(venv):
    python_include = sysconfig.get_paths()['include']
    numpy_include = numpy.get_include()
    stale_numpy = re.compile(r'/opt/python/cp\d+-cp\d+/lib/python[\d.]+/site-packages/numpy/'
                             r'(?:_core|core)/include')
    stale_python = re.compile(r'/opt/python/cp\d+-cp\d+/include/python[\d.]+')
    changed = 0
    for path in pathlib.Path(venv, 'share').rglob('*.cmake'):
        text = path.read_text()
        if '/opt/python/' not in text:
            continue
        new = stale_numpy.sub(numpy_include, text)
        new = stale_python.sub(python_include, new)
        if new != text:
            path.write_text(new)
            changed += 1
    print(f'tt-setup: rewrote stale include paths in {changed} CMake files', file=sys.stderr)


if __name__ == '__main__':
    main(sys.argv[1])
