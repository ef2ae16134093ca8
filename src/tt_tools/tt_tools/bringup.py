"""``ros2 run tt_tools bringup --params-file FILE``: the whole tt graph from one parameters file.

Starts each node the file names (``perception_node``, ``prediction_node``, ``strike_node``; a
``/**`` section applies to all of them) as its own process with ``--ros-args --params-file
FILE`` (consumers first: strike, prediction, then perception, each once the one before
logged that it is ready and each running node logged that its input is connected to the
running node that publishes it, ``/ball/prediction: connected``; DDS discovery can take a
second or two, and a video's first ball would be lost), in the environment the graph
needs (tt's Fast DDS profile for camera images when /dev/shm has room, unless
``FASTRTPS_DEFAULT_PROFILES_FILE`` is set already). Every line a node prints is shown
prefixed with its name.

- SIGINT or SIGTERM stops every node (SIGINT, then SIGTERM after ``--stop-timeout``, then
  SIGUSR1, on which a tt node writes every thread's stack, and SIGKILL) and exits 0 when they
  all exited 0. The nodes also get SIGTERM when bringup itself ends in any other way (even
  SIGKILL): none outlives it.
- A node that dies is restarted after ``--restart-delay`` seconds, with one line:
  ``bringup: prediction_node died (signal SIGKILL) after 12.3 s; restart 1``. A node that
  exits 2 (it cannot start: a bad parameter or file, its one line printed above) is not
  restarted: bringup stops the others and exits 2. More than ``--max-restarts`` restarts of
  one node in a row, each dying within STABLE_RUN_S (60 s) of its start, also stop the graph
  (exit 1); a node that ran longer before it died is restarted, not counted, and starts its
  count again (a count over a node's whole life stopped a graph up for days at its sixth
  crash). The shared memory that a node killed by a signal leaves in /dev/shm (Fast DDS's,
  32 MB a process) is removed then (:mod:`tt_ros.shm`), with one line.
- ``--namespace NS`` starts every node in NS (``-r __ns:=NS``): one robot's graph of several
  on a ROS domain, its clock on NS/clock (``-r /clock:=NS/clock``): two replays on one
  /clock stepped each other's time back (a walk-through, 6 Dec 2026); a bag played into it
  gives ``--remap /clock:=NS/clock`` with ``--clock``.
- ``--show`` prints one line per ball (track): the prediction and the strike command. Its
  subscriptions count as inputs too: the next node starts once they are connected to the
  running nodes that publish them (a video's first ball would not be shown).

The shipped files (``share/tt_tools/config``): ``robot.yaml`` (live cameras) and
``replay.yaml`` (video files or bags: video time on /clock, the other nodes on it).
Bad input (no file, bad YAML, no tt node named, a ROS_DOMAIN_ID rcl cannot use) is one line
and exit 2.
"""

import argparse
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time

from tt_ros.executor import NOT_PARAMS, names_a_node, section_matches
from tt_ros.names import name_error
from tt_ros.rosenv import domain_id_error
from tt_ros.shm import remove_dead_segments
import yaml

from .argtypes import non_negative_float, non_negative_int, positive_float
from .procs import ends_with_parent, ros_env
from .run import RunError, find_executable

NODES = {
    'perception_node': 'tt_perception',
    'prediction_node': 'tt_prediction',
    'strike_node': 'tt_strike',
}
"""The tt nodes bringup knows: node name -> package (the executable has the node's name)."""
START_ORDER = ('strike_node', 'prediction_node', 'perception_node')
"""Consumers first: each node starts once the one before logged that it is ready, so that a
video file's first ball finds the whole graph listening."""
READY_LINE = re.compile(r'\]: ready$')
"""A node's 'ready' log line (tt_ros.executor.READY)."""
INPUTS = {
    'strike_node': ('/ball/prediction', 'prediction_node'),
    'prediction_node': ('/ball/state', 'perception_node'),
}
"""Node -> (its input topic, the node that publishes it)."""
SHOWN = {
    '/ball/prediction': 'prediction_node',
    '/strike/command': 'strike_node',
}
"""``--show``'s topics -> the node that publishes each."""
INPUT_LINE = re.compile(r'\]: (/\S+): (connected|no publisher left)')
"""A node's log line when its input gets its first publisher or loses its last
(tt_ros.connections)."""
NEW_BALL_GAP_S = 1.0
"""``--show``: a command of a shown track id stamped this long after its last one (s), or
before it, is another ball's (prediction_node's TRACK_GAP_S)."""
CONNECT_WAIT_S = 10.0
"""Longest wait for a running node's input to be connected before the next node starts, s
(DDS discovery between two processes can take a second or two)."""
STARTUP_EXIT = 2
"""A node's exit status when it cannot start (tt_ros.executor.STARTUP_EXIT)."""
POLL_S = 0.2
"""Longest wait for a node's exit before a signal is looked at, s."""
STACKS_SIGNAL = signal.SIGUSR1
"""A tt node writes every thread's stack on it (tt_ros.executor.STACKS_SIGNAL)."""
STACKS_WAIT_S = 1.0
"""Time given to a node that does not stop to write its stacks before its SIGKILL, s."""


