"""Frames -> detections -> time-matched 3-D points -> tracks of ball states.

:class:`Pipeline` takes frames one at a time, ``process(t, camera_index, frame)``, in time order
(t: exposure time, s), and returns the ball states it estimated from them. Its stages:

1. per camera, a :class:`tt_perception.detect.BallDetector`, searching only a window around
   the tracked ball's predicted image position while a track runs, and then fitting the
   ball's expected image (:func:`ball_image`: the projected outline of the sphere at its
   predicted depth, moving over the exposure) to find its centre (for a track not
   confirmed yet, from starts around the blob's own centre too, which comes along);
2. a :class:`Matcher` that groups each frame of camera 0 (the time reference) with the other
   cameras' detections at the same instant: the frame with the same stamp when the cameras are
   synchronised, otherwise the detections of the frames just before and after, interpolated
   linearly in time along the ball's image track (never the nearest frame taken blindly);
3. triangulation of every combination of candidates of >= 2 cameras, gated on the
   reprojection error and on the blob width against the ball's diameter at that depth, and
   its length beyond the tracked ball's blur (a narrower blob, part of the ball lost against
   a same-coloured background, is down-weighted);
4. a :class:`Tracker`: track start from two points at a plausible speed, EKF
   (:mod:`tt_prediction.ball_filter`) with Mahalanobis gating, confirmation after
   ``confirm_updates`` updates (gated on the blobs' own centres, so that a ball-coloured
   object that is not a ball is not confirmed on centres fitted to a ball), end after
   ``max_coast`` s without a measurement or when the ball leaves the volume above the floor;
   a track's frames before confirmation get states carried back from a later estimate
   (:attr:`TrackerConfig.backfill`), so that what a track holds back is given by
   :meth:`Pipeline.finish` after the last frame.

Offline (``tt-perceive``), :meth:`Pipeline.smoothed` then replaces each track's states by
those of a fixed-interval smoother (:attr:`TrackerConfig.smooth`).
"""

import collections
import copy
import dataclasses
import itertools
import math

from numba import njit
import numpy as np
from tt_prediction.ball import ModelParams, rollout
from tt_prediction.ball_filter import BallFilter, FilterConfig, smooth

from .camera import IN_FRONT_DEPTH, MAX_TIME_OFFSET_S, project_optical
from .detect import BallDetector, BallImage, DetectorConfig
from .triangulate import refine, triangulate

LIVE = object()
"""``snapshot`` default: read the running filter (only the processing thread may)."""

SPIN_MAX_AGE = 0.06
"""A measured spin is fused as the running track's spin when taken within this time of the
filter's, s (:meth:`Tracker.measure_spin`): the spin hardly changes in a few frames, but a
bounce between them would change it."""

PERCEPTION_FILTER = FilterConfig(accel_noise_speed=0.0)
"""The ball filter's settings perception runs unless told others: FilterConfig's, with the
unmodelled acceleration the same at every speed. Its growth with speed was measured on
recorded balls (docs/prediction_measured.md) and is not yet measured on camera scenes; the
params.yaml of `tt-predict --tracks` sets it with the accel_noise learned at it."""

# Columns of a detection's row (:func:`detection_row`; :meth:`Pipeline.detect`).
XY, WIDTH, HIDDEN, BLOB_XY, SURE, BRIGHT_WIDTH = slice(0, 2), 2, 3, slice(4, 6), 6, 7
LENGTH_OVER_BLUR = 8


def detection_row(xy, width, hidden=0.0, blob_xy=None, sure=True, bright_width=None,
                  length_over_blur=math.nan):
    """One detection as the pipeline passes it between its stages (:meth:`Matcher.add`,
    :meth:`Pipeline._points`): its centre ``xy`` and its blob's own centre ``blob_xy``
    (normalised image coordinates; ``xy`` when None), the silhouette's and the bright blob's
    widths (pixels; the bright blob's ``width`` when None), ``hidden``
    (:attr:`tt_perception.detect.Detection.hidden`), whether its colour is sure, and the
    bright blob's length less the tracked ball's predicted blur (pixels; NaN: not known)."""
    blob_xy = xy if blob_xy is None else blob_xy
    bright_width = width if bright_width is None else bright_width
    return np.array([xy[0], xy[1], width, hidden, blob_xy[0], blob_xy[1], float(sure),
                     bright_width, length_over_blur])


@dataclasses.dataclass
class BallEstimate:
    """One published state: time (s), state [p, v, w] (9,), covariance (9, 9), track id."""

    t: float
    state: np.ndarray
    covariance: np.ndarray
    track_id: int


