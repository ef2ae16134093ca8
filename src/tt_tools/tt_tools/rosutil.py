"""ROS glue shared by the ``ros2`` verbs: a short-lived node with clean SIGINT/SIGTERM, QoS."""

import collections
import difflib
import faulthandler
import os
import signal
import time

import rclpy
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSPresetProfiles,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.signals import SignalHandlerOptions
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from tt_ros.executor import SHUTDOWN_LIMIT_S
from tt_ros.names import name_error
from tt_ros.rosenv import domain_id_error

from tt_tools import stop
from tt_tools.argtypes import positive_float
from tt_tools.output import say

SETTLE_MIN_S = 3.5
"""Shortest settle, s. On a loaded machine (two cores busy) a fresh process sees the
participants of running nodes one at a time, up to 1.7 s apart and up to 3.3 s after it
started (measured 28 Nov 2026 with two idle nodes: with 2.0 s, `node list` left one out in 1
of 6 to 4 of 6 calls; with 3.5 s, in none of 12)."""
SETTLE_QUIET_S = 1.0
SETTLE_ALONE_S = 8.0
SETTLE_MAX_S = 15.0
LATE_NODE_S = 5.0
"""Seconds a named node not yet discovered once discovery has settled is still waited for."""
DISCOVERY_TOPIC = 'ros_discovery_info'
"""The DDS topic on which every ROS participant announces its nodes and their endpoints."""
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'
"""The node name of an endpoint whose participant's node list has not arrived yet."""

RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE,
               'best_effort': ReliabilityPolicy.BEST_EFFORT,
               'system_default': ReliabilityPolicy.SYSTEM_DEFAULT}
DURABILITY = {'volatile': DurabilityPolicy.VOLATILE,
              'transient_local': DurabilityPolicy.TRANSIENT_LOCAL,
              'system_default': DurabilityPolicy.SYSTEM_DEFAULT}
HISTORY = {'keep_last': HistoryPolicy.KEEP_LAST, 'keep_all': HistoryPolicy.KEEP_ALL,
           'system_default': HistoryPolicy.SYSTEM_DEFAULT}


def leave_graph(executor, node, context):
    """Shut ``executor`` down, destroy ``node`` and shut its ``context`` down. Fast DDS can
    deadlock in this teardown (a write of the graph's update meeting a remote participant's
    lease running out, as in eProsima/Fast-DDS#6502: once in a fresh-clone make test, `ros2
    service find` stayed in destroy_node for good). Past SHUTDOWN_LIMIT_S every thread's stack
    goes to stderr and the process ends with 1, as a node's teardown does
    (tt_ros.executor.run_node)."""
    faulthandler.dump_traceback_later(SHUTDOWN_LIMIT_S, exit=True)
    try:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    finally:
        faulthandler.cancel_dump_traceback_later()


def run_waiting(executor, progress, idle_rounds=3):
    """Run the callbacks of messages already waiting, without blocking: spins of 0 s until
    ``idle_rounds`` in a row leave ``progress()`` (a count of handled messages) where it was.
    One idle spin is not enough: rclpy's spin_once(0) takes nothing every other call (it
    ends the wait whose callbacks the previous calls ran), so stopping at the first would
    take at most two messages a call, however many are waiting."""
    idle, last = 0, progress()
    while idle < idle_rounds:
        executor.spin_once(timeout_sec=0.0)
        idle, last = (idle + 1, last) if progress() == last else (0, progress())


