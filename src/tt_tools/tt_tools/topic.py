"""``ros2 topic list | find | echo | hz | delay | bw | info | pub`` and ``ros2 node list`` on
rclpy."""

import collections
import difflib
import time

from rclpy.action import (
    get_action_client_names_and_types_by_node,
    get_action_server_names_and_types_by_node,
)
from rclpy.duration import Duration
from rclpy.qos import ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.validate_node_name import validate_node_name

from tt_tools.argtypes import non_negative_int, positive_float, positive_int
from tt_tools.introspect import (
    dict_to_message,
    get_field,
    import_message_type,
    message_to_csv,
    message_to_yaml,
    parse_yaml_values,
    split_type,
    to_yaml,
    type_string,
)
from tt_tools.output import say, write
from tt_tools.rate import (
    bandwidth_stats,
    delay_stats,
    format_bandwidth,
    format_delay,
    format_stats,
    rate_stats,
)
from tt_tools.rosutil import (
    DURABILITY,
    HISTORY,
    LATE_NODE_S,
    QOS_PROFILES,
    RELIABILITY,
    CliNode,
    absolute_name,
    add_spin_time_argument,
    add_use_sim_time_argument,
    chosen_qos,
    graph_names,
    hidden_name,
    node_full_name,
    node_hint,
    node_name_counts,
    node_names,
    qos_matching,
    topic_type,
)


def _known_topics(cli, limit=8):
    """'/a, /b, ...' of the topics in the graph (tt's own nodes' topics left out)."""
    names = sorted({e[0] for e in cli.graph_snapshot()[3]} - {'/rosout', '/parameter_events'})
    more = f', ... ({len(names)} in all)' if len(names) > limit else ''
    return ', '.join(names[:limit]) + more if names else 'none'


def _other_types(infos, type_str):
    """'A, B': the types of the endpoint ``infos`` when all differ from ``type_str`` (they
    would never match it), else '' (none given, no endpoint, or one of its type)."""
    wanted = split_type(type_str) if type_str else None
    if wanted and infos and all(split_type(i.topic_type) != wanted for i in infos):
        return ', '.join(sorted({i.topic_type for i in infos}))
    return ''


def _wait_for_publishers(cli, topic, type_str):
    """Spin until ``topic`` has a publisher; return (message class, publisher infos) or None.

    If discovery settles without one, says so on stderr (with the known topics and the
    closest name) and goes on waiting.
    """
    state = {}

    def found():
        pubs = cli.node.get_publishers_info_by_topic(topic)
        given = _other_types(pubs, type_str)
        if given:
            raise ValueError(f'{topic} is published as {given}, not {type_str}')
        if pubs:
            state['pubs'] = pubs
            state['type'] = type_str or topic_type(cli.node, topic) or pubs[0].topic_type
        return bool(pubs)

    def message():
        topics = [name for name, _ in cli.node.get_topic_names_and_types()]
        close = difflib.get_close_matches(topic, topics, n=1)
        hint = f"; did you mean '{close[0]}'?" if close and close[0] != topic else ''
        return (f'waiting for a publisher on {topic} (none yet; known topics: '
                f'{_known_topics(cli)}){hint}')

    if not cli.wait_saying(found, message):
        return None
    return import_message_type(state['type']), state['pubs']


def topic_list(args):
    for name, types in graph_names(args.spin_time, 'topic_list', args.include_hidden_topics):
        write(f'{name} [{", ".join(types)}]\n' if args.show_types else f'{name}\n')
    return 0


def topic_find(args):
    """``ros2 topic find TYPE [-c]``: the topics of that type (``'pkg/msg/Type'`` or
    ``'pkg/Type'``), one a line, or their count."""
    wanted = split_type(args.topic_type)
    found = graph_names(args.spin_time, 'topic_find', args.include_hidden_topics)
    names = [name for name, types in found if any(split_type(t) == wanted for t in types)]
    write(f'{len(names)}\n' if args.count_topics else ''.join(n + '\n' for n in names))
    return 0


