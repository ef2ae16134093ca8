"""strike_node: /ball/prediction (+ /strike/target) -> /strike/command, /tt/markers.

The ROS glue around :mod:`tt_strike.hitpoint` and :mod:`tt_strike.solver`: parameters, QoS,
message conversion. From the prediction's hit point (after the bounce) the ball is flown on
through the robot's reach (``workspace_file``) and the hit point is chosen along that path,
once per ball: its hit time is kept from one prediction to the next (tt_strike.hitpoint)
(``use_hit_plane``: the prediction's hit point itself, the old behaviour). Every BallPrediction
with a valid hit point gives one StrikeCommand stamped with the prediction's stamp, carrying
the chosen hit time and point and the racket centre: feasible, or ``feasible = false`` with the
status (infeasible, unreachable) and reason (so that a controller knows there is no stroke for
this ball). A strike whose hit time is past or closer than ``min_time_before_hit`` by the
node's clock is not sent: it is counted (``n_too_late``) and logged (``check_hit_time`` false:
no such check, for replays; none either, with one warning, for hit times on another time base
than the node clock, :mod:`tt_ros.timebase`); once a ball's feasible stroke was sent and its
hit comes that close, the arm is on its way: its further predictions, and those without a
hit point once it is past the plane, are counted (``n_committed``), not warned of.
Predictions without a hit point, with non-finite numbers or with a ``hit_covariance`` that
is not symmetric, not positive semi-definite or wider than 1 m (all zeros: unknown, the
position taken as exact) are dropped with a throttled warning: nothing is published for
them. A bad
workspace file stops the node at start with a one-line reason. At exit it logs one line of
counts, with each of the latest tracks' predictions, commands and first command's status.
"""

import collections
import dataclasses
import math
import time
import typing

import numpy as np
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from tt_prediction.ball import load_model
from tt_prediction.predict import T_MAX, Hit
from tt_ros.connections import LostMessages, subscribe_input
from tt_ros.diagnostics import CountsStatus, report_status
from tt_ros.executor import KERNELS_LOADING, StartupError, run_node, said_if_slow
from tt_ros.markers import add_marker
from tt_ros.messages import header_problem, point_msg, set_time, set_xyz
from tt_ros.messages import stamp_ns as to_ns
from tt_ros.parameters import Param, Parameters
from tt_ros.ratelimit import ThrottledLog, due
from tt_ros.timebase import TimeBaseCheck, same_time_base
from tt_ros.worker import LatestWorker
from tt_ros.worktime import CallbackTimes
from visualization_msgs.msg import Marker, MarkerArray

from tt_msgs.msg import BallPrediction, StrikeCommand, StrikeTarget

from .hitpoint import choose
from .robust import check_covariance, in_zone_probability, landing_ensemble, noise_covariance
from .solver import (
    MAX_RACKET_SPEED_RANGE,
    NET_CLEARANCE_RANGE,
    StrikeSettings,
    StrikeSolution,
    resolve_target,
    scored_zone,
    solve,
)
from .workspace import load_workspace

