"""Running a node as its own process (``ros2 run``): start-up, spin and a clean shutdown, in
one place for every tt node (ROS glue).

The executor is rclpy's ``SingleThreadedExecutor``. ``TT_EXECUTOR=events`` in the environment
selects rclpy's C++ events executor (``rclpy.experimental.EventsExecutor``, rclpy >= 7.1.4):
it takes a message from the middleware to its callback without rebuilding a Python wait set
on every wake-up, 0.5-1.2 ms off the p99 of a state-to-prediction hop at 500 Hz on a 2-core
machine, but in rclpy 7.1.6 it aborts the process at shutdown about one time in ten
("Destroying callback manager with callbacks remaining"), so it is not the default
(docs/prediction.md).

SIGINT and SIGTERM are handled here, not by rclpy: the handler only asks the spin loop to
stop, so that the node logs its last lines and is destroyed while its context is still valid
(no "failed to publish log message to rosout" at shutdown), then the context is shut down and
the process exits 0. A teardown that hangs (seen once in CI: prediction_node still alive
15 s after SIGINT, its last lines logged) is ended after :data:`SHUTDOWN_LIMIT_S` with every
thread's stack on stderr and exit status 1. SIGUSR1 (:data:`STACKS_SIGNAL`) writes every
thread's stack to stderr at any time and the node goes on: ``kill -USR1 <pid>`` shows where a
node that does not answer is stuck, even inside compiled code. A node that cannot start
(:class:`StartupError`, e.g. a bad parameter, or ROS arguments that rcl cannot use such as a
``--params-file`` that is missing or not a ROS parameters file) exits 2 with one line on
stderr, without a traceback.
"""

import contextlib
import faulthandler
import os
import re
import signal
import sys
import threading

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args
import yaml

from tt_ros.rosenv import domain_id_error

EXECUTOR_ENV = 'TT_EXECUTOR'
EXECUTORS = ('events', 'single')
SPIN_TIMEOUT_S = 0.1
"""Longest wait of one spin_once: a signal is acted on within this time, s."""
READY = 'ready'
"""The line a node logs once it is built and about to spin (tt_tools.bringup waits for it)."""
STARTUP_EXIT = 2
"""Exit status of a node that cannot start (bad parameter, missing file)."""
SHUTDOWN_LIMIT_S = 8.0
"""Longest a node may take from the end of its spin to the end of its process (and a ``ros2``
verb's node to leave the graph: tt_tools.rosutil.leave_graph), s: past it, every thread's stack
goes to stderr and the process exits 1 (a hang in the middleware's teardown is then reported
and ended, not left to the parent's SIGKILL or to wait for ever)."""
STACKS_SIGNAL = signal.SIGUSR1
"""The signal on which a node writes every thread's stack to stderr and goes on
(faulthandler: it works while the main thread is stuck in C or numba code)."""


class StartupError(ValueError):
    """A node cannot start: the one-line reason (names the parameter or file)."""


_RCL_WHERE = re.compile(r'(\s*, at \S+:\d+)+\s*$')
"""rcl's trailer on an error message: ', at /path/file.c:123' (repeated)."""
_RCL_PARAMS_FILE = re.compile(r"Couldn't parse params file: '--params-file (.*)'\. Error: (.*)",
                              re.DOTALL)
NOT_PARAMS = 'not a ROS parameters file (a mapping of node names to ros__parameters)'


def _rcl_reason(text):
    """rcl's error ``text`` in one line: its prefix and source locations left out."""
    text = _RCL_WHERE.sub('', text.removeprefix('Failed to parse ROS arguments: '))
    match = _RCL_PARAMS_FILE.fullmatch(text)
    if match:
        path, error = match.groups()
        text = f'cannot read --params-file {path}: {error}'
    else:
        text = f'bad ROS arguments: {text}'
    return ' '.join(text.split())


