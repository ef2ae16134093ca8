"""Replay of measured ball tracks through the live ball filter and predictor (no rclpy).

Each track's samples go, in time order, through :class:`tt_prediction.ball_filter.TrackFilter`
(the EKF perception_node runs, fed 3-D positions instead of triangulated images) and, once
the filter runs, through :func:`tt_prediction.predict.predict_row` (the compiled predictor
under :func:`tt_prediction.predict.predict`, what prediction_node runs, without the Prediction
object built from its row) with ``bounced`` set once the filter has taken the ball through
its bounce on the robot's half. One output row per input sample:

    t, x, y, z, vx, vy, vz, wx, wy, wz     filtered state at t (s, m, m/s, rad/s)
    bounce_t, bounce_x, bounce_y           the bounce on the robot's half: predicted, or the
                                           one the filter went through (s, m)
    hit_t, hit_x, hit_y, hit_z             predicted crossing of x = hit_plane_x after it

NaN where there is no estimate or no prediction. :func:`lead_time_errors` compares the
predicted hit with the measured crossing at fixed lead times before it; :func:`textbook_hit`
is the reference predictor that refits a fresh flight state to the last samples.
"""

import dataclasses
import math

import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from .ball import FIELD, rollout, table_rebound_inplace
from .ball_filter import (
    AccelNoiseLearner,
    BallFilter,
    FilterConfig,
    SpinPriorLearner,
    TrackFilter,
    rebound_map,
    spin_likelihood_per_axis,
    velocity_frame,
)
from .identify.data import Track, clean_samples
from .identify.segment import drop_outliers, segment
from .predict import (
    _N_OUT,
    _O_BOUNCE_HALF,
    _O_BOUNCE_OK,
    _O_BOUNCE_P,
    _O_BOUNCE_T,
    _O_HIT_OK,
    _O_HIT_P,
    _O_HIT_T,
    DEFAULT_HIT_PLANE_X,
    predict,
    predict_row,
)

COLUMNS = ('t', 'x', 'y', 'z', 'vx', 'vy', 'vz', 'wx', 'wy', 'wz', 'bounce_t', 'bounce_x',
           'bounce_y', 'hit_t', 'hit_x', 'hit_y', 'hit_z')
LEADS_MS = (300, 200, 150, 100, 50)
"""Lead times before the measured crossing at which the hit error is evaluated, ms."""
MIN_HISTORY = 0.05
"""A track with less than this much data before the prediction time has no prediction due:
it is counted as too short, not as missing, s."""
CROSSING_WINDOW = 3
"""Samples on each side of the measured crossing used for its local quadratic fit."""
NEXT_FLIGHT_OFF = 0.015
"""A sample this far (m) from the extrapolated flight before it is on another flight (a
stroke turns the ball by ~5 cm a sample at 180 Hz; the noise is ~1 mm)."""
TEXTBOOK_SAMPLES = 20
"""The textbook predictor fits the flight model to this many last samples (~110 ms)."""


@dataclasses.dataclass
class TrackReplay:
    """Replay of one track: ``rows`` (n, 17) in COLUMNS order (input order sorted by time),
    ``crossing`` the measured crossing (t, p (3,)) or None, ``first_t`` the first valid
    sample time (s), the cleaned samples ``t``, ``p`` and the located bounces."""

    name: str
    rows: np.ndarray
    crossing: tuple
    first_t: float
    t: np.ndarray
    p: np.ndarray
    bounce_times: list
    spin_prior: tuple = None
    """The spin prior's standard deviations the track was replayed with (top/back, side,
    along v), rad/s."""
    nis: list = None
    """Squared Mahalanobis distances of the filter's accepted samples."""
    spin_prior_mean: tuple = (0.0, 0.0, 0.0)
    """The spin prior's mean on the same axes, rad/s."""
    robot_bounce: object = None
    """The first bounce on the robot's half located in the data
    (:class:`tt_prediction.identify.segment.Bounce`: t, p, v_in, v_out), or None."""
    e_t: float = None
    """The table restitution the track was replayed with."""
    c_m: float = None
    """The Magnus coefficient the track was replayed with."""
    spin_outlier_t: float = None
    """Time (s) at which the filter first took its second filter's state (the track's spin
    outside the spin prior's population: FilterConfig ``spin_outlier_rate``), or None."""
    gravity: float = None
    """The gravity the track was replayed with, m/s^2."""


def replay_samples(t, p, params, config=None, hit_plane_x=DEFAULT_HIT_PLANE_X, spin=None):
    """Rows (n, 17) of the filter and predictor over one track's samples.

    ``t`` (n,) s and ``p`` (n, 3) m as measured (NaN rows, duplicate or unsorted stamps
    allowed); rows come in time order (a stable sort of the input; NaN stamps last).
    ``spin``: measured spin at the start (rad/s, (3,)) or None.
    """
    return _replay_samples(t, p, params, config, hit_plane_x, spin)[0]


def _replay_samples(t, p, params, config, hit_plane_x, spin, from_t=None):
    """:func:`replay_samples`'s rows, the NIS of the filter's accepted samples and the time
    the filter took its second filter's state (None: never). Samples before ``from_t`` (s)
    are not fed to the filter (their rows hold no state): a ball held still before its
    launch, which a camera's tracker does not follow as a flight."""
    t = np.asarray(t, dtype=float)
    p = np.asarray(p, dtype=float)
    order = np.argsort(np.where(np.isfinite(t), t, np.inf), kind='stable')
    rows = np.full((len(t), len(COLUMNS)), np.nan)
    rows[:, 0] = t[order]
    p = p[order]
    tf = TrackFilter(params, config)
    last_key = None
    out = np.empty(_N_OUT)       # the predictor's row (predict_row) of the state at last_key
    valid = False
    spin_used = spin is None
    packed = params.packed()
    outlier_t = None
    for k, ti in enumerate(rows[:, 0].tolist()):
        if not math.isfinite(ti) or (from_t is not None and ti < from_t):
            continue
        status = tf.add(ti, p[k])
        if not tf.running:
            continue
        f = tf.filter
        if not spin_used and status == tf.STARTED:
            f.update_spin(spin, np.eye(3) * 25.0)
            spin_used = True
        if f.took_outlier and outlier_t is None:
            outlier_t = ti
        rows[k, 1:10] = f.x
        key = (f.t, tf.updates, tf.filter)
        if key != last_key:                   # else a skipped duplicate: same state, answer
            # predict()'s numbers, read from its row: an invalid state has no bounce, no hit
            # (predict's _contact / _hit would build objects: 5.5 us a sample, 9 %)
            valid = not predict_row(f.x, packed, f.t, hit_plane_x, tf.robot_bounced, out)
            last_key = key
        if tf.robot_bounced and tf.robot_bounce is not None:
            rows[k, 10:13] = tf.robot_bounce
        elif valid and out[_O_BOUNCE_OK] and out[_O_BOUNCE_HALF] < 0.0:
            rows[k, 10] = out[_O_BOUNCE_T]
            rows[k, 11:13] = out[_O_BOUNCE_P:_O_BOUNCE_P + 2]
        if valid and out[_O_HIT_OK] and tf.robot_bounces < 2:   # not after a double bounce
            rows[k, 13] = out[_O_HIT_T]
            rows[k, 14:17] = out[_O_HIT_P:_O_HIT_P + 3]
    return rows, tf.nis, outlier_t