_D = StrikeSettings()
PARAMETERS = (
    Param('target_zone', 5, "target zone on the opponent's half (MODEL.md); 0: target_point",
          lo=0, hi=9),
    Param('target_point', [0.7, 0.0], "target landing point [x, y] on the opponent's half "
          '(when target_zone is 0)', 'm', length=2),
    Param('net_clearance', _D.net_clearance, 'free direction: gap between the ball and the '
          'net top where it crosses x = 0', 'm', *NET_CLEARANCE_RANGE),
    Param('max_racket_speed', _D.max_racket_speed, 'racket speed limit at impact (along the '
          "path, the lower of this and workspace_file's max_racket_speed)", 'm/s',
          *MAX_RACKET_SPEED_RANGE),
    Param('reach_z_min', _D.reach_z[0], 'lowest ball centre the racket reaches (use_hit_plane '
          "only; otherwise workspace_file's reach)", 'm', -0.76, 2.0),
    Param('reach_z_max', _D.reach_z[1], 'highest ball centre the racket reaches (use_hit_plane '
          "only; otherwise workspace_file's reach)", 'm', -0.76, 3.0),
    Param('reach_y', _D.reach_y, 'largest |y| of the hit point the racket reaches '
          "(use_hit_plane only; otherwise workspace_file's reach)", 'm', 0.0, 3.0),
    Param('max_normal_tilt_deg', _D.max_normal_tilt_deg, 'largest angle between the racket '
          'normal and +x', 'deg', 0.0, 90.0),
    Param('aim_inside_zone', _D.aim_inside_zone, 'aim at the point of the zone with the '
          'highest in-zone probability instead of its centre (needs in_zone_probability)'),
    Param('in_zone_probability', True, 'compute the in-zone probability (1024 more flights, '
          'about 30 ms)'),
    Param('probability_rate_hz', 10.0, "rate of the in-zone probability per track and target, "
          "per the predictions' stamps; in between the last value is reused, and refreshed "
          "in a thread behind the commands (before the command: a ball's first value, the "
          'first from a known hit_covariance, one after none for two periods, every one with '
          'aim_inside_zone or at 0, every prediction)', 'Hz', 0.0, 1000.0),
    Param('velocity_sigma_fraction', 0.02, 'velocity std at the hit point per component, as a '
          'fraction of the speed (BallPrediction carries only the position covariance)',
          lo=0.0, hi=1.0),
    Param('spin_sigma_fraction', 0.10, 'spin std at the hit point per component, as a '
          'fraction of the spin magnitude', lo=0.0, hi=2.0),
    Param('model_file', '', 'model.yaml written by tt-identify; empty: the nominal model',
          read_only=True),
    Param('publish_markers', False, 'publish the racket and landing on tt/markers'),
    Param('workspace_file', '', 'workspace YAML (reach of the racket centre, racket-speed '
          'limit, min time before the hit); empty: the template config/workspace.yaml',
          read_only=True),
    Param('use_hit_plane', False, "old behaviour: strike at the prediction's hit point (its "
          'hitting plane) instead of choosing along the path inside the workspace'),
    Param('check_hit_time', True, 'do not send strikes whose hit time is past or closer than '
          "the workspace's min_time_before_hit by the node's clock (false: for replays whose "
          'stamps are not on the node clock, e.g. a bag played without --clock; a struck '
          "ball's loss is then judged by the predictions' stamps)"),
)


def _target_from(zone, point):
    """(zone, point) from a zone (0: use point) and a point [x, y]; ValueError if bad."""
    if zone:
        return resolve_target(target_zone=int(zone))
    return resolve_target(target_point=list(point))


def check_parameters(values):
    """The strike node's cross-parameter rules on all its ``values``: the one-line reason
    they are refused, or None."""
    if values['reach_z_min'] > values['reach_z_max']:
        return (f"reach_z_min ({values['reach_z_min']:g} m) must not exceed reach_z_max "
                f"({values['reach_z_max']:g} m)")
    if values['aim_inside_zone'] and not values['in_zone_probability']:
        # Taken without a word before, and the stroke aimed at the centre (a walk-through).
        return ('aim_inside_zone needs in_zone_probability: the point it aims at is the '
                'one of the highest in-zone probability')
    try:
        # target_point is checked even while target_zone is set: a point off the opponent's
        # half is refused when it is set, not later when target_zone goes to 0.
        resolve_target(target_point=list(values['target_point']))
        _target_from(values['target_zone'], values['target_point'])
    except ValueError as exc:
        return str(exc)
    return None


TALLIED_TRACKS = 20
"""Tracks whose counts the exit summary lists (the latest)."""
NEW_BALL_GAP_S = 1.0
KEPT_HIT_MARGIN_S = 0.02
"""A prediction stamped NEW_BALL_GAP_S after its track's last one (prediction_node's
TRACK_GAP_S), or before it, or KEPT_HIT_MARGIN_S after the track's kept hit time (that ball
was struck or missed; the margin: the kept hit is a row of a path whose plane crossing
noise moves), is of another ball under a used id (perception numbers its tracks from 1
again when it restarts; a ball thrown again): its hit time is chosen afresh. Unlike
prediction_node, it does not see a ball's state jump (a new ball thrown before the old
one's kept hit time keeps the old time)."""
LOST_BEFORE_PLANE_S = 0.1
"""A ball struck (a feasible stroke sent) whose last prediction came more than this before its
predicted crossing of the hitting plane was lost on the way (perception or prediction stopped
following it), s. A ball followed to the plane has predictions to within a few frames of it."""
LOST_JUDGED_AFTER_S = 0.5
"""Such a ball is judged (and warned of) once its hit time is this much past by the node
clock, s, or when another ball takes its track id: predictions up to this late (a busy
machine's queues) still count as following it."""
STROKE_CHECK_S = 0.1
"""Period of that check, s."""
INPUT_OVER_S = 2.0
"""Without check_hit_time (the stamps on no clock of the node's), every struck ball is judged
once no prediction has come for this long (s, monotonic time): the replay is over or paused,
and nothing else moves the stamps' clock on to its hit time."""


