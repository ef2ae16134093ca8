"""prediction_node: /ball/state -> /ball/prediction, /ball/predicted_path, /tt/markers.

The ROS glue around :mod:`tt_prediction.predict` and :mod:`tt_prediction.uncertainty`:
parameters, QoS, message conversion. Each BallState (subscribed best effort, a queue of
STATE_QUEUE_DEPTH) gives one BallPrediction stamped with the state's stamp; the path and
markers follow at a lower rate. Invalid or stale states are dropped with a throttled warning
(nothing is published for them).
"""

import collections
import dataclasses
import gc
import sys

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from tt_ros.connections import LostMessages, subscribe_input
from tt_ros.diagnostics import CountsStatus, report_status
from tt_ros.executor import KERNELS_LOADING, StartupError, run_node, said_if_slow
from tt_ros.markers import add_marker
from tt_ros.messages import header_problem, point_msg, seconds_text, set_time, set_xyz
from tt_ros.messages import stamp_ns as to_ns
from tt_ros.parameters import Param, Parameters
from tt_ros.ratelimit import ThrottledLog, due
from tt_ros.timebase import TimeBaseCheck
from tt_ros.worker import LatestWorker
from tt_ros.worktime import CallbackTimes
from visualization_msgs.msg import Marker, MarkerArray

from tt_msgs.msg import BallPrediction, BallState

from .ball import load_model
from .predict import DEFAULT_HIT_PLANE_X, HIT_PLANE_X_RANGE, check_state, predict
from .uncertainty import predict_uncertainty
from .units import ROOM_HALF_EXTENT_M, position_error

BOUNCE_MARGIN_S = 0.02
"""A track's state stamped this long after its predicted bounce on the robot's half is taken
to be past that bounce (so the plane crossing ahead is the hit), s."""
STATE_QUEUE_DEPTH = 100
"""States kept for the callback (best effort): a replay publishes in bursts."""
MAX_TRACKS = 8
"""Tracks remembered (the last predicted bounce and uncertainty of each); the one updated
longest ago is forgotten first."""
LATE_S = 0.05
"""A state received this long after its stamp (s) is late: counted, and warned of (at most
every 5 s). On a robot a state is out a few ms after its exposure; at 1 kHz from another
process the node fell 94-133 ms behind, its queue full, without a word (a new-user
walk-through, 29 Nov 2026)."""
MAX_LEAD_S = 1.0
"""A state stamped further ahead of the node clock is dropped (with stale_after_s > 0), s:
its clock and the node's disagree, and the hit time it gives would be as far off."""
AHEAD_S = 0.05
"""A state stamped further ahead of the node clock than this (s), but less than MAX_LEAD_S,
is predicted and warned of (at most every 5 s): an exposure cannot be later than its state's
arrival, so the clocks disagree by at least that much, and the hit time with them (0.9 s
ahead was struck 'ok' without a word; a walk-through, 6 Dec 2026). Not less: a bag's /clock
at ros2 bag play's 40 Hz runs up to 25 ms behind the states played with it. On a simulated
clock the node adds its step (CLOCK_STEPS), so 75 ms at ros2 bag play's 40 Hz and 100 ms at
-r 2, whose /clock steps by 50 ms of bag time (a walk-through, 7 Dec 2026, was told of states
53 ms ahead as clocks that disagree)."""
CLOCK_STEPS = 15
"""On a simulated clock (use_sim_time), the median of the last this many steps of the node
clock between states is taken for the step of /clock, by which it lags a state at most."""
CLOCK_STEP_MAX_S = 0.1
"""A step of the simulated clock between two states longer than this is a gap between the
states, not /clock's step (40 Hz at -r 4), s: sparse states had widened the margin to 1 s."""
TRACK_GAP_S = 1.0
"""A state of a remembered track id stamped this much after the track's last state (or
more than OUT_OF_ORDER_S before it) starts the track afresh, s: it is another ball
(perception restarted, its ids from 1 again; a replay started over). Perception ends a track
after 0.2 s without the ball; a ball flies from the opponent's racket to the robot's in
under a second."""
OUT_OF_ORDER_S = 0.1
"""A state stamped up to this much before its track's last state (or at its stamp) is a late
or repeated one of the same ball (best effort delivers out of order; a second publisher), s:
dropped with a warning.
Taken for a new ball, it lost the track's bounce and every later state of the ball was
predicted as before it (no_bounce, no hit)."""
TRACK_JUMP_M = 0.3
TRACK_JUMP_SPEED = 8.0
TRACK_JUMP_DT = 0.25
"""A state of a remembered track farther than TRACK_JUMP_M + TRACK_JUMP_SPEED * min(dt,
TRACK_JUMP_DT) (m, m/s, s) from where the track's last state would be after dt (a straight
line under gravity) starts it afresh too: another ball, sooner than TRACK_GAP_S. A bounce
changes v_z by about twice the impact speed (up to ~10 m/s), only for the time after it, and
perception ends a track after 0.2 s without its ball: on model flights no state of one ball
was taken for another down to 10 Hz (a review, 28 Nov 2026). The track it replaces is kept
for one state: when the next state carries on from it and not from the one far off, that
one was an outlier and the track goes on with its bounce."""

