"""``ros2 doctor [--report | --report-failed] [--include-warnings]`` on rclpy.

Checks what most often keeps messages from flowing in a ROS 2 graph: the discovery
environment (``network``), topics with publishers but no subscription or the other way round
(``topic``), endpoints of one topic with different types (``type``) and publisher /
subscription pairs whose QoS cannot match (``qos``: rclpy's ``qos_check_compatible``, the
rules rmw applies). Each finding is a line on stderr; the last line on stdout says how many
checks passed. A check fails on an error, and on a warning too with ``--include-warnings``;
the exit status is 1 when one failed. ``--report`` prints what the checks saw, by section.

ros2cli's doctor also checks the installed packages' versions against rosdistro (over the
network; not here) and has a ``hello`` verb for multicast between machines (not here).
"""

import collections
import importlib.metadata
import os
import platform
import re
import socket
import sys

from tt_ros.rosenv import DOMAIN_ID_SAFE_MAX, domain_id_error

from tt_tools.output import say, write
from tt_tools.rosutil import CliNode, add_spin_time_argument, hidden_name, node_full_name

CHECKS = ('network', 'topic', 'type', 'qos')
"""The checks, in the order they run and report."""
INFRASTRUCTURE_TOPICS = ('/rosout', '/parameter_events')
"""Topics every node has endpoints on, whether anything listens or not: not checked."""
DISCOVERY_RANGES = ('SYSTEM_DEFAULT', 'LOCALHOST', 'SUBNET', 'OFF')
"""Values rcl takes for ROS_AUTOMATIC_DISCOVERY_RANGE (another: a warning, and LOCALHOST)."""

Finding = collections.namedtuple('Finding', 'check level text')
"""One thing a check found: ``level`` 'error' (messages cannot flow) or 'warning'."""
Endpoint = collections.namedtuple('Endpoint', 'node kind type qos')
"""A topic's publisher (``kind`` 'publisher') or subscription, by its node's full name."""


def network_findings(environ):
    """Findings of the discovery environment ``environ`` (a mapping like os.environ)."""
    found = []
    error = domain_id_error(environ)
    domain = environ.get('ROS_DOMAIN_ID', '').strip()
    if error:
        found.append(Finding('network', 'error', error))
    elif domain and int(domain) > DOMAIN_ID_SAFE_MAX:
        found.append(Finding('network', 'warning', (
            f'ROS_DOMAIN_ID {int(domain)}: its ports can collide with ports Linux hands out '
            f'(0-{DOMAIN_ID_SAFE_MAX} keep clear of them)')))
    value = environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '')
    if value and value not in DISCOVERY_RANGES:
        found.append(Finding('network', 'warning', (
            f"ROS_AUTOMATIC_DISCOVERY_RANGE '{value}' is none of {', '.join(DISCOVERY_RANGES)}: "
            'rcl takes it as LOCALHOST')))
    if value == 'OFF' and not environ.get('ROS_STATIC_PEERS', '').strip():
        found.append(Finding('network', 'warning', (
            'ROS_AUTOMATIC_DISCOVERY_RANGE is OFF and ROS_STATIC_PEERS empty: nodes in other '
            'processes are not discovered')))
    if environ.get('ROS_LOCALHOST_ONLY', ''):
        found.append(Finding('network', 'warning', (
            'ROS_LOCALHOST_ONLY is deprecated since Jazzy: set '
            'ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST instead')))
    return found


def _checked(topics):
    """``topics`` without the infrastructure and hidden ones, sorted by name."""
    return {name: endpoints for name, endpoints in sorted(topics.items())
            if name not in INFRASTRUCTURE_TOPICS and not hidden_name(name)}


def _pairs(endpoints):
    """(publisher, subscription) pairs of one type among a topic's ``endpoints``."""
    return [(pub, sub) for pub in endpoints if pub.kind == 'publisher'
            for sub in endpoints if sub.kind != 'publisher' and sub.type == pub.type]


def _compatibility(pub, sub):
    """('OK' | 'WARNING' | 'ERROR', [reason, ...]) of a publisher and subscription's QoS, by
    rclpy's ``qos_check_compatible`` (its 'ERROR: a;WARNING: b;' split into reasons)."""
    from rclpy.qos import qos_check_compatible

    level, text = qos_check_compatible(pub.qos, sub.qos)
    return level.name, [re.sub(r'^(ERROR|WARNING): ', '', part).strip()
                        for part in text.split(';') if part.strip()]


def graph_findings(topics):
    """Findings of the ``topic``, ``type`` and ``qos`` checks on ``topics``, {name: [Endpoint,
    ...]}; infrastructure topics and hidden ones are not looked at."""
    found = []
    for name, endpoints in _checked(topics).items():
        pubs = sorted({e.node for e in endpoints if e.kind == 'publisher'})
        subs = sorted({e.node for e in endpoints if e.kind != 'publisher'})
        if pubs and not subs:
            found.append(Finding('topic', 'warning', (
                f'publisher without subscription on {name} ({", ".join(pubs)})')))
        elif subs and not pubs:
            found.append(Finding('topic', 'warning', (
                f'subscription without publisher on {name} ({", ".join(subs)})')))
        types = sorted({e.type for e in endpoints})
        if len(types) > 1:
            by_type = '; '.join(
                f'{t}: ' + ', '.join(sorted({f'{e.node} {e.kind}' for e in endpoints
                                             if e.type == t})) for t in types)
            found.append(Finding('type', 'error', (
                f'{name} has endpoints of {len(types)} types, between which no message '
                f'passes ({by_type})')))
        for pub, sub in _pairs(endpoints):
            level, reasons = _compatibility(pub, sub)
            if level != 'OK':
                found.append(Finding('qos', level.lower(), (
                    f'{name}: publisher of {pub.node} and subscription of {sub.node}: '
                    f'{"; ".join(reasons)}')))
    return found