def node_list(args):
    with CliNode('node_list') as cli:
        cli.settle(args.spin_time)
        names = node_names(cli, hidden=args.all)
        counts = node_name_counts(cli)
    shared = [f'{name} ({counts[name]})' for name in names if counts[name] > 1]
    if shared:
        # Listed once like any other; two strike_nodes command the arm both, and a parameter
        # set reaches either (ros2cli warns too).
        say(f'WARNING: nodes in the graph share an exact name: {", ".join(shared)}; '
            'their topics, services and parameters are not told apart')
    for name in names:
        write(name + '\n')
    return 0


def topic_info(args):
    topic = absolute_name(args.topic)
    with CliNode('topic_info') as cli:
        cli.settle(args.spin_time)
        type_str = topic_type(cli.node, topic)
        if type_str is None:
            raise ValueError(f"Unknown topic '{topic}'")
        pubs = cli.node.get_publishers_info_by_topic(topic)
        subs = [s for s in cli.node.get_subscriptions_info_by_topic(topic)
                if s.node_name != cli.node.get_name()]
    lines = [f'Type: {type_str}']
    for label, infos in (('Publisher', pubs), ('Subscription', subs)):
        lines.append(('\n' if args.verbose else '') + f'{label} count: {len(infos)}')
        if args.verbose:
            lines.extend('\n' + str(info) for info in infos)
    write('\n'.join(lines) + '\n')
    return 0


def topic_type_verb(args):
    topic = absolute_name(args.topic)
    with CliNode('topic_type') as cli:
        def types():
            return dict(cli.node.get_topic_names_and_types()).get(topic)

        cli.settle(args.spin_time, done=types)
        found = types()
    if not found:
        raise ValueError(f"Unknown topic '{topic}'")
    write(''.join(t + '\n' for t in found))
    return 0


def split_node_name(full_name):
    """``'/ns/node'`` -> ``('node', '/ns')``; ``'node'`` or ``'/node'`` -> ``('node', '/')``."""
    ns, _, name = absolute_name(full_name).rpartition('/')
    return name, ns or '/'


def node_info(args):
    name, ns = split_node_name(args.node_name)
    full = node_full_name(name, ns)
    with CliNode('node_info') as cli:
        def found():
            return (name, ns) in cli.node.get_node_names_and_namespaces()

        cli.settle(args.spin_time)
        # Discovery can settle before a busy machine has announced every node: a node not seen
        # yet gets a few more seconds, and then its endpoints the time to settle.
        if (args.spin_time is None and not found()
                and cli.spin_until(found, timeout=LATE_NODE_S)):
            cli.settle()
        if not found():
            raise ValueError(f"Unable to find node '{full}'{node_hint(cli, full)}")
        graph = cli.node
        sections = [
            ('Subscribers', graph.get_subscriber_names_and_types_by_node(name, ns)),
            ('Publishers', graph.get_publisher_names_and_types_by_node(name, ns)),
            ('Service Servers', graph.get_service_names_and_types_by_node(name, ns)),
            ('Service Clients', graph.get_client_names_and_types_by_node(name, ns)),
            ('Action Servers', get_action_server_names_and_types_by_node(graph, name, ns)),
            ('Action Clients', get_action_client_names_and_types_by_node(graph, name, ns)),
        ]
    lines = [full]
    for title, names_and_types in sections:
        lines.append(f'  {title}:')
        shown = [f'    {n}: {", ".join(t)}' for n, t in sorted(names_and_types)
                 if args.include_hidden or not hidden_name(n)]
        lines.extend(shown or [''])
    write('\n'.join(lines) + '\n')
    return 0


def message_filter(expression):
    """``--filter``'s test: a function of the message ``m`` that is true for the messages to
    print, from a Python expression (``'m.position.z > 0.1'``; Python's builtins usable, as
    in ros2cli); ValueError (one line) for text that is no expression."""
    try:
        return eval(f'lambda m: ({expression})')    # the user's own filter, as ros2cli's
    except SyntaxError as exc:
        raise ValueError(f"--filter '{expression}' is not a Python expression: "
                         f'{exc.msg}') from None