def measured_crossing(t, p, bounce_times, plane_x):
    """First crossing of x = plane_x after the first bounce on the robot's half: (t, p).

    Local quadratic fits in time (CROSSING_WINDOW samples each side) average the measurement
    noise; None when the data does not cross the plane after such a bounce, or bounces on
    the robot's half a second time before it (a double bounce: no ball to return).
    """
    robot = sorted(tb for tb, xb in bounce_times if xb < 0.0)
    if not robot:
        return None
    after = t > robot[0]
    g = p[:, 0] - plane_x
    idx = np.flatnonzero(after[:-1] & after[1:] & (np.sign(g[:-1]) * np.sign(g[1:]) < 0))
    if not len(idx):
        return None
    i = idx[0]
    if len(robot) > 1 and robot[1] < t[i + 1]:
        return None
    lo = max(i - CROSSING_WINDOW + 1, int(np.argmax(after)))
    hi = min(i + CROSSING_WINDOW + 1, len(t))
    w = g[i] / (g[i] - g[i + 1])
    tc = t[i] + w * (t[i + 1] - t[i])
    if hi - lo < 4:
        return tc, (1 - w) * p[i] + w * p[i + 1]
    ts = t[lo:hi] - tc
    fits = [np.polyfit(ts, p[lo:hi, k], 2) for k in range(3)]
    for _ in range(3):                      # Newton on x(t) = plane_x
        dx = np.polyval(fits[0], 0.0) - plane_x
        v = np.polyval(np.polyder(fits[0]), 0.0)
        if abs(v) < 1e-6:
            break
        tc -= dx / v
        ts = t[lo:hi] - tc
        fits = [np.polyfit(ts, p[lo:hi, k], 2) for k in range(3)]
    pc = np.array([plane_x, np.polyval(fits[1], 0.0), np.polyval(fits[2], 0.0)])
    return float(tc), pc


def crossing_noise(t, p, bounce_times, plane_x, position_noise, stamp_noise, draws=50,
                   rng=None, crossing=None):
    """Errors of the measured crossing itself (:func:`measured_crossing`) on one track: the
    hit errors a perfect predictor would be scored with, m, (k,) (empty without a crossing).

    The track near its crossing stands for the truth: a quadratic in time per axis over the
    samples within 60 ms of the crossing and after the bounce on the robot's half. Its
    samples are drawn again ``draws`` times with the data's noise (``position_noise`` m on
    each axis, ``stamp_noise`` s along the velocity) and measured again; each error is the
    distance in the plane between that and the quadratic's own crossing. ``crossing``: the
    track's measured crossing when known already.
    """
    rng = rng or np.random.default_rng(0)
    if crossing is None:
        crossing = measured_crossing(t, p, bounce_times, plane_x)
    if crossing is None:
        return np.zeros(0)
    tc = crossing[0]
    robot = min(tb for tb, xb in bounce_times if xb < 0.0)
    sel = (t > robot) & (np.abs(t - tc) < 0.06)
    if sel.sum() < 4:
        return np.zeros(0)
    fits = [np.polyfit(t[sel] - tc, p[sel, k], 2) for k in range(3)]
    roots = np.roots(fits[0] - np.array([0.0, 0.0, plane_x]))
    roots = roots[np.isreal(roots)].real
    if not len(roots):
        return np.zeros(0)
    t_true = roots[np.argmin(np.abs(roots))]
    p_true = np.array([np.polyval(f, t_true) for f in fits])
    smooth = np.stack([np.polyval(f, t - tc) for f in fits], axis=1)
    velocity = np.stack([np.polyval(np.polyder(f), t - tc) for f in fits], axis=1)
    errors = []
    for _ in range(draws):
        noisy = (smooth + rng.normal(0.0, position_noise, smooth.shape)
                 + rng.normal(0.0, stamp_noise, (len(t), 1)) * velocity)
        m = measured_crossing(t, noisy, bounce_times, plane_x)
        if m is not None:
            errors.append(np.linalg.norm(m[1][1:] - p_true[1:]))
    return np.array(errors)


def _ground_truth(name, t, p, params, plane_x):
    """Cleaned samples, located bounces (:class:`tt_prediction.identify.segment.Bounce`)
    and measured crossing of one track's incoming flight, the time that flight starts where
    the track holds another before it (a rally: the ball goes out and is struck back, or is
    lost for a while) or the ball held still before its launch, else None; and the time the
    ball was launched after it was held still (segment's ``samples_held_still``), else
    None."""
    tc, pc, notes = clean_samples(name, t, p)
    if len(tc) < 3:
        return tc, pc, [], None, None, None
    first = scored = None
    start = 0
    while len(tc) - start >= 8:
        # Any length: a track seen from 100 ms before its bounce still has a crossing to
        # score (tt-identify wants 0.2 s of flight to fit; the replay does not fit it).
        seg, bounces = segment(Track(name, tc[start:], pc[start:], None, '', notes),
                               params.radius, min_duration=0.0)
        if seg is None:
            break
        first = first or (seg, bounces, start)
        if any(b.p[0] < 0.0 for b in bounces):
            scored = (seg, bounces, start)
            break
        if seg.t[-1] >= tc[-1]:
            break
        # Cut before any bounce on the robot's half (at a stroke, a gap, a contact it
        # cannot resolve): the ball to return may come after it.
        start = _next_flight(tc, pc, seg, params.gravity_vector)
    if first is None:
        tt, pp = drop_outliers(tc, pc, {}, params.radius)
        return tt, pp, [], None, None, None
    launched = float(first[0].t[0]) if first[0].notes.get('samples_held_still') else None
    seg, bounces, start = scored or first
    times = [(b.t, b.p[0]) for b in bounces]
    return (seg.t, seg.p, bounces, measured_crossing(seg.t, seg.p, times, plane_x),
            float(seg.t[0]) if start or launched is not None else None, launched)


def _next_flight(t, p, seg, gravity):
    """Index of the first of ``t``'s samples past flight ``seg`` that is no longer on it: the
    first of two in a row more than NEXT_FLIGHT_OFF from the ballistic extrapolation of seg's
    last samples (segment() cuts a few samples before a contact), above the table.
    ``gravity``: (3,) m/s^2, table frame (ModelParams.gravity_vector)."""
    k = int(np.searchsorted(t, seg.t[-1], side='right'))
    n = min(len(seg.t), 6)
    dt = seg.t[-n:] - seg.t[-1]
    fall = 0.5 * np.asarray(gravity)
    A = np.stack([np.ones(n), dt], axis=1)                   # p0 + v dt + g dt^2 / 2
    coef = np.linalg.lstsq(A, seg.p[-n:] - np.outer(dt ** 2, fall), rcond=None)[0]
    dt = t[k:] - seg.t[-1]
    off = np.linalg.norm(p[k:] - coef[0] - np.outer(dt, coef[1]) - np.outer(dt ** 2, fall),
                         axis=1) > NEXT_FLIGHT_OFF
    new = np.flatnonzero(off[:-1] & off[1:] & (p[k:-1, 2] >= 0.0))
    return k + int(new[0]) if len(new) else len(t)


def no_crossing_reason(rp, plane_x):
    """Why track replay ``rp`` has no measured crossing of x = plane_x (one line), or ''."""
    if rp.crossing is not None:
        return ''
    if not len(rp.t):
        return 'no valid samples'
    if rp.robot_bounce is None:
        return (f"no bounce located on the robot's half (the cleaned track ends at t = "
                f'{rp.t[-1]:.3f} s, x = {rp.p[-1, 0]:.2f} m)')
    tb = rp.robot_bounce.t
    robot = sorted(t for t, x in rp.bounce_times if x < 0.0)
    if len(robot) > 1 and not np.any(rp.p[(rp.t > tb) & (rp.t < robot[1]), 0] <= plane_x):
        return (f"bounces twice on the robot's half (t = {robot[0]:.3f} and {robot[1]:.3f} s) "
                'before the plane')
    x = rp.p[rp.t > tb, 0]
    if not len(x) or np.all(x > plane_x):
        end = x.min() if len(x) else rp.p[-1, 0]
        return f'ends at x = {end:.2f} m after its bounce at t = {tb:.3f} s'
    return (f'no sample between its bounce at t = {tb:.3f} s and the plane (the first after '
            f'it is at x = {x[0]:.2f} m)')


