"""Message introspection without rosidl_runtime_py: type strings, message <-> dict, YAML.

Pure module (no rclpy): it needs only the generated Python message classes. A message becomes
an insertion-ordered dict keyed by the names of ``get_fields_and_field_types()``; nested
messages become nested dicts, fixed arrays and sequences become lists, ``builtin_interfaces``
Time/Duration are ordinary nested messages (``sec``, ``nanosec``) as in ``ros2 topic echo``.
"""

import importlib
import re

import numpy as np
from rosidl_parser.definition import (
    AbstractNestedType,
    AbstractString,
    AbstractWString,
    Array,
    BasicType,
    BoundedSequence,
    NamespacedType,
)
from tt_ros.errors import one_line_reason
import yaml

_INTEGER_RANGES = {
    'int8': (-2**7, 2**7), 'uint8': (0, 2**8), 'char': (0, 2**8), 'octet': (0, 2**8),
    'int16': (-2**15, 2**15), 'uint16': (0, 2**16), 'int32': (-2**31, 2**31),
    'uint32': (0, 2**32), 'int64': (-2**63, 2**63), 'uint64': (0, 2**64),
}
_FLOAT_TYPES = {'float', 'double', 'long double'}
_EXPONENT_FLOAT = re.compile(r'[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+')
"""A number in exponent notation without YAML 1.1's required dot (``1e-6``)."""


def split_type(type_str):
    """``'pkg/msg/Type'`` or ``'pkg/Type'`` -> ``('pkg', 'msg', 'Type')``; ValueError if bad."""
    parts = type_str.strip('/').split('/')
    if len(parts) == 2:
        parts.insert(1, 'msg')
    if len(parts) != 3 or not all(p.isidentifier() for p in parts):
        raise ValueError(f"bad message type '{type_str}': expected 'package/msg/Type'")
    return tuple(parts)


def import_message_type(type_str):
    """The Python message class named by ``'pkg/msg/Type'`` (or ``'pkg/Type'``).

    Raises ValueError with a one-line message when the package or type is unknown.
    """
    pkg, sub, name = split_type(type_str)
    try:
        module = importlib.import_module(f'{pkg}.{sub}')
    except ImportError:
        raise ValueError(f"unknown message package '{pkg}' (in type '{type_str}')") from None
    cls = getattr(module, name, None)
    if cls is None or not hasattr(cls, 'get_fields_and_field_types'):
        raise ValueError(f"unknown message type '{type_str}'")
    return cls


def split_service_type(type_str):
    """``'pkg/srv/Type'`` or ``'pkg/Type'`` -> ``('pkg', 'srv', 'Type')``; ValueError if bad."""
    parts = type_str.strip('/').split('/')
    if len(parts) == 2:
        parts.insert(1, 'srv')
    if len(parts) != 3 or parts[1] != 'srv' or not all(p.isidentifier() for p in parts):
        raise ValueError(f"bad service type '{type_str}': expected 'package/srv/Type'")
    return tuple(parts)


def import_service_type(type_str):
    """The Python service class named by ``'pkg/srv/Type'`` (or ``'pkg/Type'``).

    Raises ValueError with a one-line message when the name, package or type is bad."""
    parts = split_service_type(type_str)
    try:
        module = importlib.import_module(f'{parts[0]}.srv')
    except ImportError:
        raise ValueError(f"unknown service package '{parts[0]}' (in type '{type_str}')") from None
    cls = getattr(module, parts[2], None)
    if cls is None or not hasattr(cls, 'Request'):
        raise ValueError(f"unknown service type '{type_str}'")
    return cls


def type_string(msg_or_cls):
    """``'pkg/msg/Type'`` of a message instance or class."""
    cls = msg_or_cls if isinstance(msg_or_cls, type) else type(msg_or_cls)
    pkg, sub = cls.__module__.split('.')[:2]
    return f'{pkg}/{sub}/{cls.__name__}'


def _nested_class(slot_type):
    return import_message_type('/'.join([*slot_type.namespaces, slot_type.name]))


def _fields(msg):
    """(name, rosidl slot type) pairs of a message, in declaration order."""
    return zip(msg.get_fields_and_field_types(), msg.SLOT_TYPES, strict=True)


def _element_type_name(slot_type):
    """'double', 'string', 'geometry_msgs/msg/Pose': an array's element type as ros2cli's
    ``--no-arr`` names it."""
    if isinstance(slot_type, BasicType):
        return slot_type.typename
    if isinstance(slot_type, AbstractWString):
        return 'wstring'
    if isinstance(slot_type, AbstractString):
        return 'string'
    if isinstance(slot_type, NamespacedType):
        return '/'.join(slot_type.namespaced_name())
    return 'unknown'