_ZERO3 = (0.0, 0.0, 0.0)

PARAMETERS = (
    Param('hit_plane_x', DEFAULT_HIT_PLANE_X,
          "x of the hitting plane on the robot's side (table frame)", 'm', *HIT_PLANE_X_RANGE),
    Param('model_file', '', 'model.yaml written by tt-identify; empty: the nominal model',
          read_only=True),
    Param('max_rate_hz', 0.0, "highest prediction rate of each track, by its states' stamps; "
          '0: every state', 'Hz', 0.0, 2000.0),
    Param('uncertainty', True, 'propagate the state covariance: zone probabilities, hit '
          'covariance'),
    Param('uncertainty_rate_hz', 50.0, 'rate of the uncertainty propagation per track (19 '
          'predictions each); in between the last result of the track is reused; 0: every '
          'state', 'Hz', 0.0, 2000.0),
    Param('stale_after_s', 0.5, 'drop states whose stamp is older than this against the node '
          'clock (the clock of the recording with use_sim_time), or more than 1 s ahead of it '
          '(a stamp over an hour off is on another time base: warned of once, not dropped); '
          '0: never drop', 's',
          0.0, 60.0),
    Param('path_rate_hz', 10.0, 'highest rate of /ball/predicted_path (and markers); 0: every '
          'state (built in a worker thread: a busy worker skips states)', 'Hz', 0.0, 2000.0),
    Param('path_step_s', 0.02, 'time between the poses of the predicted path', 's',
          0.001, 0.2),
    Param('publish_markers', False, 'publish visualization markers on tt/markers'),
)


class _Track:
    """What the node remembers of one track: its predicted bounce and last uncertainty."""

    __slots__ = ('bounce', 'bounce_ns', 'second_ns', 'uncertainty', 'uncertainty_ns',
                 'last_ns', 'state', 'predicted_ns', 'replaced')

    def __init__(self):
        self.bounce = None
        self.bounce_ns = None
        self.second_ns = None           # a second bounce on the robot's half it predicted
        self.uncertainty = None
        self.uncertainty_ns = None
        self.last_ns = None
        self.state = None
        self.predicted_ns = None        # stamp of the track's last prediction (max_rate_hz)
        self.replaced = None            # the track this one's first state was far from

    def continues(self, state, stamp_ns, gravity):
        """Whether ``state`` (9,), stamped ``stamp_ns``, is the track's ball: stamped within
        TRACK_GAP_S after its last state and near where it flies (TRACK_JUMP_M) under
        ``gravity`` ((3,), m/s^2: ModelParams.gravity_vector)."""
        if not 0 <= stamp_ns - self.last_ns <= TRACK_GAP_S * 1e9:
            return False
        dt = (stamp_ns - self.last_ns) * 1e-9
        expect = self.state[:3] + self.state[3:6] * dt + 0.5 * gravity * dt * dt
        return (np.linalg.norm(state[:3] - expect)
                <= TRACK_JUMP_M + TRACK_JUMP_SPEED * min(dt, TRACK_JUMP_DT))


