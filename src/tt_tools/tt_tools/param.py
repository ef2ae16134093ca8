"""``ros2 param list | get | set | describe | dump | load``: a node's parameters through its
services.

Every rclpy and rclcpp node (unless started without parameter services) serves
``<node>/list_parameters``, ``get_parameters``, ``set_parameters`` and ``describe_parameters``
(rcl_interfaces). The output is the real ros2cli's: ``Double value is: 0.5``, ``Set parameter
successful``, a ``/node: ros__parameters:`` YAML for ``dump`` that ``load`` sets again.
"""

import time

from rcl_interfaces.msg import Parameter, ParameterType
from rcl_interfaces.srv import (
    DescribeParameters,
    GetParameters,
    ListParameters,
    SetParameters,
)
from rclpy.parameter import Parameter as PythonParameter
from rclpy.parameter import get_parameter_value, parameter_value_to_python
from tt_ros.errors import one_line_reason
from tt_ros.executor import names_a_node, parameter_items, parameter_sections, section_matches
import yaml

from tt_tools.argtypes import UsageError, positive_float
from tt_tools.output import say, write
from tt_tools.rosutil import (
    LATE_NODE_S,
    CliNode,
    absolute_node_name,
    add_spin_time_argument,
    node_hint,
    node_name_counts,
    node_names,
)

SERVICES = {
    ListParameters: 'list_parameters',
    GetParameters: 'get_parameters',
    SetParameters: 'set_parameters',
    DescribeParameters: 'describe_parameters',
}

TYPE_NAMES = {
    ParameterType.PARAMETER_NOT_SET: 'not set',
    ParameterType.PARAMETER_BOOL: 'boolean',
    ParameterType.PARAMETER_INTEGER: 'integer',
    ParameterType.PARAMETER_DOUBLE: 'double',
    ParameterType.PARAMETER_STRING: 'string',
    ParameterType.PARAMETER_BYTE_ARRAY: 'byte array',
    ParameterType.PARAMETER_BOOL_ARRAY: 'boolean array',
    ParameterType.PARAMETER_INTEGER_ARRAY: 'integer array',
    ParameterType.PARAMETER_DOUBLE_ARRAY: 'double array',
    ParameterType.PARAMETER_STRING_ARRAY: 'string array',
}

GET_LABELS = {
    ParameterType.PARAMETER_BOOL: 'Boolean value is:',
    ParameterType.PARAMETER_INTEGER: 'Integer value is:',
    ParameterType.PARAMETER_DOUBLE: 'Double value is:',
    ParameterType.PARAMETER_STRING: 'String value is:',
    ParameterType.PARAMETER_BYTE_ARRAY: 'Byte values are:',
    ParameterType.PARAMETER_BOOL_ARRAY: 'Boolean values are:',
    ParameterType.PARAMETER_INTEGER_ARRAY: 'Integer values are:',
    ParameterType.PARAMETER_DOUBLE_ARRAY: 'Double values are:',
    ParameterType.PARAMETER_STRING_ARRAY: 'String values are:',
}


def _client(cli, node_name, srv_type, args):
    """A client of ``node_name``'s parameter service of ``srv_type``, ready to be called.

    None on a signal; ValueError (one line) when the node is not in the graph, or has no
    such service within ``args.timeout`` s.
    """
    service = f'{node_name}/{SERVICES[srv_type]}'
    client = cli.node.create_client(srv_type, service)

    def ready():
        # The node's name comes apart from its services; with it, the names of the nodes of
        # its process. Two of that name: this reaches one of them, which had no word (a
        # walk-through; ros2 node list warns).
        cli.spin_until(lambda: node_name in node_names(cli, hidden=True), timeout=LATE_NODE_S)
        shared = node_name_counts(cli)[node_name]
        if shared > 1:
            say(f'WARNING: {shared} nodes in the graph are named {node_name}; this reaches '
                'one of them, not told which')
        return client

    if cli.settle(args.spin_time, done=client.service_is_ready):
        return ready()
    if cli.stopped:
        return None
    # Discovery can settle before a busy machine has announced every node: a node not seen
    # yet gets a few more seconds before it is called missing.
    if cli.spin_until(lambda: client.service_is_ready()
                      or node_name in node_names(cli, hidden=True),
                      timeout=min(args.timeout, LATE_NODE_S)) and client.service_is_ready():
        return ready()
    if cli.stopped:
        return None
    if node_name not in node_names(cli, hidden=True):
        raise ValueError(f"Node '{node_name}' not found{node_hint(cli, node_name)}")
    if cli.spin_until(client.service_is_ready, timeout=args.timeout):
        return ready()
    if cli.stopped:
        return None
    raise ValueError(f"node '{node_name}' does not answer on {service} within "
                     f'{args.timeout:g} s (started without parameter services?)')