class CliNode:
    """A hidden node in its own context; SIGINT/SIGTERM set ``stopped`` instead of raising.
    ``use_sim_time``: its clock is the ROS time of /clock instead of this machine's.
    ``node_name``: the node's name (a valid one, checked by the caller) instead of the hidden
    ``_ros2cli_<name>_<pid>``.

    Use as a context manager; ``spin_until(condition)`` spins in 0.1 s steps, so a signal is
    noticed between callbacks (never inside one: a bag being written stays consistent).
    """

    def __init__(self, name, use_sim_time=False, node_name=None):
        error = domain_id_error()
        if error:  # rcl's traceback, or Fast DDS ending the process, otherwise
            raise ValueError(error)
        # The handlers first: a signal from here on (the node is in the graph as soon as it
        # exists) stops the verb; one that came while it was importing (stop.requested) too.
        self._old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        self.stopped = stop.requested
        self._participants = 0
        self.use_sim_time = use_sim_time
        self.context = rclpy.context.Context()
        # No command line for rcl: it would take any 'a:=b' among the verb's arguments (bag
        # play --remap's, a YAML value of topic pub's) for a deprecated remap rule of its own.
        rclpy.init(args=[], context=self.context,
                   signal_handler_options=SignalHandlerOptions.NO)
        # use_sim_time: the node's clock reads /clock (a bag played with --clock).
        self.node = rclpy.create_node(
            node_name or f'_ros2cli_{name}_{os.getpid()}', context=self.context,
            start_parameter_services=False,
            parameter_overrides=[Parameter('use_sim_time', value=True)] if use_sim_time else [])
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def _on_signal(self, signum, frame):
        self.stopped = True

    def spin_until(self, condition=lambda: False, timeout=None, step=0.1):
        """Spin until ``condition()`` is true (True), or a signal or ``timeout`` s (False)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self.stopped:
            if condition():
                return True
            left = step if deadline is None else min(step, deadline - time.monotonic())
            if left <= 0:
                return False
            self.executor.spin_once(timeout_sec=left)
        return False

    def graph_snapshot(self):
        """Everything discovery has told this node so far: nodes, topics and services with
        their types, and every topic endpoint with its node (tt's own node left out)."""
        node, own = self.node, self.node.get_name()
        nodes = sorted((ns, name) for name, ns in node.get_node_names_and_namespaces()
                       if name != own)
        topics = sorted((name, tuple(types)) for name, types in node.get_topic_names_and_types())
        services = sorted((name, tuple(types))
                          for name, types in node.get_service_names_and_types())
        endpoints = []
        for name, _ in topics:
            for kind, infos in (('pub', node.get_publishers_info_by_topic(name)),
                                ('sub', node.get_subscriptions_info_by_topic(name))):
                endpoints.extend((name, kind, i.node_namespace, i.node_name) for i in infos
                                 if i.node_name != own)
        return nodes, topics, services, sorted(endpoints)

    def discovery_complete(self):
        """Whether discovery of the participants seen so far looks complete.

        Every ROS participant has one writer and one reader on the DDS topic
        ``ros_discovery_info``, created before any node's endpoint. Complete means: each
        participant with one of them known has the other known too (Fast DDS announces
        writers and readers separately, and a participant's readers can come seconds after
        its writers on a loaded machine), and every endpoint's node is known (its
        participant's node list has arrived). What it cannot know: a participant none of
        whose announcements has arrived yet (``settle`` waits ``min_time`` for those).
        """
        node = self.node
        ends = {'PUBLISHER': set(), 'SUBSCRIPTION': set()}
        for info in (node.get_publishers_info_by_topic(DISCOVERY_TOPIC, no_mangle=True)
                     + node.get_subscriptions_info_by_topic(DISCOVERY_TOPIC, no_mangle=True)):
            ends.setdefault(info.endpoint_type.name, set()).add(bytes(info.endpoint_gid[:12]))
        if ends['PUBLISHER'] != ends['SUBSCRIPTION']:
            return False
        self._participants = len(ends['PUBLISHER'])
        for name, _ in node.get_topic_names_and_types():
            for info in (node.get_publishers_info_by_topic(name)
                         + node.get_subscriptions_info_by_topic(name)):
                if info.node_name == UNKNOWN_NODE:
                    return False
        return True

    def settle(self, spin_time=None, done=None, min_time=SETTLE_MIN_S, quiet=SETTLE_QUIET_S,
               max_time=SETTLE_MAX_S):
        """Spin until discovery has settled; True when ``done()`` became true first.

        Without a daemon the first answer of a new process is incomplete while discovery
        runs (0.5-4 s on a loaded machine). Settled means: at least ``min_time`` s spun, the
        graph (``graph_snapshot``) unchanged for the last ``quiet`` s, and
        ``discovery_complete()``; at most ``max_time`` s. ``spin_time`` given
        (``--spin-time``): spin exactly that long instead (or until ``done()``). False also
        on a signal.
        """
        done = done or (lambda: False)
        if spin_time is not None:
            return self.spin_until(done, timeout=spin_time)
        start = last_change = time.monotonic()
        last = None
        while not self.stopped:
            if done():
                return True
            now = time.monotonic()
            snapshot = self.graph_snapshot()
            if snapshot != last:
                last, last_change = snapshot, now
                if os.environ.get('TT_SETTLE_DEBUG'):
                    say(f'settle {now - start:.2f} s: {len(snapshot[0])} nodes, '
                        f'{len(snapshot[1])} topics, {len(snapshot[3])} endpoints')
            if now - start >= max_time:
                return False
            if (now - start >= min_time and now - last_change >= quiet
                    and self.discovery_complete()
                    and (self._participants > 1 or now - start >= SETTLE_ALONE_S)):
                if os.environ.get('TT_SETTLE_DEBUG'):
                    say(f'settled {now - start:.2f} s')
                return False
            self.executor.spin_once(timeout_sec=0.05)
        return False

    def wait_saying(self, condition, message):
        """Spin until ``condition()`` (True) or a signal (False). If discovery settles and it
        is still false, write ``message()`` (one line, what we wait for) to stderr, once."""
        if self.settle(done=condition):
            return True
        if self.stopped:
            return False
        say(message())
        return self.spin_until(condition)

    def wait_for_clock(self):
        """With ``use_sim_time``, spin until the first /clock message has given the node a
        time (True) or a signal (False), saying so once discovery settled without one (the
        time is 0 until then: a stamp of 0, a delay of minus the stamp); else True."""
        clock = self.node.get_clock()
        return not self.use_sim_time or self.wait_saying(
            lambda: clock.now().nanoseconds > 0,
            lambda: 'waiting for /clock (--use-sim-time: no time until its first message)')

    def drain(self, progress, idle_rounds=3):
        """Run callbacks already waiting (messages received before a stop) without blocking
        (:func:`run_waiting`; ``progress()`` counts handled messages)."""
        run_waiting(self.executor, progress, idle_rounds)

    def close(self):
        leave_graph(self.executor, self.node, self.context)
        for sig, handler in self._old.items():
            signal.signal(sig, handler)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def add_spin_time_argument(parser):
    """``--spin-time S`` of the verbs that look at the graph."""
    parser.add_argument(
        '--spin-time', type=positive_float, default=None,
        help='seconds to wait for discovery (default: until discovery has settled: the graph '
             f'unchanged for {SETTLE_QUIET_S:g} s, at least {SETTLE_MIN_S:g} s, at most '
             f'{SETTLE_MAX_S:g} s)')


def add_use_sim_time_argument(parser):
    """``--use-sim-time`` of the verbs that read the clock (``topic delay``, ``topic pub``)."""
    parser.add_argument('--use-sim-time', action='store_true',
                        help='read the time from /clock (e.g. a bag played with --clock) '
                             "instead of this machine's clock")


def absolute_name(name):
    """A topic or node ``name`` with a leading '/' (names on the command line may be given
    without one)."""
    return name if name.startswith('/') else '/' + name


def hidden_name(name):
    """Whether a topic's, service's or node's name is hidden: one of its parts begins with
    '_' (ros2cli's rule)."""
    return any(part.startswith('_') for part in name.split('/'))


def graph_names(spin_time, node_name, include_hidden, services=False):
    """[(name, [type, ...])] of the topics (``services``: the services) in the graph once
    discovery settled (:meth:`CliNode.settle`), sorted; hidden ones (:func:`hidden_name`) only
    with ``include_hidden``. ``node_name``: the command's own node's."""
    with CliNode(node_name) as cli:
        cli.settle(spin_time)
        node = cli.node
        found = sorted(node.get_service_names_and_types() if services
                       else node.get_topic_names_and_types())
    return [(name, types) for name, types in found if include_hidden or not hidden_name(name)]


def absolute_node_name(name):
    """:func:`absolute_name` of a node's name from the command line; ValueError (one line)
    for one no node can have."""
    error = name_error(name)
    if error:
        raise ValueError(f"node name '{name}' is invalid: {error}")
    return absolute_name(name)


def node_full_name(name, ns):
    """``'/ns/name'`` of a node ``name`` in namespace ``ns`` (``'/name'`` in ``'/'``)."""
    return f'{ns.rstrip("/")}/{name}'


def node_names(cli, hidden=False):
    """Sorted full names of the nodes ``cli`` (a :class:`CliNode`) has discovered; nodes
    whose name starts with '_' only with ``hidden``."""
    return sorted({node_full_name(name, ns)
                   for name, ns in cli.node.get_node_names_and_namespaces()
                   if hidden or not name.startswith('_')})


def node_hint(cli, full_name):
    """``"; did you mean '<node>'?"`` for the discovered node whose name is nearest the
    absent ``full_name`` (mistyped: `ros2 node info /predictoin_node` said only that it was
    not found, where `topic echo` suggests a topic; a walk-through, 7 Dec 2026), else ''."""
    close = difflib.get_close_matches(full_name, [n for n in node_names(cli)
                                                  if n != full_name], n=1)
    return f"; did you mean '{close[0]}'?" if close else ''


def node_name_counts(cli):
    """How many nodes ``cli`` (a :class:`CliNode`) has discovered under each full name."""
    return collections.Counter(node_full_name(name, ns)
                               for name, ns in cli.node.get_node_names_and_namespaces())


def topic_type(node, topic):
    """The type string of ``topic`` in the graph ('pkg/msg/Type'), or None if not seen yet."""
    for name, types in node.get_topic_names_and_types():
        if name == topic and types:
            return types[0]
    return None


def _compatible_policies(offered, empty_reliable):
    """(reliability, durability) compatible with every offered ``(reliability, durability)``
    pair of rmw enum values: reliable only if all offer reliable, transient-local only if all
    do (what ros2cli and rosbag2 choose); reliable as ``empty_reliable`` when none is offered.
    """
    reliable = (all(r == ReliabilityPolicy.RELIABLE for r, _ in offered) if offered
                else empty_reliable)
    transient = bool(offered) and all(d == DurabilityPolicy.TRANSIENT_LOCAL for _, d in offered)
    return (ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
            DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)


def qos_matching(publishers, depth=10):
    """A subscription QoS that matches every publisher in ``publishers`` (endpoint infos).

    Reliable only if all publishers offer reliable, transient-local only if all do (what
    ros2cli and rosbag2 choose). ``depth`` None: keep all (a slow reader then holds reliable
    publishers back rather than losing their messages).
    """
    rel, dur = _compatible_policies(
        [(p.qos_profile.reliability, p.qos_profile.durability) for p in publishers],
        empty_reliable=False)
    if depth is None:
        return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=rel, durability=dur)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=rel,
                      durability=dur)


