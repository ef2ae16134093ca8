"""tt's ``ros2`` command: run, topic, node, param, service, interface, pkg, bag and doctor
verbs where ros2cli is not installed.

Where a real ros2cli is importable, ``main`` hands the whole command line to it (set
``TT_ROS2_NO_HANDOVER=1`` to keep tt's own). Errors are one line on stderr and exit 1
(usage errors, a ros2cli verb tt does not have: exit 2, as argparse's).
"""

import argparse
import importlib
import importlib.util
import os
import re
import sys

from tt_ros.entry import finish_output

from tt_tools import stop
from tt_tools.output import write

HANDOVER_ENV = 'TT_ROS2_NO_HANDOVER'


def real_ros2cli_main():
    """ros2cli's ``main`` when a real ros2cli is importable (and handover allowed), else None."""
    if os.environ.get(HANDOVER_ENV, '') not in ('', '0'):
        return None
    if importlib.util.find_spec('ros2cli') is None:
        return None
    return importlib.import_module('ros2cli.cli').main


def build_parser(only_run=False):
    """The argument parser; ``only_run`` skips the verbs that import rclpy (``ros2 run`` starts
    the executable without that second of imports)."""
    parser = argparse.ArgumentParser(
        prog='ros2', description="tt's ros2 command (a subset of ros2cli: run, topic, node, "
                                 'param, service, interface, pkg, bag, doctor, daemon)')
    verbs = parser.add_subparsers(dest='verb', metavar='verb', required=True)

    p = verbs.add_parser('run', help='run an executable of a package')
    p.add_argument('--prefix', help="prefix command, e.g. 'gdb -ex run --args'")
    p.add_argument('package')
    p.add_argument('executable')
    # Nothing need follow the executable: argparse (before 3.13) counts a missing REMAINDER
    # as a missing argument ('required: executable, argv').
    p.add_argument('argv', nargs=argparse.REMAINDER,
                   help='arguments for the executable (including --ros-args ...)'
                   ).required = False
    p.set_defaults(func=_run)
    if only_run:
        return parser
    from tt_tools import bag, doctor, interface, param, service, topic

    p = verbs.add_parser('topic', help='inspect and publish topics')
    topic_sub = p.add_subparsers(dest='subverb', metavar='subverb', required=True)
    p = verbs.add_parser('node', help='inspect nodes')
    node_sub = p.add_subparsers(dest='subverb', metavar='subverb', required=True)
    topic.add_arguments(topic_sub, node_sub)

    p = verbs.add_parser('param',
                         help="list, get, set, describe, dump and load a node's parameters")
    param.add_arguments(p.add_subparsers(dest='subverb', metavar='subverb', required=True))

    p = verbs.add_parser('service', help='list, find, inspect and call services')
    service.add_arguments(p.add_subparsers(dest='subverb', metavar='subverb', required=True))

    p = verbs.add_parser('interface', help='list and show msg, srv and action definitions')
    interface_sub = p.add_subparsers(dest='subverb', metavar='subverb', required=True)
    p = verbs.add_parser('pkg', help='packages and their executables')
    interface.add_arguments(
        interface_sub, p.add_subparsers(dest='subverb', metavar='subverb', required=True))

    for verb in GRAPH_VERBS:
        for sub in _subparsers(verbs.choices[verb]):
            sub.add_argument('--no-daemon', action='store_true',
                             help="accepted as ros2cli's scripts give it: tt's ros2 has no "
                                  'daemon (every command discovers the graph itself)')

    p = verbs.add_parser('bag', help='record, play and inspect rosbag2 bags')
    bag.add_arguments(p.add_subparsers(dest='subverb', metavar='subverb', required=True))

    p = verbs.add_parser('daemon', help="start, stop or ask for the ros2 daemon (tt's ros2 "
                                        'has none: each command discovers the graph)')
    daemon_sub = p.add_subparsers(dest='subverb', metavar='subverb', required=True)
    for name in ('start', 'stop', 'status'):
        daemon_sub.add_parser(name, help=f'{name}: says there is no daemon, exit 0'
                              ).set_defaults(func=_daemon)

    for name in ('doctor', 'wtf'):    # ros2cli's alias too
        doctor.add_arguments(verbs.add_parser(
            name, help='check the ROS environment and the graph for what keeps messages '
                       'from flowing' if name == 'doctor' else 'the same as doctor'))
    _remember_parsers(parser)
    return parser


GRAPH_VERBS = ('topic', 'node', 'param', 'service')
"""The verbs whose commands look at the graph (ros2cli's take ``--no-daemon``)."""


def _subparsers(parser):
    """The parsers of ``parser``'s subcommands."""
    return [sub for action in parser._actions if isinstance(action, argparse._SubParsersAction)
            for sub in action.choices.values()]