RESEND_S = 2.0
"""A request without an answer after this long is sent again, s."""


def _call_all(cli, calls, timeout):
    """The responses of service calls sent together, ``calls`` {key: (client, request)}:
    {key: response} of those answered within ``timeout`` s; None on a signal.

    The service can be ready (its request reader matched ours) before its response writer has
    matched our response reader: the node then answers into the void (rmw: "failed to send
    response"). So an unanswered request is sent again every RESEND_S s until ``timeout``;
    every parameter request is idempotent (a set sets the same values again)."""
    deadline = time.monotonic() + timeout
    answers = {}
    while True:
        futures = {key: (client, client.call_async(request))
                   for key, (client, request) in calls.items() if key not in answers}
        left = deadline - time.monotonic()
        cli.spin_until(lambda sent=futures: all(f.done() for _, f in sent.values()),
                       timeout=max(min(RESEND_S, left), 0.0))
        for key, (client, future) in futures.items():
            if future.done():
                answers[key] = future.result()
            else:
                client.remove_pending_request(future)
        if cli.stopped:
            return None
        if len(answers) == len(calls) or time.monotonic() >= deadline:
            return answers


def _call(cli, client, request, timeout):
    """The response of one service call; None on a signal, ValueError after ``timeout`` s
    (:func:`_call_all`)."""
    answers = _call_all(cli, {client.srv_name: (client, request)}, timeout)
    if answers is None:
        return None
    if client.srv_name not in answers:
        raise ValueError(f'no answer from {client.srv_name} within {timeout:g} s')
    return answers[client.srv_name]


def _per_name(cli, node_name, srv_type, field, names, args):
    """The answer of ``srv_type`` (Describe/GetParameters) for ``names``: its ``field``, one
    entry a name; None when the service gave no answer (said already)."""
    client = _client(cli, node_name, srv_type, args)
    if client is None:
        return None
    response = _call(cli, client, srv_type.Request(names=names), args.timeout)
    if response is None:
        return None
    entries = getattr(response, field)
    if len(entries) != len(names):
        # rclpy answers nothing at all when one name is undeclared: ask for each to name it.
        def answered(name):           # None: a signal came, taken as no news
            alone = _call(cli, client, srv_type.Request(names=[name]), args.timeout)
            return alone is None or len(getattr(alone, field)) == 1

        missing = names if len(names) == 1 else [n for n in names if not answered(n)]
        raise ValueError(f"node '{node_name}' has no parameter "
                         + ' or '.join(repr(n) for n in missing or names))
    return entries


def _describe(cli, node_name, names, args):
    return _per_name(cli, node_name, DescribeParameters, 'descriptors', names, args)


def param_list(args):
    with CliNode('param_list') as cli:
        if args.node_name:
            nodes = [absolute_node_name(args.node_name)]
            clients = {nodes[0]: _client(cli, nodes[0], ListParameters, args)}
            if clients[nodes[0]] is None:
                return 0
        else:
            cli.settle(args.spin_time)
            services = {name for name, _ in cli.node.get_service_names_and_types()}
            nodes = [n for n in node_names(cli, args.include_hidden_nodes)
                     if f'{n}/list_parameters' in services]
            clients = {n: cli.node.create_client(ListParameters, f'{n}/list_parameters')
                       for n in nodes}
            cli.spin_until(lambda: all(c.service_is_ready() for c in clients.values()),
                           timeout=args.timeout)
        request = ListParameters.Request(prefixes=args.param_prefixes)
        answers = _call_all(cli, {n: (c, request) for n, c in clients.items()
                                  if c.service_is_ready()}, args.timeout) or {}
        for node_name in nodes:
            if node_name not in answers:
                say(f"ros2 param: no answer from '{node_name}/list_parameters'")
                continue
            names = sorted(answers[node_name].result.names)
            types = {}
            if args.param_type and names:
                descriptors = _describe(cli, node_name, names, args) or []
                types = {d.name: TYPE_NAMES.get(d.type, str(d.type)) for d in descriptors}
            lines = [] if args.node_name else [f'{node_name}:']
            lines += [f'  {n} (type: {types.get(n, "?")})' if args.param_type else f'  {n}'
                      for n in names]
            if not write(''.join(line + '\n' for line in lines)):
                break
    return 0