def replay_track(name, t, p, params, config=None, hit_plane_x=DEFAULT_HIT_PLANE_X,
                 spin=None):
    """:class:`TrackReplay` of one track (see :func:`replay_samples`)."""
    config = config or FilterConfig()
    tt, pp, bounces, crossing, flight_t, launched = _ground_truth(
        name, np.asarray(t, float), np.asarray(p, float), params, hit_plane_x)
    rows, nis, outlier_t = _replay_samples(t, p, params, config, hit_plane_x, spin, launched)
    if flight_t is not None:
        first = flight_t                    # lead times count from the incoming flight
    else:
        valid = np.isfinite(t) & np.all(np.isfinite(p), axis=1)
        first = float(np.min(np.asarray(t)[valid])) if valid.any() else math.nan
    robot = [b for b in bounces if b.p[0] < 0.0]
    return TrackReplay(name, rows, crossing, first, tt, pp, [(b.t, b.p[0]) for b in bounces],
                       config.spin_prior_axes(), nis, tuple(config.spin_prior_mean),
                       robot[0] if robot else None, params.e_t, params.c_m, outlier_t,
                       params.gravity)


# ----------------------------------------------------------------------------------------------
# What a finished track says about its spin (for the learned prior)


POST_BOUNCE_WINDOW = (0.004, 0.09)
"""Samples this long after the located bounce (s) give the measured rebound velocity; the
window is longer where it would hold fewer than REBOUND_SAMPLES samples."""
REBOUND_SAMPLES = 6
"""Samples the rebound velocity's quadratic fit needs (at 60 Hz, 0.09 s held five)."""


def _before_bounce(rp, params, config):
    """The filter over a finished track's samples before its located bounce on the robot's
    half, with ``config``'s (generic) prior, so that what the data say is read against that
    prior whatever the track was replayed with; and the time of the model's contact from
    there: ``(TrackFilter, t_contact)``, or None (no such bounce, fewer than 5 updates, a ball
    not coming toward the robot, or a predicted contact more than 30 ms from the located one
    or on the other half)."""
    if rp.robot_bounce is None:
        return None
    tb = rp.robot_bounce.t
    tf = TrackFilter(params, config)
    for ti, pi in zip(rp.t, rp.p, strict=True):
        if ti >= tb - 0.004:
            break
        tf.add(ti, pi)
    if not tf.running or tf.updates < 5 or tf.filter.x[3] >= 0.0:
        return None
    bf = BallFilter(params, config)
    bf.x, bf.P, bf.t = tf.filter.x, tf.filter.P, tf.filter.t
    bf.predict(bf.t + 0.25)
    if bf.last_bounce is None or bf.last_bounce[1] >= 0.0 or abs(bf.last_bounce[0] - tb) > 0.03:
        return None
    return tf, bf.last_bounce[0]


def _flight_fit(t, p, tb, config):
    """Quadratic in time (about ``tb``) through the samples (t, p): ``(A, coef, excess)``,
    ``excess`` (n,) each sample's residual over its bound (4 sigma + 2 mm: sigma
    position_noise across the fitted velocity and, along it, with stamp_noise at the fitted
    speed too), the largest of the two, > 0 where the sample is off the flight."""
    dt = t - tb
    A = np.stack([np.ones_like(dt), dt, dt * dt], axis=1)
    coef, *_ = np.linalg.lstsq(A, p, rcond=None)
    residual = p - A @ coef
    speed = float(np.linalg.norm(coef[1]))
    heading = coef[1] / speed if speed > 0.0 else np.zeros(3)
    along = residual @ heading
    across = np.linalg.norm(residual - np.outer(along, heading), axis=1)
    sigma_along = math.hypot(config.position_noise, config.stamp_noise * speed)
    excess = np.maximum(np.abs(along) - (4.0 * sigma_along + 2e-3),
                        across - (4.0 * config.position_noise + 2e-3))
    return A, coef, excess


def _rebound_velocity(rp, config):
    """The velocity just after a finished track's located bounce on the robot's half,
    measured apart from any filter: a quadratic fit in time to the samples
    :data:`POST_BOUNCE_WINDOW` after it (:func:`_flight_fit`), at the bounce. A single
    sample off the flight while the others fit it is a spike and is left out; otherwise the
    window is shortened from its end until one flight explains it (a racket hit ends the
    flight). ``(v (3,), covariance (3, 3))`` (m/s, (m/s)^2), or None (fewer than
    REBOUND_SAMPLES samples)."""
    tb = rp.robot_bounce.t
    step = float(np.median(np.diff(rp.t))) if len(rp.t) > 1 else 0.0
    end = max(POST_BOUNCE_WINDOW[1], POST_BOUNCE_WINDOW[0] + (REBOUND_SAMPLES + 0.5) * step)
    sel = np.flatnonzero((rp.t > tb + POST_BOUNCE_WINDOW[0]) & (rp.t < tb + end))
    while True:
        if len(sel) < REBOUND_SAMPLES:
            return None
        A, coef, excess = _flight_fit(rp.t[sel], rp.p[sel], tb, config)
        if np.all(excess < 0.0):
            break
        spike = np.delete(sel, np.argmax(excess))
        if len(spike) >= REBOUND_SAMPLES:
            A_s, coef_s, excess_s = _flight_fit(rp.t[spike], rp.p[spike], tb, config)
            if np.all(excess_s < 0.0):
                A, coef = A_s, coef_s
                break
        sel = sel[:-2]
    return coef[1], float(np.linalg.inv(A.T @ A)[1, 1]) * config.sample_cov(coef[1])


def bounce_reading(rp, params, config):
    """What a finished track shows at its located bounce on the robot's half, read once for
    :func:`bounce_spin_observation` and :func:`lift_observation`: ``(filter, start
    velocity, rebound velocity, its covariance)``, the filter (a BallFilter,
    ``config``'s prior) taken over the samples before the bounce (:func:`_before_bounce`)
    and on to the model's contact, the start velocity the axes of its spin prior, the
    rebound velocity :func:`_rebound_velocity`'s; or None where either is None."""
    before = _before_bounce(rp, params, config)
    rebound = _rebound_velocity(rp, config) if before is not None else None
    if rebound is None:
        return None
    tf, tc = before
    bf = BallFilter(params, config)
    bf.x, bf.P, bf.t = tf.filter.x, tf.filter.P, tf.filter.t
    bf.predict(tc, contact_z=-math.inf)         # the same flight, up to the contact only
    return bf, tf.filter.start_velocity, rebound[0], rebound[1]