def graph_topics(cli):
    """{topic: [Endpoint, ...]} of everything ``cli`` (a settled CliNode) has discovered,
    its own endpoints left out."""
    node, own = cli.node, cli.node.get_name()
    topics = {}
    for name, _ in node.get_topic_names_and_types():
        infos = [('publisher', i) for i in node.get_publishers_info_by_topic(name)]
        infos += [('subscription', i) for i in node.get_subscriptions_info_by_topic(name)]
        topics[name] = [Endpoint(node_full_name(i.node_name, i.node_namespace), kind,
                                 i.topic_type, i.qos_profile)
                        for kind, i in infos if i.node_name != own]
    return topics


def _ros_distribution():
    """(distribution, rclpy version) of the installed ROS 2 wheels (or a ROS install's
    ``ROS_DISTRO``)."""
    for dist in importlib.metadata.distributions():
        match = re.fullmatch(r'ros-([a-z]+)-rclpy', dist.metadata['Name'] or '')
        if match:
            return match.group(1), dist.version
    return os.environ.get('ROS_DISTRO', 'unknown'), 'unknown'


def _section(title, rows):
    """A report section: its title, then ``key : value`` rows aligned."""
    width = max((len(k) for k, _ in rows), default=0)
    return f'\n   {title}\n' + (''.join(f'{k:<{width}} : {v}\n' for k, v in rows) or '(none)\n')


def report(environ, topics, rmw):
    """{check or 'platform' / 'middleware': section text} of what the checks looked at."""
    distro, rclpy_version = _ros_distribution()
    sections = {
        'platform': _section('PLATFORM INFORMATION', [
            ('system', platform.system()), ('platform info', platform.platform()),
            ('release', platform.release()), ('processor', platform.machine()),
            ('python', sys.version.split()[0])]),
        'middleware': _section('RMW MIDDLEWARE AND ROS 2', [
            ('middleware name', rmw), ('distribution name', distro),
            ('rclpy', rclpy_version)]),
        'network': _section('NETWORK CONFIGURATION', [
            ('interfaces', ', '.join(name for _, name in socket.if_nameindex())),
            *((key, environ.get(key, '') or '(unset)') for key in (
                'ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS',
                'ROS_LOCALHOST_ONLY', 'FASTRTPS_DEFAULT_PROFILES_FILE'))]),
    }
    checked = _checked(topics)
    sections['topic'] = _section('TOPIC LIST', [
        row for name, endpoints in checked.items() for row in (
            ('topic', name),
            ('publisher count', sum(e.kind == 'publisher' for e in endpoints)),
            ('subscriber count', sum(e.kind != 'publisher' for e in endpoints)))])
    sections['type'] = _section('TOPIC TYPES', [
        (name, ', '.join(sorted({e.type for e in endpoints})))
        for name, endpoints in checked.items()])
    rows = []
    for name, endpoints in checked.items():
        for pub, sub in _pairs(endpoints):
            level, reasons = _compatibility(pub, sub)
            status = level if level == 'OK' else f'{level}: {"; ".join(reasons)}'
            rows += [('topic [type]', f'{name} [{pub.type}]'), ('publisher node', pub.node),
                     ('subscriber node', sub.node), ('compatibility status', status)]
    sections['qos'] = _section('QOS COMPATIBILITY LIST', rows)
    return sections


def doctor(args):
    import rclpy

    environ = os.environ
    findings = network_findings(environ)
    topics = {}
    if not any(f.level == 'error' for f in findings):  # no domain: no graph to look at
        with CliNode('doctor') as cli:
            cli.settle(args.spin_time)
            topics = graph_topics(cli)
        findings += graph_findings(topics)
    failing = [f for f in findings if f.level == 'error' or args.include_warnings]
    failed = [c for c in CHECKS if any(f.check == c for f in failing)]
    if args.report or args.report_failed:
        sections = report(environ, topics, rclpy.get_rmw_implementation_identifier())
        shown = failed if args.report_failed else list(sections)
        write(''.join(sections[name] for name in sections if name in shown) + '\n')
    for finding in findings:
        say(f'ros2 doctor: {finding.level.upper()}: {finding.check}: {finding.text}')
    if failed:
        write(f'{len(failed)}/{len(CHECKS)} checks failed\nFailed modules: {" ".join(failed)}\n')
        return 1
    write(f'All {len(CHECKS)} checks passed\n')
    return 0


def add_arguments(parser):
    """``ros2 doctor``'s options on ``parser``."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument('--report', '-r', action='store_true',
                       help='print what the checks looked at, section by section')
    group.add_argument('--report-failed', '-rf', action='store_true',
                       help='print the sections of the failed checks only')
    parser.add_argument('--include-warnings', '-iw', action='store_true',
                        help='a warning fails its check too')
    add_spin_time_argument(parser)
    parser.set_defaults(func=doctor)
