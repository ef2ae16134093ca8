"""``ros2 interface show | list | package | proto`` and ``ros2 pkg`` (pure: no
rclpy; files and the generated classes only).

``interface show pkg/msg/Type`` prints the installed ``.msg`` (``.srv``, ``.action``) file as
ros2cli does: the file's own comments and blank lines, then, under each field of a message
type, that type's definition indented by one tab per level (without its comments unless
``--all-comments``).
"""

import os
from xml.etree import ElementTree

from rosidl_adapter.parser import parse_message_string
from tt_ros.index import interface_file, interfaces, package_prefix, packages

from tt_tools.introspect import import_message_type, import_service_type, message_to_yaml
from tt_tools.output import write
from tt_tools.run import RunError, executables

KINDS = ('msg', 'srv', 'action')
SEPARATOR = '---'


def interface_path(type_str, ament_prefix_path=None):
    """The installed definition file of ``'pkg/msg/Type'`` (or srv, action); ValueError."""
    parts = type_str.strip().split('/')
    if len(parts) != 3 or parts[1] not in KINDS or not all(parts):
        raise ValueError(f"invalid interface name '{type_str}': expected 'package/msg/Type' "
                         "(or srv, action)")
    pkg, kind, name = parts
    path = interface_file(pkg, kind, name, ament_prefix_path)
    if path is None:
        raise ValueError(f"Unknown package '{pkg}'")
    if not os.path.isfile(path):
        raise ValueError(f"Could not find the interface '{type_str}' ({path} does not exist)")
    return path


def _parse_line(pkg, name, line):
    """(text without the trailing comment, nested message type or None) of one line; the
    text is None for a comment-only line."""
    stripped = line.strip()
    if not stripped or stripped == SEPARATOR:
        return line, None
    if stripped.startswith('#'):
        return None, None
    spec = parse_message_string(pkg, name, line)
    item = (spec.fields or spec.constants or [None])[0]
    comment = item.annotations.get('comment') if item is not None else None
    text = line
    if comment and comment[0]:
        text = line[:line.rfind(comment[0])].rstrip().rstrip('#').rstrip()
    nested = None
    if spec.fields and not spec.fields[0].type.is_primitive_type():
        field_type = spec.fields[0].type
        nested = f'{field_type.pkg_name}/msg/{field_type.type}'
    return text, nested


def show_lines(type_str, comments=True, nested_comments=False, depth=0,
               ament_prefix_path=None):
    """The lines ``ros2 interface show`` prints for ``type_str``."""
    path = interface_path(type_str, ament_prefix_path)
    pkg, _, name = type_str.strip().split('/')
    with open(path, encoding='utf-8') as f:
        raw = f.read().splitlines()
    lines = []
    for line in raw:
        line = line.rstrip()
        text, nested = _parse_line(pkg, name, line)
        if comments:
            lines.append('\t' * depth + line if line else '')
        elif text is not None and text.strip():
            lines.append('\t' * depth + text)
        if nested:
            lines += show_lines(nested, nested_comments, nested_comments, depth + 1,
                                ament_prefix_path)
    return lines


def interface_show(args):
    comments = args.all_comments or not args.no_comments
    lines = show_lines(args.type, comments, args.all_comments)
    write(''.join(line + '\n' for line in lines))
    return 0


def prototype(type_str):
    """The YAML of a default ``type_str`` message (``'pkg/msg/Type'``, or a service's request:
    ``'pkg/srv/Type'``), every field at its .msg's default and no array or string cut, as
    ``ros2 interface proto`` prints it inside its quotes; ValueError (one line) for a name
    that is neither."""
    parts = type_str.strip('/').split('/')
    if len(parts) == 3 and parts[1] == 'srv':
        cls = import_service_type(type_str).Request
    elif len(parts) == 3 and parts[1] == 'action':
        raise ValueError(f"'{type_str}' is an action: tt's ros2 interface proto gives "
                         "messages and services' requests")
    else:
        cls = import_message_type(type_str)
    return message_to_yaml(cls(), truncate_length=None)


def interface_proto(args):
    """``ros2 interface proto TYPE [--no-quotes]``: a message to fill in and hand to
    ``ros2 topic pub`` (or ``service call``), in double quotes unless ``--no-quotes``."""
    text = prototype(args.type)
    write(text if args.no_quotes else f'"{text}"\n')
    return 0


def interface_list(args):
    """``ros2 interface list``: the interfaces of the ament index under ``Messages:``,
    ``Services:``, ``Actions:``, four spaces in, as ros2cli prints them (``-m``, ``-s``,
    ``-a``: only those)."""
    names = interfaces()
    only = [k for k, on in (('msg', args.only_msgs), ('srv', args.only_srvs),
                            ('action', args.only_actions)) if on]
    lines = []
    for kind, title in (('msg', 'Messages'), ('srv', 'Services'), ('action', 'Actions')):
        if only and kind not in only:
            continue
        lines.append(f'{title}:')
        lines += [f'    {n}' for n in names if n.split('/')[1] == kind]
    write(''.join(line + '\n' for line in lines))
    return 0


