"""``ros2 service list | type | find | call`` on rclpy."""

import difflib
import math
import time

from tt_tools.argtypes import positive_float
from tt_tools.introspect import (
    dict_to_message,
    import_service_type,
    parse_yaml_values,
    split_service_type,
    type_string,
)
from tt_tools.output import write
from tt_tools.rosutil import CliNode, absolute_name, add_spin_time_argument, graph_names


def _services(cli):
    """{name: [type, ...]} of the services in the graph."""
    return dict(cli.node.get_service_names_and_types())


def _served_types(cli, name):
    """The types the servers of the service ``name`` in the graph serve it as (the graph's
    service types count clients too: this command's own among them)."""
    node = cli.node
    return {t for n, ns in node.get_node_names_and_namespaces() if n != node.get_name()
            for s, types in node.get_service_names_and_types_by_node(n, ns) if s == name
            for t in types}


def service_list(args):
    for name, types in graph_names(args.spin_time, 'service_list', args.include_hidden_services,
                                   services=True):
        write(f'{name} [{", ".join(types)}]\n' if args.show_types else f'{name}\n')
    return 0


def service_find(args):
    """``ros2 service find TYPE [-c]``: the services of that type, one a line, or their
    count (a name only clients use counts, as in ``list``)."""
    wanted = split_service_type(args.service_type)
    found = graph_names(args.spin_time, 'service_find', args.include_hidden_services,
                        services=True)
    names = [name for name, types in found
             if any(split_service_type(t) == wanted for t in types)]
    write(f'{len(names)}\n' if args.count_services else ''.join(n + '\n' for n in names))
    return 0


def service_type(args):
    name = absolute_name(args.service_name)
    with CliNode('service_type') as cli:
        # What its servers serve (a client of the name can be seen before its server); the
        # graph's types (its clients' too) when discovery settles without a server.
        cli.settle(args.spin_time, done=lambda: bool(_served_types(cli, name)))
        found = sorted(_served_types(cli, name)) or _services(cli).get(name)
    if not found:
        raise ValueError(f"Unknown service '{name}'")
    write(''.join(t + '\n' for t in found))
    return 0


def service_call(args):
    name = absolute_name(args.service_name)
    cls = import_service_type(args.service_type)
    wanted = type_string(cls)
    values = parse_yaml_values(args.values)
    dict_to_message(values, cls.Request, now=lambda: None)  # bad values fail before DDS set-up
    with CliNode('service_call') as cli:
        client = cli.node.create_client(cls, name)

        # --timeout bounds the wait for the service too: it waited for one never served
        # for ever (a walk-through, 7 Dec 2026).
        deadline = time.monotonic() + (args.timeout if args.timeout is not None else math.inf)

        def ready():
            served = _served_types(cli, name)
            if served and wanted not in served:
                raise ValueError(f'{name} is served as {", ".join(sorted(served))}, not {wanted}')
            return client.service_is_ready()

        def ready_or_late():
            return ready() or time.monotonic() >= deadline

        def waiting():
            others = [s for s in _services(cli) if s != name]     # this client's own left out
            close = difflib.get_close_matches(name, others, n=1)
            hint = f"; did you mean '{close[0]}'?" if close else ''
            return f'waiting for the service {name} (not in the graph yet){hint}'

        if not cli.wait_saying(ready_or_late, waiting):
            return 0
        if not client.service_is_ready():
            raise ValueError(f'no service {name} within {args.timeout:g} s (--timeout): '
                             'nothing sent')
        # Ready means the server reads requests; it answers once its response writer has
        # matched this client too: discovery settled first, as the request is sent once (a
        # service need not be idempotent).
        cli.settle()
        request = dict_to_message(values, cls.Request,
                                  now=lambda: cli.node.get_clock().now().to_msg())
        write(f'requester: making request: {request!r}\n\n')
        future = client.call_async(request)
        if not cli.spin_until(future.done, timeout=deadline - time.monotonic()):
            if cli.stopped:
                return 0
            raise ValueError(f'no response from {name} within {args.timeout:g} s (the request '
                             'was sent once)')
        write(f'response:\n{future.result()!r}\n\n')
    return 0


def add_arguments(sub):
    """Register the service verbs on an argparse sub-parser."""
    p = sub.add_parser('list', help='list the services in the graph')
    p.add_argument('-t', '--show-types', action='store_true', help='also print each type')
    p.add_argument('--include-hidden-services', action='store_true',
                   help='also hidden services')
    add_spin_time_argument(p)
    p.set_defaults(func=service_list)

    p = sub.add_parser('find', help='list the services of a service type')
    p.add_argument('service_type', help="service type, e.g. 'std_srvs/srv/SetBool'")
    p.add_argument('-c', '--count-services', action='store_true',
                   help='print only how many there are')
    p.add_argument('--include-hidden-services', action='store_true',
                   help='also hidden services')
    add_spin_time_argument(p)
    p.set_defaults(func=service_find)

    p = sub.add_parser('type', help='print the type of a service')
    p.add_argument('service_name')
    add_spin_time_argument(p)
    p.set_defaults(func=service_type)

    p = sub.add_parser('call', help='call a service with a request given as YAML')
    p.add_argument('service_name')
    p.add_argument('service_type', help="service type 'pkg/srv/Type'")
    p.add_argument('values', nargs='?', default='{}',
                   help="request fields as YAML, e.g. '{names: [stale_after_s]}' (a Time field "
                        "may be 'now')")
    p.add_argument('--timeout', type=positive_float, default=None,
                   help='give up (exit 1) when no response came within this many seconds, '
                        'the wait for the service included (default: wait until one comes '
                        'or Ctrl-C)')
    p.set_defaults(func=service_call)