def bounce_spin_observation(rp, params, config, reading=None):
    """Per-axis measurement of a finished track's pre-bounce spin: ``(y (3,), s2 (3,))`` in
    the velocity frame (top/back, side, along v; rad/s, (rad/s)^2), or None.

    A filter with ``config``'s prior over the samples before the located robot-half bounce;
    its state is taken to
    the model's contact (eq. 8) and through the rebound's linear map S (eqs. 1-6, Jacobian
    and saltation, :func:`tt_prediction.ball_filter.rebound_map`). The rebound velocity is
    measured independently of the filter (:func:`_rebound_velocity`). Conditioning the
    joint Gaussian of (pre-bounce spin, rebound velocity) on it gives the spin's posterior
    given the whole track: flight's curvature for the spin across v, eqs. 1-2's change of
    tangential velocity (r w x n) for the spin along v. The track's prior is divided out
    (:func:`tt_prediction.ball_filter.spin_likelihood_per_axis`). ``reading``: the
    track's :func:`bounce_reading`, when made already.
    """
    reading = reading or bounce_reading(rp, params, config)
    if reading is None:
        return None
    bf, v0, _, _ = reading        # v0: the prior's axes (the filter's start velocity)
    xc, Sv, d, A = _rebound_innovation(reading, params)
    Cwv = bf.P[6:] @ Sv.T
    K = Cwv @ np.linalg.inv(A + np.eye(3) * config.bounce_velocity_noise ** 2)
    m = xc[6:] + K @ d
    C = bf.P[6:, 6:] - K @ Cwv.T
    return spin_likelihood_per_axis(m, C, bf.spin_prior_cov(v0), v0, bf.spin_prior_mean(v0))


def _rebound_innovation(reading, params):
    """The model's rebound (eqs. 1-6) of a :func:`bounce_reading`'s filter at the contact
    against the measured rebound velocity: ``(xc, Sv, d, A)``, the contact state (9,), the
    rebound's linear map onto the velocity after it (3, 9), the measured minus the
    predicted velocity after it (3,) (m/s) and that difference's covariance without the
    rebound's own noise (3, 3): the filter's, mapped, plus the measurement's."""
    bf, _, v_meas, var_fit = reading
    xc = bf.x.copy()
    xc[2] = params.radius
    x_out, S = rebound_map(xc, bf.P_model)
    Sv = S[3:6]
    return xc, Sv, v_meas - x_out[3:6], Sv @ bf.P @ Sv.T + var_fit


def rebound_noise_observation(rp, params, config):
    """What a finished track's bounce on the robot's half says of the rebound's own noise
    (``bounce_velocity_noise``): ``(d (3,), A (3, 3))`` of :func:`_rebound_innovation` for
    the filter ``config`` (the one the track was replayed with) over the samples before it,
    or None (no bounce read, :func:`bounce_reading`)."""
    reading = bounce_reading(rp, params, config)
    return None if reading is None else _rebound_innovation(reading, params)[2:]


SPIN_RATIO_RANGE = (0.4, 2.5)
"""The spin the tracks' flights and bounces show, over the spin index.csv gives, outside this
range is warned of: a Magnus coefficient off by half reads the spin within it; rev/s read as
rad/s is 2 pi, a frame turned about z is negative."""


def given_spin_warning(replays, spins, params, config, index='index.csv', min_tracks=5):
    """One line when the spins ``index`` (a path) gives (``spins``: per replay, (3,) rad/s in
    the table frame, or None) disagree in scale or sign with what the tracks' own flights and
    bounces show (:func:`bounce_spin_observation`, ``config``'s prior: never the given spin),
    else ''.

    On the axes across the velocity (top/back, side), where flight's curvature measures the
    spin, the given spin g and the tracks' reading y (variance s^2) of every track with
    both give the weighted slope b = sum(y g / s^2) / sum(g^2 / s^2). Warned when at least
    ``min_tracks`` tracks take part and b is outside :data:`SPIN_RATIO_RANGE` by more than
    three of its standard errors.
    """
    num = den = 0.0
    used = 0
    for rp, given in zip(replays, spins, strict=True):
        if given is None:
            continue
        reading = bounce_reading(rp, params, config)
        if reading is None:
            continue
        y, s2 = bounce_spin_observation(rp, params, config, reading)
        across = velocity_frame(reading[1]) @ np.asarray(given, dtype=float)
        ok = [k for k in (0, 1) if math.isfinite(s2[k]) and s2[k] > 0.0]
        if not ok:
            continue
        used += 1
        num += sum(y[k] * across[k] / s2[k] for k in ok)
        den += sum(across[k] ** 2 / s2[k] for k in ok)
    if used < min_tracks or den <= 0.0:
        return ''
    ratio, sd = num / den, 1.0 / math.sqrt(den)
    low, high = SPIN_RATIO_RANGE
    if low - 3.0 * sd <= ratio <= high + 3.0 * sd:
        return ''
    return (f"{index}: the tracks' flights and bounces show {ratio:.3g} times the spin it "
            f'gives ({used} tracks): is the spin in rad/s (rev/s read as rad/s: 6.28 times) '
            'and in the table frame (turned: negative)?')


# ----------------------------------------------------------------------------------------------
# What a finished track says about the table's restitution


MIN_IMPACT_SPEED = 0.5
"""A located bounce slower than this along the normal (m/s) says nothing of e_t."""


def restitution_observation(rp, params):
    """The table restitution e_t (eqs. 1-6) that explains a finished track's bounce on the
    robot's half, and its standard error: ``(e_t, sd)`` (sd None where the bounce has no
    fit errors), or None.

    Measured from the data alone: the located bounce's normal velocities (quadratic fits on
    each side of the contact, :func:`tt_prediction.identify.segment.locate_bounce`) give
    -v_z'/v_z, and their fits' standard errors its own. What ``params``' effects add to e_t
    at this bounce (impact speed, spin, place: eqs. 1-6 as
    :func:`tt_prediction.ball.table_rebound_inplace` has them, with the measured incoming
    velocity and the filter's last spin before the contact) is taken off, so the value is
    the model's e_t for this bounce.
    """
    b = rp.robot_bounce
    if b is None or b.v_in[2] > -MIN_IMPACT_SPEED or b.v_out[2] <= 0.0:
        return None
    before = np.flatnonzero(np.isfinite(rp.rows[:, 7]) & (rp.rows[:, 0] < b.t))
    spin = rp.rows[before[-1], 7:10] if len(before) else np.zeros(3)
    contact = np.concatenate([[b.p[0], b.p[1], params.radius], b.v_in, spin])
    out = contact.copy()
    table_rebound_inplace(out, params.packed())
    effects = -out[5] / contact[5] - params.e_t
    return float(b.restitution - effects), b.restitution_sd


def _weighted_median(values, weights):
    """The weighted median of ``values`` (n,) with ``weights`` (n,) > 0."""
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return values[order][np.searchsorted(cum, 0.5 * cum[-1])]


class PooledLearner:
    """A model coefficient (``field``) learned from finished tracks, one observation each.

    Each finished track adds the value its own data show and that value's standard error.
    The learned value weighs them by their precision with the model's own value as a prior
    of sd ``prior_sd``; a value more than ``reject`` standard deviations from the weighted
    median (a bounce fitted across a racket hit or a table edge) is left out; the result is
    held to the field's declared range. ``spread``: the track-to-track scatter beyond the
    fits' errors, added to each one's variance; ``default_sd``: an observation's standard
    error where it has none.
    """

    field = None

    def __init__(self, generic, prior_sd, default_sd, spread, reject=3.0, bounds=None):
        self.generic = float(generic)
        self.prior_sd = float(prior_sd)
        self.default_sd = float(default_sd)
        self.spread = float(spread)
        self.reject = float(reject)
        self.bounds = FIELD[self.field].bounds if bounds is None else bounds
        self._e, self._var = [], []

    def observe(self, observation):
        """Add one track's ``(value, sd)`` (sd None: ``default_sd``), or None (none shown).
        A value or sd that is not a finite number (an sd below 0 included) says nothing."""
        if observation is None:
            return
        value, sd = observation
        sd = self.default_sd if sd is None else sd
        if math.isfinite(value) and math.isfinite(sd) and sd >= 0.0:
            self._e.append(float(value))
            self._var.append(max(sd * sd + self.spread ** 2, 1e-12))

    @property
    def count(self):
        """Tracks that informed the value."""
        return len(self._e)

    @property
    def value(self):
        """The learned value."""
        if not self._e:
            return self.generic
        e = np.array(self._e + [self.generic])
        w = 1.0 / np.array(self._var + [self.prior_sd ** 2])
        centre = _weighted_median(e, w)
        keep = np.abs(e - centre) <= self.reject / np.sqrt(w)
        keep[-1] = True                                            # the prior
        value = float(np.sum(w[keep] * e[keep]) / np.sum(w[keep]))
        return min(max(value, self.bounds[0]), self.bounds[1])

    def params(self, base):
        """``base`` (ModelParams) with the learned value."""
        return base.replace(**{self.field: self.value})