def _get_values(cli, node_name, names, args):
    return _per_name(cli, node_name, GetParameters, 'values', names, args)


def format_value(value):
    """``'Double value is: 0.5'`` for a ParameterValue, as ``ros2 param get`` prints it."""
    if value.type == ParameterType.PARAMETER_NOT_SET:
        return 'Parameter not set.'
    label = GET_LABELS.get(value.type)
    if label is None:
        raise ValueError(f'unknown parameter type {value.type}')
    return f'{label} {parameter_value_to_python(value)}'


def param_get(args):
    node_name = absolute_node_name(args.node_name)
    with CliNode('param_get') as cli:
        values = _get_values(cli, node_name, [args.parameter_name], args)
    if values is None:
        return 0
    value = values[0]
    if args.hide_type and value.type != ParameterType.PARAMETER_NOT_SET:
        write(f'{parameter_value_to_python(value)}\n')
    else:
        write(format_value(value) + '\n')
    return 0


def parse_value(text, declared_type=None):
    """ParameterValue of a command-line value, typed as YAML types it (``1`` integer, ``1.0``
    double, ``true`` bool, ``[1, 2]`` integer array, anything else a string), as ros2cli does;
    an integer (array) given for a ``declared_type`` double (array) becomes a double (array).
    """
    try:
        return _typed(get_parameter_value(text), declared_type)
    except (OverflowError, ValueError):      # OverflowError: in an array
        raise ValueError(f"value '{text}': {TOO_BIG}") from None


TOO_BIG = 'an integer outside the 64-bit range'


def _typed(value, declared_type):
    """``value`` (a ParameterValue) checked (ValueError: an integer beyond 64 bits) and, an
    integer (array) for a ``declared_type`` double (array), made a double (array); so is a
    list of integers and doubles mixed, which YAML gives rcl as a string."""
    if not all(-2 ** 63 <= v < 2 ** 63
               for v in [value.integer_value, *value.integer_array_value]):
        raise ValueError(TOO_BIG)
    if (declared_type == ParameterType.PARAMETER_DOUBLE
            and value.type == ParameterType.PARAMETER_INTEGER):
        value.type, value.double_value = declared_type, float(value.integer_value)
    elif (declared_type == ParameterType.PARAMETER_DOUBLE_ARRAY
          and value.type == ParameterType.PARAMETER_INTEGER_ARRAY):
        value.type = declared_type
        value.double_array_value = [float(v) for v in value.integer_array_value]
    elif (declared_type == ParameterType.PARAMETER_DOUBLE_ARRAY
          and value.type == ParameterType.PARAMETER_STRING):
        # '[0.5, 0]', integers and doubles mixed: YAML's list is no one array type, so rcl
        # takes it for a string, which the node refused as 'not a list of 2 numbers' (a
        # walk-through, 6 Dec 2026). For a double array it is one.
        try:
            items = yaml.safe_load(value.string_value)
        except yaml.YAMLError:
            items = None
        if _numbers(items):
            value.type, value.string_value = declared_type, ''
            value.double_array_value = [float(v) for v in items]
    return value


def _numbers(items):
    """Whether ``items`` is a non-empty list of integers and doubles (no bools)."""
    return (isinstance(items, list) and bool(items)
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in items))


def file_value(name, value, declared_type=None):
    """ParameterValue of a parameters file's ``value`` for the parameter ``name``, typed as
    rcl types it (and, as :func:`parse_value`, an integer for a declared double a double)."""
    if declared_type == ParameterType.PARAMETER_DOUBLE_ARRAY and _numbers(value):
        value = [float(v) for v in value]     # [0.5, 0]: one array type, as on the command line
    try:
        parameter = PythonParameter(name, value=value)
        if parameter.type_ == PythonParameter.Type.NOT_SET:
            raise ValueError('no value')
        return _typed(parameter.get_parameter_value(), declared_type)
    except (TypeError, ValueError, OverflowError) as exc:
        reason = TOO_BIG if isinstance(exc, OverflowError) else str(exc).rstrip('.')
        raise ValueError(f'{name}: {value!r}: {reason}') from None


def _set(cli, node_name, parameters, args):
    """The node's results of setting ``parameters`` (rcl_interfaces Parameter, in one
    request, each on its own), or None on a signal."""
    client = _client(cli, node_name, SetParameters, args)
    if client is None:
        return None
    response = _call(cli, client, SetParameters.Request(parameters=parameters), args.timeout)
    return None if response is None else response.results