class PredictionNode(Node):
    """Predicts bounce, hit point and landing zone for every ball state it receives."""

    def __init__(self, **kwargs):
        super().__init__('prediction_node', **kwargs)

        self.p = Parameters(self, PARAMETERS)

        try:
            self.params = load_model(self.p.model_file)
        except ValueError as exc:
            raise StartupError(f'model_file: {exc}') from None
        # Compile (or load from numba's cache) the kernels now, not on the first ball.
        warm = np.array([1.6, 0.0, 0.3, -6.0, 0.0, 1.5, 0.0, 0.0, 0.0])
        with said_if_slow(self.get_logger(), KERNELS_LOADING):
            predict_uncertainty(warm, np.eye(9) * 1e-4, self.params)
            predict(warm, self.params, path_dt=0.02)
        self.packed = self.params.packed()
        self.out = BallPrediction()
        self.path = Path()
        self.n_bad_covariance = 0
        self.uncertainty_worker = LatestWorker('uncertainty', self._propagate)
        self.path_worker = LatestWorker('path', self._publish_path)
        self.tracks = {}
        self.last_path_ns = None
        self.stamps_ns = None             # (earliest, latest) valid stamp received, ns
        self.clock_seen_ns = 0            # the node clock at the last state, ns
        self.clock_back = (0, 0)          # (from, to) of its last jump back, ns
        self.clock_steps = collections.deque(maxlen=CLOCK_STEPS)  # simulated clock's, ns
        self.work = CallbackTimes()       # the callback's time for the last states
        self.n_predicted = 0
        self.n_dropped = 0
        self.n_late = 0
        self.time_base = TimeBaseCheck(self.get_logger().warning)
        self.warn = ThrottledLog(self.get_logger().warning)

        reliable = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        # Names relative to the node's namespace (/ball/prediction in the root one).
        self.pub = self.create_publisher(BallPrediction, 'ball/prediction', reliable)
        self.pub_path = self.create_publisher(Path, 'ball/predicted_path', reliable)
        self.pub_markers = self.create_publisher(MarkerArray, 'tt/markers', reliable)
        states_qos = QoSProfile(depth=STATE_QUEUE_DEPTH,
                                reliability=ReliabilityPolicy.BEST_EFFORT)
        self.queue_lost = LostMessages()        # states lost before the callback
        self.sub = subscribe_input(self, BallState, 'ball/state', self.on_state, states_qos,
                                   lost=self.queue_lost)
        self.counts_status = CountsStatus(('states_dropped', 'states_late', 'states_lost'),
                                          self.work)
        report_status(self, 'predictions', '', self._status)
        self.get_logger().info(
            f'predicting {self.sub.topic_name} -> {self.pub.topic_name}, hitting plane x = '
            f'{self.p.hit_plane_x:.3f} m, model '
            f'{self.p.model_file or "nominal"}')

    def _drop(self, why):
        """Count a dropped state and warn, at most once a second for each kind of reason
        (its first word: stale, frame, velocity, ...): with one throttle for all, a stream of
        stale states hid the states of a camera frame dropped beside them."""
        self.n_dropped += 1
        self.warn('drop:' + why.replace(':', ' ').split(' ', 1)[0], 1.0,
                  f'ball state dropped: {why}')

    def _clock_seen(self, now_ns):
        """Take the node clock ``now_ns`` at a state: a jump back (a bag looped) into
        clock_back, and on a simulated clock its step since the last state into clock_steps
        (a step up to CLOCK_STEP_MAX_S: a longer one is a gap between states)."""
        last, self.clock_seen_ns = self.clock_seen_ns, now_ns
        if now_ns < last:
            self.clock_back = (last, now_ns)
        elif last and 0 < now_ns - last <= CLOCK_STEP_MAX_S * 1e9 \
                and self.get_clock().ros_time_is_active:
            self.clock_steps.append(now_ns - last)

    def _lag_s(self):
        """How far the node clock may lag a state, s: AHEAD_S, and on a simulated clock the
        median of its last CLOCK_STEPS steps (0 on the system clock, and before any step)."""
        return AHEAD_S + (float(np.median(self.clock_steps)) * 1e-9 if self.clock_steps else 0.0)

    def on_state(self, msg):
        self.work.call(self._on_state, msg)

    @property
    def n_received(self):
        """States received (the callback's calls)."""
        return self.work.count

    def work_summary(self):
        """Counts, the median and p99 of the time the callback took for the last states (ms),
        and the earliest and the latest stamp of the states whose header was valid (s, to the
        nanosecond: which part of a replay reached the node)."""
        times = self.work.latest_ms()
        if not len(times):
            return 'no state received'
        stamps = ('no state with a valid header (stamp, frame)' if self.stamps_ns is None else
                  'stamps {} to {} s'.format(*map(seconds_text, self.stamps_ns)))
        return (f'{self.n_received} states, {self.n_predicted} predictions, {self.n_dropped} '
                f'dropped; callback median {np.median(times):.3f} ms, p99 '
                f'{np.percentile(times, 99):.3f} ms (last {len(times)}); {stamps}; '
                f'{self.n_late} received more than {LATE_S * 1e3:.0f} ms after their stamp; '
                f'{self.queue_lost.count} lost in the input queue')

    def _status(self):
        """The status on /diagnostics: WARN when states were dropped, came late or were lost in
        the input queue since the last report; the totals, and the callback's time over the
        latest states."""
        level, new, values = self.counts_status.report(
            {'states_received': self.n_received, 'predictions_published': self.n_predicted,
             'states_dropped': self.n_dropped, 'states_late': self.n_late,
             'states_lost': self.queue_lost.count})
        message = (f"{new['states_received']} states, {new['predictions_published']} "
                   f"predictions, {new['states_dropped']} dropped, {new['states_late']} "
                   f'received more than {LATE_S * 1e3:.0f} ms after their stamp, '
                   f"{new['states_lost']} lost in the input queue, since the last report")
        return level, message, values

    def _on_state(self, msg):
        stamp_ns = to_ns(msg.header.stamp)
        why = header_problem(stamp_ns, msg.header.frame_id)
        if why:
            self._drop(why)
            return
        low, high = self.stamps_ns or (stamp_ns, stamp_ns)
        self.stamps_ns = (min(low, stamp_ns), max(high, stamp_ns))
        stale = self.p.stale_after_s
        now_ns = self.get_clock().now().nanoseconds
        self._clock_seen(now_ns)
        if not now_ns:                  # use_sim_time, no /clock yet: nothing to compare
            self.time_base(stamp_ns * 1e-9, 0.0)         # (said once if it lasts)
        elif stale > 0.0:
            age = (now_ns - stamp_ns) * 1e-9
            if self.time_base(stamp_ns * 1e-9, now_ns * 1e-9):
                if age > stale:
                    self._drop(f'stale: stamp {age:.3f} s old (stale_after_s {stale})')
                    return
                if -age > MAX_LEAD_S:
                    back_from, back_to = self.clock_back
                    if (back_from and now_ns - back_to <= MAX_LEAD_S * 1e9
                            and stamp_ns <= back_from + self._lag_s() * 1e9):
                        # A looped bag: its /clock starts the next pass as the last states
                        # of this one are on their way (another topic), so the node judged
                        # them against the new time (a walk-through, 7 Dec 2026).
                        self._drop(f'looped: stamp {-age:.3f} s ahead of the node clock, '
                                   f'which went back from {back_from * 1e-9:.3f} s (a bag '
                                   'played again): a state of before it')
                    else:
                        self._drop(f'stamp {-age:.3f} s ahead of the node clock (more than '
                                   f'{MAX_LEAD_S:g} s): the clocks disagree')
                    return
                if -age > AHEAD_S and -age > (lag_s := self._lag_s()):
                    self.warn('ahead', 5.0,
                              f'a state stamped {-age * 1e3:.0f} ms ahead of the node clock '
                              f'(more than the {lag_s * 1e3:.0f} ms it may lag): the clocks '
                              'disagree (its hit time is off by as much)')
                if age > LATE_S:
                    self.n_late += 1
                    self.warn('late', 5.0,
                              f'a state received {age * 1e3:.0f} ms after its stamp (more than '
                              f'{LATE_S * 1e3:.0f} ms): the node or its publisher falls behind')
        p, v, w = msg.position, msg.velocity, msg.spin
        if max(abs(p.x), abs(p.y), abs(p.z)) > ROOM_HALF_EXTENT_M:
            self._drop(position_error((p.x, p.y, p.z), 'position'))
            return
        state = np.array([p.x, p.y, p.z, v.x, v.y, v.z, w.x, w.y, w.z])
        reason = check_state(state, self.params.radius)
        if reason:
            # Before the track takes it: one state with a NaN or a 45 m/s velocity after the
            # bounce became the track's last, the next state was no longer on its path, and
            # the ball's bounce was forgotten (no hit for the rest of it; a walk-through).
            self._drop(reason)
            return
        track = self._track(msg.track_id, state, stamp_ns)
        if track is None:
            return
        track.last_ns = stamp_ns
        track.state = state
        if not due(stamp_ns, track.predicted_ns, self.p.max_rate_hz):
            return                  # each track at max_rate_hz: a second ball has its own
        plane_x = self.p.hit_plane_x
        margin_ns = BOUNCE_MARGIN_S * 1e9
        near = track.bounce_ns is not None and stamp_ns > track.bounce_ns - margin_ns
        bounced = near and stamp_ns > track.bounce_ns + margin_ns
        # Times relative to the stamp inside the integrator (float64 keeps sub-ns resolution
        # there), added to the integer stamp in nanoseconds on output.
        pred = predict(state, self.packed, 0.0, plane_x, bounced=bounced)
        if near and not bounced and (pred.status == 'no_bounce' or state[5] > 0.0):
            # Within the margin of the bounce the track expects, a state already rising from
            # the table: it has bounced (the estimator's bounce is not exactly the model's; a
            # ball coming down to a bounce does not rise in the 20 ms before it, and another
            # tracker's velocity smoothed over the kink can still see one ahead).
            bounced = True
            pred = predict(state, self.packed, 0.0, plane_x, bounced=True)
        if pred.status == 'invalid':
            self._drop(pred.reason)
            return
        track.predicted_ns = stamp_ns
        if not bounced:
            later = (pred.bounce is not None and near
                     and stamp_ns + pred.bounce.t * 1e9 > track.bounce_ns + margin_ns)
            if not later:
                # A state within the margin before the bounce foreseeing one later still is
                # no reason to forget it: smoothed over the kink by a tracker that does not
                # model the bounce, it moved the bounce on, and the ball's next states, past
                # no bounce it knew of, lost their hit for good (a walk-through, 6 Dec 2026).
                track.bounce = None
                track.bounce_ns = None
                track.second_ns = None
                if pred.bounce is not None and pred.bounce.half < 0:
                    track.bounce = pred.bounce
                    track.bounce_ns = stamp_ns + round(pred.bounce.t * 1e9)
        elif pred.status == 'double_bounce' and stamp_ns > track.bounce_ns + margin_ns:
            # Foreseen from a state past the margin after the bounce only: within it, a
            # velocity smoothed over the kink rises too slowly and foresees a second bounce
            # the ball never makes.
            track.second_ns = stamp_ns + round(pred.stop_t * 1e9)
        elif track.second_ns is not None and stamp_ns > track.second_ns + margin_ns:
            # Past the second bounce on the robot's half it foresaw: from there the ball flies
            # to the plane as if it had bounced once, but it is no ball to return.
            pred = dataclasses.replace(
                pred, status='double_bounce', hit=None,
                explanation="bounced a second time on the robot's half before the plane")
        out = self._prediction_msg(msg, stamp_ns, pred, track, plane_x)
        request = self._add_uncertainty(out, msg, state, stamp_ns, track, plane_x, bounced)
        self.pub.publish(out)
        self.n_predicted += 1
        if request is not None:         # after the publish: the prediction goes out first
            self.uncertainty_worker.submit(request, key=msg.track_id)
        if due(stamp_ns, self.last_path_ns, self.p.path_rate_hz):
            self.last_path_ns = stamp_ns
            self.path_worker.submit((msg, stamp_ns, state, plane_x, bounced))

    def _track(self, track_id, state, stamp_ns):
        """The remembered track ``state`` belongs to, made the latest updated (a new one for
        another ball under a used id), or None: a late or repeated state, dropped
        (OUT_OF_ORDER_S)."""
        gravity = self.params.gravity_vector
        track = self.tracks.get(track_id)
        if track is None:
            if len(self.tracks) >= MAX_TRACKS:
                self.tracks.pop(next(iter(self.tracks)))     # the one updated longest ago
            track = _Track()
        elif track.replaced is not None and track.replaced.continues(state, stamp_ns, gravity):
            # The state before this one was far off, this one carries on from the track
            # before it: that one was an outlier (even stamped ahead of this one).
            self.warn('outlier', 1.0,
                      f'track {track_id}: one state off its path (an outlier); the track goes on')
            track = track.replaced
        elif -OUT_OF_ORDER_S * 1e9 <= stamp_ns - track.last_ns <= 0:
            self._drop(f'track {track_id}: stamp {(track.last_ns - stamp_ns) * 1e-6:.1f} ms '
                       "before the track's last state: out of order or repeated")
            return None
        elif track.continues(state, stamp_ns, gravity):
            track.replaced = None           # not an outlier: the track it replaced is gone
        else:
            replaced, track = track, _Track()       # another ball under a used id
            replaced.replaced = None
            track.replaced = replaced
        self.tracks.pop(track_id, None)
        self.tracks[track_id] = track
        return track

    def _prediction_msg(self, msg, stamp_ns, pred, track, plane_x):
        """Fill the node's one BallPrediction (every field, each time) and return it.

        One message reused: rclpy serialises it in publish(), and building a new one (its
        nested headers, times, points and arrays) costs more than the prediction itself.
        """
        out = self.out
        out.header.stamp = msg.header.stamp
        out.header.frame_id = msg.header.frame_id or 'table'
        out.track_id = msg.track_id
        out.status = pred.status
        out.hit_plane_x = float(plane_x)
        if pred.bounce is not None:
            bounce, bounce_ns = pred.bounce, stamp_ns + round(pred.bounce.t * 1e9)
        else:
            bounce, bounce_ns = track.bounce, track.bounce_ns     # the bounce already past
        out.bounce_valid = bounce is not None
        if bounce is not None:
            set_time(out.bounce_time, bounce_ns)
            set_xyz(out.bounce_point, bounce.p)
            out.bounce_zone = bounce.zone
            out.bounce_half = bounce.half
        else:
            set_time(out.bounce_time, 0)
            set_xyz(out.bounce_point, _ZERO3)
            out.bounce_zone = 0
            out.bounce_half = 0
        hit = pred.hit
        out.hit_valid = hit is not None
        set_time(out.hit_time, stamp_ns + round(hit.t * 1e9) if hit is not None else 0)
        set_xyz(out.hit_point, hit.p if hit is not None else _ZERO3)
        set_xyz(out.hit_velocity, hit.v if hit is not None else _ZERO3)
        set_xyz(out.hit_spin, hit.w if hit is not None else _ZERO3)
        return out

    def _add_uncertainty(self, out, msg, state, stamp_ns, track, plane_x, bounced):
        """Zone probabilities and hit covariance of ``out`` from the track's last propagation;
        returns the request for a new propagation when one is due, else None."""
        unc = None
        request = None
        if self.p.uncertainty:
            unc = track.uncertainty
            if due(stamp_ns, track.uncertainty_ns,
                   self.p.uncertainty_rate_hz):
                track.uncertainty_ns = stamp_ns
                request = (track, state, np.array(msg.covariance), plane_x, bounced)
        out.hit_covariance[:] = 0.0
        out.hit_time_std = 0.0
        out.zone_probabilities[:] = 0.0
        if unc is not None:
            out.zone_probabilities[:] = unc.zone_probabilities
            out.zone_probabilities_half = int(unc.zone_half)
            if out.hit_valid:      # a no_hit message carried the last hit's (a walk-through)
                out.hit_covariance[:] = unc.hit_covariance.ravel()
                out.hit_time_std = float(unc.hit_time_std)
        elif out.bounce_valid:
            out.zone_probabilities[out.bounce_zone] = 1.0
            out.zone_probabilities_half = out.bounce_half
        else:
            out.zone_probabilities[0] = 1.0
            out.zone_probabilities_half = -1
        return request

    def _propagate(self, request):
        """Uncertainty worker: the track's zone probabilities and hit covariance."""
        track, state, cov, plane_x, bounced = request
        if not np.any(cov):             # BallState's 'unknown', not an exactly known state
            track.uncertainty = None
            self.n_bad_covariance += 1
            # Said once: a publisher that knows no covariance (the README's ros2 topic pub)
            # is not one to warn of every second.
            self.get_logger().info('a state with covariance all zeros (unknown): its '
                                   'prediction carries probability 1 for its zone and no '
                                   'hit covariance', once=True)
            return
        try:
            track.uncertainty = predict_uncertainty(state, cov, self.packed, 0.0, plane_x,
                                                    bounced=bounced)
        except ValueError as exc:
            track.uncertainty = None
            self.n_bad_covariance += 1
            self.warn('covariance', 1.0, f'covariance ignored: {exc}')

    def _publish_path(self, request):
        """Path worker: /ball/predicted_path and the markers.

        The worker predicts the state again with its path (the same flight as the callback's
        prediction: same state, model and plane): sampling the path costs more than the
        prediction itself (about 55 us), which the state's callback does not wait for. It
        keeps one Path and its PoseStamped and updates them: building 30-70 new poses in
        Python would hold the GIL for about 0.5 ms, while the state callback waits.
        """
        msg, stamp_ns, state, plane_x, bounced = request
        step = self.p.path_step_s
        pred = predict(state, self.packed, 0.0, plane_x, bounced=bounced, path_dt=step)
        frame = msg.header.frame_id or 'table'
        path = self.path
        path.header.stamp = msg.header.stamp
        path.header.frame_id = frame
        poses = path.poses
        del poses[len(pred.path):]
        while len(poses) < len(pred.path):
            pose = PoseStamped()
            pose.pose.orientation.w = 1.0
            poses.append(pose)
        for k, (pose, p) in enumerate(zip(poses, pred.path.tolist(), strict=True)):
            set_time(pose.header.stamp, stamp_ns + round(k * step * 1e9))
            pose.header.frame_id = frame
            position = pose.pose.position
            position.x, position.y, position.z = p
        self.pub_path.publish(path)
        if self.p.publish_markers:
            self.pub_markers.publish(self._markers(msg, pred))

    def _markers(self, msg, pred):
        markers = MarkerArray()

        def marker(mid, kind, rgb, scale):
            return add_marker(markers, msg.header, 'ball_prediction', mid, kind, rgb, scale)

        ball = marker(0, Marker.SPHERE, (1.0, 0.55, 0.0), 2 * self.params.radius)
        ball.pose.position = msg.position
        line = marker(1, Marker.LINE_STRIP, (0.2, 0.6, 1.0), 0.005)
        line.points = [point_msg(p) for p in pred.path]
        if pred.bounce is not None:
            marker(2, Marker.CYLINDER, (1.0, 1.0, 0.0), 0.06).pose.position = point_msg(
                pred.bounce.p)
        if pred.hit is not None:
            marker(3, Marker.SPHERE, (0.0, 1.0, 0.3), 0.05).pose.position = point_msg(pred.hit.p)
        return markers

    def destroy_node(self):
        self.uncertainty_worker.stop()
        self.path_worker.stop()
        return super().destroy_node()


def _started_node():
    node = PredictionNode()
    gc.freeze()     # start-up objects out of the collector's way: shorter pauses
    return node


def main(args=None):
    # The workers hold the GIL for their Python parts; a short switch interval
    # (default 5 ms) lets a state's callback take it back within a fraction of a millisecond.
    sys.setswitchinterval(2e-4)
    run_node(_started_node, args, name='prediction_node', parameters=PARAMETERS,
             on_exit=lambda node: node.get_logger().info(node.work_summary()))


if __name__ == '__main__':
    main()