def _passes(test, expression, value):
    """Whether ``value`` (the message, or its ``--field``) passes ``--filter``; an expression
    that fails on it is one line."""
    try:
        return bool(test(value))
    except Exception as exc:                        # whatever the expression raises
        raise ValueError(f"--filter '{expression}' failed on a {type(value).__name__}: "
                         f'{type(exc).__name__}: {exc}') from None


MESSAGE_INFO_KEYS = ('source_timestamp', 'received_timestamp', 'publication_sequence_number',
                     'reception_sequence_number')
"""The message info ``echo -i`` prints, in ros2cli's CSV order (its YAML sorts them)."""


def _echo_text(args, test, data, cls, info):
    """What ``echo`` prints of one message (serialized ``data``, its message ``info``), or None
    when ``--filter``'s ``test`` leaves it out."""
    msg = data if args.raw else deserialize_message(data, cls)
    if test is not None:
        chosen = msg if args.field is None else get_field(msg, args.field)
        if not _passes(test, args.filter, chosen):
            return None
    keys = MESSAGE_INFO_KEYS if args.include_message_info else ()
    if args.csv:
        return ''.join(f'{info[k]},' for k in keys) + message_to_csv(
            msg, args.no_arr, args.no_str, args.field) + '\n'
    head = to_yaml({k: info[k] for k in sorted(keys)}) + '---\n' if keys else ''
    if args.raw:
        return f'{head}{msg!r}\n---\n'
    return head + message_to_yaml(
        msg, None if args.full_length else args.truncate_length, args.field, args.no_arr,
        args.no_str, args.flow_style) + '---\n'


def topic_echo(args):
    topic = absolute_name(args.topic)
    if args.raw and (args.csv or args.field):
        raise ValueError('--raw prints the serialized message: not with --csv or --field')
    if args.type:
        import_message_type(args.type)  # a bad type fails before any waiting
    test = message_filter(args.filter) if args.filter else None
    with CliNode('echo') as cli:
        if args.timeout is not None:    # ends the command as a signal would: exit 0
            cli.node.create_timer(args.timeout, lambda: setattr(cli, 'stopped', True))
        found = _wait_for_publishers(cli, topic, args.type)
        if found is None:  # interrupted while waiting: a clean exit
            return 0
        cls, pubs = found
        if args.field:
            get_field(cls(), args.field)
        qos = chosen_qos(args, pubs)
        state = {'count': 0, 'done': False}

        def on_message(data, info):
            if state['done']:
                return
            text = _echo_text(args, test, data, cls, info)
            if text is None:
                return                          # not printed, not counted by --once/--times
            state['count'] += 1
            state['done'] = not write(text) or (
                args.once or (args.times and state['count'] >= args.times))

        cli.node.create_subscription(cls, topic, on_message, qos, raw=True)
        cli.spin_until(lambda: state['done'])
    return 0


def _report_each_second(args, name, watch, raw=True, use_sim_time=False):
    """The run of ``hz``, ``delay`` and ``bw``: wait for a publisher of ``args.topic`` (of
    ``args.type``), subscribe to it and write a report at the end of every second that
    brought a message, until a signal or a closed stdout. ``watch(cli, cls)`` gives
    (``on_message``, called with the serialized bytes with ``raw``, else the message;
    ``report()``, the text or None when there is nothing to say yet). ``use_sim_time``: the
    clock ``watch`` reads is /clock's (:class:`tt_tools.rosutil.CliNode`)."""
    topic = absolute_name(args.topic)
    with CliNode(name, use_sim_time) as cli:
        found = _wait_for_publishers(cli, topic, args.type)
        if found is None or not cli.wait_for_clock():
            return 0
        cls, pubs = found
        on_message, report = watch(cli, cls)
        state = {'new': False, 'next': time.monotonic() + 1.0}

        def received(msg):
            on_message(msg)
            state['new'] = True

        def report_due():
            return time.monotonic() >= state['next']

        cli.node.create_subscription(cls, topic, received, qos_matching(pubs, depth=100),
                                     raw=raw)
        while cli.spin_until(report_due):
            state['next'] += 1.0
            text = report() if state['new'] else None
            if text is not None and not write(text + '\n'):
                break
            state['new'] = False
    return 0