class RestitutionLearner(PooledLearner):
    """The table's restitution e_t learned from finished tracks' bounces
    (:func:`restitution_observation`; :class:`PooledLearner`).

    Tables and balls differ (the ITTF's table test asks for a bounce of about 23 cm from
    30 cm, e ~ 0.88; the MPI sets' bounces show 0.94), and 0.03 less of it moves the median
    hit error at a 300 ms lead from 23 to 40 mm (measured on mpi_launcher). The model's own
    e_t is the prior, of sd ``prior_sd`` (the tables' spread): a bounce at 100 Hz with 2 mm
    noise measures e_t to about 0.1, at 500 Hz to 0.03, and a few of the former must not
    move it far.
    """

    field = 'e_t'

    def __init__(self, generic, prior_sd=0.03, default_sd=0.05, spread=0.01, reject=3.0,
                 bounds=None):
        super().__init__(generic, prior_sd, default_sd, spread, reject, bounds)


# ----------------------------------------------------------------------------------------------
# What a finished track says about the Magnus coefficient


MIN_SPIN_SIGNIFICANCE = 3.0
"""The flight's and the bounce's top/back spin must each be this many standard errors from 0
for their ratio to say anything of C_M."""
GRIP_MARGIN = 0.5
"""A bounce is taken to grip where its change of tangential velocity is below this fraction
of the sliding one with the model's mu, as a table's mu may be well below the model's 0.25:
mpi_pam's sliding bounces change by 0.70-0.85 of it (its mu is about 0.2), mpi_launcher's by
0.78-1.17, and mpi_launcher's gripping ones by 0.03-0.35."""


def lift_observation(rp, params, config, reading=None):
    """The Magnus coefficient C_M (eq. 8) that a finished track's flight and bounce on the
    robot's half show together, and its standard error: ``(c_m, sd)``, or None.

    A flight's curvature shows only the product C_M w (eq. 8's k_M w x v): the filter over
    the samples before the bounce (``config``'s prior, :func:`_before_bounce`), taken to the
    model's contact, turns it into a spin with ``params``' C_M, and gives the incoming
    velocity v (v_h: its horizontal part, of the ball's centre). The bounce shows the spin
    itself where the ball grips the table: there eqs. 1-6 with alpha = 2/5 (1 +
    e_t_tangential) give v_h' = (1 - alpha) v_h + alpha r w x n, so
    r w x n = (v_h' - (1 - alpha) v_h) / alpha, with the rebound velocity v' measured apart
    from the filter (:func:`_rebound_velocity`). It grips where the change of horizontal
    velocity is below :data:`GRIP_MARGIN` of the sliding one, mu (1 + e) |v_z| (``params``'
    mu, without its effects; e = -v_z'/v_z), by 2 of its standard errors. Both spins are
    projected on the top/back axis n x v_h / |v_h|, the one component both see; where both
    are significant (:data:`MIN_SPIN_SIGNIFICANCE`) and of one sign,
    C_M = params' C_M x flight / bounce. Its standard error is taken at flight = bounce
    (the prior's C_M), so that it does not lean with the value: params' C_M
    hypot(sd_flight, sd_bounce) / |bounce|; the bounce's includes the rebound's own noise
    (``bounce_velocity_noise``), as :func:`bounce_spin_observation`'s does. A sliding bounce
    shows only the slip's direction, and a weak spin's curvature only noise: None then; so
    with the effect lift_spin_ratio on (C_M a line in the spin ratio, tt-identify's).
    ``reading``: the track's :func:`bounce_reading`, when made already.
    """
    if params.c_m_spin_ratio_slope != 0.0:
        return None
    reading = reading or bounce_reading(rp, params, config)
    if reading is None:
        return None
    bf, _, v_out, cov_out = reading
    v_in = bf.x[3:6]
    speed = math.hypot(v_in[0], v_in[1])
    if v_in[2] > -MIN_IMPACT_SPEED or v_out[2] <= 0.0 or speed < MIN_IMPACT_SPEED:
        return None
    along = v_in[:2] / speed
    axis = np.array([-along[1], along[0], 0.0])             # n x v_h: top/back spin
    var_in = float(along @ bf.P[3:5, 3:5] @ along)
    var_out = float(along @ cov_out[:2, :2] @ along)
    change_sd = math.sqrt(var_in + var_out)
    sliding = params.mu * (1.0 - v_out[2] / v_in[2]) * -v_in[2]
    if np.linalg.norm(v_out[:2] - v_in[:2]) > GRIP_MARGIN * sliding - 2.0 * change_sd:
        return None
    grip = 0.4 * (1.0 + params.e_t_tangential)
    radius = params.radius
    bounce = float((v_out[:2] - (1.0 - grip) * v_in[:2]) @ along) / (grip * radius)
    bounce_sd = math.sqrt(var_out + (1.0 - grip) ** 2 * var_in
                          + config.bounce_velocity_noise ** 2) / (grip * radius)
    flight = float(bf.x[6:9] @ axis)
    flight_sd = math.sqrt(float(axis @ bf.P[6:9, 6:9] @ axis))
    if (abs(flight) < MIN_SPIN_SIGNIFICANCE * flight_sd
            or abs(bounce) < MIN_SPIN_SIGNIFICANCE * bounce_sd or flight * bounce <= 0.0):
        return None
    return (params.c_m * flight / bounce,
            params.c_m * math.hypot(flight_sd, bounce_sd) / abs(bounce))


class LiftLearner(PooledLearner):
    """The Magnus coefficient C_M learned from finished tracks' flights and bounces
    (:func:`lift_observation`; :class:`PooledLearner`).

    The filter reads a spin from a flight's curvature through C_M, and the rebound turns
    that spin into the ball's new velocity (eqs. 1-6): a C_M too small reads too much spin,
    and a topspin ball that grips is predicted to leave the table too fast (mpi_launcher's
    long balls: 11-16 mm off at the plane 50-200 ms before the hit, their gripping bounces
    showing C_M = 0.10-0.17 against the nominal 0.069). The model's C_M is the prior, of sd
    ``prior_sd`` (lift coefficients measured on spinning balls spread that much).
    """

    field = 'c_m'

    def __init__(self, generic, prior_sd=0.03, default_sd=0.03, spread=0.01, reject=3.0,
                 bounds=None):
        super().__init__(generic, prior_sd, default_sd, spread, reject, bounds)


# ----------------------------------------------------------------------------------------------
# What a finished track's flight after its bounce says about gravity


GRAVITY_SETTLE = 0.04
"""Time after the located bounce on the robot's half at which the filter's state is flown on
by the model (:func:`gravity_observation`), s: the rebound's velocity is measured by then."""
GRAVITY_SPAN = 0.3
"""Longest stretch of the flight after that state that :func:`gravity_observation` reads, s."""
GRAVITY_MIN_SPAN = 0.1
"""Shortest such stretch that says anything, s (the curvature grows as its square)."""
GRAVITY_LEAST = 0.3
"""Least change of g, m/s^2 (3 %), that the tracks' weighted median must show before
:class:`GravityLearner` takes one: a smaller one is as likely the topspin a ball takes from
its bounce, which the model may give too little of (mpi_launcher's balls launched without
spin fall 0.11-0.25 m/s^2 faster after their bounce, its others 0.07), as the data's scale."""
GRAVITY_MIN_TRACKS = 10
"""Tracks that must show it first."""