def _params_files(argv):
    """The paths given to ``--params-file`` in the ROS arguments of ``argv``."""
    paths, in_ros, i = [], False, 0
    while i < len(argv):
        if argv[i] == '--ros-args':
            in_ros = True
        elif argv[i] == '--':
            in_ros = False
        elif in_ros and argv[i] == '--params-file' and i + 1 < len(argv):
            paths.append(argv[i + 1])
            i += 1
        i += 1
    return paths


def parameter_sections(data, prefix=''):
    """(node path, its ros__parameters) of each section of a parameters file's mapping, in
    the file's order: the node paths ('/ns/name', wildcards kept) join nested namespaces."""
    for key, value in data.items():
        if isinstance(value, dict):
            path = f"{prefix}/{str(key).strip('/')}"
            if 'ros__parameters' in value:
                yield path, value['ros__parameters']
            yield from parameter_sections(value, path)


def parameter_items(params, prefix=''):
    """(name, value) of each parameter of a ros__parameters mapping (nested names joined
    with '.')."""
    for key, value in (params.items() if isinstance(params, dict) else ()):
        if isinstance(value, dict):
            yield from parameter_items(value, f'{prefix}{key}.')
        else:
            yield f'{prefix}{key}', value


def names_a_node(section):
    """Whether a section's path ends in a node's name, not a wildcard (``/**``, ``/ns/*``:
    sections shared by design with other nodes)."""
    return section.rsplit('/', 1)[-1] not in ('*', '**')


def section_matches(section, node_path):
    """Whether the section ``section`` applies to the node ``node_path`` ('/ns/name'):
    rcl's wildcards, ``*`` for one name and ``**`` for any number of names."""
    wildcards = {'*': '/[^/]+', '**': '(?:/[^/]+)*'}
    regex = ''.join(wildcards.get(token, '/' + re.escape(token))
                    for token in section.strip('/').split('/'))
    return re.fullmatch(regex, node_path) is not None


def _params_file_sections(args):
    """(path, [(node path, ros__parameters)]) of each readable ``--params-file`` in the ROS
    arguments of ``args`` (rcl judges the others)."""
    for path in _params_files(args):
        try:
            with open(path) as f:
                data = yaml.safe_load(f)
        except (OSError, yaml.YAMLError):
            continue
        yield path, list(parameter_sections(data)) if isinstance(data, dict) else []


def unused_params_files(args, node_path):
    """'<path> (its sections: ...)' for each readable ``--params-file`` in the ROS
    arguments of ``args`` that has no section for the node ``node_path``: rcl sets nothing
    from it, without a word (a file written for another node name or namespace)."""
    unused = []
    for path, sections in _params_file_sections(args):
        if not any(section_matches(section, node_path) for section, _ in sections):
            names = ', '.join(section for section, _ in sections) or 'none'
            unused.append(f'{path} (its sections: {names})')
    return unused


def shared_parameter_names(args, node_path):
    """The parameter names that only sections of no node name (``/**:``, ``/robot1/*:``) of
    the ``--params-file`` files in ``args`` give the node ``node_path``: such a section is
    shared by design with other nodes, whose parameters it holds too. Names that a section
    naming the node (``prediction_node:``, ``/**/prediction_node:``) or ``-p`` gives are
    not among them."""
    shared, own = set(), set()
    for _, sections in _params_file_sections(args):
        for section, params in sections:
            if section_matches(section, node_path):
                (own if names_a_node(section) else shared).update(
                    name for name, _ in parameter_items(params))
    argv = list(args)
    for i, arg in enumerate(argv[:-1]):
        if arg in ('-p', '--param'):
            own.add(argv[i + 1].split(':=', 1)[0])
    return shared - own


ROS_VALUE_FLAGS = ('-p', '--param', '-r', '--remap', '--params-file', '--log-level',
                   '--log-file-name', '--log-config-file', '-e', '--enclave')
"""rcl's flags after --ros-args that take the next argument as their value."""