class BringupError(Exception):
    """Bad input to bringup: one line."""


_STDOUT = threading.Lock()
"""Held while one line goes to stdout: the children's pumps and bringup's own lines come
from several threads, and print() writes a line's text and its newline apart (a node's
'ready' and bringup's next line ended up on one line)."""


def emit(line):
    """Write ``line`` and its newline to stdout in one piece, and flush."""
    with _STDOUT:
        sys.stdout.write(line + '\n')
        sys.stdout.flush()


def say(text):
    emit(f'bringup: {text}')


def read_params(params_file):
    """The sections of a ROS parameters file: {section name: its ros__parameters}.
    BringupError with one line when the file cannot be read or is not such a file."""
    try:
        with open(params_file) as f:
            data = yaml.safe_load(f)
    except OSError as exc:
        raise BringupError(f'{params_file}: {exc.strerror or exc}') from None
    except UnicodeDecodeError:          # a video given for it: a traceback
        raise BringupError(f'{params_file}: not valid YAML (not UTF-8 text)') from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' (line {mark.line + 1})' if mark is not None else ''
        raise BringupError(f'{params_file}: not valid YAML{where}') from None
    if not isinstance(data, dict):
        raise BringupError(f'{params_file}: {NOT_PARAMS}')
    for key, value in data.items():
        if not isinstance(value, dict) or 'ros__parameters' not in value:
            raise BringupError(f'{params_file}: {key}: no ros__parameters')
    return {str(key): value['ros__parameters'] for key, value in data.items()}


def nodes_in(sections, params_file, namespace=''):
    """The tt nodes that the parameters file ``params_file`` (its :func:`read_params`
    ``sections``) names, in the order of ``NODES``, each started in ``namespace`` ('' the
    root): a section names a node as rcl applies it (``prediction_node:``,
    ``/**/prediction_node:``, ``/robot1/prediction_node:`` in /robot1); all of them when the
    file only has shared sections (``/**:``). BringupError with one line when it names none.
    (Only the plain names were looked for: the ``/**/NAME:`` sections the docs give were
    'none of the tt nodes'; a walk-through, 6 Dec 2026.)"""
    found = [n for n in NODES if any(names_a_node(key) and section_matches(key, f'{namespace}/{n}')
                                     for key in sections)]
    if not found and any(section_matches(key, f'{namespace}/{n}')
                         for key in sections for n in NODES):
        found = list(NODES)
    if not found:
        where = f' in {namespace}' if namespace else ''
        raise BringupError(f'{params_file}: names none of the tt nodes ({", ".join(NODES)})'
                           f'{where} (its sections: {", ".join(sections)})')
    return found


def configured_rig(sections, namespace=''):
    """The rig_file that a parameters file's ``sections`` (:func:`read_params`) give
    perception_node in ``namespace``, in any section that applies to it, or ''."""
    rig = ''
    for key, params in sections.items():
        if section_matches(key, f'{namespace}/perception_node') \
                and isinstance(params, dict) and 'rig_file' in params:
            rig = params['rig_file'] or ''          # a later section wins, as in rcl
    return str(rig)


def _signal_name(code):
    try:
        return signal.Signals(-code).name
    except ValueError:
        return f'signal {-code}'


class Child:
    """One node process, its output prefixed on our stdout, its exit put on ``events``."""

    def __init__(self, name, argv, env, events):
        self.name, self.argv, self.env, self.events = name, argv, env, events
        self.proc = None
        self.started = None
        self.restarts = 0
        self.last_line = ''
        self.ready = False
        self.connected = set()      # input topics with a publisher, as the node logged

    def start(self):
        self.started = time.monotonic()
        self.ready = False
        self.connected = set()
        self.proc = subprocess.Popen(self.argv, env=self.env, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, errors='replace', start_new_session=True,
                                     preexec_fn=ends_with_parent())
        threading.Thread(target=self._pump, args=(self.proc,), daemon=True).start()
        say(f'started {self.name} (pid {self.proc.pid})')

    def _pump(self, proc):
        for line in proc.stdout:
            line = line.rstrip('\n')
            if line.strip():
                self.last_line = line
            if READY_LINE.search(line):
                self.ready = True
                self.events.put(('ready', self, proc))
            connection = INPUT_LINE.search(line)
            if connection:
                topic, state = connection.groups()
                if state == 'connected':
                    self.connected.add(topic)
                else:
                    self.connected.discard(topic)
                self.events.put(('input', self, proc))
            emit(f'[{self.name}] {line}')
        proc.wait()
        self.events.put(('exit', self, proc))

    def signal(self, sig):
        if self.proc is not None and self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                pass


