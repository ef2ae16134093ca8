"""``ros2 bag record | play | info`` on rclpy and rosbags (rosbag2's on-disk format)."""

import difflib
import os
import re
import sys
import time

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from tt_ros.bagfile import (
    STORAGES,
    BagError,
    BagWriter,
    bag_folder,
    default_bag_name,
    format_info,
    open_bag,
)
from tt_ros.messages import seconds_text
from tt_ros.names import name_error

from tt_tools.argtypes import non_negative_float, non_negative_int, positive_float, positive_int
from tt_tools.introspect import import_message_type
from tt_tools.rosutil import CliNode, absolute_name, qos_from_bag, qos_matching, qos_to_bag

MARGIN_S = 0.5
"""Time the player gives DDS at both ends of a play, s: its subscribers, once it has
matched them, to match it in turn (--wait-for-subscribers, --wait-for-topic), and its last
messages to reach best-effort subscribers (which no acknowledgement tells of) before the
process ends."""


def _say(text):
    print(text, file=sys.stderr, flush=True)


def bag_info(args):
    reader = open_bag(args.bag)
    try:
        print(format_info(reader, bag_folder(args.bag)), flush=True)
    finally:
        reader.close()
    return 0


def _topic_names(names, option=''):
    """Absolute names of the topic ``names`` from the command line; BagError (one line, naming
    ``option``) for one no topic can have."""
    for name in names:
        error = name_error(name)
        if error:
            raise BagError(f"{option}topic name '{absolute_name(name)}' is invalid: {error}")
    return {absolute_name(n) for n in names}


def _regex(text, option):
    """``text`` compiled; BagError (one line, naming ``option``) when it is no regex."""
    try:
        return re.compile(text)
    except re.error as exc:
        raise BagError(f"{option} '{text}' is not a regular expression: {exc}") from None


def _filters(args, named_option=''):
    """(topics named, --exclude-topics, -e's regex, --exclude-regex's) of ``args``; None for a
    regex not given. BagError (one line) for a bad name or regex."""
    named = _topic_names(args.topics or [], named_option)
    excluded = _topic_names(args.exclude_topics or [], '--exclude-topics: ')
    include = None if args.regex is None else _regex(args.regex, '-e')
    exclude = None if args.exclude_regex is None else _regex(args.exclude_regex,
                                                             '--exclude-regex')
    return named, excluded, include, exclude


def topic_chooser(args):
    """(the topics ``bag record`` was given by name, a test of a topic's name): a topic is
    recorded when given by name, or under ``-a`` or matching ``-e`` (anywhere in the name) and
    then neither matching ``--exclude-regex`` nor in ``--exclude-topics`` (which apply to
    ``-a`` and ``-e`` only, as rosbag2's). BagError (one line) for a bad name or regex."""
    named, excluded, include, exclude = _filters(args)

    def chosen(name):
        if name in named:
            return True
        return ((args.all or (include is not None and include.search(name) is not None))
                and name not in excluded and not (exclude is not None and exclude.search(name)))

    return named, chosen


def play_chooser(args):
    """A test of a recorded topic's name for ``bag play``: every topic when neither
    ``--topics`` nor ``-e`` is given, else those named and those ``-e`` matches (anywhere in
    the name); then none that ``--exclude-regex`` matches or ``--exclude-topics`` names (they
    apply to every topic, named ones too, as rosbag2's play). BagError (one line) for a bad
    name or regex."""
    named, excluded, include, exclude = _filters(args, '--topics: ')

    def chosen(name):
        wanted = ((not named and include is None) or name in named
                  or (include is not None and include.search(name) is not None))
        return (wanted and name not in excluded
                and not (exclude is not None and exclude.search(name)))

    return chosen


