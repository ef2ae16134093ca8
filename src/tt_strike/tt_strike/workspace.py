"""The robot's reach: where the racket centre can be at the hit, how fast, how soon.

Pure module (no rclpy). A workspace file (YAML, see config/workspace.yaml for a typical arm)
gives, in the table frame (MODEL.md), SI units:

    workspace:
      shape: box                     # or cylinder
      box: {x: [x_min, x_max], y: [y_min, y_max], z: [z_min, z_max]}         # m
      cylinder: {centre: [x, y], radius: r, z: [z_min, z_max]}               # m (shape cylinder)
      max_racket_speed: 8.0          # m/s at impact
      min_time_before_hit: 0.15      # s: the arm needs at least this long to get there

A bad file (missing or unknown key, a size that is not positive, min not below max, NaN, a
wrong type, a length beyond the room's 10 m (millimetres), a speed outside strike_node's
max_racket_speed range, a time above 2 s (milliseconds)) raises :class:`WorkspaceError`
with one line naming the key.
"""

import dataclasses
import math
import pathlib

import numpy as np
from tt_prediction.units import ROOM_HALF_EXTENT_M
from tt_ros.errors import one_line_reason
from tt_ros.index import package_prefix
from tt_ros.yamlfile import load_yaml
import yaml

from .solver import MAX_RACKET_SPEED_RANGE


def _template():
    """share/tt_strike/config/workspace.yaml of the installed package; the source tree's copy
    when the package is not in the ament index (tests run from the sources)."""
    prefix = package_prefix('tt_strike')
    installed = prefix and pathlib.Path(prefix, 'share', 'tt_strike', 'config', 'workspace.yaml')
    if installed and installed.is_file():
        return installed
    return pathlib.Path(__file__).resolve().parent.parent / 'config' / 'workspace.yaml'


TEMPLATE = _template()
"""The template workspace (the default of ``workspace_file``)."""


MIN_TIME_BEFORE_HIT_RANGE = (0.0, 2.0)
"""Allowed ``min_time_before_hit``, s: a ball crosses the table in under a second."""


class WorkspaceError(ValueError):
    """A bad workspace file; the message is one line naming the key."""


@dataclasses.dataclass(frozen=True)
class Workspace:
    """Reach of the racket centre at the hit, racket-speed limit, least time before the hit."""

    shape: str
    """'box' or 'cylinder'."""
    x: tuple = (math.nan, math.nan)
    """Box: x range of the racket centre, m (table frame)."""
    y: tuple = (math.nan, math.nan)
    """Box: y range, m."""
    z: tuple = (math.nan, math.nan)
    """Box and cylinder: z range, m."""
    centre: tuple = (math.nan, math.nan)
    """Cylinder: axis (x, y), m (vertical axis)."""
    radius: float = math.nan
    """Cylinder: radius, m."""
    max_racket_speed: float = 8.0
    """Largest racket speed at impact, m/s."""
    min_time_before_hit: float = 0.15
    """Least time between the decision and the hit that the arm needs, s."""

    def contains(self, p, margin=0.0):
        """True where the point(s) p (..., 3), m, are inside (grown by ``margin`` m)."""
        p = np.asarray(p, dtype=float)
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        inside_z = (z >= self.z[0] - margin) & (z <= self.z[1] + margin)
        if self.shape == 'box':
            return (inside_z & (x >= self.x[0] - margin) & (x <= self.x[1] + margin)
                    & (y >= self.y[0] - margin) & (y <= self.y[1] + margin))
        d = np.hypot(x - self.centre[0], y - self.centre[1])
        return inside_z & (d <= self.radius + margin)

    def slowed_to(self, max_racket_speed):
        """This workspace with the lower of its racket speed limit and ``max_racket_speed``
        (m/s; None: its own): a faster limit than the arm's is not the arm's."""
        if max_racket_speed is None or max_racket_speed >= self.max_racket_speed:
            return self
        return dataclasses.replace(self, max_racket_speed=max_racket_speed)

    def describe(self):
        """One line: the reach, for reasons."""
        if self.shape == 'box':
            return (f'box x [{self.x[0]:.2f}, {self.x[1]:.2f}], y [{self.y[0]:.2f}, '
                    f'{self.y[1]:.2f}], z [{self.z[0]:.2f}, {self.z[1]:.2f}] m')
        return (f'cylinder centre ({self.centre[0]:.2f}, {self.centre[1]:.2f}), radius '
                f'{self.radius:.2f}, z [{self.z[0]:.2f}, {self.z[1]:.2f}] m')

    def x_range(self):
        """(x_min, x_max) of the reach, m."""
        if self.shape == 'box':
            return self.x
        return (self.centre[0] - self.radius, self.centre[0] + self.radius)


def _get(mapping, key, path):
    if mapping is None and not path:
        raise WorkspaceError('empty')
    if not isinstance(mapping, dict):
        where = f"key '{path}'" if path else 'the top level'
        raise WorkspaceError(f'{where} must be a mapping')
    if key not in mapping:
        raise WorkspaceError(f"missing key '{path}.{key}'" if path else f"missing key '{key}'")
    return mapping[key]