def gravity_observation(rp, params):
    """The gravity g that a finished track's flight after its bounce on the robot's half
    shows, and its standard error: ``(g, sd)``, or None.

    The replayed filter's state :data:`GRAVITY_SETTLE` after the bounce (its rebound
    measured) is flown on by ``params``' model (eq. 8, no further bounce) over the samples
    up to :data:`GRAVITY_SPAN` later, before a second bounce and while the ball still comes
    toward the robot. The measured height minus the flown one is fitted with a + b T + c T^2
    (T the time flown): a and b take up the state's own error, and c = -dg / 2 is a steady
    vertical acceleration the model lacks. Where the data's vertical scale or clock is off,
    or the ball falls faster than the model's g for a reason the model does not name
    (tt-identify's ``gravity_or_scale``: mpi_pam's flights after their bounce fall about
    0.45 m/s^2 faster than the nominal model's), the flight to the hitting plane misses
    its height by dg T^2 / 2: 5 mm at 150 ms. Returns ``params``' g + dg; its standard error
    from the fit's residual.
    """
    b = rp.robot_bounce
    if b is None:
        return None
    rows = rp.rows
    after = np.flatnonzero((rows[:, 0] >= b.t + GRAVITY_SETTLE)
                           & np.all(np.isfinite(rows[:, 1:10]), axis=1))
    if not len(after):
        return None
    k = after[0]
    t0 = rows[k, 0]
    later = sorted(t for t, x in rp.bounce_times if x < 0.0 and t > b.t + 0.01)
    end = min(t0 + GRAVITY_SPAN, later[0] - 0.01 if later else math.inf)
    window = np.flatnonzero((rp.t > t0) & (rp.t <= end))
    if len(window):                      # up to where the ball stops coming toward the robot
        window = window[:int(np.argmin(rp.p[window, 0])) + 1]
    if len(window) < 10 or rp.t[window[-1]] - t0 < GRAVITY_MIN_SPAN:
        return None
    _, flown = rollout(rows[k, 1:10], params, t0=t0, t_max=rp.t[window[-1]] + 0.01,
                       stop_at_plane=False, stop_at_net=False, max_bounces=1,
                       sample_times=rp.t[window])
    dz = rp.p[window, 2] - flown[:, 2]
    ok = np.isfinite(dz)
    if ok.sum() < 10:
        return None
    T = rp.t[window][ok] - t0
    A = np.stack([np.ones_like(T), T, T * T], axis=1)
    coef, *_ = np.linalg.lstsq(A, dz[ok], rcond=None)
    dof = len(T) - 3
    sigma2 = float(np.sum((dz[ok] - A @ coef) ** 2)) / dof
    var_c = sigma2 * float(np.linalg.inv(A.T @ A)[2, 2])
    return params.gravity - 2.0 * float(coef[2]), 2.0 * math.sqrt(var_c)


class GravityLearner(PooledLearner):
    """The model's gravity learned from finished tracks' flights after their bounce
    (:func:`gravity_observation`; :class:`PooledLearner`).

    Gravity is known, but a recording's vertical scale or clock may not be, and a ball may
    fall faster than the model says for a reason it does not name: what the predictor needs
    is the ball's fall as the data show it. The model's g is the prior, of sd ``prior_sd``.
    """

    field = 'gravity'

    def __init__(self, generic, prior_sd=0.3, default_sd=0.3, spread=0.05, reject=3.0,
                 bounds=None):
        super().__init__(generic, prior_sd, default_sd, spread, reject, bounds)

    @property
    def value(self):
        """The learned g; the model's until :data:`GRAVITY_MIN_TRACKS` tracks show one
        whose weighted median differs from it by :data:`GRAVITY_LEAST` or more."""
        if self.count < GRAVITY_MIN_TRACKS:
            return self.generic
        centre = _weighted_median(np.array(self._e), 1.0 / np.array(self._var))
        return super().value if abs(centre - self.generic) >= GRAVITY_LEAST else self.generic


class BounceNoiseLearner:
    """The live filter's ``bounce_velocity_noise`` learned from finished tracks' rebounds
    (:func:`rebound_noise_observation`).

    At a bounce the filter adds q^2 I to the velocity's covariance for what eqs. 1-6 leave
    out (a table's and a ball's scatter, the model's error). Each finished track gives the
    difference d between the rebound velocity measured apart from the filter and the one the
    filter predicted from the samples before it, and that difference's covariance A without
    q; q maximises the likelihood of all of them, sum of log N(d; 0, A + q^2 I), within
    [``low``, ``high``] m/s. A track whose squared Mahalanobis distance under that q is over
    ``reject`` (chi-square(3)'s 99.9 % point) is left out and q fitted again, until the
    tracks kept no longer change (a bounce on a table edge or located wrongly; on mpi_pam
    with its model.yaml one such track held q at 0.09-0.32 m/s, where the others show
    0.03). The configured value (``generic``) holds until ``min_tracks`` tracks have shown a
    bounce. ``low``: a floor under what the data show, as a likelihood peaked at 0 (the
    filter's covariance before the bounce covering the rebound already) would make the
    filter take the rebound as exact. The readings that the spin prior and C_M are learned
    from keep the configured value (they read each track against one fixed prior).
    """

    def __init__(self, generic, low=0.03, high=1.0, min_tracks=5, reject=16.27):
        self.generic = float(generic)
        self.reject = float(reject)
        self.low, self.high = float(low), float(high)
        self.min_tracks = int(min_tracks)
        self._d, self._A = [], []
        self.value = self.generic

    @property
    def count(self):
        """Tracks that informed the value."""
        return len(self._d)

    def observe(self, observation):
        """Add one track's ``(d, A)``, or None (no bounce read). Not finite: left out."""
        if observation is None:
            return
        d, A = (np.asarray(v, dtype=float) for v in observation)
        if not (np.all(np.isfinite(d)) and np.all(np.isfinite(A))):
            return
        self._d.append(d)
        self._A.append(A)
        if self.count >= self.min_tracks:
            self.value = self._fit()

    def _fit(self):
        d, A = np.array(self._d), np.array(self._A)
        keep = np.ones(len(d), dtype=bool)
        for _ in range(10):
            best = minimize_scalar(
                lambda log_q, dk=d[keep], Ak=A[keep]: _rebound_neg_log_likelihood(
                    dk, Ak, math.exp(log_q)),
                method='bounded', bounds=(math.log(self.low), math.log(self.high)))
            q = min(max(math.exp(best.x), self.low), self.high)
            kept = _rebound_nis(d, A, q) <= self.reject
            if np.array_equal(kept, keep) or kept.sum() < self.min_tracks:
                break
            keep = kept
        return q


def _rebound_nis(d, A, q):
    """Squared Mahalanobis distances of rebound differences ``d`` (n, 3) under their
    covariances ``A`` (n, 3, 3) plus ``q``^2 I."""
    C = A + q * q * np.eye(3)
    return np.einsum('ni,ni->n', d, np.linalg.solve(C, d[..., None])[..., 0])


def _rebound_neg_log_likelihood(d, A, q):
    """Negative log-likelihood (without its constant) of rebound differences ``d`` (n, 3),
    each N(0, A + q^2 I)."""
    logdet = np.linalg.slogdet(A + q * q * np.eye(3))[1]
    return 0.5 * float(np.sum(_rebound_nis(d, A, q) + logdet))