@dataclasses.dataclass
class TrackerConfig:
    """Track management (SI units)."""

    confirm_updates: int = 3
    """Filter updates after the start before states are published (and a point among the
    track's seen by a camera sure of the ball's colour: ``unsure_updates``)."""
    unsure_updates: int = 5
    """Updates beyond ``confirm_updates`` after which a track ends, without a state, that no
    camera sure of the ball's colour has seen
    (:attr:`tt_perception.detect.Detection.colour_sure`). A track starts and goes on from
    points no camera is sure of, but is confirmed (its states published) only once one is:
    a far orange ball of 2-3 px radius, whose colour JPEG's halved chroma resolution washes
    out, is sure in a camera only now and then, and its track started up to 0.09 s late
    when its points had to be sure (docs/perception_measured.md, "Other rigs"); a grey thing of the
    ball's size is never sure."""
    backfill: bool = True
    """Also give the states of a confirmed track's earlier frames (its seed, its start and
    the updates before confirmation), carried back from a later estimate
    (:meth:`tt_prediction.ball_filter.BallFilter.earlier_state`; ``backfill_after``): a track
    then covers its whole flight. Off where only the newest state matters (the live node: a
    state 30 ms old is of no use to the robot)."""
    backfill_after: float = 0.1
    """With ``backfill``, the time from a track's seed frame at which its earlier frames'
    states are given, s: carried back from the estimate of the first update then, which has
    every frame up to it (what the fixed-interval smoother gives when the process noise over
    the interval is negligible), rather than from the confirming one, whose velocity rests on
    4-5 frames (a far ball's 0.46 m/s off, the states carried back from it 4-13 mm;
    docs/perception.md); a frame with a bounce between it and that estimate (no path back)
    gets the confirming estimate's. The states of the updates in between are held back until then,
    each its own (the filter's at its time), so that a track's states come in time order; a
    track that ends sooner gives them as it ends, from its last estimate (:meth:`Tracker.add`;
    after the last frame, :meth:`Pipeline.finish`). 0: with the confirming update's state
    (perception_node's ``backfill``, which publishes every state as soon as it can)."""
    smooth: bool = False
    """Keep each track's filtered states and covariances (its start and every update), so
    that :meth:`Pipeline.smoothed` can give every state from all of the track's frames, the
    later ones too (:func:`tt_prediction.ball_filter.smooth`). For offline use
    (``tt-perceive``); off in the live node, which publishes each state as it comes."""
    search_updates: int = 2
    """Filter updates after the start during which the outline fit also starts around the
    blob's centre (:meth:`tt_perception.detect.BallDetector.detect`'s ``search``): the
    prediction then rests on the start's two blob centres and at most one fitted point. Not
    on the update that confirms a track (3 by default), so that the first published state
    does not wait for the search (1.7 ms of work per frame pair at 640x480)."""
    blob_sigma: float = 0.01
    """Standard deviation per axis added to the positions a track starts from (its seed
    and start points: the blobs' own centres, as no prediction places the outline fit
    yet), m; half the ball's radius. A blob's centre leans toward the ball's lit side by up
    to a quarter of its radius, a bias the triangulation's covariance does not know: with
    it the filter takes its position from the outline fits of the updates that follow;
    without it, it started millimetres high and stayed so for tens of milliseconds
    (docs/perception.md)."""
    max_coast: float = 0.15
    """Time without an accepted measurement after which a track ends, s. The filter carries
    the ball meanwhile (the bounce included) and gates the next points on its grown
    covariance: a ball keeps its track through a burst of frame pairs the live node dropped
    under load, or a longer occlusion (docs/perception.md, "Tracks")."""
    min_speed: float = 1.0
    """Slowest speed of a new track (a ball in play), m/s."""
    max_speed: float = 40.0
    """Fastest speed of a new track, m/s."""
    min_z: float = -0.3
    """A track ends below this height (the ball has left the table's volume), m."""
    pixel_sigma: float = 0.4
    """Standard deviation of a detection's centre, pixels."""
    max_reprojection: float = 2.5
    """Largest reprojection error of a triangulated point, pixels."""
    width_ratio: tuple = (0.45, 1.9)
    """Accepted range of blob width over the ball's expected image diameter. Too narrow:
    the silhouette's width (the shaded side included); too wide: the smaller of the
    silhouette's and the bright blob's (:attr:`tt_perception.detect.Detection.bright_width`),
    as around a ball of 2-3 px radius behind JPEG q30 the silhouette takes in its compression
    block's ringing (twice the ball's width) while its bright part is no wider than the
    ball. The upper bound also holds the bright blob's length beyond the tracked ball's
    predicted blur (:attr:`tt_perception.detect.Detection.bright_length`): a racket's disc
    seen at a slant is as wide as a ball twice its size, and longer. Not within a diameter
    of the table, where a ball's blob takes in its contact shadow (the difference from the
    background is a shadow's too: a side light's sharp shadow made it 2 diameters long)."""
    fitted_width_min: float = 0.1
    """Too narrow for a centre fitted to the ball's outline: its silhouette narrower than this
    part of the ball's expected diameter (``width_ratio``'s lower bound is the blob's own
    centre's: a ball darker than the background behind it keeps only its lit edge in the
    silhouette, 0.14-0.3 of its width on a third renderer's light floor, while the fit
    places the whole ball to 0.3 px)."""
    kink_window: float = 0.1
    kink_velocity_noise: float = 1.0
    kink_spin_noise: float = 200.0
    """A confirmed track's point that fails the gate within ``kink_window`` s after the
    filter's bounce is held; when the next point fails it too, both are tried again (once a
    bounce) with the rebound's velocity and spin that much more uncertain (m/s, rad/s;
    :meth:`tt_prediction.ball_filter.BallFilter.update_after_bounce`) and fused if both then
    pass: the kink observed, so that a rebound the model got wrong (a flight model that read
    the spin wrong: an independent renderer's Magnus five times the model's put 550 rad/s for
    120 on a ball, and its track ended at the bounce) does not end the track, while a single
    outlier there (a frame delivered twice) is not taken for it (``Tracker._kink``). The held
    point's state then comes with the next one's, a frame late."""
    narrow_weight: float = 30.0
    """A blob narrower than the ball by a fraction f has its own centre's sigma times
    1 + narrow_weight f (not a centre fitted to the ball's outline)."""
    hidden_weight: float = 20.0
    """... and a blob whose outline is a fraction h ball-bright background, plus
    hidden_weight h."""


def ball_image(cam, position, velocity, radius, exposure):
    """The :class:`tt_perception.detect.BallImage` of a ball of ``radius`` (m) at ``position``
    (3,) moving at ``velocity`` (3,) (table frame, m, m/s) in camera ``cam`` over an
    ``exposure`` (s): the projection of its centre, the projection of its outline (the circle
    where the lines of sight touch the sphere, through the lens distortion; an ellipse,
    longer along the radius of the image off the axis) and of its motion over the exposure.
    None when the ball's centre is within its radius of the camera (no outline) or not in
    front of it (:meth:`tt_perception.camera.Camera.in_front`).

    One compiled kernel (numba, run without the GIL): it runs on every frame of every
    camera's thread while a track runs, where numpy's small calls held the GIL about 0.1 ms
    a frame."""
    out = _ball_image(cam.R, cam.t, cam.intrinsics, cam.rational_dist,
                      np.ascontiguousarray(position, dtype=float),
                      np.ascontiguousarray(velocity, dtype=float), float(radius), float(exposure))
    if out[10] == 0.0:
        return None
    up = out[8:10] if out[10] == 1.0 else None
    return BallImage(float(out[0]), float(out[1]), out[2:6].reshape(2, 2), out[6:8], up)


def warm_up():
    """Load the compiled kernel of :func:`ball_image` before the first ball needs it."""
    _ball_image(np.eye(3), np.array([0.0, 0.0, 1.0]), np.array([500.0, 500.0, 320.0, 240.0]),
                np.zeros(8), np.zeros(3), np.zeros(3), 0.02, 2e-3)


