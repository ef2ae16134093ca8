"""Segmentation of a measured track into free flights and table bounces.

Real tracks hold more than free flight and table bounces: outliers, gaps, a racket contact, a
ball that rolls or falls past the table's edge. Each is handled explicitly here and counted
in ``Track.notes``; what remains is a track that the model (flight + table rebounds) can
explain, with its bounces located from the data: the bounce time is where the parabolas
fitted to the samples before and after the contact meet, not the lowest sample.
"""

import dataclasses
import math

import numpy as np

from ..ball import HALF_LENGTH, HALF_WIDTH
from ..predict import MAX_SPEED
from .data import Track

OUTLIER_DISTANCE = 0.02
"""A sample farther than this from the time-interpolated midpoint of its neighbours is an
outlier, m (noise is ~2 mm; a racket hit bends the path by < 1.5 cm at 150 Hz). A table
contact bends it by up to (|vz_in| + vz_out) dt / 2, 3 cm at 100 Hz: a sample below both
neighbours, near the table but not under it (CONTACT_BELOW), within OUTLIER_DISTANCE
sideways and without a gap on either side (GAP_FACTOR), is a bounce, not an outlier."""
SPIKE_SIGMAS = 5.0
SPIKE_FLOOR = 0.005
"""A sample nearer its neighbours than OUTLIER_DISTANCE is still a spike when the quadratic
through its four neighbours and the flights from the two samples on either side (gravity
included) all miss it by more than SPIKE_SIGMAS standard deviations of those predictions
on an axis, and by SPIKE_FLOOR (m); the noise per axis is the track's own (the median
offset from the neighbours' midpoints, less gravity's). A racket hit or a bounce leaves the
sample on one side's flight; a spike is off both (1-2 cm spikes were kept in the flights
tt-identify fits and in the crossing the replay scores against). Not within BOUNCE_HEIGHT
of the table, where a real contact is off both flights."""
CONTACT_BELOW = 0.01
"""A contact sample is at most this far below the contact height z = r (noise), m."""
GAP_FACTOR = 2.5
GAP_MIN = 0.015
"""Samples further apart than GAP_FACTOR typical intervals (the median) and GAP_MIN (s: a
500 Hz track missing two samples at the contact is still located) have a gap between them:
no contact is taken across it (a 40 ms gap at a 180 Hz bounce gave e_t 1.65)."""
MAX_RESTITUTION = 1.0
"""A located bounce that gives back more than this of its normal speed, by over three of its
own standard errors, is no bounce (a spike or a gap at the contact): unresolved."""
JUMP_SPEED = MAX_SPEED
JUMP_MIN = 0.1
"""A step between two samples longer than JUMP_SPEED (m/s; a state's largest speed, 40 m/s,
faster than any ball) times its interval and than JUMP_MIN (m) is another ball (two flights
written into one file, a tracker that switched balls): the track ends before it."""
MAX_GAP = 0.15
"""A gap in the samples longer than this ends the track, s."""
BOUNCE_HEIGHT = 0.05
"""A bounce is a minimum of z lower than this above the contact height (ball centre), m."""
CONTACT_WINDOW = 0.06
"""Samples within this time of a contact are used to fit the flight on each side, s (at
least CONTACT_SAMPLES sample intervals)."""
CONTACT_SAMPLES = 4.5
"""Sample intervals (the median around the contact) the contact window spans at least: four
samples a side, as a quadratic fit and its residual need (at 60 Hz, 0.06 s held three)."""
SPLIT_WINDOW = 0.01
"""The contact is looked for between samples within this time of the lowest one, s (at
500 Hz noise can put a sample just after the contact lower than the one before it)."""
GRAVITY = 9.81
"""m/s^2: a ball leaving the table at vz cannot touch it again before about 2 vz / g (half
of it is waited for: a lower bound, which a set's own g within 5 % does not move)."""
HIT_WINDOW = 0.033
"""The velocities compared at each sample for a contact away from the table are fitted over
this time on either side, s (3 to 6 samples)."""
HIT_TURN = 0.5
"""A contact away from the table (racket, net, hand) turns the velocity: the cosine between
the velocities fitted before and after it falls below this."""
HIT_CHANGE = 1.0
"""... and changes it, beyond what gravity does between the fits (g times their spacing, 0.33
m/s at 150 Hz, 1 m/s at 30 Hz), by more than this, m/s, and three times the noise of that
change (from the track's own position noise): gravity turns a slow ball at its apex as
much (a toss straight up turns by 180 degrees; a review's tosses lost all but their first
20-50 ms as 'after racket contact', 7 Dec 2026); a stroke changes it by metres a second."""
ROLL_DURATION = 0.05
"""Longer than this within ROLL_HEIGHT of the contact height is rolling, s (a rebound at
ROLL_SPEED spends ~0.08 s there, one at 1 m/s ~0.024 s)."""
ROLL_HEIGHT = 0.012
"""Height band above the contact height in which a ball is taken to roll, m."""
ROLL_SPEED = 0.3
"""A located bounce with a smaller normal speed after contact is no rebound, m/s."""
MIN_DURATION = 0.2
"""Tracks shorter than this after cutting are dropped, s."""
REST_RADIUS = 0.01
REST_DURATION = 0.15
"""A track that starts with the ball held still (in a launcher, on a hand or a tee) starts
with samples within REST_RADIUS (m) of where it starts for longer than REST_DURATION (s):
no free flight does that (through its apex a ball stays within a band 2 cm high, 1 cm either
side of a point, for at most 2 sqrt(2 (0.02 m) / g) = 128 ms; 0.1 s cut up to 133 ms of a
toss in a review, 7 Dec 2026). They are left out, and the first sample after them (the
launch)."""