def _array_summary(length, slot_type):
    """What ``--no-arr`` prints in place of an array field of ``length`` elements
    (rosidl_runtime_py's words)."""
    element = _element_type_name(slot_type.value_type)
    if isinstance(slot_type, Array):
        return f'<array type: {element}[{slot_type.size}]>'
    if isinstance(slot_type, BoundedSequence):
        return f'<sequence type: {element}[{slot_type.maximum_size}], length: {length}>'
    return f'<sequence type: {element}, length: {length}>'


def _value_to_plain(value, slot_type, truncate_length, no_arr=False, no_str=False):
    if isinstance(slot_type, NamespacedType):
        return message_to_dict(value, truncate_length, no_arr, no_str)
    if isinstance(slot_type, AbstractNestedType):
        # Length and slice of the field itself: an image's 921,600 bytes are not copied into
        # a list to be named by --no-arr or cut to 128.
        if no_arr:
            return _array_summary(len(value), slot_type)
        truncated = truncate_length is not None and len(value) > truncate_length
        out = [_value_to_plain(v, slot_type.value_type, truncate_length, no_arr, no_str)
               for v in (value[:truncate_length] if truncated else value)]
        if truncated:
            out.append('...')
        return out
    if isinstance(value, bytes):  # 'byte' fields
        return value[0] if len(value) == 1 else list(value)
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, str) and no_str:
        return f'<string length: <{len(value)}>>'
    if isinstance(value, str) and truncate_length is not None and len(value) > truncate_length:
        return value[:truncate_length] + '...'
    return value


def message_to_dict(msg, truncate_length=None, no_arr=False, no_str=False):
    """Insertion-ordered dict of a message; lists for arrays/sequences, dicts for nested types.

    ``truncate_length``: longer arrays and strings are cut and end in ``'...'`` (as echo does).
    ``no_arr``, ``no_str``: each array, each string, in nested messages too, replaced by a line
    that names its type and length, as ``ros2 topic echo --no-arr --no-str`` prints them
    (``'<array type: double[81]>'``, ``'<sequence type: double, length: 3>'``,
    ``'<string length: <5>>'``).
    """
    return {
        name: _value_to_plain(getattr(msg, name), slot_type, truncate_length, no_arr, no_str)
        for name, slot_type in _fields(msg)
    }


def _field_and_type(msg, path):
    """(value, rosidl slot type) at a dotted field path; the slot type is None for ``''``."""
    value, slot_type = msg, None
    for part in path.split('.') if path else []:
        slots = dict(_fields(value)) if hasattr(value, 'get_fields_and_field_types') else {}
        if part not in slots:
            raise KeyError(f"no field '{path}' in {type_string(msg)}")
        value, slot_type = getattr(value, part), slots[part]
    return value, slot_type


def get_field(msg, path):
    """The value at a dotted field path (``'position.x'``) of a message; KeyError if absent."""
    return _field_and_type(msg, path)[0]


def _convert_basic(value, slot_type, where):
    kind = slot_type.typename if isinstance(slot_type, BasicType) else None
    try:
        if isinstance(slot_type, AbstractString | AbstractWString):
            if not isinstance(value, str):
                raise TypeError
            return value
        if kind == 'boolean':
            if not isinstance(value, bool):
                raise TypeError
            return value
        if kind == 'byte':
            return bytes([int(value)]) if not isinstance(value, bytes) else value
        if kind in _INTEGER_RANGES:
            low, high = _INTEGER_RANGES[kind]
            if isinstance(value, bool) or int(value) != value or not low <= value < high:
                raise TypeError
            return int(value)
        if kind in _FLOAT_TYPES:
            # YAML 1.1 (PyYAML) reads 1e-6 as a string (a float needs its dot: 1.0e-6);
            # YAML 1.2 and JSON read it as the number it is.
            if isinstance(value, str) and _EXPONENT_FLOAT.fullmatch(value.strip()):
                return float(value)
            if isinstance(value, bool | str):
                raise TypeError
            return float(value)
    except (TypeError, ValueError):
        pass
    raise ValueError(f"field '{where}': {value!r} is not a valid {kind or 'string'}")