def bag_record(args):
    if not args.all and not args.topics and args.regex is None:
        raise BagError('give the topics to record, -e REGEX, or -a for all')
    named, chosen = topic_chooser(args)   # before the bag is made: no empty bag left behind
    out = args.output or default_bag_name()
    if os.path.exists(out):
        raise BagError(f"output '{out}' already exists")
    with CliNode('bag_record') as cli:
        own = cli.node.get_name()
        try:
            writer = BagWriter(out, args.storage)
        except OSError as exc:            # /proc/x, a read-only disk, a file as the parent
            raise BagError(f"output '{out}': cannot write: {exc.strerror or exc}") from None
        subscribed, skipped = {}, set()

        def subscribe(topic):
            pubs = [p for p in cli.node.get_publishers_info_by_topic(topic)
                    if p.node_name != own]
            if not pubs:
                return
            msgtype = pubs[0].topic_type
            try:
                cls = import_message_type(msgtype)
                conn = writer.add_topic(topic, msgtype, [qos_to_bag(p.qos_profile) for p in pubs],
                                        str(pubs[0].topic_type_hash))
            except (ValueError, BagError) as exc:
                skipped.add(topic)
                _say(f"[WARN] not recording '{topic}': {exc}")
                return
            clock = cli.node.get_clock()

            def on_message(data):
                writer.write(conn, clock.now().nanoseconds, data)

            subscribed[topic] = cli.node.create_subscription(
                cls, topic, on_message, qos_matching(pubs, depth=args.qos_depth), raw=True)
            _say(f"[INFO] Subscribed to topic '{topic}' ({msgtype})")

        def discover():
            # Called between spins: subscribe to wanted topics as their publishers appear.
            topics = (named if not args.all and args.regex is None
                      else [name for name, _ in cli.node.get_topic_names_and_types()])
            for topic in topics:
                if topic not in subscribed and topic not in skipped and chosen(topic):
                    subscribe(topic)
            return False

        _say(f"[INFO] Recording to '{out}' ({args.storage}); Ctrl-C or SIGTERM stops")
        try:
            cli.spin_until(discover)
            cli.drain(lambda: writer.count)
        finally:
            for sub in subscribed.values():
                cli.node.destroy_subscription(sub)
            writer.close()
        if not args.all and args.regex is None:
            known = [name for name, _ in cli.node.get_topic_names_and_types()]
            for topic in sorted(set(named) - set(subscribed) - skipped):
                close = difflib.get_close_matches(topic, [k for k in known if k != topic], n=1)
                hint = f"; did you mean '{close[0]}'?" if close else ''
                _say(f"[WARN] '{topic}' not recorded: no publisher of it appeared{hint}")
    _say(f"[INFO] Recorded {writer.count} messages to '{out}'")
    return 0


def _playable(reader, chosen, args):
    """Connections to replay (those whose topic ``chosen`` passes) and their message
    classes."""
    conns = [c for c in reader.connections if chosen(c.topic)]
    if not conns:
        given = [option for option, value in (
            ('--topics', args.topics), ('-e', args.regex), ('--exclude-regex', args.exclude_regex),
            ('--exclude-topics', args.exclude_topics)) if value is not None]
        raise BagError(f'{", ".join(given)}: no topic of the bag chosen (it has '
                       + ' '.join(sorted({c.topic for c in reader.connections})) + ')')
    classes = {}
    for conn in conns:
        try:
            classes[conn.id] = import_message_type(conn.msgtype)
        except ValueError as exc:
            _say(f"[WARN] not playing '{conn.topic}': {exc}")
    if not classes:
        raise BagError('no topic of the bag has a message type installed here')
    return [c for c in conns if c.id in classes], classes


def play_window(args, start_ns, end_ns):
    """(first, last) bag time to play, ns, both included: from ``--start-offset`` after the
    bag's start ``start_ns``, until ``--playback-duration`` after that or
    ``--playback-until-sec`` / ``--playback-until-nsec``, whichever comes first (rosbag2's),
    else the bag's end ``end_ns``. BagError (one line) when that leaves nothing to play."""
    length = (end_ns - start_ns) / 1e9
    if args.start_offset > length:
        raise BagError(f'--start-offset {args.start_offset:g} s is past the end of the bag '
                       f'({length:.2f} s long): nothing to play')
    first = start_ns + int(round(args.start_offset * 1e9))
    last = end_ns
    if args.playback_duration is not None:
        last = min(last, first + int(round(args.playback_duration * 1e9)))
    until = (args.playback_until_nsec if args.playback_until_nsec is not None
             else None if args.playback_until_sec is None
             else int(round(args.playback_until_sec * 1e9)))
    if until is not None:
        if until < first:
            option = ('--playback-until-nsec' if args.playback_until_nsec is not None
                      else '--playback-until-sec')
            raise BagError(f'{option}: {seconds_text(until)} s is before the play starts '
                           f'({seconds_text(first)} s): nothing to play')
        last = min(last, until)
    return first, last