@dataclasses.dataclass
class Bounce:
    """A table bounce located in the data: time (s), contact point (3,), velocities (3,),
    and the standard errors of the normal velocities v_in[2], v_out[2] from their fits'
    residuals (m/s; None where not known)."""

    t: float
    p: np.ndarray
    v_in: np.ndarray
    v_out: np.ndarray
    vz_sd: tuple = None

    @property
    def restitution(self):
        """-v_z' / v_z: the normal speed the bounce gives back."""
        return float(-self.v_out[2] / self.v_in[2])

    @property
    def restitution_sd(self):
        """Standard error of :attr:`restitution` from ``vz_sd``, taken as if it were 1 (a
        weight by the measured ratio would count high values less than low ones); None
        where ``vz_sd`` is."""
        return None if self.vz_sd is None else math.hypot(*self.vz_sd) / -self.v_in[2]


def _count(notes, key, n=1):
    if n:
        notes[key] = notes.get(key, 0) + int(n)


def drop_outliers(t, p, notes, radius=0.02):
    """Remove samples far from the midpoint of their neighbours (interpolated in time); a
    sample below both neighbours near the table, off their midpoint along z only, is a
    bounce's contact and is kept (``radius``: the ball's, m). Then the spikes nearer than
    that but off the flights on both sides (:data:`SPIKE_SIGMAS`)."""
    keep = np.ones(len(t), dtype=bool)
    for _ in range(2):
        idx = np.flatnonzero(keep)
        if len(idx) < 3:
            break
        tt, pp = t[idx], p[idx]
        off = _midpoint_offsets(tt, pp)
        dist = np.linalg.norm(off, axis=1)
        z = pp[:, 2]
        step = np.diff(tt)
        no_gap = np.maximum(step[:-1], step[1:]) <= _gap_limit(step)
        contact = ((z[1:-1] < radius + BOUNCE_HEIGHT) & (z[1:-1] >= radius - CONTACT_BELOW)
                   & (z[1:-1] < z[:-2]) & (z[1:-1] < z[2:]) & no_gap
                   & (np.hypot(off[:, 0], off[:, 1]) <= OUTLIER_DISTANCE))
        # A sample beside a gap is not judged by a midpoint across it (mpi_launcher's tracks
        # lose 40-55 ms at some bounces: the samples beside were dropped as outliers).
        bad = np.flatnonzero((dist > OUTLIER_DISTANCE) & ~contact & no_gap) + 1
        # An outlier also displaces its neighbours' midpoints: drop only the local worst.
        worst = [i for i in bad if dist[i - 1] >= max(dist[max(i - 2, 0)],
                                                      dist[min(i, len(dist) - 1)])]
        if not worst:
            break
        keep[idx[worst]] = False
    idx = np.flatnonzero(keep)
    keep[idx[_spikes(t[idx], p[idx], radius)]] = False
    _count(notes, 'outlier_samples', (~keep).sum())
    return t[keep], p[keep]