class Learning:
    """What the replay learns from finished tracks, for the tracks after them: the spin prior
    (:class:`tt_prediction.ball_filter.SpinPriorLearner`, :func:`bounce_spin_observation`),
    ``accel_noise`` (:class:`tt_prediction.ball_filter.AccelNoiseLearner`),
    ``bounce_velocity_noise`` (:class:`BounceNoiseLearner`), the table's
    restitution e_t (:class:`RestitutionLearner`, :func:`restitution_observation`), the
    Magnus coefficient C_M (:class:`LiftLearner`, :func:`lift_observation`) and, unless
    ``gravity`` is false, the gravity the flights after their bounce show
    (:class:`GravityLearner`, :func:`gravity_observation`), each starting from ``config``'s
    (FilterConfig) and ``params``' (ModelParams) values."""

    def __init__(self, config, params, gravity=True):
        self.noise = AccelNoiseLearner(config.accel_noise)
        self.spin = SpinPriorLearner(generic=config.spin_prior_axes(),
                                     generic_mean=config.spin_prior_mean)
        self.restitution = RestitutionLearner(params.e_t)
        self.lift = LiftLearner(params.c_m)
        self.gravity = GravityLearner(params.gravity)
        self.learns_gravity = gravity
        self.bounce = BounceNoiseLearner(config.bounce_velocity_noise)

    def config(self, base):
        """``base`` (FilterConfig) with the learned spin prior, accel_noise and
        bounce_velocity_noise."""
        return dataclasses.replace(self.spin.config(base), accel_noise=self.noise.value,
                                   bounce_velocity_noise=self.bounce.value)

    def model(self, base):
        """``base`` (ModelParams) with the learned e_t, C_M and gravity."""
        return self.gravity.params(self.lift.params(self.restitution.params(base)))

    def observe(self, rp, model, base):
        """Learn from the finished replay ``rp``, run with ``model``; ``base``: the
        FilterConfig the tracks are configured with (its spin prior, not the learned one,
        reads the bounce)."""
        generic = dataclasses.replace(base, accel_noise=self.noise.value)   # rp's own
        self.bounce.observe(rebound_noise_observation(rp, model, self.config(base)))
        self.noise.observe(rp.nis)
        self.restitution.observe(restitution_observation(rp, model))
        if self.learns_gravity:
            self.gravity.observe(gravity_observation(rp, model))
        reading = bounce_reading(rp, model, generic)       # once for the two below
        if reading is not None:
            self.lift.observe(lift_observation(rp, model, generic, reading))
            obs = bounce_spin_observation(rp, model, generic, reading)
            if obs is not None:
                self.spin.observe(*obs)


# ----------------------------------------------------------------------------------------------
# The textbook reference


def textbook_hit(t, p, bounce_times, t_query, params, hit_plane_x, n=TEXTBOOK_SAMPLES):
    """Hit point (3,) of the textbook predictor at ``t_query``, or None.

    It refits a fresh flight state to the last ``n`` samples up to t_query that follow the
    last measured bounce before it (at least 5, else it keeps the samples before the bounce):
    least squares of the model's flight (eq. 8, spin included with a weak prior) to those
    positions, then the same :func:`predict` from the fitted state at the last sample.
    """
    upto = t <= t_query + 1e-12
    past = [tb for tb, _ in bounce_times if tb <= t_query]
    sel = upto.copy()
    bounced = False
    if past:
        post = upto & (t > past[-1])
        if post.sum() >= 5:
            sel, bounced = post, any(xb < 0.0 for tb, xb in bounce_times if tb <= t_query)
        else:
            sel = upto & (t < past[-1])
            bounced = any(xb < 0.0 for tb, xb in bounce_times if tb < past[-1]) if len(
                past) > 1 else False
    idx = np.flatnonzero(sel)[-n:]
    if len(idx) < 5:
        return None
    ts, ps = t[idx], p[idx]
    packed = params.packed()
    v0 = np.polyfit(ts - ts[-1], ps, 2)[1]
    x0 = np.concatenate([ps[-1], v0, np.zeros(3)])
    spin_scale = 100.0           # rad/s of spin per unit of the fitted variable (weak prior)

    def residual(q):
        s = np.concatenate([q[:6], q[6:] * spin_scale])
        # The state is fitted at the window's first sample (forward integration only).
        events, samples = rollout(s, packed, t0=ts[0], t_max=ts[-1] + 1e-9, sample_times=ts,
                                  stop_at_plane=False, stop_at_net=False, max_bounces=0)
        r = (samples[:, :3] - ps).ravel()
        r = np.where(np.isfinite(r), r, 1.0)
        return np.concatenate([r / 1e-3, q[6:] / 3.0])

    first = np.concatenate([ps[0], v0, np.zeros(3)])
    first[3:6] = np.polyfit(ts - ts[0], ps, 2)[1]
    try:
        sol = least_squares(residual, first, method='lm', max_nfev=200)
    except (ValueError, np.linalg.LinAlgError):
        return None
    s = np.concatenate([sol.x[:6], sol.x[6:] * spin_scale])
    _, end = rollout(s, packed, t0=ts[0], t_max=ts[-1] + 1e-9, sample_times=ts[-1:],
                     stop_at_plane=False, stop_at_net=False, max_bounces=0)
    state = end[0] if np.all(np.isfinite(end[0])) else x0
    pred = predict(state, packed, t0=ts[-1], hit_plane_x=hit_plane_x, bounced=bounced)
    return None if pred.hit is None else pred.hit.p


# ----------------------------------------------------------------------------------------------
# Lead-time errors


def _row_at(rows, t_query):
    """Index of the last row with t <= t_query, or None."""
    ok = np.flatnonzero(np.isfinite(rows[:, 0]) & (rows[:, 0] <= t_query + 1e-12))
    return int(ok[-1]) if len(ok) else None


def lead_time_errors(replays, params, hit_plane_x, leads_ms=LEADS_MS, textbook=True):
    """Hit-point errors at each lead time before every track's measured crossing.

    Returns ``{'filter': {lead: stats}, 'textbook': {lead: stats}}`` with stats = median_mm,
    p90_mm, mean_mm, count (tracks evaluated), missing (no prediction although the track had
    MIN_HISTORY of samples), too_short (less data than that: not counted),
    ``mean_offset_mm`` (the mean of predicted minus measured hit point across the table and
    up, [y, z]: a bias the distances hide) and ``errors_mm`` (track name -> [distance, y
    offset, z offset] of each track evaluated).
    """
    out = {'filter': {}, 'textbook': {}} if textbook else {'filter': {}}
    for lead in leads_ms:
        acc = {k: {'errors': {}, 'missing': [], 'too_short': 0} for k in out}
        for rp in replays:
            if rp.crossing is None:
                continue
            tc, pc = rp.crossing
            tq = tc - lead * 1e-3
            if not math.isfinite(rp.first_t) or tq - rp.first_t < MIN_HISTORY:
                for k in out:
                    acc[k]['too_short'] += 1
                continue
            i = _row_at(rp.rows, tq)
            hit = rp.rows[i, 14:17] if i is not None else np.full(3, np.nan)
            hits = {'filter': hit if np.all(np.isfinite(hit)) else None}
            if textbook:
                hits['textbook'] = textbook_hit(rp.t, rp.p, rp.bounce_times, tq, params,
                                                hit_plane_x)
            for k, h in hits.items():
                if h is None:
                    acc[k]['missing'].append(rp.name)
                else:
                    acc[k]['errors'][rp.name] = (h - pc) * 1e3
        for k, a in acc.items():
            offsets = np.array(list(a['errors'].values())).reshape(-1, 3)
            e = np.linalg.norm(offsets, axis=1)
            out[k][str(lead)] = {
                'median_mm': round(float(np.median(e)), 2) if len(e) else None,
                'p90_mm': round(float(np.percentile(e, 90)), 2) if len(e) else None,
                'mean_mm': round(float(np.mean(e)), 2) if len(e) else None,
                'mean_offset_mm': ([round(float(v), 2) for v in offsets[:, 1:].mean(axis=0)]
                                   if len(e) else None),
                'count': int(len(e)), 'missing': len(a['missing']),
                'missing_tracks': a['missing'][:20], 'too_short': a['too_short'],
                'errors_mm': {name: [round(float(dist), 2), round(float(d[1]), 2),
                                     round(float(d[2]), 2)]
                              for (name, d), dist in zip(a['errors'].items(), e, strict=True)},
            }
    return out