STABLE_RUN_S = 60.0
"""A node that ran this long (s) before it died starts its count of restarts again."""


class Bringup:
    """The supervisor: start, restart, stop (see the module docstring)."""

    def __init__(self, params_file, nodes, extra_args=None, restart_delay=1.0,
                 max_restarts=5, stop_timeout=10.0, env=None, namespace=''):
        self.events = queue.Queue()
        self.namespace = namespace
        self.show = None            # --show's Show: its subscriptions are waited for as inputs
        self.restart_delay = restart_delay
        self.max_restarts = max_restarts
        self.stop_timeout = stop_timeout
        # The robot's discovery range as the caller set it (not only this machine).
        env = ros_env(large_messages=True, localhost=False) if env is None else env
        self.children = []
        for name in sorted(nodes, key=START_ORDER.index):
            exe = find_executable(NODES[name], name)
            extra = (extra_args or {}).get(name, [])
            ns = ['-r', f'__ns:={namespace}', '-r', f'/clock:={namespace}/clock'] \
                if namespace else []
            self.children.append(Child(name, [exe, '--ros-args', *ns, '--params-file',
                                              os.path.abspath(params_file), *extra],
                                       env, self.events))
        self.profile = env.get('FASTRTPS_DEFAULT_PROFILES_FILE', '')
        self.pending = {}           # child -> monotonic time of its restart
        self.stopping = False
        self.stop_requested = False
        self.status = 0

    def request_stop(self, signum=None, _frame=None):
        """Signal handler: only a flag (a queue's lock is not safe in a handler)."""
        self.stop_requested = True

    def run(self):
        """Run until a signal or a fatal exit; the exit status."""
        say(f'starting {", ".join(c.name for c in self.children)} (Fast DDS profile: '
            f'{self.profile or "default"})')
        waiting = list(self.children)       # not started yet, in order
        since = None                        # when the nodes started so far were all ready
        while not self.stopping:
            if waiting and all(c.ready for c in self.children if c.proc is not None):
                since = since or time.monotonic()
                late = self._unconnected()
                if not late or time.monotonic() - since > CONNECT_WAIT_S:
                    if late:
                        say(f'{", ".join(late)} not connected after {CONNECT_WAIT_S:.0f} s; '
                            f'starting {waiting[0].name} anyway')
                    waiting.pop(0).start()
                    since = None
                    continue
            timeout = POLL_S
            if self.pending:
                timeout = min(timeout, max(0.0, min(self.pending.values()) - time.monotonic()))
            try:
                kind, a, b = self.events.get(timeout=timeout)
            except queue.Empty:
                kind = 'due'
            if self.stop_requested:
                self.stopping = True
            elif kind == 'exit':
                self._exited(a, b)
            now = time.monotonic()
            for child, when in list(self.pending.items()):
                if when <= now and not self.stopping:
                    del self.pending[child]
                    child.start()
        return self._stop_all()

    def _unconnected(self):
        """'<node>'s <topic>' for each running node whose input's publisher (:data:`INPUTS`)
        runs too but which has not logged that its subscription is connected to it."""
        running = {c.name: c for c in self.children if c.proc is not None}
        late = []
        for child in running.values():
            topic, producer = INPUTS.get(child.name, (None, None))
            if producer in running and f'{self.namespace}{topic}' not in child.connected:
                late.append(f"{child.name}'s {self.namespace}{topic}")
        if self.show is not None:
            late += [f"--show's {topic}" for topic in self.show.unconnected(running)]
        return late

    def _exited(self, child, proc):
        if proc is not child.proc or self.stopping:
            return
        code = proc.returncode
        lived = time.monotonic() - child.started
        how = f'signal {_signal_name(code)}' if code < 0 else f'exit {code}'
        self._remove_left_files(child.name)
        if code == STARTUP_EXIT:
            say(f'{child.name} cannot start ({how}): {child.last_line}; stopping the graph')
            self.status, self.stopping = STARTUP_EXIT, True
            return
        if lived >= STABLE_RUN_S:       # ran a while: restarted, its count starts again
            child.restarts = 0
            say(f'{child.name} died ({how}) after {lived:.1f} s; restart (after '
                f'{STABLE_RUN_S:g} s or more of running: not counted)')
        else:
            child.restarts += 1
            if child.restarts > self.max_restarts:
                say(f'{child.name} died ({how}) after {lived:.1f} s; more than '
                    f'{self.max_restarts} restarts in a row, each within {STABLE_RUN_S:g} s: '
                    'stopping the graph')
                self.status, self.stopping = 1, True
                return
            say(f'{child.name} died ({how}) after {lived:.1f} s; restart {child.restarts}')
        self.pending[child] = time.monotonic() + self.restart_delay

    @staticmethod
    def _remove_left_files(names):
        """Remove the Fast DDS shared-memory files of processes that ended without deleting
        their participant (:func:`tt_ros.shm.remove_dead_segments`), with one line."""
        removed = remove_dead_segments()
        if removed:
            say(f'{names} ended: removed {removed} Fast DDS shared-memory files in /dev/shm '
                'that no running process holds')

    def _stop_all(self):
        """SIGINT to every running node, then SIGTERM, then (its stacks written, SIGUSR1)
        SIGKILL; the exit status."""
        live = [c for c in self.children if c.proc is not None and c.proc.poll() is None]
        for c in live:
            c.signal(signal.SIGINT)
        codes = {}
        for sig, wait in ((None, self.stop_timeout), (signal.SIGTERM, 5.0),
                          (STACKS_SIGNAL, STACKS_WAIT_S), (signal.SIGKILL, 5.0)):
            deadline = time.monotonic() + wait
            for c in live:
                if c.name in codes:
                    continue
                if sig == STACKS_SIGNAL:
                    say(f'{c.name} did not stop on SIGINT nor SIGTERM; the stacks of its '
                        'threads follow, then SIGKILL')
                if sig is not None:
                    c.signal(sig)
                try:
                    codes[c.name] = c.proc.wait(max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    pass
            if len(codes) == len(live):
                break
        bad = {n: code for n, code in codes.items() if code != 0}
        if bad:
            self._remove_left_files(', '.join(bad))
            say('stopped; not clean: ' + ', '.join(
                f'{n} {_signal_name(c) if c < 0 else f"exit {c}"}' for n, c in bad.items()))
            return self.status or 1
        say('stopped')
        return self.status


class Show:
    """``--show``: one line per ball (track) from /ball/prediction and /strike/command (in
    ``namespace``)."""

    def __init__(self, namespace=''):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile
        from rclpy.signals import SignalHandlerOptions

        from tt_msgs.msg import BallPrediction, StrikeCommand

        self.rclpy = rclpy
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(f'_bringup_show_{os.getpid()}', context=self.context)
        self.last_prediction = {}
        self.shown = {}             # track id -> the stamp of its last command, ns
        self.namespace = namespace
        self.subscriptions = {
            '/ball/prediction': self.node.create_subscription(
                BallPrediction, f'{namespace}/ball/prediction', self._prediction,
                QoSProfile(depth=100)),
            '/strike/command': self.node.create_subscription(
                StrikeCommand, f'{namespace}/strike/command', self._command,
                QoSProfile(depth=100)),
        }
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        last_error = None
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.1)
            except Exception as exc:
                if not self.context.ok():       # shut down under us: the end
                    return
                error = f'{type(exc).__name__}: {exc}'
                if error != last_error:         # shown once in a row, and spinning goes on
                    say(f'--show: {error}')
                last_error = error

    def unconnected(self, running):
        """The topics (:data:`SHOWN`) whose publishing node is among ``running`` but which
        have no publisher matched yet."""
        return [f'{self.namespace}{topic}' for topic, producer in SHOWN.items()
                if producer in running and self.subscriptions[topic].get_publisher_count() == 0]

    def _prediction(self, msg):
        self.last_prediction[msg.track_id] = msg

    def _command(self, msg):
        # One line per ball: a track id's first command, or one stamped before its last or
        # more than NEW_BALL_GAP_S after it (another ball under the id: a bag played again, a
        # restarted perception_node numbering from 1; each id was shown once for good).
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        last = self.shown.get(msg.track_id)
        self.shown[msg.track_id] = stamp
        if last is not None and last <= stamp <= last + NEW_BALL_GAP_S * 1e9:
            return
        p = self.last_prediction.get(msg.track_id)
        bounce = (f'bounce zone {p.bounce_zone} at ({p.bounce_point.x:.2f}, '
                  f'{p.bounce_point.y:.2f}) m, ' if p is not None and p.bounce_valid else '')
        h = msg.hit_point
        stroke = (f'racket ({msg.racket_velocity.x:.2f}, {msg.racket_velocity.y:.2f}, '
                  f'{msg.racket_velocity.z:.2f}) m/s to zone {msg.landing_zone}'
                  if msg.feasible else f'no stroke: {msg.reason}')
        say(f'ball {msg.track_id}: {bounce}hit ({h.x:.2f}, {h.y:.2f}, {h.z:.2f}) m; '
            f'strike {msg.status}: {stroke}')

    def close(self):
        self.rclpy.try_shutdown(context=self.context)
        self.thread.join(2.0)