def topic_hz(args):
    arrivals = collections.deque(maxlen=args.window)
    test = message_filter(args.filter) if args.filter else None

    def report():
        stats = rate_stats(list(arrivals))
        return None if stats is None else format_stats(stats)

    def watch(cli, cls):
        def on_message(data):
            now = time.monotonic()
            if test is None or _passes(test, args.filter, deserialize_message(data, cls)):
                arrivals.append(now)

        return on_message, report

    return _report_each_second(args, 'hz', watch)


def topic_delay(args):
    delays = collections.deque(maxlen=args.window)

    def watch(cli, cls):
        if 'header' not in cls.get_fields_and_field_types():
            raise ValueError(f'{absolute_name(args.topic)}: {type_string(cls)} has no header, so '
                             'no stamp to measure a delay from')
        clock = cli.node.get_clock()

        def on_message(msg):
            stamp = msg.header.stamp
            delays.append((clock.now().nanoseconds - stamp.sec * 10**9 - stamp.nanosec) * 1e-9)

        return on_message, lambda: format_delay(delay_stats(list(delays)))

    return _report_each_second(args, 'delay', watch, raw=False, use_sim_time=args.use_sim_time)


def topic_bw(args):
    arrivals = collections.deque(maxlen=args.window)

    def report():
        stats = bandwidth_stats(list(arrivals), time.monotonic())
        return None if stats is None else format_bandwidth(stats)

    return _report_each_second(args, 'bw', lambda cli, cls: (
        lambda data: arrivals.append((time.monotonic(), len(data))), report))


def _wait_for_subscriptions(cli, pub, topic, type_str, count, max_wait):
    """Spin until ``pub`` has ``count`` matching subscriptions (True); says on stderr what it
    waits for when discovery settles without them. False on a signal or after ``max_wait``
    s (with a one-line error). ValueError when the topic's subscriptions are all of another
    type than ``type_str`` (they would never match)."""
    def matched():
        return pub.get_subscription_count() >= count

    def bounded():
        if matched():
            return True
        given = _other_types(cli.node.get_subscriptions_info_by_topic(topic), type_str)
        if given:
            raise ValueError(f'{topic} is subscribed as {given}, not {type_str}')
        return time.monotonic() >= deadline

    deadline = time.monotonic() + (max_wait if max_wait is not None else float('inf'))
    limit = (f'up to {max_wait:g} s (--max-wait-time-secs)' if max_wait is not None
             else 'until there is one; -w 0 publishes without waiting')
    if not cli.wait_saying(bounded, lambda: (
            f'waiting for {count} matching subscription(s) on {topic} '
            f'({pub.get_subscription_count()} now), {limit}')):
        return False
    if not matched():
        say(f'ros2 topic: no {count} matching subscription(s) on {topic} after '
            f'{max_wait:g} s: nothing published')
        return False
    return True


def topic_pub(args):
    topic = absolute_name(args.topic)
    cls = import_message_type(args.type)
    values = parse_yaml_values(args.values)
    times = 1 if args.once else args.times
    wait_subs = args.wait_matching_subscriptions
    if wait_subs is None:
        wait_subs = 1 if times else 0
    dict_to_message(values, cls, now=lambda: None)  # bad values fail before any DDS set-up
    if args.node_name is not None:
        validate_node_name(args.node_name)          # one line, before rclpy starts
    with CliNode('pub', args.use_sim_time, args.node_name) as cli:
        def build():
            return dict_to_message(values, cls, now=lambda: cli.node.get_clock().now().to_msg())

        qos = chosen_qos(args)
        pub = cli.node.create_publisher(cls, topic, qos)
        if wait_subs and not _wait_for_subscriptions(cli, pub, topic, args.type, wait_subs,
                                                     args.max_wait_time_secs):
            return 1 if not cli.stopped else 0
        if not cli.wait_for_clock():
            return 0
        write('publisher: beginning loop\n')
        state = {'count': 0}

        def tick():
            msg = build()
            pub.publish(msg)
            state['count'] += 1
            if args.print and state['count'] % args.print == 0:
                write(f'publishing #{state["count"]}: {msg}\n\n')

        period = 1.0 / args.rate if args.rate > 0 else None
        tick()
        if period is not None:
            cli.node.create_timer(period, tick)
        cli.spin_until(lambda: bool(times) and state['count'] >= times)
        if times and qos.reliability == ReliabilityPolicy.RELIABLE:
            pub.wait_for_all_acked(Duration(seconds=args.keep_alive))
    return 0


