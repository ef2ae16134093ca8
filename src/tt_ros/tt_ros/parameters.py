"""One way for every tt node to declare, validate and apply its ROS parameters (ROS glue).

A node lists its parameters as :class:`Param` (name, default, description, unit, range or
choices) and builds a :class:`Parameters` from them. That

- declares each parameter with a descriptor that ``ros2 param describe`` shows: the
  description with its unit and range, the range itself, read-only where the node reads the
  value only at start-up;
- accepts an integer where a float is expected (``-p stale_after_s:=0``, ``ros2 param set
  /prediction_node stale_after_s 0``, ``max_racket_speed: 10`` in a YAML file) and stores it
  as a float, so the parameter keeps its type;
- refuses an out-of-range or wrong-typed value with one line naming the parameter and what it
  accepts: at start-up by raising :class:`ParameterError` (the node exits 2 with that line,
  see :func:`tt_ros.executor.run_node`), at run time by refusing the set (the node keeps the
  old value and logs the line) -- the node's own cross-parameter ``check`` included;
- keeps the current values in :attr:`Parameters.values` (read in callbacks without a
  ``get_parameter`` call) and calls the node's ``apply`` after a set succeeded.

Validation itself (:func:`coerce`) is pure; only :class:`Parameters` touches rclpy.
"""

from dataclasses import dataclass
import math
import sys

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.parameter import Parameter

from .executor import StartupError, shared_parameter_names


class ParameterError(StartupError):
    """A parameter value that is refused: one line naming the parameter and what it accepts."""


def _kind_of(default):
    if isinstance(default, bool):
        return 'bool'
    if isinstance(default, int):
        return 'int'
    if isinstance(default, float):
        return 'float'
    if isinstance(default, str):
        return 'str'
    if isinstance(default, (list, tuple)) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in default):
        return 'floats'
    raise TypeError(f'no parameter kind for the default {default!r}')


def _num(v):
    return f'{v:g}' if isinstance(v, float) else str(v)


@dataclass(frozen=True)
class Param:
    """One node parameter.

    Parameters
    ----------
    name : str
        Parameter name.
    default : bool, int, float, str or list of float
        Default value; its type is the parameter's kind (a list: a list of floats).
    description : str
        What the parameter does (one sentence, no unit: ``unit`` says it).
    unit : str
        Unit of the value (SI: 'm', 's', 'Hz', ...), '' for none.
    lo, hi : float or None
        Inclusive range of a number (of each element of a list); None: unbounded.
    choices : tuple of str
        Allowed values of a string; empty: any.
    length : int or None
        Number of elements of a list; None: any.
    read_only : bool
        Read once at start-up: a set at run time is refused.
    """

    name: str
    default: object
    description: str
    unit: str = ''
    lo: float = None
    hi: float = None
    choices: tuple = ()
    length: int = None
    read_only: bool = False

    @property
    def kind(self):
        """'bool', 'int', 'float', 'str' or 'floats' (from the default's type)."""
        return _kind_of(self.default)

    def expected(self):
        """What the parameter accepts, in words: 'a number in [0, 60] s', 'a list of 2
        numbers (m)'."""
        rng = ''
        if self.lo is not None and self.hi is not None:
            rng = f' in [{_num(self.lo)}, {_num(self.hi)}]'
        elif self.lo is not None:
            rng = f' >= {_num(self.lo)}'
        elif self.hi is not None:
            rng = f' <= {_num(self.hi)}'
        unit = '' if not self.unit else f' {self.unit}' if rng else f' ({self.unit})'
        kind = self.kind
        if kind == 'bool':
            return 'true or false'
        if kind == 'str':
            return 'one of ' + ', '.join(self.choices) if self.choices else 'a string'
        if kind == 'int':
            return f'an integer{rng}{unit}'
        if kind == 'float':
            return f'a number{rng}{unit}'
        count = f'{self.length} ' if self.length is not None else ''
        return f'a list of {count}numbers{rng}{unit}'

    def descriptor(self):
        """The ParameterDescriptor ``ros2 param describe`` shows."""
        desc = ParameterDescriptor(
            name=self.name, description=f'{self.description} ({self.expected()})',
            read_only=self.read_only, dynamic_typing=True)
        if self.kind in ('float', 'floats') and self.lo is not None and self.hi is not None:
            desc.floating_point_range = [FloatingPointRange(
                from_value=float(self.lo), to_value=float(self.hi), step=0.0)]
        elif self.kind == 'int' and self.lo is not None and self.hi is not None:
            desc.integer_range = [IntegerRange(
                from_value=int(self.lo), to_value=int(self.hi), step=1)]
        return desc