@njit(cache=True, nogil=True)
def _ball_image(R, t, intrinsics, dist, position, velocity, radius, exposure):
    """Kernel of :func:`ball_image`: (11,) the centre u, v; the outline's M row by row (4);
    the blur (2); the up direction (2), pixels; and what holds: 0 no image, 1 an image, 2 an
    image whose up direction is not worth trusting (zeros)."""
    out = np.zeros(11)
    c = R @ position + t
    d = math.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
    if not d > radius or not c[2] > IN_FRONT_DEPTH:
        return out
    ax, ay, az = c[0] / d, c[1] / d, c[2] / d
    # Two directions across the line of sight: e1 = axis x (0, 1, 0), e2 = axis x e1.
    across = math.hypot(ax, az)
    e1 = np.array([-az, 0.0, ax]) / across
    e2 = np.array([ax * ay, -across * across, ay * az]) / across
    # The outline: the circle of radius r sqrt(d^2 - r^2) / d at (d^2 - r^2) / d along the axis.
    ring = radius * math.sqrt(d * d - radius * radius) / d
    mid = (d * d - radius * radius) / (d * d) * c
    half = 0.5 * exposure * (R @ velocity)
    points = np.empty((8, 3))               # the optical frame
    points[0] = c
    points[1] = mid + ring * e1
    points[2] = mid + ring * e2
    points[3] = mid - ring * e1
    points[4] = mid - ring * e2
    points[5] = c - half
    points[6] = c + half
    points[7] = c + radius * R[:, 2]        # the ball's top
    uv = project_optical(points, intrinsics, dist)
    out[0], out[1] = uv[0, 0], uv[0, 1]
    # Four points a quarter turn apart on the projected circle: c + M (cos, sin).
    m00, m10 = 0.5 * (uv[1, 0] - uv[3, 0]), 0.5 * (uv[1, 1] - uv[3, 1])
    m01, m11 = 0.5 * (uv[2, 0] - uv[4, 0]), 0.5 * (uv[2, 1] - uv[4, 1])
    out[2], out[3], out[4], out[5] = m00, m01, m10, m11
    out[6], out[7] = uv[6, 0] - uv[5, 0], uv[6, 1] - uv[5, 1]
    # The image of the ball's top radius, over the ball's own radius in the image, is the
    # sine of the angle between the line of sight and the vertical: under 0.5 (a camera
    # looking within 30 degrees of straight down) it shows no direction worth trusting.
    up_u, up_v = uv[7, 0] - uv[0, 0], uv[7, 1] - uv[0, 1]
    norm = math.hypot(up_u, up_v)
    steep = not norm > 0.5 * math.sqrt(abs(m00 * m11 - m01 * m10))
    if steep:
        out[10] = 2.0
    else:
        out[8], out[9], out[10] = up_u / norm, up_v / norm, 1.0
    return out


class Matcher:
    """Groups detections of all cameras at the instants of camera 0's frames.

    The frames come in the order they arrive, their times on camera 0's clock. A camera whose
    clock is out of step with camera 0's by more than a frame (``time_offset``) delivers its
    frame of an instant that much later or earlier than camera 0 does (video files are read
    frame n of each camera in turn, cameras deliver at exposure): camera 0's frames wait for a
    camera's next frame ``max_wait`` periods plus how far that camera's frames lagged camera
    0's when it last delivered one, and frames are kept until camera 0 has been matched past
    them. (A camera 8 frames out of step lost every state: its frames were given up after
    3 periods, or pruned by the time of the camera ahead.)
    """

    def __init__(self, n_cameras, frame_period, tolerance=None, max_wait=3):
        self.n = n_cameras
        self.period = frame_period
        self.tol = tolerance if tolerance is not None else 0.1 * frame_period
        self.max_wait = max_wait * frame_period
        # Frames kept per camera: a clock up to MAX_TIME_OFFSET_S either way of camera 0's,
        # and the wait; bounded while camera 0 sends nothing (none was matched past them).
        keep = int(np.ceil((2.0 * MAX_TIME_OFFSET_S + self.max_wait) / frame_period)) + 4
        self.frames = [collections.deque(maxlen=keep) for _ in range(n_cameras)]
        self.pending = collections.deque(maxlen=keep)
        self.latest = [-np.inf] * n_cameras
        self.lag = [0.0] * n_cameras    # how far camera k's last frame came after camera 0's

    def add(self, k, t, detections):
        """Add camera ``k``'s frame at ``t`` with its detections (a list of
        :func:`detection_row`); returns the groups now complete: ``(t, [per-camera list])``."""
        self.frames[k].append((t, detections))
        self.latest[k] = max(self.latest[k], t)
        if k > 0 and np.isfinite(self.latest[0]):
            self.lag[k] = max(0.0, self.latest[0] - t)
        if k == 0:
            self.pending.append(t)
        out = []
        while self.pending:
            t0 = self.pending[0]
            group = self._group(t0)
            if group is None:
                break
            self.pending.popleft()
            out.append((t0, group))
        self._prune()
        return out

    def _group(self, t0):
        group = []
        for k in range(self.n):
            frames = self.frames[k]
            same = [d for t, d in frames if abs(t - t0) <= self.tol]
            if same:
                group.append(same[0])
                continue
            before = [(t, d) for t, d in frames if t < t0]
            after = [(t, d) for t, d in frames if t > t0]
            if before and after and after[0][0] - before[-1][0] <= 2.5 * self.period:
                group.append(self._interpolate(before[-1], after[0], t0))
                continue
            if not after and self.latest[0] - t0 < self.max_wait + self.lag[k]:
                return None                   # camera k's next frame is still to come
            group.append([])
        return group

    @staticmethod
    def _interpolate(a, b, t0):
        """Detections at t0 between frames a and b: each of a with its nearest in b."""
        (ta, da), (tb, db) = a, b
        out = []
        frac = (t0 - ta) / (tb - ta)
        for x in da:
            if not db:
                break
            gaps = [np.hypot(*(y[:2] - x[:2])) for y in db]
            j = int(np.argmin(gaps))
            if gaps[j] < 0.1:       # normalised units (~6 degrees)
                out.append(x + frac * (db[j] - x))
        return out

    def _prune(self):
        # Camera 0's next instant is after its latest frame: a camera ahead of it keeps its
        # frames until then.
        oldest = self.pending[0] if self.pending else self.latest[0]
        for frames in self.frames:
            while len(frames) > 2 and frames[1][0] < oldest - self.period:
                frames.popleft()