def check_ros_args(args=None):
    """Raise :class:`StartupError` with one line if rcl cannot use the ROS arguments of
    ``args`` (None: ``sys.argv``): a ``--params-file`` that cannot be read, is not YAML or is
    not a ROS parameters file, an unknown ``--ros-args`` flag, a malformed ``-p`` or ``-r``.
    Returns the arguments that are not ROS arguments (the program's name left out).

    Checked before ``rclpy.init``, which would log an extra line and raise with a traceback.
    """
    argv = list(sys.argv if args is None else args)
    try:
        rest = remove_ros_args(argv)[1:]
    except _rclpy.UnknownROSArgsError as exc:
        raise StartupError(f'unknown ROS arguments: {exc}') from None
    except _rclpy.RCLError as exc:
        raise StartupError(_rcl_reason(str(exc))) from None
    # rcl takes a file whose YAML is one scalar ('hello') and sets nothing from it.
    for path in _params_files(argv):
        try:
            with open(path) as f:
                data = yaml.safe_load(f)
        except (OSError, yaml.YAMLError):
            continue                    # rcl has read it: its own parser is the judge
        if data is not None and not isinstance(data, dict):
            raise StartupError(f'cannot read --params-file {path}: {NOT_PARAMS}')
    return rest


def yaml_value(value):
    """``value`` as ``-p NAME:=VALUE`` and a parameters file spell it (YAML, one line): true
    and false for Python's booleans, 1.0e-05 for 1e-05 (which YAML reads as a string), lists
    in brackets."""
    text = yaml.safe_dump(value, default_flow_style=True, width=float('inf'))
    return text.removesuffix('\n...\n').strip()


def node_help(name, parameters, package='<package>'):
    """What ``<node> --help`` prints: how to set the parameters, and each one
    (:class:`tt_ros.parameters.Param`) with its default and what it accepts."""
    lines = [f'usage: ros2 run {package} {name} [--ros-args [-p NAME:=VALUE ...] '
             '[--params-file FILE]]', '', 'parameters (ros2 param describe shows the same):']
    for p in parameters:
        when = '; read at start-up only' if p.read_only else ''
        lines.append(f'  {p.name} = {yaml_value(p.default)}: {p.expected()}{when}')
        lines.append(f'      {p.description}')
    return '\n'.join(lines)


def make_executor(kind=None, context=None):
    """The executor ``kind`` ('events' or 'single'; None: $TT_EXECUTOR, else 'single').

    'events' falls back to 'single' with an rclpy older than the events executor. Raises
    ValueError for another name.
    """
    kind = kind or os.environ.get(EXECUTOR_ENV) or 'single'
    if kind not in EXECUTORS:
        raise ValueError(f'{EXECUTOR_ENV}={kind!r} is not one of: {", ".join(EXECUTORS)}')
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor(context=context)
        except ImportError:
            pass
    return SingleThreadedExecutor(context=context)


KERNELS_LOADING = ('loading the compiled kernels (compiled on the first start after an install '
                   'or a change of the code: up to a minute)')
"""What a node says while its start-up loads its compiled kernels slowly (said_if_slow)."""
SLOW_START_S = 2.0
"""A node's start-up step longer than this (s) is said while it runs (:func:`said_if_slow`)."""


@contextlib.contextmanager
def said_if_slow(logger, text, after_s=SLOW_START_S):
    """Context manager: ``logger.info(text)`` once if the block is still running after
    ``after_s`` seconds (from a timer thread), nothing if it ends sooner. A node that loads its
    compiled kernels at start compiles them on its first start after an install or a change
    of the model's code: perception_node sat silent for about a minute, as if hung (a
    walk-through's three starts: 55, 67 and 2 s)."""
    timer = threading.Timer(after_s, logger.info, args=(text,))
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