def add_arguments(topic_sub, node_sub):
    """Register the topic and node verbs on argparse sub-parsers."""
    def qos_args(p, default):
        p.add_argument('--qos-profile', choices=QOS_PROFILES,
                       help=f'a preset QoS profile (default: {default}); the options below '
                            'change its parts')
        p.add_argument('--qos-reliability', choices=sorted(RELIABILITY),
                       help="QoS reliability (default: the profile's)")
        p.add_argument('--qos-durability', choices=sorted(DURABILITY),
                       help="QoS durability (default: the profile's)")
        p.add_argument('--qos-depth', type=positive_int,
                       help="QoS history depth (default: the profile's, else 10)")
        p.add_argument('--qos-history', choices=sorted(HISTORY),
                       help="QoS history (default: the profile's; keep_all ignores the depth)")

    p = topic_sub.add_parser('list', help='list the topics in the graph')
    p.add_argument('-t', '--show-types', action='store_true', help='also print each type')
    p.add_argument('--include-hidden-topics', action='store_true', help='also hidden topics')
    add_spin_time_argument(p)
    p.set_defaults(func=topic_list)

    p = topic_sub.add_parser('find', help='list the topics of a message type')
    p.add_argument('topic_type', help="message type, e.g. 'tt_msgs/msg/BallState'")
    p.add_argument('-c', '--count-topics', action='store_true',
                   help='print only how many there are')
    p.add_argument('--include-hidden-topics', action='store_true', help='also hidden topics')
    add_spin_time_argument(p)
    p.set_defaults(func=topic_find)

    p = topic_sub.add_parser('info', help='type and endpoints of a topic')
    p.add_argument('topic')
    p.add_argument('-v', '--verbose', action='store_true', help='print every endpoint and QoS')
    add_spin_time_argument(p)
    p.set_defaults(func=topic_info)

    p = topic_sub.add_parser('type', help='print the type of a topic')
    p.add_argument('topic')
    add_spin_time_argument(p)
    p.set_defaults(func=topic_type_verb)

    p = topic_sub.add_parser('echo', help='print the messages of a topic as YAML')
    p.add_argument('topic')
    p.add_argument('type', nargs='?', help="message type 'pkg/msg/Type' (default: from graph)")
    p.add_argument('--once', action='store_true', help='print one message and exit')
    p.add_argument('--times', type=non_negative_int, default=0,
                   help='print N messages and exit (0: no limit)')
    p.add_argument('--field', help="print only this dotted field, e.g. 'position.x'")
    p.add_argument('-l', '--truncate-length', type=non_negative_int, default=128,
                   help='cut arrays and strings longer than this (default 128)')
    p.add_argument('-f', '--full-length', action='store_true',
                   help='never cut arrays or strings')
    p.add_argument('--csv', action='store_true',
                   help='one line of comma-separated values a message (every field, nested '
                        'ones in place, arrays whole), e.g. for plotting')
    p.add_argument('--no-arr', action='store_true',
                   help="print each array as its type and length ('<array type: "
                        "double[81]>')")
    p.add_argument('--no-str', action='store_true',
                   help="print each string as its length ('<string length: <5>>')")
    p.add_argument('--flow-style', action='store_true',
                   help='print collections in YAML flow style ({x: 1.0, y: 2.0})')
    p.add_argument('-i', '--include-message-info', action='store_true',
                   help="also print each message's info: source and received timestamps "
                        '(ns), publication and reception sequence numbers')
    p.add_argument('--raw', action='store_true',
                   help='print the serialized message (CDR bytes)')
    p.add_argument('--filter', metavar='EXPR',
                   help="print only the messages m for which this Python expression is true, "
                        "e.g. 'm.position.z > 0.1'; with --field, m is that field (--once and "
                        "--times count those only)")
    p.add_argument('--timeout', type=positive_float, default=None, metavar='S',
                   help='end after this many seconds (exit 0), message or not')
    p.add_argument('--no-lost-messages', action='store_true',
                   help='accepted for scripts written for ros2cli: lost messages are not '
                        'reported here')
    qos_args(p, "one matching the topic's publishers")
    p.set_defaults(func=topic_echo)

    for verb, func, window, text in (
            ('hz', topic_hz, 10000, 'print the average publishing rate of a topic'),
            ('delay', topic_delay, 10000,
             "print the delay of a topic's messages from the stamps in their headers"),
            ('bw', topic_bw, 100, 'print the bandwidth a topic takes')):
        p = topic_sub.add_parser(verb, help=text)
        p.add_argument('topic')
        p.add_argument('type', nargs='?', help='message type (default: from graph)')
        p.add_argument('--window', '-w', type=positive_int, default=window,
                       help=f'number of messages in the rolling window (default {window})')
        if verb == 'delay':
            add_use_sim_time_argument(p)
        if verb == 'hz':
            p.add_argument('--filter', metavar='EXPR',
                           help='count only the messages m for which this Python expression '
                                "is true, e.g. 'm.track_id == 3'")
        p.set_defaults(func=func)

    p = topic_sub.add_parser('pub', help='publish a message given as YAML')
    p.add_argument('topic')
    p.add_argument('type', help="message type 'pkg/msg/Type'")
    p.add_argument('values', nargs='?', default='{}',
                   help="field values as YAML, e.g. '{position: {x: 1.0}}' "
                        "(a Time field may be 'now')")
    p.add_argument('-r', '--rate', type=positive_float, default=1.0,
                   help='publishing rate, Hz')
    p.add_argument('-1', '--once', action='store_true', help='publish one message and exit')
    p.add_argument('-t', '--times', type=non_negative_int, default=0,
                   help='publish N messages and exit (0: no limit)')
    p.add_argument('-w', '--wait-matching-subscriptions', type=int, default=None,
                   help='wait for N matching subscriptions first (default 1 with --once or '
                        '--times, else 0)')
    p.add_argument('--max-wait-time-secs', type=float, default=None,
                   help='with -w, give up (exit 1) after this long (default: wait until the '
                        'subscriptions appear, saying so on stderr)')
    p.add_argument('--keep-alive', type=float, default=1.0,
                   help='with --once/--times, wait up to this long (s) for delivery')
    p.add_argument('-p', '--print', type=non_negative_int, default=1, metavar='N',
                   help='print every N-th message published (0: none; default 1)')
    p.add_argument('-n', '--node-name',
                   help='name of the publishing node (default: a hidden _ros2cli_pub_<pid>)')
    qos_args(p, 'reliable, volatile')
    add_use_sim_time_argument(p)
    p.set_defaults(func=topic_pub)

    p = node_sub.add_parser('list', help='list the nodes in the graph')
    p.add_argument('-a', '--all', action='store_true', help='also hidden nodes')
    add_spin_time_argument(p)
    p.set_defaults(func=node_list)

    p = node_sub.add_parser('info', help='subscribers, publishers, services and actions of a node')
    p.add_argument('node_name', help="full node name, e.g. '/prediction_node'")
    p.add_argument('--include-hidden', action='store_true',
                   help='also hidden topics, services and actions')
    add_spin_time_argument(p)
    p.set_defaults(func=node_info)