class Tracker:
    """Starts, updates and ends the track of one ball at a time."""

    def __init__(self, fps, params=None, filter_config=None, config=None):
        self.params = params or ModelParams()
        self.filter_config = filter_config or PERCEPTION_FILTER
        self.config = config or TrackerConfig()
        self.period = 1.0 / fps
        self.gravity = self.params.gravity_vector
        self.packed = self.params.packed()
        self.filter = None
        self.track_id = 0
        self.updates = 0
        self.last_update = -np.inf
        self.seeds = []
        self.early = []            # times of the running track's frames before confirmation
        self.held = []             # its states since confirmation, while early ones wait
        self.fallback = {}         # early time -> state carried back from the confirming one
        self.ended = []            # the states held back of a track that ended, for add()
        self.runs = {}             # track id -> (seed time, filter steps), with ``smooth``
        self.kinked = None         # the bounce (t, x, y) whose kink was taken
        self.kink_point = None     # (filter, point) of a point the gate refused after a bounce,
        #                            held until a second one says whether it is the kink
        self.kink_state = None     # the held point's state, once a kink was taken
        self.doubtful = None       # the filter before its last update, when that was doubtful
        self.sure = False          # a camera sure of the ball's colour saw one of its points

    @property
    def active(self):
        return self.filter is not None

    def predicted_motion(self, t, snapshot=LIVE):
        """(position, velocity) of the tracked ball at ``t``, or None; from ``snapshot`` (see
        :meth:`snapshot`; None: no track) instead of the running filter when given. Ahead of
        the state: its flight by the model (eq. 8), bounce included (eqs. 1-6), as a camera
        thread's snapshot may be a few frames old and from before a bounce; behind it (a
        rolling shutter's early rows), or where the model's flight stops: ballistic."""
        snap = self.snapshot() if snapshot is LIVE else snapshot
        if snap is None:
            return None
        t_filter, x = snap[:2]
        dt = t - t_filter
        if dt > 0.0:
            _, at = rollout(x, self.packed, t0=t_filter, t_max=t + self.period,
                            stop_at_plane=False, stop_at_net=False, max_bounces=2,
                            sample_times=np.array([t]))
            if np.isfinite(at[0, 0]):
                return at[0, :3], at[0, 3:6]
        return (x[:3] + x[3:6] * dt + 0.5 * self.gravity * dt * dt,
                x[3:6] + self.gravity * dt)

    @property
    def confirmed(self):
        """True while a track runs whose states are published."""
        return (self.filter is not None and self.updates >= self.config.confirm_updates
                and self.sure)

    @property
    def rough(self):
        """True while a track runs whose prediction is still rough (fewer than
        ``search_updates`` updates, and not confirmed)."""
        return (self.filter is not None and not self.confirmed
                and self.updates < self.config.search_updates)

    def snapshot(self):
        """(time, state (9,), rough, confirmed) of the running track, a copy, or None: what
        :meth:`predicted_motion` needs, for a camera thread to place its search window,
        whether the prediction is rough (:attr:`rough`: :meth:`Pipeline.detect` then
        searches wider for the ball's outline) and whether the track is :attr:`confirmed`."""
        f = self.filter
        return None if f is None else (f.t, f.x.copy(), self.rough, self.confirmed)

    def end(self):
        """End the running track; its states held back (``backfill_after``) come with the
        next :meth:`add`."""
        self.ended += self._release()
        self.filter = None
        self.doubtful = self.kink_point = None
        self.sure = False
        self.updates = 0
        self.early = []

    def finish(self):
        """After the last frame: the states held back (``backfill_after``) by a track that
        ended since the last :meth:`add`, then by the running one (:meth:`_release`)."""
        out, self.ended = self.ended, []
        return out + self._release()

    def _release(self):
        """The states the running track holds back (a confirmed track younger than
        ``backfill_after``): its earlier frames' carried back from its estimate now, then
        those of its updates since confirmation. A list of :class:`BallEstimate`, in time
        order."""
        if not (self.config.backfill and self.early and self.confirmed):
            return []
        f = self.filter
        out = []
        for te in self.early:
            state = f.earlier_state(te) or self.fallback.get(te)
            if state is not None:
                out.append(BallEstimate(te, state[0], state[1], self.track_id))
        out += self.held
        self.early, self.held, self.fallback = [], [], {}
        return out

    def advance(self, t):
        """Bring the running track to ``t`` (s): predicted there, or ended when it has had no
        measurement for ``max_coast`` or is below ``min_z``. Call it once for each instant
        before :meth:`add`, which then knows whether the track is still confirmed (whether
        the points need their blobs' own centres)."""
        cfg = self.config
        if self.filter is not None:
            if t - self.last_update > cfg.max_coast:
                self.end()
            else:
                self.filter.predict(t)
                if self.filter.x[2] < cfg.min_z:
                    self.end()

    def add(self, t, points, unsure=()):
        """Fuse the 3-D points seen at ``t``, after :meth:`advance` to ``t``
        (:meth:`Pipeline._points`: pairs of (X, cov) from the detections' centres and from
        their blobs' own centres, either None; the blobs' are not needed while the track is
        confirmed; ``unsure``: those of detections no camera was sure of the ball's colour
        in, which alone do not confirm a track: ``unsure_updates``); returns the list of
        :class:`BallEstimate` it completes, in time order:
        the state at ``t`` when a confirmed track was updated, preceded by the states it
        held back on its first update ``backfill_after`` from its seed (``backfill``), and
        first those a track that has ended held back (:meth:`end`)."""
        cfg = self.config
        out, self.ended = self.ended, []
        if self.filter is None:
            self._seed(t, [(*blob, sure) for pairs, sure in ((points, True), (unsure, False))
                           for _, blob in pairs if blob is not None])
            return out
        if not self._update(points, unsure):
            return out
        self.updates += 1
        self.last_update = t
        if cfg.smooth:
            self.runs[self.track_id][1].append(self._step())
        if not self.confirmed:
            self.early.append(t)
            if not self.sure and self.updates >= cfg.confirm_updates + cfg.unsure_updates:
                self.end()                  # never seen by a camera sure of the colour
            return out
        f = self.filter
        states = [BallEstimate(t, f.x.copy(), f.P.copy(), self.track_id)]
        if self.kink_state is not None:     # the held point's, fused with this one (_kink)
            states.insert(0, self.kink_state)
            self.kink_state = None
        if cfg.backfill and self.early:
            if t - self.early[0] < cfg.backfill_after - 1e-9:
                if not self.held:   # for a bounce between: no path back from a later one
                    self.fallback = {te: f.earlier_state(te) for te in self.early}
                self.held += states
                return out
            out += self._release()
        return out + states

    def _update(self, points, unsure=()):
        """Update the running track with the nearest of ``points`` and ``unsure`` (those no
        camera is sure of the colour of: a confirmed track takes them as the others, its gate
        on the prediction the evidence); True when one passed.

        A confirmed track takes the detections' centres (fitted to the ball's outline). A
        track not confirmed yet is gated on the blobs' own centres, so that a ball-coloured
        object that is not a ball (a racket's disc) is not confirmed on centres fitted to a
        ball's outline; the filter then takes the fitted point when it passes too (a blob's
        centre leans toward the ball's lit side)."""
        f = self.filter
        confirmed = self.confirmed
        best = None
        for pairs, sure in ((points, True), (unsure, False)):
            for point, blob in pairs:
                gated = point if confirmed else blob
                if gated is None:
                    continue
                d2 = f.innovation(*gated)[2]
                if best is None or d2 < best[0]:
                    best = (d2, point, blob, sure)
        if best is None:
            return False
        _, point, blob, sure = best
        if confirmed:
            before = copy.copy(f)               # update() replaces arrays, never writes them
            if f.update(*point, rebounce=True):
                # A point that passed the gate but far out (beyond its robust bound) may be
                # an outlier; the next may take it back (below).
                self.doubtful = before if f.last_d2 > f.config.robust else None
                self.kink_point = None
                return True
            if self._take_back(point):
                return True
            return self._kink(point, before)
        trial = copy.copy(f)                    # update() replaces arrays, never writes them
        if not trial.update(*blob, rebounce=True):
            return False
        self.sure |= sure
        if point is not None and point is not blob and f.update(*point, rebounce=True):
            return True
        # No fitted point that passes (none was made: a camera thread detected the frame
        # before the track started): the blob's own centre, which leans toward the lit
        # side, counts with that lean's variance, as the seeds do (start).
        X, R = blob
        if not f.update(X, R + np.eye(3) * self.config.blob_sigma ** 2, rebounce=True):
            self.filter = trial
        return True

    def _kink(self, point, before):
        """The rebound's kink observed: ``point``, refused by the gate within ``kink_window``
        s after the filter's bounce (``before``: the filter at its time, a copy), is fused
        with the rebound's velocity and spin more uncertain (``kink_velocity_noise``,
        ``kink_spin_noise``) only when the point refused before it, held since, passes so too
        and ``point`` then passes the gate as it is; else ``point`` is held in its place. True
        when fused (the held point's state, :attr:`kink_state`, comes with ``point``'s from
        :meth:`add`, a frame late). Once a bounce. A single point off the predicted rebound
        is as often a detector's outlier: synth's hall ball in a frame a camera delivered
        twice, or 40 ms after its bounce under a light that stepped up 30 %, was taken as the
        kink on its own and its state published 32-45 mm off."""
        cfg = self.config
        f = self.filter
        if (f.last_bounce is None or f.t - f.last_bounce[0] > cfg.kink_window
                or self.kinked == f.last_bounce):      # once a bounce
            self.kink_point = None
            return False
        held, self.kink_point = self.kink_point, (before, point)
        if held is None or held[0].last_bounce != f.last_bounce:
            return False
        trial, first = copy.copy(held[0]), held[1]
        noise = (cfg.kink_velocity_noise, cfg.kink_spin_noise)
        Q = trial.rebound_noise(*noise)
        if not trial.update_after_bounce(*first, Q):
            return False
        at_first = copy.copy(trial)         # predict() replaces arrays, never writes them
        trial.predict(f.t)
        if not trial.update(*point, rebounce=True):
            return False
        self.kink_state = BallEstimate(at_first.t, at_first.x.copy(), at_first.P.copy(),
                                       self.track_id)
        self.filter, self.kinked, self.kink_point = trial, f.last_bounce, None
        self.doubtful = before          # two outliers in a row are taken back too
        if cfg.smooth:
            # For the smoother the rebound's noise enters at the first step past the contact
            # (the updates since it were made with the rebound as predicted): the held
            # point's, unless an earlier one is past it.
            steps = self.runs[self.track_id][1]
            after = next((i for i, s in enumerate(steps) if s[0] > f.last_bounce[0]), None)
            if after is not None:
                steps[after] = (*steps[after][:4], trial.rebound_noise(*noise, t=steps[after][0]))
            steps.append(self._step(at_first, Q if after is None else None))
        return True

    def _take_back(self, point):
        """When ``point`` fails the gate just after a doubtful update (one beyond its robust
        bound, or a rebound's kink: the state before it in :attr:`doubtful`), and passes
        against the state before that update, carried to now: that update was an outlier's,
        and it is taken back and ``point`` fused instead. True when so. An orange ball in
        synth's hall, 44 ms after its bounce, crossing the table's white end line behind it:
        one fit 2-3 px off, taken as the rebound's kink, put the track 15 mm off, every later
        point failed the gate and the track ended 0.17 s before the ball reached the robot.
        (With ``smooth``, the kink's noise added to an earlier step stays: more uncertainty
        there, no bias.)"""
        doubtful, self.doubtful = self.doubtful, None
        f = self.filter
        if doubtful is None:
            return False
        doubtful.predict(f.t)
        if not doubtful.update(*point, rebounce=True):
            return False
        self.filter = doubtful
        if self.config.smooth:      # the step of the update taken back goes too
            self.runs[self.track_id][1].pop()
        return True

    def measure_spin(self, t, w, R):
        """Fuse a measured spin (rad/s, covariance R) taken at ``t`` into the running track,
        when the filter's time is within :data:`SPIN_MAX_AGE` of it. Returns True when it was
        used."""
        if self.filter is None or abs(t - self.filter.t) > SPIN_MAX_AGE:
            return False
        self.filter.update_spin(w, R)
        return True

    def _step(self, f=None, Q=None):
        """The filter ``f``'s (None: the running one's) (t, x, P, contact_z, Q), as
        :func:`smooth` takes them (``Q``: a kink's extra covariance of the update just made,
        :meth:`_kink`)."""
        f = self.filter if f is None else f
        return f.t, f.x.copy(), f.P.copy(), f.contact_z, Q

    def _seed(self, t, points):
        """Start a track from a previous point and one of ``points`` ((X, cov, whether a
        camera was sure of its colour)) at a plausible speed; pairs of sure points first."""
        cfg = self.config
        self.seeds = [s for s in self.seeds if 0.0 < t - s[0] <= 2.5 * self.period]
        pairs = sorted(itertools.product(self.seeds, points),
                       key=lambda pair: -(pair[0][3] + pair[1][2]))     # the sure first
        for (t1, X1, R1, sure1), (X2, R2, sure2) in pairs:
            dt = t - t1
            v = (X2 - X1) / dt + 0.5 * self.gravity * dt  # velocity at t (constant accel.)
            if cfg.min_speed <= np.linalg.norm(v) <= cfg.max_speed:
                self.start(t1, X1, R1, t, X2, R2, sure=sure1 or sure2)
                return
        self.seeds = [s for s in self.seeds if t - s[0] < 1.5 * self.period]
        self.seeds.extend((t, *point) for point in points)

    def start(self, t1, X1, R1, t, X2, R2, new_track=True, sure=True):
        """Start a track at ``t`` from the seed points X1 at ``t1`` and X2 at ``t`` (m, with
        their covariances R1, R2), ``sure``: either seen by a camera sure of the ball's
        colour; ``new_track`` False: start the running one again (its id and ``sure``
        kept)."""
        cfg = self.config
        dt = t - t1
        v = (X2 - X1) / dt + 0.5 * self.gravity * dt  # velocity at t (constant accel.)
        self.track_id += new_track
        if new_track:
            self.sure = sure
        self.filter = BallFilter(self.params, self.filter_config)
        bias = np.eye(3) * cfg.blob_sigma ** 2
        self.filter.start(t, X2, v, R2 + bias, (R1 + R2 + 2.0 * bias) / dt ** 2
                          + np.eye(3) * 0.05)
        self.updates = 0
        self.last_update = t
        self.seeds = []
        self.doubtful = self.kink_point = None
        self.early, self.held, self.fallback = [t1, t], [], {}
        if cfg.smooth:
            self.runs[self.track_id] = (t1, [self._step()])