def _midpoint_offsets(t, p):
    """Offsets (n - 2, 3) of the inner samples from the time-interpolated midpoint of their
    neighbours, m."""
    w = ((t[1:-1] - t[:-2]) / (t[2:] - t[:-2]))[:, None]
    return p[1:-1] - (1.0 - w) * p[:-2] - w * p[2:]


def _noise(t, p):
    """The track's position noise per axis (3,), m: from each sample's offset from its
    neighbours' midpoint, less gravity's (a chord under the parabola by g d1 d2 / 2: 1.4 mm
    at 60 Hz), noise sqrt(1.5) sigma per axis; the median absolute of a normal is 0.6745 of
    its standard deviation."""
    g = np.array([0.0, 0.0, -GRAVITY])
    off = (_midpoint_offsets(t, p)
           + 0.5 * g * ((t[1:-1] - t[:-2]) * (t[2:] - t[1:-1]))[:, None])
    return np.median(np.abs(off), axis=0) / (0.6745 * math.sqrt(1.5))


def _spikes(t, p, radius):
    """Mask (n,) of the samples off the flights on both sides of them by far more than the
    track's noise (:data:`SPIKE_SIGMAS`); samples nearer the table than BOUNCE_HEIGHT above
    the contact height and the two at either end are never spikes."""
    n = len(t)
    bad = np.zeros(n, dtype=bool)
    if n < 10 or not np.all(np.diff(t) > 0.0):
        return bad
    g = np.array([0.0, 0.0, -GRAVITY])
    sigma = _noise(t, p)
    i = np.arange(2, n - 2)

    def flight(a, b):       # from samples a, b (constant acceleration g) to sample i
        d1, d2 = (t[b] - t[a])[:, None], (t[i] - t[b])[:, None]
        v = (p[b] - p[a]) / d1 + 0.5 * g * d1
        return p[b] + v * d2 + 0.5 * g * d2 * d2, 1.0 + d2 / d1     # (and its noise gain)

    left, gain_l = flight(i - 2, i - 1)
    right, gain_r = flight(i + 2, i + 1)
    # The quadratic in time through the four neighbours, at t_i (least squares).
    nb = np.stack([i - 2, i - 1, i + 1, i + 2], axis=1)
    dt = t[nb] - t[i][:, None]
    A = np.stack([np.ones_like(dt), dt, dt * dt], axis=2)
    coef = np.linalg.solve(np.einsum('kij,kil->kjl', A, A),
                           np.einsum('kij,kil->kjl', A, p[nb]))
    between = coef[:, 0]
    miss = np.abs(p[i][None] - np.stack([left, right, between]))      # (3, m, 3)
    # Standard deviation of each miss per unit noise: the sample's own, and the
    # prediction's (two-sample flights: gain^2 + (gain - 1)^2; the quadratic: below 1).
    spread = np.stack([np.sqrt(1.0 + gain_l ** 2 + (gain_l - 1.0) ** 2),
                       np.sqrt(1.0 + gain_r ** 2 + (gain_r - 1.0) ** 2),
                       np.full_like(gain_l, math.sqrt(2.0))])          # (3, m, 1)
    limit = np.maximum(SPIKE_SIGMAS * spread * sigma, SPIKE_FLOOR)
    missed = np.all(np.any(miss > limit, axis=2), axis=0)
    high = np.minimum(np.min(p[nb, 2], axis=1), p[i, 2]) >= radius + BOUNCE_HEIGHT
    bad[i] = missed & high
    return bad


def _poly_fit(t, y, deg):
    """Least-squares polynomial coefficients (highest first), or None if too few points."""
    if len(t) < deg + 2:
        return None
    return np.polyfit(t, y, deg)


def _side_fit(t, p, sel, t_ref):
    """Quadratic z, linear x, y fits of the samples ``sel`` around t_ref; (fits, sse)."""
    ts = t[sel] - t_ref
    fits = [_poly_fit(ts, p[sel, 0], 1), _poly_fit(ts, p[sel, 1], 1), _poly_fit(ts, p[sel, 2], 2)]
    if any(f is None for f in fits):
        return None, np.inf
    sse = sum(float(np.sum((np.polyval(f, ts) - p[sel, k]) ** 2)) for k, f in enumerate(fits))
    return fits, sse