QOS_PROFILES = [k for k in QoSPresetProfiles.short_keys() if k != 'unknown']
"""``--qos-profile`` choices: rclpy's presets by ros2cli's names (``sensor_data``, ...)."""


def chosen_qos(args, publishers=None):
    """The QoS ``topic echo`` (``publishers`` given) or ``topic pub`` asks for:
    ``args.qos_profile``'s preset, else one matching the ``publishers``
    (:func:`qos_matching`), else reliable, volatile, depth 10; then ``args.qos_reliability``,
    ``qos_durability``, ``qos_depth`` and ``qos_history`` in place of the preset's where
    given (keep_all: the depth is not used)."""
    if args.qos_profile:
        preset = QoSPresetProfiles.get_from_short_key(args.qos_profile)
        qos = QoSProfile(history=preset.history, depth=preset.depth,
                         reliability=preset.reliability, durability=preset.durability)
    elif publishers is not None:
        qos = qos_matching(publishers)
    else:
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
    if args.qos_reliability:
        qos.reliability = RELIABILITY[args.qos_reliability]
    if args.qos_durability:
        qos.durability = DURABILITY[args.qos_durability]
    if args.qos_depth is not None:
        qos.history, qos.depth = HistoryPolicy.KEEP_LAST, args.qos_depth
    if args.qos_history:
        qos.history = HISTORY[args.qos_history]
    return qos


def _qos_time(duration):
    ns = duration.nanoseconds
    return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)


def qos_to_bag(profile):
    """rclpy QoSProfile -> rosbags Qos (the offered_qos_profiles entry of metadata.yaml)."""
    return Qos(
        history=QosHistory(int(profile.history)),
        depth=int(profile.depth),
        reliability=QosReliability(int(profile.reliability)),
        durability=QosDurability(int(profile.durability)),
        deadline=_qos_time(profile.deadline),
        lifespan=_qos_time(profile.lifespan),
        liveliness=QosLiveliness(int(profile.liveliness)),
        liveliness_lease_duration=_qos_time(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


def qos_from_bag(profiles, depth=100):
    """Publisher QoS for replaying a topic recorded with ``profiles`` (rosbags Qos list).

    Reliability and durability are kept (best-effort if any recorded publisher offered it,
    transient-local only if every one did; reliable when the bag has no profiles); deadline,
    lifespan and liveliness are left at the defaults.
    """
    rel, dur = _compatible_policies(
        [(q.reliability.value, q.durability.value) for q in profiles], empty_reliable=True)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=rel, durability=dur,
        liveliness=LivelinessPolicy.AUTOMATIC, lifespan=Duration(),
    )