class Probability(typing.NamedTuple):
    """An in-zone probability worked out for a track."""

    aim: tuple
    """The target it was worked out for: (zone, point)."""
    stamp_ns: int
    """Stamp of the prediction it was worked out from, ns."""
    value: float
    known: bool
    """That prediction's hit_covariance was known (not all zeros)."""


@dataclasses.dataclass
class TrackTally:
    """What one track (ball) got from this node."""

    received: int = 0
    """Predictions received."""
    commands: int = 0
    """Commands published."""
    first_status: str = ''
    """Status of the first command ('' before one)."""
    ok: bool = False
    """A command with a feasible stroke was sent."""
    hit_t: float = None
    """The hit time of the last feasible stroke, s (kept: tt_strike.hitpoint)."""
    stamp: float = -math.inf
    """The stamp of the track's last prediction, s."""
    plane_t: float = None
    """Its last prediction's hit time (the ball's crossing of the hitting plane), s."""
    checked: bool = False
    """Its stroke's hit time is past and was checked for a lost ball (LOST_BEFORE_PLANE_S)."""
    lost_before: int = 0
    """Predictions this node had lost in its input queue when it took the last one."""
    lost_by_plane: int = None
    """... and when it took the first prediction (of any ball) stamped after that one's hit
    time: losses after the ball was at the plane are not why it was lost (None: none yet)."""
    probability: 'Probability' = None
    """The last in-zone probability worked out for it."""
    requested_ns: int = None
    """Stamp of the prediction whose probability the worker was last asked for, ns."""
    ball: int = 0
    """Balls seen under this id before the current one (a probability worked out for an
    earlier ball is not its)."""