def param_set(args):
    node_name = absolute_node_name(args.node_name)
    pairs = args.params_and_values
    if len(pairs) % 2:
        raise UsageError('parameters must be given as name value pairs: '
                         f'got {len(pairs)} argument(s)')
    names, texts = pairs[::2], pairs[1::2]
    with CliNode('param_set') as cli:
        descriptors = _describe(cli, node_name, names, args)
        if descriptors is None:
            return 0
        parameters = [Parameter(name=n, value=parse_value(t, d.type))
                      for n, t, d in zip(names, texts, descriptors, strict=True)]
        results = _set(cli, node_name, parameters, args)
    if results is None:
        return 0
    failed = False
    for name, result in zip(names, results, strict=True):
        prefix = f'{name}: ' if len(names) > 1 else ''
        reason = f': {result.reason}' if result.reason else ''
        if result.successful:
            write(f'{prefix}Set parameter successful{reason}\n')
        else:
            failed = True
            say(f'{prefix}Setting parameter failed{reason}')
    return 1 if failed else 0


def format_descriptor(descriptor):
    """The lines ``ros2 param describe`` prints for one ParameterDescriptor."""
    lines = [f'Parameter name: {descriptor.name}',
             f'  Type: {TYPE_NAMES.get(descriptor.type, descriptor.type)}']
    if descriptor.description:
        lines.append(f'  Description: {descriptor.description}')
    lines.append('  Constraints:')
    if descriptor.read_only:
        lines.append('    Read only: true')
    ranges = [*descriptor.floating_point_range, *descriptor.integer_range]
    if ranges:
        lines += [f'    Min value: {ranges[0].from_value}',
                  f'    Max value: {ranges[0].to_value}']
        if ranges[0].step:
            lines.append(f'    Step: {ranges[0].step}')
    if descriptor.additional_constraints:
        lines.append(f'    Additional constraints: {descriptor.additional_constraints}')
    return lines


def param_describe(args):
    node_name = absolute_node_name(args.node_name)
    with CliNode('param_describe') as cli:
        descriptors = _describe(cli, node_name, args.parameter_names, args)
    if descriptors is None:
        return 0
    write(''.join(line + '\n' for d in descriptors for line in format_descriptor(d)))
    return 0


def nest(names_values):
    """``{'a.b': 1, 'c': 2}`` -> ``{'a': {'b': 1}, 'c': 2}`` (dots separate the levels of a
    parameters file)."""
    out = {}
    for name, value in names_values:
        *parents, leaf = name.split('.')
        level = out
        for part in parents:
            level = level.setdefault(part, {})
        level[leaf] = value
    return out


def _declared(cli, node_name, args):
    """The names of the node's parameters (its list_parameters' answer), or None on a
    signal."""
    client = _client(cli, node_name, ListParameters, args)
    if client is None:
        return None
    response = _call(cli, client, ListParameters.Request(), args.timeout)
    return None if response is None else list(response.result.names)


def param_dump(args):
    node_name = absolute_node_name(args.node_name)
    with CliNode('param_dump') as cli:
        names = _declared(cli, node_name, args)
        if names is None:
            return 0
        names.sort()
        values = _get_values(cli, node_name, names, args) if names else []
    if values is None:
        return 0
    params = nest((n, parameter_value_to_python(v)) for n, v in zip(names, values, strict=True))
    write(yaml.safe_dump({node_name: {'ros__parameters': params}}, default_flow_style=False)
          + '\n')
    return 0


def node_parameters(path, node_name, use_wildcard=True):
    """{name: value} that the parameters file at ``path`` gives the node ``node_name``
    ('/ns/name'): the sections that apply to it (rcl's wildcards; without ``use_wildcard``
    only those that name it), first those of no node name (``/**:``), then those that name
    it (``node:``, ``/**/node:``), each in the file's order, a later value of a name taking
    the place of an earlier one. ValueError (one line) for a file that is not YAML, not a
    parameters file, has no section for the node, or cannot be read."""
    try:
        with open(path, encoding='utf-8') as f:
            data = yaml.safe_load(f)
    except OSError as exc:
        raise ValueError(f'{path}: {one_line_reason(exc)}') from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ValueError(f'{path}: not YAML ({one_line_reason(exc)})') from None
    sections = list(parameter_sections(data)) if isinstance(data, dict) else []
    if not sections:
        raise ValueError(f'{path}: no section with ros__parameters (not a ROS 2 parameters '
                         'file)')
    applying = [(section, params) for section, params in sections
                if section_matches(section, node_name) and (use_wildcard
                                                            or names_a_node(section))]
    if not applying:
        raise ValueError(f"{path} has no section for the node '{node_name}' (its sections: "
                         f"{', '.join(section for section, _ in sections)})")
    values = {}
    for named in (False, True):
        for section, params in applying:
            if names_a_node(section) == named:
                values.update(parameter_items(params))
    return values