def parse_args(argv):
    p = argparse.ArgumentParser(prog='bringup',
                                description=__doc__.splitlines()[0].replace('``', ''))
    p.add_argument('--params-file', required=True,
                   help='ROS parameters file naming the nodes to start (e.g. the installed '
                        'share/tt_tools/config/robot.yaml or replay.yaml)')
    p.add_argument('--nodes', help='comma-separated subset of the nodes the file names '
                   '(e.g. prediction_node,strike_node)')
    p.add_argument('--rig', help='rig file for perception_node (overrides rig_file)')
    p.add_argument('--namespace', default='', metavar='NS',
                   help="ROS namespace of every node (-r __ns:=NS): one robot's graph of "
                        "several on a domain, its topics NS/ball/state, ... and its clock "
                        "NS/clock; the file's sections apply as rcl applies them "
                        '(/NS/prediction_node:, /**/prediction_node:, /**:)')
    p.add_argument('--show', action='store_true',
                   help='print one line per ball: prediction and strike command')
    p.add_argument('--restart-delay', type=non_negative_float, default=1.0,
                   help='seconds before a node that died is started again (default 1)')
    p.add_argument('--max-restarts', type=non_negative_int, default=5,
                   help=f'restarts of one node in a row, each dying within {STABLE_RUN_S:g} s '
                   'of its start, before the graph stops (default 5)')
    p.add_argument('--stop-timeout', type=positive_float, default=10.0,
                   help='seconds a node has to exit after SIGINT (default 10)')
    args = p.parse_args(argv)
    return args