def _known(mapping, known, path):
    """WorkspaceError naming the first key of ``mapping`` not in ``known``: a misspelt key
    would otherwise be ignored without a word; or naming ``path`` when ``mapping`` is none
    (an empty 'box:', its lines commented out, gave a traceback)."""
    if not isinstance(mapping, dict):
        raise WorkspaceError(f"key '{path}' must be a mapping of {', '.join(known)}")
    unknown = [str(k) for k in mapping if k not in known]
    if unknown:
        name = f'{path}.{unknown[0]}' if path else unknown[0]
        raise WorkspaceError(f"unknown key '{name}' (known: {', '.join(known)})")


_UNIT_HINTS = {'m': ' (metres, not millimetres?)', 's': ' (seconds, not milliseconds?)'}


def _number(value, key, positive=False, bounds=None, unit='m'):
    """The float of ``value`` (key ``key``); ``bounds``: (lo, hi) it must lie within, in
    ``unit`` (default: a length within the room)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise WorkspaceError(f"key '{key}' must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise WorkspaceError(f"key '{key}' is not a finite number: {value}")
    if positive and value <= 0.0:
        raise WorkspaceError(f"key '{key}' must be positive, got {value}")
    lo, hi = bounds or (-ROOM_HALF_EXTENT_M, ROOM_HALF_EXTENT_M)
    if not lo <= value <= hi:
        hint = _UNIT_HINTS.get(unit, '') if abs(value) > hi else ''   # a thousand times
        raise WorkspaceError(f"key '{key}' must be within [{lo:g}, {hi:g}] {unit}, got "
                             f'{value:g}{hint}')
    return value


def _pair(value, key, ordered=True):
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise WorkspaceError(f"key '{key}' must be two numbers [min, max], got {value!r}")
    lo, hi = (_number(v, key) for v in value)
    if ordered and not lo < hi:
        raise WorkspaceError(f"key '{key}' must have min below max (a positive size), "
                             f'got [{lo}, {hi}]')
    return lo, hi


def parse_workspace(data):
    """A :class:`Workspace` from the parsed YAML (a dict holding 'workspace')."""
    ws = _get(data, 'workspace', '')
    _known(data, ('workspace',), '')
    shape = _get(ws, 'shape', 'workspace')
    speed = _number(_get(ws, 'max_racket_speed', 'workspace'), 'workspace.max_racket_speed',
                    bounds=MAX_RACKET_SPEED_RANGE, unit='m/s')
    min_time = _number(_get(ws, 'min_time_before_hit', 'workspace'),
                       'workspace.min_time_before_hit', bounds=MIN_TIME_BEFORE_HIT_RANGE,
                       unit='s')
    # Both shapes' keys may stay in a file: 'shape' picks one.
    _known(ws, ('shape', 'box', 'cylinder', 'max_racket_speed', 'min_time_before_hit'),
           'workspace')
    if shape == 'box':
        box = _get(ws, 'box', 'workspace')
        _known(box, ('x', 'y', 'z'), 'workspace.box')
        return Workspace(
            'box', x=_pair(_get(box, 'x', 'workspace.box'), 'workspace.box.x'),
            y=_pair(_get(box, 'y', 'workspace.box'), 'workspace.box.y'),
            z=_pair(_get(box, 'z', 'workspace.box'), 'workspace.box.z'),
            max_racket_speed=speed, min_time_before_hit=min_time)
    if shape == 'cylinder':
        cyl = _get(ws, 'cylinder', 'workspace')
        _known(cyl, ('centre', 'radius', 'z'), 'workspace.cylinder')
        return Workspace(
            'cylinder',
            centre=_pair(_get(cyl, 'centre', 'workspace.cylinder'), 'workspace.cylinder.centre',
                         ordered=False),
            radius=_number(_get(cyl, 'radius', 'workspace.cylinder'),
                           'workspace.cylinder.radius', positive=True),
            z=_pair(_get(cyl, 'z', 'workspace.cylinder'), 'workspace.cylinder.z'),
            max_racket_speed=speed, min_time_before_hit=min_time)
    raise WorkspaceError(f"key 'workspace.shape' must be 'box' or 'cylinder', got {shape!r}")


def load_workspace(path=None):
    """Read a workspace file (None or '': the template). Raises WorkspaceError (one line,
    naming the file and the key) for a bad one."""
    path = pathlib.Path(path) if path else TEMPLATE
    try:
        text = path.read_text()
    except OSError as exc:
        raise WorkspaceError(f'{path}: cannot read: {exc.strerror}') from None
    try:
        data = load_yaml(text)
    except yaml.YAMLError as exc:
        raise WorkspaceError(f'{path}: not YAML: {one_line_reason(exc)}') from None
    try:
        return parse_workspace(data)
    except WorkspaceError as exc:
        raise WorkspaceError(f'{path}: {exc}') from None