def _python(value):
    """A ParameterValue as a comparable Python value (arrays as lists)."""
    out = parameter_value_to_python(value)
    return out if isinstance(out, (bool, int, float, str)) else list(out)


def param_load(args):
    node_name = absolute_node_name(args.node_name)
    values = node_parameters(args.parameter_file, node_name, not args.no_use_wildcard)
    outcome = {}           # name: (successful, line), in the file's order below
    with CliNode('param_load') as cli:
        declared = _declared(cli, node_name, args)
        if declared is None:
            return 0
        names = [n for n in values if n in declared]
        descriptors = _describe(cli, node_name, names, args) if names else []
        current = _get_values(cli, node_name, names, args) if names else []
        if descriptors is None or current is None:
            return 0
        parameters = []
        for name, descriptor, now in zip(names, descriptors, current, strict=True):
            value = file_value(name, values[name], descriptor.type)
            if descriptor.read_only and value.type == now.type and _python(value) == _python(now):
                outcome[name] = (True, f'Parameter {name} left as it is: read only, and the '
                                 'node has this value')
            else:
                parameters.append(Parameter(name=name, value=value))
        if parameters:
            results = _set(cli, node_name, parameters, args)
            if results is None:
                return 0
            for parameter, result in zip(parameters, results, strict=True):
                reason = f': {result.reason}' if result.reason else ''
                outcome[parameter.name] = (
                    result.successful, f'Set parameter {parameter.name} '
                    + (f'successful{reason}' if result.successful else f'failed{reason}'))
    for name in values:
        successful, line = outcome.get(name, (False, f'Set parameter {name} failed: the node '
                                                    'has no such parameter'))
        if successful:
            write(line + '\n')
        else:
            say(line)
    return 0 if all(outcome.get(name, (False,))[0] for name in values) else 1


def add_arguments(sub):
    """Register the param verbs on an argparse sub-parser."""
    def common(p, node_required=True):
        if node_required:
            p.add_argument('node_name', help="node name, e.g. '/prediction_node'")
        p.add_argument('--timeout', type=positive_float, default=10.0,
                       help='seconds to wait for the parameter service and its answer '
                            '(default 10)')
        add_spin_time_argument(p)

    p = sub.add_parser('list', help='list the parameters of a node (or of every node)')
    p.add_argument('node_name', nargs='?', help='node name (default: every node)')
    p.add_argument('--include-hidden-nodes', action='store_true', help='also hidden nodes')
    p.add_argument('--param-prefixes', nargs='+', default=[],
                   help='only parameters with these prefixes')
    p.add_argument('--param-type', action='store_true', help='print the type of each')
    common(p, node_required=False)
    p.set_defaults(func=param_list)

    p = sub.add_parser('get', help='print the value of a parameter')
    common(p)
    p.add_argument('parameter_name')
    p.add_argument('--hide-type', action='store_true', help='print the value only')
    p.set_defaults(func=param_get)

    p = sub.add_parser('set', help='set parameters (name value [name value ...])')
    common(p)
    p.add_argument('params_and_values', nargs='+', metavar='name value',
                   help="value as YAML: '1' integer, '1.0' double, 'true', '[1, 2]', text")
    p.set_defaults(func=param_set)

    p = sub.add_parser('describe', help='type, description and constraints of parameters')
    common(p)
    p.add_argument('parameter_names', nargs='+')
    p.set_defaults(func=param_describe)

    p = sub.add_parser('dump', help="print a node's parameters as a parameters YAML file")
    common(p)
    p.set_defaults(func=param_dump)

    p = sub.add_parser('load', help="set a node's parameters from a parameters YAML file")
    common(p)
    p.add_argument('parameter_file', help='a parameters file (--params-file, param dump)')
    p.add_argument('--no-use-wildcard', action='store_true',
                   help="only the file's sections that name the node, not '/**:' ones")
    p.set_defaults(func=param_load)