def _plain_to_value(value, slot_type, where, now):
    if isinstance(slot_type, NamespacedType):
        cls = _nested_class(slot_type)
        is_time = type_string(cls) == 'builtin_interfaces/msg/Time'
        if value == 'now' and now is not None and is_time:
            return now()
        if not isinstance(value, dict):
            raise ValueError(f"field '{where}': expected a mapping for {type_string(cls)}")
        return dict_to_message(value, cls, now, prefix=where + '.')
    if isinstance(slot_type, AbstractNestedType):
        if not isinstance(value, list | tuple):
            raise ValueError(f"field '{where}': expected a list")
        if isinstance(slot_type, Array) and len(value) != slot_type.size:
            raise ValueError(
                f"field '{where}': expected {slot_type.size} values, got {len(value)}")
        if isinstance(slot_type, BoundedSequence) and len(value) > slot_type.maximum_size:
            raise ValueError(f"field '{where}': at most {slot_type.maximum_size} values")
        return [
            _plain_to_value(v, slot_type.value_type, f'{where}[{i}]', now)
            for i, v in enumerate(value)
        ]
    return _convert_basic(value, slot_type, where)


def dict_to_message(values, cls, now=None, prefix=''):
    """A new message of class ``cls`` with the fields given in ``values`` (others default).

    ``now``: optional callable returning a ``builtin_interfaces/Time``, used where a Time field
    is given as the string ``'now'``. Raises ValueError naming the first bad field.
    """
    msg = cls()
    if values is None:
        return msg
    if not isinstance(values, dict):
        raise ValueError(f'expected a mapping of fields for {type_string(cls)}, got {values!r}')
    slots = dict(_fields(msg))
    for name, value in values.items():
        if name not in slots:
            raise ValueError(f"{type_string(cls)} has no field '{prefix}{name}'")
        setattr(msg, name, _plain_to_value(value, slots[name], prefix + name, now))
    return msg


class _Dumper(yaml.SafeDumper):
    pass


def _represent_float(dumper, value):
    # Like ros2 topic echo: repr() of the float (1.0, 0.1, 1e-05), .nan / .inf for specials.
    if value != value:
        return dumper.represent_scalar('tag:yaml.org,2002:float', '.nan')
    if value in (float('inf'), float('-inf')):
        return dumper.represent_scalar('tag:yaml.org,2002:float', '.inf' if value > 0 else '-.inf')
    return dumper.represent_scalar('tag:yaml.org,2002:float', repr(value))


_Dumper.add_representer(float, _represent_float)


def to_yaml(value, flow_style=False):
    """Block-style YAML of a plain value (dict in field order), as ``ros2 topic echo`` prints
    (with ``flow_style``, flow style: ``{x: 1.0, y: 2.0}``)."""
    return yaml.dump(value, Dumper=_Dumper, default_flow_style=flow_style, sort_keys=False,
                     allow_unicode=True, width=float('inf'))


def _selected(msg, field, truncate_length, no_arr, no_str):
    """The plain value of ``msg`` or of its dotted ``field`` (:func:`message_to_dict`)."""
    value, slot_type = _field_and_type(msg, field)
    if slot_type is None:
        return message_to_dict(msg, truncate_length, no_arr, no_str)
    return _value_to_plain(value, slot_type, truncate_length, no_arr, no_str)


def message_to_yaml(msg, truncate_length=128, field=None, no_arr=False, no_str=False,
                    flow_style=False):
    """YAML text of a message (or of one dotted ``field`` of it), without the ``---`` line;
    ``no_arr``, ``no_str`` as :func:`message_to_dict`; ``flow_style``: collections in YAML's
    flow style (``{x: 1.0, y: 2.0}``), as ``ros2 topic echo --flow-style``."""
    text = to_yaml(_selected(msg, field, truncate_length, no_arr, no_str), flow_style)
    return text[:-len('...\n')] if text.endswith('\n...\n') else text


def message_to_csv(msg, no_arr=False, no_str=False, field=None):
    """One CSV line of a message (or of one dotted ``field`` of it), as ``ros2 topic echo
    --csv`` prints it: every field's value in declaration order, nested messages' fields in
    place, arrays one value per element (all of them), strings as they are, floats as Python
    prints them; with ``no_arr``, ``no_str`` one value naming each array, each string, in its
    place (:func:`message_to_dict`)."""
    values = []

    def add(plain):
        if isinstance(plain, dict):
            for value in plain.values():
                add(value)
        elif isinstance(plain, list):
            for value in plain:
                add(value)
        else:
            values.append(repr(plain) if isinstance(plain, float) else str(plain))

    add(_selected(msg, field, None, no_arr, no_str))
    return ','.join(values)


def parse_yaml_values(text):
    """Parse the YAML (or JSON) field values given on a command line; ValueError if invalid."""
    try:
        values = yaml.safe_load(text) if text and text.strip() else {}
    except yaml.YAMLError as exc:
        raise ValueError(f'invalid YAML for the message: {one_line_reason(exc)}') from None
    if values is None:
        return {}
    if not isinstance(values, dict):
        raise ValueError(f"message values must be a YAML mapping like '{{x: 1.0}}', got {text!r}")
    return values