def remappings(pairs):
    """{bag topic: topic to play it on} from ``--remap``'s 'OLD:=NEW' pairs; BagError (one
    line) for a pair that is not one, or a name no topic can have."""
    out = {}
    for pair in pairs or []:
        old, sep, new = pair.partition(':=')
        if not sep or not old or not new:
            raise BagError(f"--remap '{pair}': not OLD_TOPIC:=NEW_TOPIC")
        _topic_names([old, new], '--remap: ')
        out[absolute_name(old)] = absolute_name(new)
    return out


def bag_play(args):
    chosen = play_chooser(args)
    remap = remappings(args.remap)
    chain = sorted({absolute_name(t) for t in args.wait_for_topic or []})
    reader = open_bag(args.bag)
    try:
        if reader.message_count == 0:
            raise BagError(f"bag '{args.bag}' holds no message: nothing to play")
        first, last = play_window(args, reader.start_time, reader.end_time)
        conns, classes = _playable(reader, chosen, args)
        recorded = {c.topic for c in reader.connections}
        absent = sorted(_topic_names(args.topics or [], '--topics: ') - recorded)
        if absent:
            _say(f'[WARN] --topics: {" ".join(absent)} not in the bag (it has '
                 f'{" ".join(sorted(recorded))})')
        # --clock's /clock may be remapped too (rosbag2 applies remaps to it: a robot's graph
        # in a namespace, on its own clock; refused before, a walk-through, 6 Dec 2026).
        clock_topic = remap.get('/clock', '/clock') if args.clock is not None else None
        unknown = sorted(set(remap) - {c.topic for c in conns}
                         - ({'/clock'} if clock_topic else set()))
        if unknown:
            raise BagError(f'--remap {" ".join(unknown)}: not among the topics played')
        with CliNode('bag_play') as cli:
            pubs = {}
            for conn in conns:
                qos = qos_from_bag(conn.ext.offered_qos_profiles, depth=args.qos_depth)
                pubs[conn.id] = cli.node.create_publisher(
                    classes[conn.id], remap.get(conn.topic, conn.topic), qos)
            # /clock's publisher with the others, and waited for as they are: made after the
            # wait, a node on /clock matched it up to 2 s after the first messages, and judged
            # them against the clock a previous player had left (stale, too late). Every
            # /clock subscription the graph shows, none when there is none (no consumer on
            # sim time: ros2 topic echo, a recorder).
            clock_pub = _clock_publisher(cli, clock_topic) if clock_topic else None

            def waiting():
                out = []
                if args.wait_for_subscribers:
                    out = [p.topic_name for p in pubs.values() if p.get_subscription_count() == 0]
                    if clock_pub is not None and (clock_pub.get_subscription_count()
                                                  < cli.node.count_subscribers(clock_topic)):
                        out.append(clock_topic)
                # Links further down the chain (prediction -> strike), which the player does
                # not publish: the graph shows a publisher and a subscription of each.
                out += [t for t in chain if not (cli.node.count_publishers(t)
                                                 and cli.node.count_subscribers(t))]
                return sorted(out)

            if args.wait_for_subscribers or chain:
                options = ', '.join(o for o, on in (('--wait-for-subscribers',
                                                     args.wait_for_subscribers),
                                                    ('--wait-for-topic', chain)) if on)
                if not cli.wait_saying(
                        lambda: not waiting(),
                        lambda: f'waiting for the graph ({options}; not yet: '
                                + ', '.join(waiting()) + ')'):
                    return 0
                # The player has matched each subscription; the subscriber matches the player
                # in turn, a moment later, and a message sent before drops (1-2 of 40 states
                # in 3 of 6 plays into a node just started). No DDS call tells when.
                cli.spin_until(timeout=MARGIN_S)
                if cli.stopped:
                    return 0
            if args.delay > 0:
                cli.spin_until(timeout=args.delay)          # the delay, or a signal
                if cli.stopped:
                    return 0
            # Bag time now = first + (monotonic time since t0) * rate, never past the window's
            # end: a player woken late (a busy machine) ran its /clock tick 15 ms beyond it.
            state = {'t0': time.monotonic()}
            unheard, sent = {}, {}        # per publisher: messages sent with no match, all
            tick = None
            if clock_pub is not None:
                def bag_time_ns():
                    if state.get('ended'):
                        return None
                    elapsed = time.monotonic() - state['t0']
                    return min(last, first + int(elapsed * args.rate * 1e9))

                tick = _publish_clock(cli, clock_pub, args.clock, bag_time_ns)
            while not cli.stopped:
                state['t0'] = time.monotonic()
                if tick is not None:
                    # The pass's start on /clock before its first message: after --loop's
                    # jump back, the timer's last tick was the previous pass's end, and
                    # the first messages were stale by the bag's length.
                    tick()
                played = 0
                for conn, stamp, data in reader.messages(connections=conns, start=first,
                                                    stop=last + 1):
                    due = state['t0'] + (stamp - first) / 1e9 / args.rate
                    cli.spin_until(timeout=due - time.monotonic())
                    if cli.stopped:
                        break
                    pub = pubs[conn.id]
                    if not pub.get_subscription_count():
                        unheard[conn.id] = unheard.get(conn.id, 0) + 1
                    sent[conn.id] = sent.get(conn.id, 0) + 1
                    pub.publish(bytes(data))
                    played += 1
                if not args.loop or not played:
                    break
            for pub in pubs.values():  # let reliable subscribers fetch the last messages
                pub.wait_for_all_acked(Duration(seconds=1.0))
            _say_unheard(pubs, unheard, sent)
            # A node's best-effort subscription of a reliable recording (a state from ros2
            # topic pub into prediction_node) lost the last state in 1 of 6 plays.
            if not cli.stopped:
                state['ended'] = True           # the bag's time stops at its end
                cli.spin_until(timeout=MARGIN_S)
    finally:
        reader.close()
    return 0