class StrikeNode(Node):
    """Solves the racket stroke for every predicted hit point."""

    def __init__(self, **kwargs):
        super().__init__('strike_node', **kwargs)
        self.target = None
        self.settings = None
        self.p = Parameters(self, PARAMETERS, check=check_parameters, apply=self._apply)
        try:
            self.params = load_model(self.p.model_file)
        except ValueError as exc:
            raise StartupError(f'model_file: {exc}') from None
        try:
            self.workspace = load_workspace(self.p.workspace_file)
        except ValueError as exc:           # WorkspaceError is one
            raise StartupError(f'workspace_file: {exc}') from None
        # Compile (or load from numba's cache) the kernels now, not on the first ball.
        warm = np.array([-1.5, 0.0, 0.3, -4.0, 0.0, -1.0, 0.0, 0.0, 0.0])
        with said_if_slow(self.get_logger(), KERNELS_LOADING):
            solve(warm, self.params, target_zone=5, covariance=np.eye(9) * 1e-6)
            plan = choose(warm, self.params, self.workspace, target_zone=5, bounced=True)
            if plan.hit is not None:        # a ball's next prediction keeps its hit time
                choose(warm, self.params, self.workspace, target_zone=5, bounced=True,
                       keep_t=plan.hit.t)
        self.n_commands = self.n_dropped = self.n_too_late = self.n_committed = 0
        self.n_lost = 0                   # struck balls lost before the plane
        self.last_stamp = -math.inf       # the last valid prediction's stamp, s
        self.last_arrival = -math.inf     # time.monotonic() when a prediction last came, s
        self.tracks = collections.OrderedDict()   # track id -> TrackTally, the latest last
        self.work = CallbackTimes()       # the callback's time for the last predictions
        self.time_base = TimeBaseCheck(self.get_logger().warning)
        self.warn = ThrottledLog(self.get_logger().warning)
        reliable = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        # Names relative to the node's namespace (/strike/command in the root one).
        self.pub = self.create_publisher(StrikeCommand, 'strike/command', reliable)
        self.pub_markers = self.create_publisher(MarkerArray, 'tt/markers', reliable)
        self.queue_lost = LostMessages()        # predictions lost before the callback
        self.queue_lost_said = 0                # ... as many as the last warning said
        # In-zone probabilities refreshed behind the commands (_refresh_probability): the
        # worker appends (track id, ball, Probability), the callback takes them.
        self.probabilities = collections.deque()
        self.probability_worker = LatestWorker(
            'probability', self._refresh_probability, on_error=lambda exc: self.warn(
                'refresh', 1.0, f'in-zone probability not refreshed: {exc!r}'))
        self.sub = subscribe_input(self, BallPrediction, 'ball/prediction',
                                   self.on_prediction, reliable, lost=self.queue_lost)
        self.sub_target = self.create_subscription(StrikeTarget, 'strike/target',
                                                   self.on_target, reliable)
        self.create_timer(STROKE_CHECK_S, self._check_strokes)
        self.counts_status = CountsStatus(
            ('predictions_dropped', 'strokes_too_late', 'struck_balls_lost', 'predictions_lost'),
            self.work)
        report_status(self, 'strokes', '', self._status)
        self.get_logger().info(self._start_up_text())

    # --- target and parameters ---------------------------------------------------------

    def _start_up_text(self):
        """The start-up line: topics, target, reach and the model the strokes are solved
        with (a model_file from a params file is otherwise seen only by ros2 param get)."""
        return (f'striking {self.sub.topic_name} -> {self.pub.topic_name}, target '
                f'{self._target_text()}, {self._reach_text()}, model '
                f'{self.p.model_file or "nominal"}')

    def _target_text(self):
        zone, point = self.target
        return f'zone {zone}' if zone else f'point ({point[0]:.3f}, {point[1]:.3f}) m'

    def _reach(self):
        """The workspace with the racket speed limit that applies: the lower of its own and
        the max_racket_speed parameter."""
        return self.workspace.slowed_to(self.settings.max_racket_speed)

    def _reach_text(self):
        ws = self._reach()
        if self.p.use_hit_plane:
            return f'at the hitting plane, racket speed limit {ws.max_racket_speed:.1f} m/s'
        return (f'reach {ws.describe()} ({self.p.workspace_file or "default"}), racket speed '
                f'limit {ws.max_racket_speed:.1f} m/s')

    def _apply(self, v, changed):
        """Parameters set: the solver settings, and the target when it changed."""
        self.settings = StrikeSettings(
            net_clearance=v.net_clearance, max_racket_speed=v.max_racket_speed,
            reach_z=(v.reach_z_min, v.reach_z_max), reach_y=v.reach_y,
            max_normal_tilt_deg=v.max_normal_tilt_deg, aim_inside_zone=v.aim_inside_zone)
        if self.target is None or changed & {'target_zone', 'target_point'}:
            first = self.target is None
            self.target = _target_from(v.target_zone, v.target_point)
            if not first:
                self.get_logger().info(f'target {self._target_text()}')

    def on_target(self, msg):
        """A target from the topic sets the parameters target_zone (and target_point for
        zone 0), checked as ``ros2 param set`` is: ``ros2 param get`` and ``dump`` show the
        target in use."""
        values = [Parameter('target_zone', value=int(msg.zone))]
        if not msg.zone:
            values.append(Parameter('target_point', value=[msg.point.x, msg.point.y]))
        self.p.set_from(self.sub_target.topic_name, values)      # a refusal is logged once

    # --- predictions --------------------------------------------------------------------

    def _drop(self, why):
        self.n_dropped += 1
        self.warn('drop', 1.0, f'prediction dropped: {why}')

    def _covariance(self, msg, state):
        """9x9 covariance at the hit point: the prediction's position block, and velocity and
        spin stds as fractions of their magnitudes (parameters)."""
        cov = noise_covariance(state, 0.0, self.p.velocity_sigma_fraction,
                               self.p.spin_sigma_fraction)
        pos = np.array(msg.hit_covariance, dtype=float).reshape(3, 3)   # checked: finite
        cov[:3, :3] = 0.5 * (pos + pos.T)             # symmetric within rounding
        return cov

    def _probability_plan(self, tally, aim, stamp_ns, known):
        """When this prediction's in-zone probability is worked out: 'before' its command,
        'behind' it (in the worker's thread) or None (the track's value reused, or none).
        Behind only when the track has a value of this target from within two periods, from
        a known covariance if this one is known; else (a ball's first value, one after an
        interval without any, the first from a known covariance) before, as with
        aim_inside_zone and at rate 0. ``known``: the prediction's hit_covariance is not all
        zeros (unknown)."""
        if not self.p.in_zone_probability:
            return None
        rate = self.p.probability_rate_hz
        last = tally.probability
        if (self.settings.aim_inside_zone or rate <= 0.0 or last is None or last.aim != aim
                or (known and not last.known)
                or not 0 <= stamp_ns - last.stamp_ns <= 2e9 / rate):
            return 'before'
        asked = last.stamp_ns if tally.requested_ns is None else max(last.stamp_ns,
                                                                     tally.requested_ns)
        return 'behind' if due(stamp_ns, asked, rate) else None

    def _refresh_probability(self, request):
        """In the worker's thread: the in-zone probability of a stroke already sent (the
        ensemble's 1024 flights, 15-30 ms, their kernel without the GIL), handed back to the
        callback through ``self.probabilities``."""
        track_id, ball, asked, hit_state, sol, cov, samples = request
        value = in_zone_probability(landing_ensemble(hit_state, cov, sol.normal,
                                                     sol.racket_velocity, self.params, samples),
                                    scored_zone(sol))
        self.probabilities.append((track_id, ball, asked._replace(value=value)))

    def _take_probabilities(self):
        """The worker's refreshed probabilities into their tracks: their ball's still, and
        not older than a value worked out since (aim_inside_zone set meanwhile)."""
        while self.probabilities:
            track_id, ball, result = self.probabilities.popleft()
            tally = self.tracks.get(track_id)
            if (tally is not None and tally.ball == ball
                    and (tally.probability is None
                         or result.stamp_ns >= tally.probability.stamp_ns)):
                tally.probability = result

    def _tally(self, track_id):
        """The counts of track ``track_id`` (the latest :data:`TALLIED_TRACKS` are kept)."""
        tally = self.tracks.get(track_id)
        if tally is None:
            tally = self.tracks[track_id] = TrackTally()
            while len(self.tracks) > TALLIED_TRACKS:
                self.tracks.popitem(last=False)
        return tally

    def work_summary(self):
        """One line for the log at exit: the counts, then each of the latest tracks as
        ``id: predictions/commands first status`` (which balls reached this node, and what it
        sent for them)."""
        if not self.n_received:
            return 'no prediction received'
        ok = sum(t.ok for t in self.tracks.values())
        tracks = ', '.join(f'{i}: {t.received}/{t.commands} {t.first_status or "-"}'
                           for i, t in self.tracks.items())
        times = self.work.latest_ms()
        return (f'{self.n_received} predictions, {self.n_commands} commands, '
                f'{self.n_dropped} dropped, {self.n_too_late} too late, {self.n_committed} '
                f'after their stroke was sent, {self.n_lost} struck balls lost before the '
                f'plane, {self.queue_lost.count} predictions lost in the input queue; callback '
                f'median {np.median(times):.3f} ms, p99 {np.percentile(times, 99):.3f} ms, max '
                f'{times.max():.3f} ms (last {len(times)}); tracks (predictions/commands, '
                f"first command's status; {ok} with an ok stroke): {tracks}")

    def _status(self):
        """The status on /diagnostics: WARN when, since the last report, predictions were
        dropped, strokes came too late to send, struck balls were lost before the plane or
        predictions were lost in the input queue; the totals, and the callback's time over
        the latest predictions."""
        level, new, values = self.counts_status.report(
            {'predictions_received': self.n_received, 'commands_published': self.n_commands,
             'predictions_dropped': self.n_dropped, 'strokes_too_late': self.n_too_late,
             'after_stroke_sent': self.n_committed, 'struck_balls_lost': self.n_lost,
             'predictions_lost': self.queue_lost.count})
        message = (f"{new['predictions_received']} predictions, {new['commands_published']} "
                   f"commands, {new['predictions_dropped']} dropped, {new['strokes_too_late']} "
                   f"too late, {new['struck_balls_lost']} struck balls lost, "
                   f"{new['predictions_lost']} predictions lost in the input queue, since the "
                   'last report')
        return level, message, values

    def on_prediction(self, msg):
        self.work.call(self._on_prediction, msg)

    @property
    def n_received(self):
        """Predictions received (the callback's calls)."""
        return self.work.count

    def _on_prediction(self, msg):
        self.last_arrival = time.monotonic()
        self._take_probabilities()
        # Said in the exit line only before (a ROS walk-through, -r 2); the count a line
        # the throttle held back said is said by the next.
        if self.queue_lost.count > self.queue_lost_said and self.warn(
                'queue_lost', 5.0, f'{self.queue_lost.count} predictions lost in the input '
                'queue so far (it keeps the latest 5): this node falls behind its input (a '
                'faster replay, or a busy machine)'):
            self.queue_lost_said = self.queue_lost.count
        stamp_ns = to_ns(msg.header.stamp)
        stamp = stamp_ns * 1e-9
        for other in self.tracks.values():      # the balls this one's stamp is past
            if other.lost_by_plane is None and other.plane_t is not None \
                    and stamp >= other.plane_t:
                other.lost_by_plane = self.queue_lost.count
        tally = self._tally(msg.track_id)
        tally.received += 1
        if not msg.hit_valid:
            if (tally.commands and msg.status == 'no_hit'
                    and 0.0 <= stamp - tally.stamp <= NEW_BALL_GAP_S):
                # The struck ball past the plane: what every ball does once struck, not a
                # warning each (a ROS user's walk-through), nor a drop that set /diagnostics
                # to WARN for every ball struck (another, 7 Dec 2026); a ball never struck
                # (its commands infeasible) still counts as dropped, quietly; a new ball
                # under its id is not this.
                if tally.hit_t is not None:
                    self.n_committed += 1
                else:
                    self.n_dropped += 1
                self.get_logger().debug(f'track {msg.track_id}: no hit point after its '
                                        f'stroke (prediction status {msg.status!r})')
            else:
                self._drop(f'no hit point (prediction status {msg.status!r})')
            return
        why = header_problem(stamp_ns, msg.header.frame_id)
        if why:
            self._drop(why)
            return
        p, v, w = msg.hit_point, msg.hit_velocity, msg.hit_spin
        state = np.array([p.x, p.y, p.z, v.x, v.y, v.z, w.x, w.y, w.z])
        if not np.all(np.isfinite(state)):
            self._drop('hit point, velocity or spin is not finite')
            return
        ahead = (to_ns(msg.hit_time) - stamp_ns) * 1e-9
        if ahead < 0.0:
            self._drop('hit_time precedes header.stamp (the state it was predicted from)')
            return
        if ahead > T_MAX:
            self._drop(f'hit_time {ahead:.4g} s after header.stamp: beyond the {T_MAX:g} s of '
                       'flight a prediction covers (another clock?)')
            return
        try:       # zeros (unknown): the position taken as exact, only v and w uncertain
            check_covariance(np.array(msg.hit_covariance, dtype=float).reshape(3, 3),
                             'hit_covariance')
        except ValueError as exc:
            self._drop(str(exc))
            return
        zone, point = self.target
        settings = self.settings
        aim = (zone, tuple(point))
        hit_t = msg.hit_time.sec + 1e-9 * msg.hit_time.nanosec
        if (stamp < tally.stamp or stamp > tally.stamp + NEW_BALL_GAP_S
                or (tally.hit_t is not None and stamp > tally.hit_t + KEPT_HIT_MARGIN_S)):
            self._judge_stroke(msg.track_id, tally)   # the old ball is over
            tally.hit_t = tally.probability = tally.requested_ns = None  # another ball
            tally.checked = False                                           # under a used id
            tally.ball += 1
        tally.stamp = self.last_stamp = stamp
        tally.plane_t = hit_t
        tally.lost_before, tally.lost_by_plane = self.queue_lost.count, None
        known = any(msg.hit_covariance)
        # A value the ball has is refreshed behind the command, not before it (15-30 ms).
        when = self._probability_plan(tally, aim, stamp_ns, known)
        cov = self._covariance(msg, state) if when else None
        solve_cov = cov if when == 'before' else None
        now = self.get_clock().now().nanoseconds * 1e-9
        if not self.time_base(hit_t, now):           # or now 0: use_sim_time, no /clock yet
            now = -math.inf                          # no hit-time check: not comparable
        if not self.p.check_hit_time:
            now = -math.inf
        ws = self._reach()
        target = {'target_zone': zone or None, 'target_point': None if zone else point}
        if self.p.use_hit_plane:
            hit = Hit(hit_t, state[:3], state[3:6], state[6:9])
            if hit_t - now < ws.min_time_before_hit:
                self._too_late(tally, f'hit in {hit_t - now:.3f} s, below '
                               f'min_time_before_hit {ws.min_time_before_hit:.3f} s')
                return
            # The workspace's limit too, as in the workspace's mode (it was the parameter's
            # alone: a stroke of 1.9 m/s sent to an arm rated 1.0; a walk-through).
            plane = dataclasses.replace(settings, max_racket_speed=ws.max_racket_speed)
            sol = solve(state, self.params, settings=plane, covariance=solve_cov, **target)
            status, reason = sol.status, sol.reason
            if sol.feasible:
                tally.hit_t = hit_t
        else:
            plan = choose(state, self.params, ws, t0=hit_t, now=now, settings=settings,
                          covariance=solve_cov, bounced=True, keep_t=tally.hit_t, **target)
            if plan.status == 'too_late':
                self._too_late(tally, plan.reason)
                return
            hit, sol = plan.hit, plan.solution
            status, reason = plan.status, plan.reason
            if plan.feasible:
                tally.hit_t = hit.t
            if sol is None:
                sol = StrikeSolution(status, reason, target_point=point, target_zone=zone)
        if solve_cov is not None and sol.feasible:
            tally.probability = Probability(aim, stamp_ns, sol.in_zone_probability, known)
        elif (sol.feasible and self.p.in_zone_probability and tally.probability
              and tally.probability.aim == aim):
            # Reused between computations only while they go on: after in_zone_probability
            # was set false, a track sent its last value for ever (a walk-through).
            sol.in_zone_probability = tally.probability.value
            if when == 'behind':
                tally.requested_ns = stamp_ns
                self.probability_worker.submit((
                    msg.track_id, tally.ball, Probability(aim, stamp_ns, math.nan, known),
                    hit.state, sol, cov, settings.probability_samples), key=msg.track_id)
        out = self._command(msg, sol, hit, status, reason)
        self.pub.publish(out)
        self.n_commands += 1
        tally.commands += 1
        tally.ok = tally.ok or status == 'ok'
        tally.first_status = tally.first_status or status
        if status != 'ok':
            self.warn('infeasible', 1.0, f'no feasible stroke ({status}): {reason}')
        if self.p.publish_markers and sol.normal is not None:
            self.pub_markers.publish(self._markers(msg, sol))

    def _check_strokes(self):
        """Each struck ball whose hit time is LOST_JUDGED_AFTER_S past by the node clock:
        :meth:`_judge_stroke`. Without check_hit_time, by the last prediction's stamp: a bag
        played without --clock has its hit times minutes before the clock, and every struck
        ball was judged lost at its first prediction (a walk-through, 6 Dec 2026); and every
        struck ball once no prediction has come for INPUT_OVER_S (one lost at a bag's end was
        never judged)."""
        now = self.get_clock().now().nanoseconds * 1e-9
        over = False
        if not self.p.check_hit_time:
            now = self.last_stamp
            over = time.monotonic() - self.last_arrival >= INPUT_OVER_S
        for track_id, tally in self.tracks.items():
            if over or (tally.hit_t is not None and same_time_base(tally.hit_t, now)
                        and now >= tally.hit_t + LOST_JUDGED_AFTER_S):
                self._judge_stroke(track_id, tally)

    def _judge_stroke(self, track_id, tally):
        """Once per struck ball: warned of when its predictions stopped more than
        LOST_BEFORE_PLANE_S before it reached the plane (the arm struck where it was last
        predicted)."""
        if tally.hit_t is None or tally.checked:
            return
        tally.checked = True
        early = tally.plane_t - tally.stamp
        if early > LOST_BEFORE_PLANE_S:
            self.n_lost += 1
            queued = (self.queue_lost.count if tally.lost_by_plane is None
                      else tally.lost_by_plane) - tally.lost_before
            why = (f"{queued} predictions were lost in this node's input queue since (it "
                   'falls behind: a faster replay, or a busy machine)' if queued else
                   'no prediction with a hit point since: no state from perception, or '
                   'predictions without a hit, no_bounce say')
            self.get_logger().warning(
                f'track {track_id}: struck at {tally.hit_t:.3f} s, but its last prediction '
                f'came {1e3 * early:.0f} ms before it reached the hitting plane: the ball was '
                f'lost on the way ({why}), the stroke went on that prediction')

    def _too_late(self, tally, why):
        """A strike too close to its hit time: not sent. Counted and logged, unless a feasible
        stroke was sent for this ball (``tally``): then the arm is on its way, as it should."""
        if tally.hit_t is not None:
            self.n_committed += 1
            return
        self.n_too_late += 1
        self.warn('too_late', 1.0, f'strike not sent, too late ({self.n_too_late} so far): {why}')

    def _command(self, msg, sol, hit, status, reason):
        out = StrikeCommand()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = msg.header.frame_id or 'table'
        out.track_id = msg.track_id
        out.status = status
        out.feasible = status == 'ok'
        out.reason = reason
        if hit is None:
            out.hit_time = msg.hit_time
            out.hit_point = msg.hit_point
        else:
            set_time(out.hit_time, round(hit.t * 1e9))
            out.hit_point = point_msg(hit.p)
        out.target_zone = sol.target_zone
        if sol.target_point is not None:
            out.target_point = point_msg(sol.target_point)
        if sol.normal is not None:
            out.racket_position = point_msg(sol.racket_position)
            q = sol.orientation_xyzw
            out.racket_orientation.x, out.racket_orientation.y = float(q[0]), float(q[1])
            out.racket_orientation.z, out.racket_orientation.w = float(q[2]), float(q[3])
            set_xyz(out.racket_normal, sol.normal)
            set_xyz(out.racket_velocity, sol.racket_velocity)
            set_xyz(out.ball_out_velocity, sol.ball_out_v)
            set_xyz(out.ball_out_spin, sol.ball_out_w)
        if sol.landing is not None:
            out.landing_point = point_msg(sol.landing)
            out.landing_zone = sol.landing_zone
        for key in ('net_clearance', 'margin', 'in_zone_probability'):
            value = float(getattr(sol, key))
            setattr(out, key, value if math.isfinite(value) else math.nan)
        return out

    def _markers(self, msg, sol):
        markers = MarkerArray()

        def marker(mid, kind, rgb, scale):
            return add_marker(markers, msg.header, 'strike', mid, kind, rgb, scale,
                              alpha=1.0 if sol.feasible else 0.4)

        red = (0.8, 0.1, 0.1)
        racket = marker(0, Marker.CYLINDER, red, (0.15, 0.15, 0.01))   # blade, z = normal
        racket.pose.position = point_msg(sol.racket_position)
        q = sol.orientation_xyzw
        o = racket.pose.orientation
        o.x, o.y, o.z, o.w = float(q[0]), float(q[1]), float(q[2]), float(q[3])
        arrow = marker(1, Marker.ARROW, red, (0.01, 0.02, 0.03))          # racket velocity
        tip = sol.racket_position + 0.05 * sol.racket_velocity
        arrow.points = [point_msg(sol.racket_position), point_msg(tip)]
        if sol.landing is not None:
            marker(2, Marker.CYLINDER, (0.1, 0.8, 0.1), (0.06, 0.06, 0.005)).pose.position = \
                point_msg(sol.landing)
        return markers

    def destroy_node(self):
        self.probability_worker.stop()
        return super().destroy_node()


def main(args=None):
    run_node(StrikeNode, args, name='strike_node', parameters=PARAMETERS,
             on_exit=lambda node: node.get_logger().info(node.work_summary()))


if __name__ == '__main__':
    main()