def replay_tracks(tracks, params, config=None, hit_plane_x=DEFAULT_HIT_PLANE_X,
                  leads_ms=LEADS_MS, textbook=True, learn=True, learning=None):
    """Replay every track and score it.

    ``tracks``: iterable of (name, t (n,), p (n, 3), spin (3,) or None) as measured, in the
    order a robot would have seen them. With ``learn`` each track is replayed with what the
    tracks before it taught (causal: never its own data; the config's and the model's values
    until enough was seen; :class:`Learning`): the spin prior, accel_noise, the table's
    restitution, the Magnus coefficient and gravity. ``learning``: the :class:`Learning` to
    use, which then holds what the whole set taught (None: a new one). The textbook
    reference keeps ``params``. Returns ``(replays, summary)``: the :class:`TrackReplay` list and a
    JSON-ready dict.
    """
    config = config or FilterConfig()
    if learn and learning is None:
        learning = Learning(config, params)
    elif not learn:
        learning = None
    replays = []
    for name, t, p, spin in tracks:
        cfg, model = config, params
        if learning is not None:
            cfg, model = learning.config(config), learning.model(params)
        rp = replay_track(name, t, p, model, cfg, hit_plane_x, spin)
        replays.append(rp)
        if learning is not None:
            learning.observe(rp, model, config)
    errors = lead_time_errors(replays, params, hit_plane_x, leads_ms, textbook)
    rng = np.random.default_rng(0)
    floor = np.concatenate([np.zeros(0)] + [
        crossing_noise(rp.t, rp.p, rp.bounce_times, hit_plane_x, config.position_noise,
                       config.stamp_noise, rng=rng, crossing=rp.crossing)
        for rp in replays if rp.crossing])
    summary = {
        'hit_plane_x': hit_plane_x,
        'leads_ms': list(leads_ms),
        'tracks': len(replays),
        'tracks_with_crossing': sum(rp.crossing is not None for rp in replays),
        'tracks_without_crossing': {rp.name: no_crossing_reason(rp, hit_plane_x)
                                    for rp in replays if rp.crossing is None},
        'samples': int(sum(len(rp.rows) for rp in replays)),
        'filter_config': dataclasses.asdict(config),
        'hit_error': errors['filter'],
        'reference_error': {
            'note': 'the error of the measured crossing itself (what a perfect predictor '
                    'scores): each track redrawn with position_noise and stamp_noise',
            'median_mm': round(float(np.median(floor)) * 1e3, 2) if len(floor) else None,
            'p90_mm': round(float(np.percentile(floor, 90)) * 1e3, 2) if len(floor) else None,
        },
    }
    if learning is not None:
        learner, noise = learning.spin, learning.noise
        restitution, lift = learning.restitution, learning.lift
        final_mean, final_sd = learner.moments()
        summary['spin_prior_learned'] = {
            'rule': 'causal: each track uses the prior learned from the tracks before it '
                    '(input order); axes top/back, side, along v; rad/s',
            'final': [round(float(v), 1) for v in final_sd],
            'final_mean': [round(float(v), 1) for v in final_mean],
            'accel_noise_final': round(noise.value, 4),
            'tracks_informing': learner.counts(),
            'per_track': {rp.name: [round(float(v), 1) for v in rp.spin_prior]
                          for rp in replays},
            'per_track_mean': {rp.name: [round(float(v), 1) for v in rp.spin_prior_mean]
                               for rp in replays},
        }
        summary['bounce_noise_learned'] = {
            'rule': 'causal: each track uses the bounce_velocity_noise that the rebounds '
                    'before it show (maximum likelihood of the measured against the predicted '
                    f'rebound velocity, at least {learning.bounce.low:g} m/s; the configured '
                    f'{config.bounce_velocity_noise:g} m/s until {learning.bounce.min_tracks} '
                    'bounces), m/s',
            'final': round(learning.bounce.value, 4),
            'tracks_informing': learning.bounce.count,
        }
        summary['restitution_learned'] = {
            'rule': 'causal: each track uses the e_t of the bounces before it, weighed by '
                    f"their precision with the model's e_t = {params.e_t} as a prior of sd "
                    f'{restitution.prior_sd}',
            'final': round(restitution.value, 4),
            'tracks_informing': restitution.count,
            'per_track': {rp.name: round(rp.e_t, 4) for rp in replays},
        }
        summary['lift_learned'] = {
            'rule': 'causal: each track uses the C_M of the flights and bounces before it '
                    'that show one (a grip and a spin significant in both), weighed by their '
                    f"precision with the model's c_m = {params.c_m} as a prior of sd "
                    f'{lift.prior_sd}',
            'final': round(lift.value, 4),
            'tracks_informing': lift.count,
            'per_track': {rp.name: round(rp.c_m, 4) for rp in replays},
        }
        gravity = learning.gravity
        summary['gravity_learned'] = {
            'rule': "causal: each track uses the g that the flights after the bounces before "
                    "it show (the filter's state flown on by the model against the measured "
                    "heights), weighed by their precision with the model's gravity = "
                    f'{params.gravity} as a prior of sd {gravity.prior_sd}, taken once '
                    f'{GRAVITY_MIN_TRACKS} tracks show one whose weighted median differs from '
                    f'it by {GRAVITY_LEAST} or more (a scale or clock of the data off), m/s^2',
            'final': round(gravity.value, 4),
            'pooled': round(PooledLearner.value.fget(gravity), 4),
            'tracks_informing': gravity.count,
            'per_track': {rp.name: round(rp.gravity, 4) for rp in replays},
        }
    summary['spin_outlier_taken'] = {
        'rule': "tracks whose filter took its second filter's state (spin_outlier_prior "
                "instead of the spin prior: the data put the ball's spin outside the "
                "population), with the time it first did, s",
        'tracks': {rp.name: round(rp.spin_outlier_t, 4) for rp in replays
                   if rp.spin_outlier_t is not None},
    }
    if textbook:
        summary['textbook_hit_error'] = errors['textbook']
    summary['rows_without_hit'] = rows_without_hit(replays)
    return replays, summary


def rows_without_hit(replays, history=MIN_HISTORY):
    """Rows without a predicted hit among those from ``history`` s after a track's first
    sample up to its measured crossing: ``{'rows': n checked, 'missing': k, 'tracks': [...]}``
    (the stricter form of "no missing prediction once a track has 50 ms of samples")."""
    checked, missing, names = 0, 0, []
    for rp in replays:
        if rp.crossing is None:
            continue
        t = rp.rows[:, 0]
        sel = np.isfinite(t) & (t >= rp.first_t + history) & (t < rp.crossing[0])
        bad = sel & ~np.isfinite(rp.rows[:, 14])
        checked += int(sel.sum())
        missing += int(bad.sum())
        if bad.any():
            names.append(rp.name)
    return {'rows': checked, 'missing': missing, 'tracks': names[:20]}