def _gap_limit(steps):
    """The longest interval (s) between samples that is not a gap, given the intervals
    ``steps`` around (GAP_FACTOR of their median, GAP_MIN at least)."""
    return max(GAP_FACTOR * np.median(steps), GAP_MIN) if len(steps) else np.inf


def _slope_sds(t, p, sides, t_ref, fits_z, tb):
    """Standard errors of the quadratic z fits' slopes at tb (s from t_ref) on each side of
    a contact, m/s: their residual variance, pooled over both sides (a few samples per side
    at 100 Hz estimate it poorly), through (A^T A)^-1."""
    designs = [np.vander(t[sel] - t_ref, 3) for sel in sides]
    sse = sum(float(np.sum((a @ f - p[sel, 2]) ** 2))
              for a, f, sel in zip(designs, fits_z, sides, strict=True))
    var = sse / max(sum(len(a) for a in designs) - 6, 1)
    d = np.array([2.0 * tb, 1.0, 0.0])
    return tuple(math.sqrt(var * d @ np.linalg.pinv(a.T @ a) @ d) for a in designs)


def locate_bounce(t, p, i):
    """Bounce near the z-minimum sample i: the meeting point of the two flights, or None.

    The contact lies between two consecutive samples, one of them within SPLIT_WINDOW of
    sample i: the split whose two flights fit best (None with a gap there, GAP_FACTOR);
    the bounce time is the root of z_before(t) - z_after(t) between the last sample before
    and the first after contact.
    """
    t_ref = t[i]
    steps = np.diff(t[max(i - 5, 0):i + 6])
    reach = max(CONTACT_WINDOW, CONTACT_SAMPLES * float(np.median(steps))) if len(steps) \
        else CONTACT_WINDOW
    near = np.abs(t - t_ref) <= reach
    best = None
    window = np.flatnonzero(np.abs(t - t_ref) <= SPLIT_WINDOW + 1e-9)
    around = t[max(window[0] - 1, 0):window[-1] + 2]
    if len(around) > 1 and np.diff(around).max() > _gap_limit(np.diff(t[near])):
        return None                 # a gap at the contact: neither side's flight is whole
    for split in range(max(window[0], 1), min(window[-1] + 1, len(t) - 1) + 1):
        before = near & (np.arange(len(t)) < split)
        after = near & (np.arange(len(t)) >= split)
        fb, sb = _side_fit(t, p, before, t_ref)
        fa, sa = _side_fit(t, p, after, t_ref)
        if fb is None or fa is None:
            continue
        lo, hi = t[split - 1] - t_ref, t[split] - t_ref
        slack = 0.25 * (hi - lo)    # a contact within noise of a sample: either side of it
        roots = np.roots(fb[2] - fa[2])
        roots = roots[np.isreal(roots)].real
        roots = roots[(roots >= lo - slack) & (roots <= hi + slack)]
        if len(roots) == 0 or (best is not None and sb + sa >= best[0]):
            continue
        tb = float(roots[0])
        pos = np.array([0.5 * (np.polyval(fb[k], tb) + np.polyval(fa[k], tb)) for k in range(2)]
                       + [np.polyval(fb[2], tb)])
        v_in = np.array([fb[0][0], fb[1][0], 2 * fb[2][0] * tb + fb[2][1]])
        v_out = np.array([fa[0][0], fa[1][0], 2 * fa[2][0] * tb + fa[2][1]])
        if v_in[2] < 0.0 < v_out[2]:
            sd = _slope_sds(t, p, (before, after), t_ref, (fb[2], fa[2]), tb)
            best = (sb + sa, Bounce(t_ref + tb, pos, v_in, v_out, sd))
    return None if best is None else best[1]


def _turns(t, p, half=6):
    """Cosine between the velocities fitted (lines over ``half`` samples) before and after
    each sample, and the size of the change between them beyond gravity's (m/s); 1 and 0
    where there are too few samples. Line fits over several samples keep the time-stamp
    jitter of real trackers from looking like a contact."""
    n = len(t)
    cos, change = np.ones(n), np.zeros(n)
    g = np.array([0.0, 0.0, -GRAVITY])
    for i in range(half, n - half + 1):
        vb = np.polyfit(t[i - half:i], p[i - half:i], 1)[0]
        va = np.polyfit(t[i:i + half], p[i:i + half], 1)[0]
        cos[i] = vb @ va / max(np.linalg.norm(vb) * np.linalg.norm(va), 1e-9)
        # Less what gravity does between the windows' middles (1 m/s at 30 Hz, where a
        # window holds at least 3 samples: 100 ms).
        spacing = t[i:i + half].mean() - t[i - half:i].mean()
        change[i] = np.linalg.norm(va - vb - g * spacing)
    return cos, change