def main(argv=None):
    args = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        error = domain_id_error()
        if error:  # each node would refuse it; --show's node would not start
            raise BringupError(error)
        namespace = args.namespace.rstrip('/')
        if namespace and (not namespace.startswith('/') or name_error(namespace)):
            raise BringupError(f'--namespace {args.namespace}: '
                               + (name_error(namespace) or 'must start with /'))
        sections = read_params(args.params_file)
        nodes = nodes_in(sections, args.params_file, namespace)
        if args.nodes is not None:                    # '' names no node: refused too
            wanted = [n.strip() for n in args.nodes.split(',') if n.strip()]
            unknown = [n for n in wanted if n not in nodes]
            if unknown or not wanted:
                raise BringupError(f'--nodes {args.nodes}: not among the nodes of '
                                   f'{args.params_file} ({", ".join(nodes)})')
            nodes = [n for n in nodes if n in wanted]
        extra = {}
        if args.rig:
            if 'perception_node' not in nodes:
                raise BringupError('--rig given but the file starts no perception_node')
            if not os.path.isfile(args.rig):
                why = 'not a file' if os.path.exists(args.rig) else 'no such file'
                raise BringupError(f'--rig {args.rig}: {why}')
            extra['perception_node'] = ['-p', f'rig_file:={os.path.abspath(args.rig)}']
        elif 'perception_node' in nodes and not configured_rig(sections, namespace):
            # Checked before any node starts: prediction and strike came up, then the graph
            # stopped with perception_node's 'rig_file is empty'.
            raise BringupError(f'perception_node has no rig: give --rig RIG (or rig_file in '
                               f'a section of {args.params_file} that applies to it)')
        bringup = Bringup(args.params_file, nodes, extra, args.restart_delay,
                          args.max_restarts, args.stop_timeout, namespace=namespace)
    except (BringupError, RunError) as exc:
        print(f'bringup: {exc}', file=sys.stderr)
        return 2
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, bringup.request_stop)
    show = bringup.show = Show(namespace) if args.show else None
    try:
        return bringup.run()
    finally:
        if show is not None:
            show.close()


if __name__ == '__main__':
    sys.exit(main())