def interface_package(args):
    """``ros2 interface package PACKAGE``: its interfaces, one per line."""
    if package_prefix(args.package) is None:
        raise ValueError(f"Unknown package '{args.package}'")
    names = [n for n in interfaces() if n.split('/')[0] == args.package]
    write(''.join(n + '\n' for n in names))
    return 0


def pkg_executables(args):
    try:
        names = [args.package] if args.package else packages()
        lines = [f'{pkg} {exe}' for pkg in names for exe in executables(pkg)]
    except RunError as exc:
        raise ValueError(str(exc)) from None
    write(''.join(line + '\n' for line in lines))
    return 0


def pkg_prefix(args):
    """``ros2 pkg prefix PACKAGE``: the install prefix of an indexed package (``--share``:
    its share folder), as ros2cli prints it."""
    prefix = package_prefix(args.package)
    if prefix is None:
        raise ValueError(f"Package '{args.package}' not found")
    write((os.path.join(prefix, 'share', args.package) if args.share else prefix) + '\n')
    return 0


def pkg_xml(args):
    """``ros2 pkg xml PACKAGE [-t TAG]``: the package's installed package.xml, or the text of
    each element ``TAG`` names (an ElementTree path: ``depend``, ``export/build_type``), one a
    line, as ros2cli prints them."""
    prefix = package_prefix(args.package)
    if prefix is None:
        raise ValueError(f"Package '{args.package}' not found")
    path = os.path.join(prefix, 'share', args.package, 'package.xml')
    try:
        with open(path, encoding='utf-8') as f:
            text = f.read()
    except FileNotFoundError:
        raise ValueError(f'{path}: no package.xml installed for {args.package}') from None
    if args.tag is None:
        write(text)
        return 0
    try:
        root = ElementTree.fromstring(text)
    except ElementTree.ParseError as exc:
        raise ValueError(f'{path}: not XML: {exc}') from None
    try:
        elements = root.findall(args.tag)
    except (SyntaxError, TypeError, KeyError):     # what ElementPath raises for a bad path
        raise ValueError(f"--tag '{args.tag}' is not an element path (e.g. 'depend', "
                         "'export/build_type')") from None
    if not elements:
        raise ValueError(f"{path}: no tag '{args.tag}'")
    write(''.join(f'{e.text}\n' for e in elements))
    return 0


def pkg_list(args):
    write(''.join(name + '\n' for name in packages()))
    return 0


def add_arguments(interface_sub, pkg_sub):
    """Register ``interface show | list | package | proto`` and ``pkg executables | list | xml |
    prefix`` on argparse sub-parsers."""
    p = interface_sub.add_parser('show', help='print the definition of a msg, srv or action')
    p.add_argument('type', help="interface name, e.g. 'tt_msgs/msg/BallState'")
    group = p.add_mutually_exclusive_group()
    group.add_argument('--all-comments', action='store_true',
                       help='also the comments of the nested definitions')
    group.add_argument('--no-comments', action='store_true',
                       help='no comments and no blank lines')
    p.set_defaults(func=interface_show)

    p = interface_sub.add_parser('list', help='list the installed msg, srv and action types')
    p.add_argument('-m', '--only-msgs', action='store_true', help='only the messages')
    p.add_argument('-s', '--only-srvs', action='store_true', help='only the services')
    p.add_argument('-a', '--only-actions', action='store_true', help='only the actions')
    p.set_defaults(func=interface_list)

    p = interface_sub.add_parser('package', help='list the interfaces of one package')
    p.add_argument('package', help='the package, e.g. tt_msgs')
    p.set_defaults(func=interface_package)

    p = interface_sub.add_parser('proto', help='print a message (a request) to fill in, as YAML')
    p.add_argument('type', help="e.g. 'geometry_msgs/msg/Point' or 'std_srvs/srv/SetBool'")
    p.add_argument('--no-quotes', action='store_true', help='without the outer double quotes')
    p.set_defaults(func=interface_proto)

    p = pkg_sub.add_parser('executables', help="print '<package> <executable>' lines")
    p.add_argument('package', nargs='?', help='only this package')
    p.set_defaults(func=pkg_executables)

    p = pkg_sub.add_parser('list', help='print the packages of the ament index')
    p.set_defaults(func=pkg_list)

    p = pkg_sub.add_parser('xml', help="print a package's package.xml, or one tag's values")
    p.add_argument('package', help='the package, e.g. tt_prediction')
    p.add_argument('-t', '--tag', help="print only this tag's text, one a line, e.g. depend")
    p.set_defaults(func=pkg_xml)

    p = pkg_sub.add_parser('prefix', help='print the install prefix of a package')
    p.add_argument('package', help='the package, e.g. tt_tools')
    p.add_argument('--share', action='store_true', help='its share folder instead')
    p.set_defaults(func=pkg_prefix)