def _shown(value):
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, (list, tuple)) or type(value).__name__ == 'array':
        return '[' + ', '.join(_shown(v) for v in value) + ']'
    return str(value).lower() if isinstance(value, bool) else str(value)


def _number(value, integer):
    """``value`` as a float (an int: as int when ``integer``); None when it is not one."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    if integer:
        if isinstance(value, float) and not value.is_integer():
            return None
        return int(value)
    value = float(value)
    return value if math.isfinite(value) else None


def coerce(spec, value):
    """``value`` of parameter ``spec`` in the parameter's kind (an int for a float, ...).

    Raises
    ------
    ParameterError
        One line, ``<name>: <value> is not <what it accepts>``, when the value has the wrong
        type, is out of range, not among the choices or a list of the wrong length.
    """
    kind = spec.kind
    out = None
    if kind == 'bool':
        out = value if isinstance(value, bool) else None
    elif kind == 'str':
        if isinstance(value, str) and (not spec.choices or value in spec.choices):
            out = value
    elif kind in ('int', 'float'):
        out = _number(value, kind == 'int')
        if out is not None and not _in_range(spec, out):
            out = None
    else:
        try:
            items = [_number(v, False) for v in value] if not isinstance(value, str) else None
        except TypeError:
            items = None
        if (items is not None and None not in items
                and (spec.length is None or len(items) == spec.length)
                and all(_in_range(spec, v) for v in items)):
            out = items
    if out is None:
        raise ParameterError(f'{spec.name}: {_shown(value)} is not {spec.expected()}')
    return out


def _differs(value, parameter):
    """Whether the coerced ``value`` differs from the rclpy Parameter ``parameter``'s value
    or type: [1, 0] given for a list of floats equals [1.0, 0.0] in Python, and stayed an
    integer array (ros2 param describe: integer array)."""
    return (Parameter.Type.from_parameter_value(value) != parameter.type_
            or value != parameter.value)


def _in_range(spec, v):
    return (spec.lo is None or v >= spec.lo) and (spec.hi is None or v <= spec.hi)


class Values(dict):
    """The current parameter values, by name or as attributes."""

    def __getattr__(self, name):
        try:
            return self[name]
        except KeyError:
            raise AttributeError(name) from None


def unknown_overrides(node, declared):
    """Names given to ``node`` (``-p NAME:=VALUE``, a parameters file) that are neither in
    ``declared`` nor rclpy's own (those the node has declared already: use_sim_time,
    start_type_description_service, as ``ros2 param dump`` writes them; qos_overrides.*,
    declared with each publisher): a misspelt name that rclpy would ignore without a word.
    Sorted."""
    given = getattr(node, '_parameter_overrides', {})    # rclpy keeps them there
    return sorted(n for n in given if n not in declared and not node.has_parameter(n)
                  and not n.startswith('qos_overrides.'))


class Parameters:
    """The declared parameters of ``node`` (see the module docstring).

    Parameters
    ----------
    node : rclpy.node.Node
        The node; its parameters are declared here.
    specs : sequence of Param
        The node's parameters.
    check : callable or None
        ``check(values) -> str or None``: a cross-parameter rule on all values (a dict, the
        proposed ones merged in); a string refuses them with that one-line reason.
    apply : callable or None
        ``apply(values, changed)``: called with :attr:`values` and the set of names a set
        has changed (after :attr:`values` is updated), also once at start-up with every
        name.

    Raises
    ------
    ParameterError
        At start-up, for the first value refused.
    """

    def __init__(self, node, specs, check=None, apply=None):
        self.node = node
        self.specs = {s.name: s for s in specs}
        self.check = check
        self.apply = apply
        self.values = Values()
        self._source = None
        self._refused = None        # the refusal _pre_set logged for the set under way
        for spec in specs:
            node.declare_parameter(spec.name, spec.default, ParameterDescriptor(
                description=spec.description, dynamic_typing=True))
        shared = shared_parameter_names(sys.argv, node.get_fully_qualified_name())
        for name in unknown_overrides(node, self.specs):
            if name in shared:      # a /** section's parameter of another node
                continue
            node.get_logger().warning(
                f"parameter '{name}' given but {node.get_name()} has no such parameter: "
                'ignored (--help lists them)')
        for spec in specs:
            self.values[spec.name] = coerce(spec, node.get_parameter(spec.name).value)
        reason = check(dict(self.values)) if check is not None else None
        if reason:
            raise ParameterError(reason)
        for spec in specs:
            value = self.values[spec.name]
            if _differs(value, node.get_parameter(spec.name)):
                node.set_parameters([Parameter(spec.name, value=value)])
            node.set_descriptor(spec.name, spec.descriptor())
        node.add_pre_set_parameters_callback(self._pre_set)
        node.add_on_set_parameters_callback(self._on_set)
        node.add_post_set_parameters_callback(self._post_set)
        if apply is not None:
            apply(self.values, set(self.values))

    def __getattr__(self, name):
        values = self.__dict__.get('values')
        if values is not None and name in values:
            return values[name]
        raise AttributeError(name)

    def __getitem__(self, name):
        return self.values[name]

    def set_from(self, source, parameters):
        """Set ``parameters`` (rclpy Parameters) at once, as a message on topic ``source``
        asks: a refusal is logged once, as ``<source> ignored: <reason>`` (not also as a
        refused ``ros2 param set``). Returns rclpy's SetParametersResult."""
        outer, self._source = self._source, source       # nested calls keep their own
        try:
            result = self.node.set_parameters_atomically(parameters)
        finally:
            self._source = outer
        if not result.successful:
            self.node.get_logger().warning(f'{source} ignored: {result.reason}')
        return result

    def _pre_set(self, parameters):
        """Coerce what can be (an int for a float): the value keeps its parameter's type.
        A set rclpy refuses before the node's check (a number outside the descriptor's
        range, a read-only parameter) is logged here as the node's own refusals are: `ros2
        param set /prediction_node stale_after_s -1` was refused to the caller only, with
        nothing in the node's log (a walk-through, 7 Dec 2026)."""
        out = []
        self._refused = None
        for p in parameters:
            spec = self.specs.get(p.name)
            if spec is not None:
                reason = (f'{p.name} is read-only (set at start: --ros-args -p '
                          f'{p.name}:=...)' if spec.read_only else None)   # rclpy's first
                try:
                    value = coerce(spec, p.value)
                except ParameterError as exc:
                    value = None                        # refused by rclpy or in _on_set
                    reason = reason or str(exc)
                if reason and self._source is None and self._refused is None:
                    self.node.get_logger().warning(f'parameter refused: {reason}')
                    self._refused = reason              # not logged again by _on_set
                if value is not None and _differs(value, p):
                    p = Parameter(p.name, value=value)
            out.append(p)
        return out

    def _on_set(self, parameters):
        refused, self._refused = self._refused, None    # what _pre_set logged for this set
        proposed = dict(self.values)
        try:
            for p in parameters:
                spec = self.specs.get(p.name)
                if spec is not None:
                    proposed[p.name] = coerce(spec, p.value)
            reason = self.check(proposed) if self.check is not None else None
        except ParameterError as exc:
            reason = str(exc)
        if reason:
            # set_from logs it, naming its topic; _pre_set may have logged it already.
            if self._source is None and reason != refused:
                self.node.get_logger().warning(f'parameter refused: {reason}')
            # rclpy has already given the stored descriptor of a dynamically typed parameter
            # the refused value's type (Node._apply_descriptor, before the callbacks): the
            # kept value's type goes back, or `ros2 param describe` says what was refused.
            for p in parameters:
                if p.name in self.specs:
                    self.node.describe_parameter(p.name).type = (
                        self.node.get_parameter(p.name).type_.value)
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _post_set(self, parameters):
        changed = set()
        for p in parameters:
            if p.name in self.specs:
                self.values[p.name] = coerce(self.specs[p.name], p.value)
                changed.add(p.name)
        if changed and self.apply is not None:
            self.apply(self.values, changed)