def _remember_parsers(parser):
    """Each (sub)command's parser as its ``_parser`` default, so that an argument too many
    is reported with that command's usage (``ros2 param get``'s), not the top level's."""
    for sub in _subparsers(parser):
        sub.set_defaults(_parser=sub)
        _remember_parsers(sub)


def _daemon(args):
    """``ros2 daemon start | stop | status``, as scripts written for ros2cli run them (before a
    test, say): there is no daemon to start or stop, and each command discovers the graph
    itself, so the script goes on (exit 0)."""
    if args.subverb == 'start':
        write("tt's ros2 has no daemon to start: each command discovers the graph itself\n")
    else:
        write('The daemon is not running\n')     # ros2cli's words when none runs
    return 0


def _run(args):
    from tt_tools import run

    run.main(args)  # only returns on error (exec replaces the process)
    return 1


def main(argv=None):
    """Entry point of the ``ros2`` console script; returns the exit code.

    Ctrl-C or SIGTERM is noted from the start (``stop``): one that comes before the verb has
    started (while importing) ends it quietly with exit 0 as soon as it starts; once a verb
    runs, its node handles both signals itself (see ``rosutil.CliNode``).
    """
    real = real_ros2cli_main()
    if real is not None:
        return real()
    stop.install()
    if argv is None:
        argv = sys.argv[1:]
        if argv[:1] != ['run']:
            _keep_stdout_for_output()
    return finish_output(lambda: _main(argv), 'ros2')


def _keep_stdout_for_output():
    """Give Python's stdout a file descriptor of its own and point fd 1 at stderr.

    The DDS library logs to fd 1 (e.g. Fast DDS's shared-memory port errors); without this
    its lines would land in the middle of ``echo``'s YAML or ``bag info``'s summary.
    """
    sys.stdout.flush()
    try:
        out = os.dup(1)
        os.dup2(2, 1)
    except OSError:
        return
    sys.stdout = os.fdopen(out, 'w', buffering=1, encoding=sys.stdout.encoding or 'utf-8')


def _one_line(exc):
    """``exc``'s message on one line: rcl's source file and line left out; a name check's
    three lines (what is wrong, the name, a caret under the fault) as 'what: name'."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip() and ln.strip() != '^']
    text = ': '.join([lines[0].rstrip(':'), *lines[1:2]]) if lines else type(exc).__name__
    return re.sub(r', at [^ ]+:[0-9]+$', '', text)


ROS2CLI_ONLY = ('action', 'launch', 'lifecycle', 'component', 'multicast',
                'security', 'extensions', 'extension_points')
"""ros2cli's verbs that tt's ros2 command does not have (docs/tools.md, Limits)."""
LAUNCH_HINT = ('; the graph starts with `ros2 run tt_tools bringup --params-file '
               'install/tt_tools/share/tt_tools/config/robot.yaml` (docs/demo.md)')
"""What ``ros2 launch`` is told: tt ships no launch files, its bringup starts the nodes."""


def _main(argv):
    from tt_tools.argtypes import UsageError
    from tt_tools.run import RunError

    if argv[:1] and argv[0] in ROS2CLI_ONLY:
        # argparse said only "invalid choice", after `ros2 node info` had listed services.
        hint = LAUNCH_HINT if argv[0] == 'launch' else ''
        print(f"ros2: '{argv[0]}' is a verb of ros2cli that tt's ros2 command does not have "
              '(ros2cli has no PyPI wheels; these are run, topic, node, param, service, '
              'interface, pkg, bag, doctor and daemon: docs/tools.md); where ros2cli is '
              f'installed, tt hands over to it{hint}',
              file=sys.stderr)
        return 2
    only_run = argv[:1] == ['run']
    parser = build_parser(only_run=only_run)
    args, extra = parser.parse_known_args(argv)
    if extra:
        getattr(args, '_parser', parser).error(f'unrecognized arguments: {" ".join(extra)}')
    if stop.requested:  # before ``run`` execs the executable (its handlers start afresh)
        return 0
    errors = (RunError, ValueError, OSError)
    if not only_run:  # ``ros2 run`` raises no BagError: it skips importing rosbags (0.15 s)
        from rclpy.exceptions import NameValidationException
        from tt_ros.bagfile import BagError

        errors += (BagError, NameValidationException)
    try:
        return args.func(args)
    except BrokenPipeError:
        raise
    except UsageError as exc:
        print(f'ros2 {args.verb}: {exc}', file=sys.stderr)
        return 2
    except errors as exc:  # bad input: one line (without rcl's source file and line)
        print(f'ros2 {args.verb}: {_one_line(exc)}', file=sys.stderr)
    except KeyError as exc:  # an unknown message field
        print(f'ros2 {args.verb}: {exc.args[0]}', file=sys.stderr)
    return 1


if __name__ == '__main__':
    sys.exit(main())