def _say_unheard(pubs, unheard, sent):
    """Warn, for each topic whose subscriber matched only after the play had begun, of the
    messages that went out before it did (``unheard``, ``sent``: counts by the key of the
    publisher in ``pubs``): they reached no one (at least those; a match is not seen from
    the subscriber's side). A plain play into nodes already running lost the first 1-3.5 s
    of a bag (discovery), all of a 2.5 s one at -r 2, with nothing said (a walk-through, 7
    Dec 2026). Not a topic nobody subscribes (no loss), nor a transient-local one (a late
    subscriber gets the latest messages)."""
    by_topic = {}
    for key, pub in pubs.items():
        if (unheard.get(key) and pub.get_subscription_count()
                and pub.qos_profile.durability != DurabilityPolicy.TRANSIENT_LOCAL):
            lost, of = by_topic.get(pub.topic_name, (0, 0))
            by_topic[pub.topic_name] = (lost + unheard[key], of + sent[key])
    for topic, (lost, of) in sorted(by_topic.items()):
        _say(f'[WARN] {lost} of {of} messages on {topic} went out before its subscriber '
             'matched, to no one: --wait-for-subscribers waits for the subscribers first')


def _clock_publisher(cli, topic='/clock'):
    """The player's rosgraph_msgs/Clock publisher on ``topic`` (/clock, or where --remap puts
    it; rclcpp's ClockQoS: best effort, depth 1)."""
    from rosgraph_msgs.msg import Clock

    return cli.node.create_publisher(
        Clock, topic, QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))


def _publish_clock(cli, pub, rate_hz, bag_time_ns):
    """Publish the bag time on ``pub`` (:func:`_clock_publisher`) at ``rate_hz``, while
    ``bag_time_ns()`` gives one (None: no more); returns the function that publishes it once,
    now."""
    from rosgraph_msgs.msg import Clock

    def tick():
        ns = bag_time_ns()
        if ns is None:                  # the play has ended
            return
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(ns, 1_000_000_000)
        pub.publish(msg)

    cli.node.create_timer(1.0 / rate_hz, tick)
    return tick