def _seen_by_most(points):
    """The pairs (point, blob) of ``points`` (triples of the number of cameras that saw
    them, point, blob) that the most cameras saw."""
    most = max((n for n, _, _ in points), default=0)
    return [(point, blob) for n, point, blob in points if n == most]


class Pipeline:
    """The whole perception chain for one rig (see the module docstring)."""

    def __init__(self, rig, params=None, detector_config=None, filter_config=None,
                 tracker_config=None):
        self.rig = rig
        self.cameras = rig.cameras
        self.params = params or ModelParams()
        dcfg = detector_config or DetectorConfig()
        self.detectors = [BallDetector(dataclasses.replace(dcfg, white_bgr=cam.white_bgr),
                                       cam.focal, self.params.radius)
                          for cam in self.cameras]
        self.matcher = Matcher(len(self.cameras), 1.0 / rig.fps)
        self.tracker = Tracker(rig.fps, self.params, filter_config, tracker_config)
        self.config = self.tracker.config
        self.offsets = [c.time_offset or 0.0 for c in self.cameras]
        # A rolling shutter's last groups, for the seeds of a track (_restart_from_moved_seeds).
        rolling = any(c.readout_time for c in self.cameras)
        self.recent_groups = collections.deque(maxlen=4) if rolling else None
        self.last_error = None
        self.seen_by_two = 0        # instants with detections in two cameras or more
        self.triangulated = 0       # ... of which a point passed the gates

    def detect(self, t, k, frame, snapshot=LIVE, later=False):
        """Detections in camera ``k``'s frame stamped ``t`` (s, its own clock), for
        :meth:`process` (``detections=``): a list, or the ValueError of a missing or corrupt
        frame. The search window comes from ``snapshot`` (:meth:`Tracker.snapshot`, taken by
        the caller from the processing thread; None: no track) rather than the running
        filter, so that each camera's thread can detect in its own frames (only that camera's
        detector is used) while another thread processes. ``later``: the camera's background
        update waits for :meth:`update_background` (the caller hands the detections on
        first)."""
        if frame is None:
            return ValueError('no frame')
        cam = self.cameras[k]
        if (getattr(frame, 'ndim', 0) in (2, 3)         # else _detect names what it is
                and frame.shape[:2] != (cam.height, cam.width)):  # pixels misread
            return ValueError(f'frame {frame.shape[1]}x{frame.shape[0]}, its calibration '
                              f'{cam.width}x{cam.height}: frames of another size are skipped')
        t = float(t) - self.offsets[k]
        try:
            return self._detect(t, k, frame, snapshot, later)
        except ValueError as exc:
            return exc

    def update_background(self, k):
        """Camera ``k``'s background update left by :meth:`detect` (``later``), if any."""
        self.detectors[k].update_background()

    def process(self, t, k, frame, detections=None):
        """Process camera ``k``'s frame stamped ``t`` (s, its own clock); returns the list of
        :class:`BallEstimate` it completes, in time order (on the frame that confirms a
        track, its earlier frames' too: :attr:`TrackerConfig.backfill`). A missing or corrupt
        frame (None, wrong size, not 8-bit) is skipped: ``last_error`` says why, nothing is
        estimated from it.
        ``detections``: the result of :meth:`detect` on this frame, when done already."""
        if detections is None:
            detections = self.detect(t, k, frame)
        t = float(t) - self.offsets[k]
        self.last_error = None
        if isinstance(detections, ValueError):
            self.last_error = f'camera {self.cameras[k].name}: {detections}'
            detections = []
        out = []
        for t0, group in self.matcher.add(k, t, detections):
            self.tracker.advance(t0)
            started = self.tracker.active
            if self.recent_groups is not None:
                self.recent_groups.append((t0, group))
                group = self._at_frame_time(t0, group, self.tracker.snapshot())
            # A confirmed track takes only the fitted points: no triangulation of the blobs'.
            points, unsure = self._points(group, blobs=not self.tracker.confirmed)
            self.seen_by_two += sum(1 for dets in group if dets) >= 2
            self.triangulated += bool(points or unsure)
            out += self.tracker.add(t0, points, unsure)
            if self.recent_groups is not None and not started and self.tracker.active:
                self._restart_from_moved_seeds()
        return out

    def geometry_warning(self):
        """One line when the cameras saw a ball together at many instants (20 or more) but
        almost never (under a tenth) did their rays meet within ``max_reprojection``: a pose
        in another convention, a transposed rotation or a wrong ``time_offset``, which gave
        no track without a word (or detections that are not the ball: a wrong colour, a
        ball too small to be seen); else None."""
        if self.seen_by_two < 20 or self.triangulated >= 0.1 * self.seen_by_two:
            return None
        return (f'two cameras or more saw a ball at {self.seen_by_two} instants but their rays '
                f'met (within max_reprojection {self.config.max_reprojection:g} px) at only '
                f"{self.triangulated}: check the rig's poses (rotation and translation take "
                'table points into the camera frame: x_cam = R x_table + t) and each '
                "camera's time_offset (its clock minus camera 0's), or whether what they saw "
                'is the ball (one of another colour than the colour setting, or of a pixel or '
                'two, is matched to other things)')

    def colour_refused_warning(self, least=20):
        """One line when no track ever started but a camera refused ``least`` ball-like blobs
        or more for their colour alone: a ball under a light the camera is not balanced for
        (a white ball under a warm lamp is yellow), named with their median colour; else
        None."""
        if self.tracker.track_id or self.detectors[0].config.colour == 'any':
            return None
        for cam, d in zip(self.cameras, self.detectors, strict=True):
            if d.colour_refused >= least:
                b, g, r = np.median(np.array(d.refused_colours), axis=0)
                return (f"no track, and camera {cam.name} refused {d.colour_refused} ball-like "
                        f"blobs for their colour (not {d.config.colour!r}; median B, G, R "
                        f'{b:.0f}, {g:.0f}, {r:.0f}): under a coloured light give each '
                        "camera's white_bgr in the rig (a white surface's B, G, R in its "
                        'images), or the colour any')
        return None

    def colour_warning(self):
        """One line when the ball's colour is set but a camera's frames are grey (its
        detector's :attr:`tt_perception.detect.BallDetector.colourless`): the colour cannot
        be checked there, so any ball-like blob is taken; else None."""
        colour = self.detectors[0].config.colour
        grey = [cam.name for cam, d in zip(self.cameras, self.detectors, strict=True)
                if d.colourless]
        if colour == 'any' or not grey:
            return None
        return (f"camera(s) {', '.join(grey)}: grey images, so the ball colour {colour!r} is "
                'not checked there (any ball-like blob is taken)')

    def finish(self):
        """After the last frame: the states the tracker still holds back
        (:meth:`Tracker.finish`; a list of :class:`BallEstimate`)."""
        return self.tracker.finish()

    def smoothed(self, estimates):
        """``estimates`` (:class:`BallEstimate` of :meth:`process`) with each state and
        covariance given all of its track's frames (:func:`tt_prediction.ball_filter.smooth`;
        a track's seed frame, before its filter started, carried back from the smoothed start
        as :attr:`TrackerConfig.backfill` does); the estimates of a track not kept
        (:attr:`TrackerConfig.smooth` off) unchanged."""
        tracker = self.tracker
        done = {}
        for track_id in {e.track_id for e in estimates} & tracker.runs.keys():
            t_seed, steps = tracker.runs[track_id]
            states = smooth(steps, self.params, tracker.filter_config)
            done.update(((track_id, step[0]), state)
                        for step, state in zip(steps, states, strict=True))
            start = BallFilter(self.params, tracker.filter_config)
            start.t, (start.x, start.P) = steps[0][0], states[0]
            earlier = start.earlier_state(t_seed)
            if earlier is not None:
                done[(track_id, t_seed)] = earlier
        out = []
        for e in estimates:
            state = done.get((e.track_id, e.t))
            out.append(e if state is None else
                       BallEstimate(e.t, state[0].copy(), state[1].copy(), e.track_id))
        return out

    def _detect(self, t, k, frame, snapshot, later=False):
        cam = self.cameras[k]
        roi = expected = None
        snap = self.tracker.snapshot() if snapshot is LIVE else snapshot
        motion = self.tracker.predicted_motion(t, snap)
        if motion is not None:
            # Each candidate's centre is the fit of the tracked ball's outline; its blob's own
            # centre comes too, for a track not confirmed yet (Tracker.add). While the
            # predicted centre is rough (Tracker.rough) the fit searches around the blob's.
            # None: a ball not in front of this camera.
            expected = ball_image(cam, motion[0], motion[1], self.params.radius,
                                  self.detectors[k].config.exposure)
            if expected is not None and cam.readout_time:
                # A rolling shutter: the ball's rows were exposed at their own time.
                motion = self.tracker.predicted_motion(t + cam.row_delay(expected.v), snap)
                expected = ball_image(cam, motion[0], motion[1], self.params.radius,
                                      self.detectors[k].config.exposure)
        if expected is not None:
            roi = (expected.u, expected.v)
        dets = self.detectors[k].detect(frame, roi, expected=expected,
                                        search=expected is not None and snap[2], later=later)
        if not dets and roi is not None:
            dets = self.detectors[k].detect(frame, None, update_background=False)
        if not dets:
            return []
        # The centres and the blobs' centres in one call (each call holds the GIL).
        both = cam.normalise(np.array([[d.u, d.v] for d in dets]
                                      + [[d.blob_u, d.blob_v] for d in dets]))
        # A ball's blob is no longer than the ball stretched by its predicted blur.
        blur = math.hypot(*expected.blur) if expected is not None else math.nan
        return [detection_row(c, d.width, d.hidden, b, d.colour_sure, d.bright_width,
                              d.bright_length - blur)
                for c, b, d in zip(both[:len(dets)], both[len(dets):], dets, strict=True)]

    def _at_frame_time(self, t, group, snap):
        """``group`` (one time-matched group at ``t``, :meth:`Matcher.add`) with the
        detections of each rolling-shutter camera, seen when their rows were exposed
        (:meth:`tt_perception.camera.Camera.row_delay`), moved back along the tracked ball's
        predicted image motion (``snap``: :meth:`Tracker.snapshot`; None: unchanged) to where
        they were at ``t``. The motion is taken in normalised image coordinates, each
        detection's row through the lens (:func:`tt_perception.camera.project_optical`)."""
        if snap is None:
            return group
        out = []
        for cam, dets in zip(self.cameras, group, strict=True):
            half = 0.5 * cam.readout_time
            ends = [cam.R @ self.tracker.predicted_motion(t + dt, snap)[0] + cam.t
                    for dt in (-half, half)] if dets and half else None
            if ends is None or min(c[2] for c in ends) <= IN_FRONT_DEPTH:
                out.append(dets)
                continue
            first, last = (c[:2] / c[2] for c in ends)
            velocity = (last - first) / cam.readout_time     # normalised units per s
            moved = []
            for det in dets:
                det = det.copy()
                for cols in (XY, BLOB_XY):
                    ray = np.array([[det[cols][0], det[cols][1], 1.0]])
                    row = project_optical(ray, cam.intrinsics, cam.rational_dist)[0, 1]
                    det[cols] -= cam.row_delay(row) * velocity
                moved.append(det)
            out.append(moved)
        return out

    def _restart_from_moved_seeds(self):
        """A track of a rolling-shutter rig has just started from two seed points whose
        detections nothing moved to their frame's time (no track predicted their motion):
        it starts again from the same detections moved along its own motion
        (:meth:`_at_frame_time`; without it a 14 m/s ball's first states were 2.5 mm off
        at 5 ms readout, 0.9 with it, settling over 50 ms)."""
        tracker = self.tracker
        snap = tracker.snapshot()
        seeds = []
        for t, group in self.recent_groups:
            if t not in tracker.early:
                continue
            blobs = [blob for points in self._points(self._at_frame_time(t, group, snap))
                     for _, blob in points if blob is not None]
            if not blobs:
                return
            nearest = tracker.predicted_motion(t, snap)[0]
            seeds.append((t, *min(blobs, key=lambda b: np.linalg.norm(b[0] - nearest))))
        if len(seeds) == 2:
            tracker.start(*seeds[0], *seeds[1], new_track=False)

    def _points(self, group, blobs=True):
        """Triangulated, gated candidate points of one time-matched group, each a pair: the
        point (X, cov) of the detections' centres and that of their blobs' own centres (the
        same when none was fitted), either None when it fails the gates; for
        :meth:`Tracker.add`: two lists, the points seen by a camera sure of the ball's colour
        (:attr:`tt_perception.detect.Detection.colour_sure`) and those seen by none. Without
        ``blobs`` (a confirmed track) a blobs' point that differs is not triangulated: None.
        Only the points seen by the most cameras are kept, in each list."""
        options = [list(dets) + [None] for dets in group]
        points = []
        for combo in itertools.product(*options):
            used = [k for k, d in enumerate(combo) if d is not None]
            if len(used) < 2:
                continue
            sure = any(combo[k][SURE] > 0.0 for k in used)
            cams = [self.cameras[k] for k in used]
            obs = np.array([combo[k] for k in used])
            point = self._point(cams, obs[:, XY], obs)
            if np.array_equal(obs[:, XY], obs[:, BLOB_XY]):
                blob = point
            else:
                blob = self._point(cams, obs[:, BLOB_XY], obs) if blobs else None
            if point is not None or blob is not None:
                points.append((len(used), sure, point, blob))
        return tuple(_seen_by_most([(n, point, blob) for n, sure, point, blob in points
                                    if sure == wanted]) for wanted in (True, False))

    def _point(self, cams, centres, obs):
        """(X, cov) triangulated from the normalised image ``centres`` (n, 2) of ``cams``,
        gated on the reprojection error and on the blobs' widths (``obs``: the
        :func:`detection_row` of each camera; :attr:`TrackerConfig.width_ratio`); None when
        it fails."""
        cfg = self.config
        result = triangulate(cams, centres, cfg.pixel_sigma, cfg.max_reprojection)
        if result is None or len(result[3]) < len(cams):
            return None
        X, cov, _, _ = result
        diameter = np.array([2.0 * cam.focal * self.params.radius / (cam.R @ X + cam.t)[2]
                             for cam in cams])
        ratio = obs[:, WIDTH] / diameter
        bright = obs[:, BRIGHT_WIDTH] / diameter
        # Too narrow is less asked of a centre fitted to the ball's outline (fitted_width_min).
        fitted = np.any(centres != obs[:, BLOB_XY], axis=1)
        least = np.where(fitted, cfg.fitted_width_min, cfg.width_ratio[0])
        if np.any(ratio < least) or np.any(np.fmin(ratio, bright) > cfg.width_ratio[1]):
            return None
        # Nor longer, beyond the tracked ball's blur (a racket's disc seen at a slant), but
        # on the table, where a ball's blob takes in its contact shadow.
        if (X[2] > 2.0 * self.params.radius
                and np.any(obs[:, LENGTH_OVER_BLUR] > cfg.width_ratio[1] * diameter)):
            return None
        # A blob narrower than the ball, or bordered by background as bright as the ball,
        # may have lost part of it (a white line behind a white ball): its own centre may be
        # biased, so it counts for less. Not a centre fitted to the ball's outline: the fit
        # models the background, and a blob that lost the shaded side does not move it.
        weak = (1.0 + cfg.narrow_weight * np.maximum(0.0, 1.0 - ratio)
                + cfg.hidden_weight * obs[:, HIDDEN])
        weak[fitted] = 1.0
        if np.any(weak > 1.0):
            try:
                X, cov, _ = refine(cams, centres, X, cfg.pixel_sigma * weak)
            except np.linalg.LinAlgError:       # the rays fix no point (triangulate: None)
                return None
        return X, cov