def _gains_speed(bounce):
    """Whether a located bounce returns more than MAX_RESTITUTION of its normal speed by over
    three of its standard errors (the fits' normal velocities, :class:`Bounce`)."""
    return bounce.restitution > MAX_RESTITUTION + 3.0 * bounce.restitution_sd


def _first_rolling(t, low):
    """Index of the first sample of the first run of ``low`` samples lasting over
    ROLL_DURATION, or None."""
    start = None
    for i, is_low in enumerate(low):
        if not is_low:
            start = None
        elif start is None:
            start = i
        elif t[i] - t[start] > ROLL_DURATION:
            return start
    return None


def _held_still(t, p):
    """How many samples a track starts with of a ball held still before its flight
    (:data:`REST_RADIUS`, :data:`REST_DURATION`), and the launch's after them; 0 when it
    does not start so."""
    if len(t) < 5:
        return 0
    away = np.linalg.norm(p - np.median(p[:5], axis=0), axis=1) > REST_RADIUS
    gone = np.flatnonzero(away[:-1] & away[1:])       # two in a row: not an outlier
    n = gone[0] if len(gone) else len(t)
    if n == 0 or t[n - 1] - t[0] <= REST_DURATION:
        return 0
    return min(n + 1, len(t))


def _first_flight_piece(t, gaps, min_duration):
    """Index range (first, end) of the first piece between gaps (``gaps``: the indices the
    gaps follow) long enough for a flight (8 samples over ``min_duration``): a tracker that
    loses the ball early in a track leaves a few samples before the gap; the first piece
    when none is."""
    bounds = np.concatenate([[0], gaps + 1, [len(t)]])
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        if b - a >= 8 and t[b - 1] - t[a] >= min_duration:
            return a, b
    return 0, bounds[1]


def _too_little(t, notes, notes_out):
    """Why a track is dropped (one line: what is left, and what each step removed), the
    step counts and the samples left (``samples_of_dropped_tracks``) added to ``notes_out``
    (a dict, or None)."""
    removed = {k: n for k, n in notes.items() if n}
    if notes_out is not None:
        for key, n in list(removed.items()) + [('samples_of_dropped_tracks', len(t))]:
            if n:
                notes_out[key] = notes_out.get(key, 0) + n
    steps = ', '.join(f'{k} {n}' for k, n in removed.items())
    return (f'{len(t)} samples over {np.ptp(t) if len(t) else 0.0:.3f} s left after cleaning'
            + (f' ({steps})' if steps else ''))