def add_arguments(bag_sub):
    """Register the bag verbs on an argparse sub-parser."""
    p = bag_sub.add_parser('record', help='record topics into a rosbag2 bag')
    p.add_argument('topics', nargs='*', help='topics to record')
    p.add_argument('-a', '--all', action='store_true', help='record every topic')
    p.add_argument('-e', '--regex', metavar='REGEX',
                   help='also record every topic whose name this regular expression matches '
                        "(anywhere in it: '/ball/' records /ball/state and /ball/prediction)")
    p.add_argument('-x', '--exclude-regex', metavar='REGEX',
                   help='leave out of -a and -e the topics this regular expression matches')
    p.add_argument('--exclude-topics', nargs='+', metavar='TOPIC',
                   help='leave these topics out of -a and -e')
    p.add_argument('-o', '--output', help='bag directory (default rosbag2_<date>-<time>)')
    p.add_argument('-s', '--storage', choices=sorted(STORAGES), default='mcap',
                   help='storage format (default mcap)')
    p.add_argument('--qos-depth', type=positive_int, default=None,
                   help='subscription history depth (default: keep all, nothing dropped)')
    p.set_defaults(func=bag_record)

    p = bag_sub.add_parser('play', help='replay a rosbag2 bag')
    p.add_argument('bag', help='bag directory')
    p.add_argument('-r', '--rate', type=positive_float, default=1.0,
                   help='playback speed factor')
    p.add_argument('-l', '--loop', action='store_true', help='play again from the start')
    p.add_argument('--topics', nargs='+', help='replay only these topics (and those of -e)')
    p.add_argument('-e', '--regex', metavar='REGEX',
                   help='replay only the topics this regular expression matches (anywhere in '
                        'the name) and those of --topics')
    p.add_argument('-x', '--exclude-regex', metavar='REGEX',
                   help='do not replay the topics this regular expression matches')
    p.add_argument('--exclude-topics', nargs='+', metavar='TOPIC',
                   help='do not replay these topics')
    p.add_argument('-m', '--remap', nargs='+', metavar='OLD:=NEW',
                   help="play a recorded topic on another name, e.g. '/ball/state:=/replay/state'")
    p.add_argument('--start-offset', type=non_negative_float, default=0.0,
                   help='start this many seconds after the beginning of the bag')
    p.add_argument('-d', '--delay', type=non_negative_float, default=0.0,
                   help='wait this many seconds before playing')
    p.add_argument('--playback-duration', type=non_negative_float, default=None, metavar='S',
                   help='play only this many seconds of the bag (from --start-offset)')
    until = p.add_mutually_exclusive_group()
    until.add_argument('--playback-until-sec', type=non_negative_float, default=None,
                       metavar='T', help='play the messages recorded until this time (s since '
                                         'the epoch, as ros2 bag info prints the end)')
    until.add_argument('--playback-until-nsec', type=non_negative_int, default=None,
                       metavar='NS', help='the same in nanoseconds')
    p.add_argument('--disable-keyboard-controls', action='store_true',
                   help='accepted for scripts written for rosbag2: this player has no '
                        'keyboard controls')
    p.add_argument('--wait-for-subscribers', action='store_true',
                   help='(tt) wait until every topic has a matched subscription (with '
                        '--clock, /clock too: each node on sim time the graph shows)')
    p.add_argument('--wait-for-topic', action='append', metavar='TOPIC',
                   help='(tt) also wait until the graph shows a publisher and a subscription '
                        'of TOPIC (a link further down the chain, e.g. /ball/prediction from '
                        'prediction to strike); repeatable')
    p.add_argument('--clock', type=positive_float, nargs='?', const=40.0, default=None,
                   metavar='HZ',
                   help='publish the bag time on /clock at HZ (default 40 when given)')
    p.add_argument('--qos-depth', type=positive_int, default=100, help='publisher queue depth')
    p.set_defaults(func=bag_play)

    p = bag_sub.add_parser('info', help='summary of a rosbag2 bag')
    p.add_argument('bag', help='bag directory')
    p.set_defaults(func=bag_info)