class _StopOnSignal:
    """SIGINT and SIGTERM set ``stopped`` (a second SIGINT raises KeyboardInterrupt); the
    previous handlers come back on exit.

    The handler takes no lock: Python runs a signal's handler between two bytecodes of the
    main thread, also inside a handler already running, and a node whose parent dies can
    get SIGTERM more than once (PR_SET_PDEATHSIG: the kernel sends it again as each thread
    of the dying parent it was handed on to ends). A threading.Event's set() there,
    re-entered while its lock is held, waits on that lock for ever."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.stopped = False
        self._old = {}

    def _handle(self, signum, _frame):
        if self.stopped and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.stopped = True

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)


def run_node(make_node, args=None, on_exit=None, name=None, parameters=()):
    """Run the node that ``make_node()`` returns until SIGINT or SIGTERM, then shut down
    cleanly: ``on_exit(node)`` (may log), the node destroyed, the context shut down, exit
    status 0 and no traceback.

    A :class:`StartupError` from ``make_node``, from :func:`check_ros_args` on ``args``
    (None: ``sys.argv``) or for a ``ROS_DOMAIN_ID`` rcl cannot use (:mod:`tt_ros.rosenv`)
    ends the process with status 2 and the line ``<name>: <reason>`` on stderr (``name``:
    the executable's name by default). A signal that comes while the node
    starts (compiling its kernels, say) stops it once started.

    ``-h`` or ``--help``, before or after ``--ros-args``, prints :func:`node_help` of
    ``parameters`` and exits 0. Other arguments outside ``--ros-args`` (``-p x:=1`` without
    it, say), which rclpy does not take as parameters, are named in a warning on stderr.
    """
    name = name or os.path.basename(sys.argv[0] or 'node')
    argv = list(sys.argv if args is None else args)
    faulthandler.register(STACKS_SIGNAL, all_threads=True)
    # Help also after --ros-args, where rcl knows no such flag (`--ros-args --help`); not
    # the value of a ROS flag (`--log-level -h` is rcl's to refuse).
    if any(arg in ('-h', '--help') and argv[i] not in ROS_VALUE_FLAGS
           for i, arg in enumerate(argv[1:])):
        package = getattr(make_node, '__module__', '').split('.')[0] or '<package>'
        print(node_help(name, parameters, package), flush=True)
        raise SystemExit(0)
    try:
        rest = check_ros_args(argv)
        error = domain_id_error()
        if error:
            raise StartupError(error)
    except StartupError as exc:
        print(f'{name}: {exc}', file=sys.stderr, flush=True)
        raise SystemExit(STARTUP_EXIT) from None
    if rest:
        print(f'{name}: warning: {" ".join(rest)} before --ros-args: not taken as parameters '
              '(rcl takes a NAME:=VALUE there as a remapping, deprecated, and ignores the rest); '
              'give them after --ros-args: -p NAME:=VALUE, -r FROM:=TO',
              file=sys.stderr, flush=True)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    try:
        executor = make_executor()
    except ValueError as exc:
        rclpy.try_shutdown()
        print(f'{name}: {exc}', file=sys.stderr, flush=True)
        raise SystemExit(STARTUP_EXIT) from None
    node = None
    status = 0
    with _StopOnSignal() as signals:
        try:
            node = make_node()
            for unused in unused_params_files(argv, node.get_fully_qualified_name()):
                node.get_logger().warning(f'--params-file {unused} has no section for '
                                          f'{node.get_fully_qualified_name()}: nothing set '
                                          "from it ('/**/NAME:' is NAME in any namespace)")
            executor.add_node(node)
            node.get_logger().info(READY)
            while not signals.stopped and rclpy.ok():
                executor.spin_once(timeout_sec=SPIN_TIMEOUT_S)
        except StartupError as exc:
            print(f'{name}: {exc}', file=sys.stderr, flush=True)
            status = STARTUP_EXIT
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            # Left armed through the interpreter's own exit, which can hang too.
            faulthandler.dump_traceback_later(SHUTDOWN_LIMIT_S, exit=True)
            if node is not None:
                if on_exit is not None:
                    on_exit(node)
                executor.remove_node(node)
            executor.shutdown()
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
    if status:
        raise SystemExit(status)