def segment(track, radius=0.02, notes_out=None, min_duration=MIN_DURATION):
    """A copy of ``track`` cut to what the model explains, and its bounces.

    Steps, each counted in the notes: a ball held still before its flight (REST_RADIUS);
    outliers; the first gap over MAX_GAP ends the track (one after too short a piece to fly
    in starts it), and so does the first jump (JUMP_SPEED) to another ball; a ball below
    the table surface ends it; a contact away from the table (racket, net: the velocity
    turns, cosine below HIT_TURN) ends it; an unresolved bounce or rolling ends it; so does
    a bounce located off the table's outline (the model's ball bounces only with its centre
    over the table: such a bounce is data in another frame, or an edge ball).
    Returns ``(track, bounces)`` or ``(None, reason)`` when too little is left (under eight
    samples, or a span under ``min_duration``, s); then the samples each step removed are
    added to the dict ``notes_out`` when given.
    """
    notes = dict(track.notes)
    # Before the outliers: noise at rest is not a flight's (a still ball measured without
    # noise made flight samples spikes).
    t, p = track.t, track.p
    still = _held_still(t, p)
    if still:
        _count(notes, 'samples_held_still', still)
        t, p = t[still:], p[still:]
    t, p = drop_outliers(t, p, notes, radius)
    gaps = np.flatnonzero(np.diff(t) > MAX_GAP)
    if len(gaps):
        first, end = _first_flight_piece(t, gaps, min_duration)
        _count(notes, 'samples_before_gap', first)
        _count(notes, 'samples_after_gap', len(t) - end)
        t, p = t[first:end], p[first:end]
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    jumps = np.flatnonzero(steps > np.maximum(JUMP_SPEED * np.diff(t), JUMP_MIN))
    if len(jumps):
        _count(notes, 'samples_after_jump', len(t) - jumps[0] - 1)
        t, p = t[:jumps[0] + 1], p[:jumps[0] + 1]
    below = np.flatnonzero(p[:, 2] < 0.0)
    if len(below):
        _count(notes, 'samples_below_table', len(t) - below[0])
        t, p = t[:below[0]], p[:below[0]]
    # Contacts away from the table: racket hits (direction reversal), net, hand.
    if len(t) > 12:
        # Line fits over HIT_WINDOW a side, 3 to 6 samples (6 from 180 Hz on; 6 at 45 Hz
        # reached 110-135 ms back from a racket contact and cut the flight there).
        step = float(np.median(np.diff(t)))
        half = int(np.clip(round(HIT_WINDOW / step), 3, 6)) if step > 0.0 else 6
        cos, change = _turns(t, p, half)
        # The change's noise: a line's slope over `half` samples `step` apart, before and
        # after, on each of three axes (500 Hz at 2 mm made 1 m/s of it at a toss's apex).
        spread = step * math.sqrt(half * (half * half - 1) / 12.0)     # sqrt(sum (t - mean)^2)
        noise = math.sqrt(2.0) * float(np.linalg.norm(_noise(t, p))) / max(spread, 1e-9)
        # Away from the table: no sample of either fitting window near the surface.
        z_low = np.array([p[max(i - half, 0):i + half, 2].min() for i in range(len(t))])
        hits = np.flatnonzero((cos < HIT_TURN) & (change > HIT_CHANGE + 3.0 * noise)
                              & (z_low > radius + BOUNCE_HEIGHT))
        if len(hits):
            # The contact is before the sharpest turn from there on (its first sample after
            # the contact, without noise); one more sample is left out as a margin for noise.
            end = hits[0] + int(np.argmin(cos[hits[0]:hits[0] + half + 1])) - 1
            _count(notes, 'samples_after_racket_contact', len(t) - end)
            t, p = t[:end], p[:end]
    if len(t) < 8:
        return None, _too_little(t, notes, notes_out)
    bounces = []
    z = p[:, 2]
    # A contact is the lowest sample within SPLIT_WINDOW; noise at high rates makes other
    # local minima beside it, and after a bounce the ball is away for about 2 vz_out / g.
    minima = [i for i in range(1, len(t) - 1)
              if z[i] <= z[i - 1] and z[i] < z[i + 1] and z[i] < radius + BOUNCE_HEIGHT
              and z[i] <= z[np.abs(t - t[i]) <= SPLIT_WINDOW].min()]
    end, why = len(t), 'samples_rolling'
    for i in minima:
        if bounces and t[i] < bounces[-1].t + bounces[-1].v_out[2] / GRAVITY:
            continue
        b = locate_bounce(t, p, i)
        if b is None or b.v_out[2] <= ROLL_SPEED or _gains_speed(b):
            # No clear rebound: too few samples after the contact, a ball that skids, or
            # more speed back than came in (a spike or a gap at the contact).
            end, why = i, 'samples_from_unresolved_bounce'
            break
        if abs(b.p[0]) > HALF_LENGTH or abs(b.p[1]) > HALF_WIDTH:
            # The model's ball would fall past the edge here: its fit would sit on the edge,
            # where the least change of the state switches the bounce on and off.
            end, why = i, 'samples_from_bounce_off_table'
            break
        bounces.append(b)
    rolling = _first_rolling(t, z < radius + ROLL_HEIGHT)
    if rolling is not None and rolling < end:
        end, why = rolling, 'samples_rolling'
    if end < len(t):
        _count(notes, why, len(t) - end)
        t, p = t[:end], p[:end]
        bounces = [b for b in bounces if b.t < t[-1]]
    if len(t) < 8 or t[-1] - t[0] < min_duration:
        return None, _too_little(t, notes, notes_out)
    out = Track(track.name, t, p, track.spin, track.label, notes, track.spin_source)
    return out, bounces
